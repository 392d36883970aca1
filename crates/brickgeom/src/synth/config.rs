//! Generator settings and their validation.

use crate::error::{BrickGeomError, Result};
use crate::library::library;
use crate::raster::RenderOptions;

/// Generator settings. Defaults resemble the paper's data (about 25 steps per manual).
#[derive(Debug, Clone, PartialEq)]
pub struct SynthConfig {
    /// Footprint side range of the bounding box, in studs.
    pub footprint: (i32, i32),
    /// Height range of the bounding box, in plates.
    pub height: (i32, i32),
    /// Range of the number of component instances the forward stage aims for.
    pub components: (usize, usize),
    /// Partition-and-fill rounds of the forward stage.
    pub rounds: usize,
    /// Probability that a component is a submodule.
    pub p_submodule: f64,
    /// Probability that a component is a stack/tiling of one primitive.
    pub p_stack: f64,
    /// Bricks per submodule.
    pub submodule_bricks: (usize, usize),
    pub max_step_instances: usize,
    pub max_step_types: usize,
    /// Minimum fraction of a component's pixels visible in its step image.
    pub visibility: f32,
    /// Camera elevation: centre and half range (degrees).
    pub elevation: (f64, f64),
    /// Camera azimuth: centre and half range (degrees). The default, 315 +- 10, is the
    /// front-left three-quarter view instruction tools use (the camera on LDraw's front, -z,
    /// which is the lattice's +z, and on its left, -x).
    pub azimuth: (f64, f64),
    /// Probability that a build is seen from the other front three-quarter view: its azimuth
    /// mirrored about the front (`360 - azimuth`, front-right for the default).
    pub p_mirror_view: f64,
    /// Fraction of the frame the shape fills: range.
    pub fill: (f64, f64),
    /// Image side in pixels.
    pub image_size: u32,
    /// Supersampling of the step images (1 or 3).
    pub supersample: u32,
    /// Part ids to draw from (default: all library parts).
    pub parts: Vec<&'static str>,
    /// LDraw colour codes to draw from.
    pub palette: Vec<i32>,
}

impl Default for SynthConfig {
    fn default() -> Self {
        SynthConfig {
            footprint: (4, 10),
            height: (6, 24),
            components: (40, 85),
            rounds: 3,
            p_submodule: 0.08,
            p_stack: 0.15,
            submodule_bricks: (2, 5),
            max_step_instances: 10,
            max_step_types: 5,
            visibility: 0.25,
            elevation: (27.5, 12.5),
            azimuth: (315.0, 10.0),
            p_mirror_view: 0.5,
            fill: (0.6, 0.9),
            image_size: 256,
            supersample: 1,
            parts: library().ids(),
            palette: vec![
                0, 1, 2, 4, 14, 15, 19, 25, 27, 28, 70, 71, 72, 272, 288, 320, 73, 5,
            ],
        }
    }
}

impl SynthConfig {
    /// Reject settings that cannot produce a manual.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(BrickGeomError::InvalidArgument(m));
        if self.footprint.0 < 2 || self.footprint.1 < self.footprint.0 || self.footprint.1 > 64 {
            return bad(format!(
                "footprint range {:?} must be within 2..=64 studs",
                self.footprint
            ));
        }
        if self.height.0 < 3 || self.height.1 < self.height.0 || self.height.1 > 200 {
            return bad(format!(
                "height range {:?} must be within 3..=200 plates",
                self.height
            ));
        }
        if self.components.0 < 1
            || self.components.1 < self.components.0
            || self.components.1 > 2000
        {
            return bad(format!(
                "components range {:?} must be within 1..=2000",
                self.components
            ));
        }
        if self.max_step_instances == 0 || self.max_step_types == 0 {
            return bad("steps must allow at least one instance and one type".into());
        }
        if self.parts.is_empty() || self.palette.is_empty() {
            return bad("the part list and the palette must not be empty".into());
        }
        for p in &self.parts {
            library().get(p)?;
        }
        if !(0.0..=1.0).contains(&self.visibility) {
            return bad(format!(
                "visibility must be in [0, 1], got {}",
                self.visibility
            ));
        }
        for (name, p) in [
            ("p_submodule", self.p_submodule),
            ("p_stack", self.p_stack),
            ("p_mirror_view", self.p_mirror_view),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return bad(format!("{name} must be a probability in [0, 1], got {p}"));
            }
        }
        for (name, (centre, half)) in [("elevation", self.elevation), ("azimuth", self.azimuth)] {
            if !centre.is_finite() || !half.is_finite() || half < 0.0 {
                return bad(format!(
                    "{name} must be (centre, half range) with a finite centre and half range >= 0, got ({centre}, {half})"
                ));
            }
        }
        if self.elevation.0.abs() + self.elevation.1 > 90.0 {
            return bad(format!(
                "elevation {:?} must stay within -90..90 degrees",
                self.elevation
            ));
        }
        let (lo, hi) = self.fill;
        let fill_ok = lo > 0.0 && lo <= hi && hi <= 1.0; // false for NaN too
        if !fill_ok {
            return bad(format!(
                "fill range {:?} must satisfy 0 < low <= high <= 1",
                self.fill
            ));
        }
        RenderOptions {
            supersample: self.supersample,
            ..RenderOptions::new(self.image_size, self.image_size)
        }
        .validate()
    }
}
