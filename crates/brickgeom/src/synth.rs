//! Synthetic manuals: the generator of the paper's supplementary ("Synthetic Dataset
//! Generation"), deterministic for a seed.
//!
//! Forward stage: sample a bounding box, then in a few rounds partition it into boxes and fill
//! each box, or grow its edges then fill it, with components placed by rejection sampling over
//! the valid (connected, collision-free) placements: single primitives, submodules (a few bricks
//! stacked in a small box, with their own manual) or several instances of one primitive stacked
//! or tiled. Backward stage: from the finished shape, repeatedly take away a chunk of removable
//! and visible components (<= 10 instances, <= 5 types); each chunk is a step, in reverse.

use std::collections::{BTreeSet, HashMap, HashSet};
use std::sync::Arc;

use crate::assembly::{Assembly, AttachKind, GroundSearch};
use crate::camera::Camera;
use crate::colours::ColourTable;
use crate::component::{cells_around, Brick, Component, MAIN_COLOUR};
use crate::error::{BrickGeomError, Result};
use crate::lattice::{pack, Pose};
use crate::library::library;
use crate::raster::RenderOptions;
use crate::scene::{render_assembly, MeshSource};

/// SplitMix64: small, fast, deterministic; plenty for sampling shapes.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator for a seed (and a stream, so sub-generators do not overlap).
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut r = Rng(seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        r.next_u64();
        r
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform integer in [lo, hi] (inclusive).
    pub fn range(&mut self, lo: i64, hi: i64) -> i64 {
        if hi <= lo {
            return lo;
        }
        lo + (self.next_u64() % (hi - lo + 1) as u64) as i64
    }
    /// Uniform index below n (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
    /// Uniform in [c - d, c + d].
    pub fn around(&mut self, c: f64, d: f64) -> f64 {
        c + d * (2.0 * self.f64() - 1.0)
    }
    /// Fisher-Yates shuffle.
    pub fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            let j = self.below(i + 1);
            v.swap(i, j);
        }
    }
}

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
    /// Camera azimuth: centre and half range (degrees).
    pub azimuth: (f64, f64),
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
            elevation: (30.0, 10.0),
            azimuth: (225.0, 10.0),
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
        RenderOptions {
            supersample: self.supersample,
            ..RenderOptions::new(self.image_size, self.image_size)
        }
        .validate()
    }
}

/// What an instance places.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ComponentRef {
    Part(&'static str),
    /// Index into `SynthManual::submodules`.
    Submodule(usize),
}

/// A placed component instance.
#[derive(Debug, Clone)]
pub struct PlacedInstance {
    pub cref: ComponentRef,
    pub component: Arc<Component>,
    pub pose: Pose,
    pub colour: i32,
}

/// One step: the instances it adds (indices into the build's instances), the attach kind of
/// each, and the camera of its image.
#[derive(Debug, Clone)]
pub struct SynthStep {
    pub instances: Vec<usize>,
    pub attach: Vec<AttachKind>,
    pub camera: Camera,
}

/// A shape with its manual: instances (ids = indices, in build order) and steps.
#[derive(Debug, Clone, Default)]
pub struct Build {
    pub instances: Vec<PlacedInstance>,
    pub steps: Vec<SynthStep>,
}

impl Build {
    /// The components and poses a step adds.
    pub fn step_items(&self, step: usize) -> Vec<(Arc<Component>, Pose)> {
        self.steps[step]
            .instances
            .iter()
            .map(|&i| (self.instances[i].component.clone(), self.instances[i].pose))
            .collect()
    }

    /// Every step checked against the shape of the steps before it (`Assembly::check_step`):
    /// per step, per instance, its attach kind or why it is invalid. Instances that cannot be
    /// added (overlapping real parts) stay out of later base shapes.
    pub fn step_checks(&self) -> Vec<Vec<Result<AttachKind>>> {
        let mut asm = Assembly::new();
        (0..self.steps.len())
            .map(|s| {
                let items = self.step_items(s);
                let res = asm.check_step(&items);
                for (c, p) in items {
                    let _ = asm.add(c, p);
                }
                res
            })
            .collect()
    }

    /// The finished shape.
    pub fn assembly(&self) -> Result<Assembly> {
        let mut asm = Assembly::new();
        for inst in &self.instances {
            let id = asm.add(inst.component.clone(), inst.pose)?;
            asm.set_colour(id, inst.colour)?;
        }
        Ok(asm)
    }
}

/// A submodule: its component (in its own frame) and its own manual.
#[derive(Debug, Clone)]
pub struct SynthSubmodule {
    pub name: String,
    pub component: Arc<Component>,
    pub build: Build,
}

/// A generated manual: the main build and its submodules.
#[derive(Debug, Clone)]
pub struct SynthManual {
    pub seed: u64,
    pub main: Build,
    pub submodules: Vec<SynthSubmodule>,
}

/// Inclusive lattice box in x/z (half-studs) with a height limit (plates).
#[derive(Debug, Clone, Copy)]
struct Region {
    x0: i32,
    x1: i32,
    z0: i32,
    z1: i32,
}

/// Forward-stage state for one build.
struct Forward<'a> {
    cfg: &'a SynthConfig,
    rng: Rng,
    asm: Assembly,
    instances: Vec<PlacedInstance>,
    /// Groups added together (a stack or tiling), removed together by the backward stage.
    units: Vec<Vec<usize>>,
    bbox: Region,
    height: i32,
    target: usize,
    submodules: Vec<SynthSubmodule>,
    /// May this build use submodules (not inside a submodule)?
    allow_submodules: bool,
    primitives: HashMap<&'static str, Arc<Component>>,
}

impl<'a> Forward<'a> {
    fn primitive(&mut self, id: &'static str) -> Arc<Component> {
        self.primitives
            .entry(id)
            .or_insert_with(|| {
                Arc::new(Component::primitive(id).expect("configured parts are library parts"))
            })
            .clone()
    }

    fn random_part(&mut self) -> &'static str {
        self.cfg.parts[self.rng.below(self.cfg.parts.len())]
    }

    fn random_colour(&mut self) -> i32 {
        self.cfg.palette[self.rng.below(self.cfg.palette.len())]
    }

    fn fits(&self, comp: &Component, pose: &Pose, region: &Region) -> bool {
        let inside =
            |x: i32, z: i32| x >= region.x0 && x <= region.x1 && z >= region.z0 && z <= region.z1;
        if !inside(pose.t[0], pose.t[2]) {
            return false;
        }
        comp.voxels.iter().all(|&v| {
            let w = pose.apply_cell(v);
            w[0] >= self.bbox.x0
                && w[0] <= self.bbox.x1
                && w[2] >= self.bbox.z0
                && w[2] <= self.bbox.z1
                && w[1] < self.height
        })
    }

    /// A valid placement of `comp` near `target` (x, z) with its origin in `region`.
    fn place(&mut self, comp: &Component, target: (i32, i32), region: &Region) -> Option<Pose> {
        let mut yaws = [0u8, 1, 2, 3];
        self.rng.shuffle(&mut yaws);
        let tries = 1 + self.rng.below(comp.symmetry.max(1) as usize).min(3);
        let ground = if self.asm.is_empty() || self.rng.f64() < 0.25 {
            GroundSearch::Region {
                x0: region.x0,
                x1: region.x1,
                z0: region.z0,
                z1: region.z1,
            }
        } else {
            GroundSearch::Off
        };
        let mut best: Option<(f64, Pose)> = None;
        for &yaw in yaws.iter().take(tries.max(2)) {
            let Ok(cands) = self.asm.candidates(comp, yaw, ground) else {
                continue;
            };
            for c in cands {
                if !self.fits(comp, &c.pose, region) {
                    continue;
                }
                let (dx, dz) = (
                    (c.pose.t[0] - target.0) as f64,
                    (c.pose.t[2] - target.1) as f64,
                );
                // prefer low placements a little, so shapes grow as solids rather than spires
                let score =
                    (dx * dx + dz * dz).sqrt() + 0.15 * c.pose.t[1] as f64 + 3.0 * self.rng.f64();
                if best.is_none_or(|(s, _)| score < s) {
                    best = Some((score, c.pose));
                }
            }
        }
        best.map(|(_, p)| p)
    }

    /// Add an instance if the shape stays connected to the ground under the strict connection
    /// graph (a new part must not block a connection made earlier); false otherwise.
    fn try_add(
        &mut self,
        cref: ComponentRef,
        comp: Arc<Component>,
        pose: Pose,
        colour: i32,
    ) -> Option<usize> {
        let id = self.add_instance(cref, comp, pose, colour);
        let (adj, ground) = connection_graph(&self.instances);
        let all: HashSet<usize> = (0..self.instances.len()).collect();
        if grounded(&all, &adj, &ground) {
            return Some(id);
        }
        self.instances.pop();
        self.asm.remove(id as u32).expect("just added");
        None
    }

    fn add_instance(
        &mut self,
        cref: ComponentRef,
        comp: Arc<Component>,
        pose: Pose,
        colour: i32,
    ) -> usize {
        let id = self
            .asm
            .add(comp.clone(), pose)
            .expect("placement was checked");
        self.asm.set_colour(id, colour).expect("instance exists");
        self.instances.push(PlacedInstance {
            cref,
            component: comp,
            pose,
            colour,
        });
        self.instances.len() - 1
    }

    /// Add one component (primitive, submodule or stack) near `target`; false on failure.
    fn add_component(&mut self, target: (i32, i32), region: &Region) -> bool {
        let u = self.rng.f64();
        if self.allow_submodules && u < self.cfg.p_submodule {
            return self.add_submodule(target, region);
        }
        let part = self.random_part();
        let comp = self.primitive(part);
        let Some(pose) = self.place(&comp, target, region) else {
            return false;
        };
        let colour = self.random_colour();
        let Some(first) = self.try_add(ComponentRef::Part(part), comp.clone(), pose, colour) else {
            return false;
        };
        let mut unit = vec![first];
        if u < self.cfg.p_submodule + self.cfg.p_stack {
            // several instances of one primitive: stacked up, or tiled side by side
            let n = self.rng.range(2, 4) as usize;
            let (lo, hi) =
                comp.voxels
                    .iter()
                    .fold(([i32::MAX; 3], [i32::MIN; 3]), |(lo, hi), v| {
                        (
                            [lo[0].min(v[0]), lo[1].min(v[1]), lo[2].min(v[2])],
                            [hi[0].max(v[0]), hi[1].max(v[1]), hi[2].max(v[2])],
                        )
                    });
            let rot = Pose::new(pose.yaw, [0, 0, 0]);
            let ext = rot.apply_point([hi[0] - lo[0] + 1, 0, hi[2] - lo[2] + 1]);
            let step = match self.rng.below(3) {
                0 => [0, hi[1] - lo[1] + 1, 0],
                1 => [ext[0].abs(), 0, 0],
                _ => [0, 0, ext[2].abs()],
            };
            let mut t = pose.t;
            for _ in 1..n {
                t = [t[0] + step[0], t[1] + step[1], t[2] + step[2]];
                let p = Pose::new(pose.yaw, t);
                if !self.fits(&comp, &p, &self.bbox.clone()) || self.asm.check(&comp, &p).is_err() {
                    break;
                }
                match self.try_add(ComponentRef::Part(part), comp.clone(), p, colour) {
                    Some(id) => unit.push(id),
                    None => break,
                }
            }
        }
        self.units.push(unit);
        true
    }

    /// Build a submodule in a small box, give it its own manual, and place it.
    fn add_submodule(&mut self, target: (i32, i32), region: &Region) -> bool {
        let seed = self.rng.next_u64();
        let Ok(sub) = generate_submodule(self.cfg, seed, self.submodules.len()) else {
            return false;
        };
        let comp = sub.component.clone();
        let Some(pose) = self.place(&comp, target, region) else {
            return false;
        };
        let index = self.submodules.len();
        self.submodules.push(sub);
        let Some(id) = self.try_add(ComponentRef::Submodule(index), comp, pose, MAIN_COLOUR) else {
            self.submodules.pop();
            return false;
        };
        self.units.push(vec![id]);
        true
    }

    fn random_point(&mut self, r: &Region) -> (i32, i32) {
        (
            self.rng.range(r.x0 as i64, r.x1 as i64) as i32,
            self.rng.range(r.z0 as i64, r.z1 as i64) as i32,
        )
    }

    fn fill(&mut self, r: &Region, attempts: usize) {
        let mut failures = 0;
        for _ in 0..attempts {
            if self.instances.len() >= self.target {
                return;
            }
            let p = self.random_point(r);
            if !self.add_component(p, r) {
                failures += 1;
                if failures > attempts / 2 + 2 {
                    return;
                }
            }
        }
    }

    /// Grow one or two edges of the box upwards, then fill it.
    fn grow_edges(&mut self, r: &Region) {
        let edges = 1 + self.rng.below(2);
        for _ in 0..edges {
            let strip = match self.rng.below(4) {
                0 => Region {
                    x1: (r.x0 + 2).min(r.x1),
                    ..*r
                },
                1 => Region {
                    x0: (r.x1 - 2).max(r.x0),
                    ..*r
                },
                2 => Region {
                    z1: (r.z0 + 2).min(r.z1),
                    ..*r
                },
                _ => Region {
                    z0: (r.z1 - 2).max(r.z0),
                    ..*r
                },
            };
            let n = self.rng.range(3, 8) as usize;
            self.fill(&strip, n);
        }
        let n = self.rng.range(2, 6) as usize;
        self.fill(r, n);
    }

    /// Random guillotine partition of the bounding box into up to four boxes (on the stud grid).
    fn partition(&mut self) -> Vec<Region> {
        let mut out = vec![self.bbox];
        for _ in 0..2 {
            let mut next = Vec::new();
            for r in out {
                let (w, d) = (r.x1 - r.x0 + 1, r.z1 - r.z0 + 1);
                if self.rng.f64() < 0.5 || (w < 4 && d < 4) {
                    next.push(r);
                    continue;
                }
                if w >= d {
                    let cut = r.x0 + 2 * self.rng.range(1, (w / 2 - 1).max(1) as i64) as i32;
                    next.push(Region { x1: cut - 1, ..r });
                    next.push(Region { x0: cut, ..r });
                } else {
                    let cut = r.z0 + 2 * self.rng.range(1, (d / 2 - 1).max(1) as i64) as i32;
                    next.push(Region { z1: cut - 1, ..r });
                    next.push(Region { z0: cut, ..r });
                }
            }
            out = next;
        }
        out
    }

    fn run(&mut self) {
        for _ in 0..self.cfg.rounds.max(1) {
            let mut boxes = self.partition();
            self.rng.shuffle(&mut boxes);
            for b in boxes {
                if self.instances.len() >= self.target {
                    return;
                }
                if self.rng.f64() < 0.5 {
                    let n = self.rng.range(4, 10) as usize;
                    self.fill(&b, n);
                } else {
                    self.grow_edges(&b);
                }
            }
        }
    }
}

/// A submodule: a few bricks stacked in a small box, with its own (backward-stage) manual.
fn generate_submodule(cfg: &SynthConfig, seed: u64, index: usize) -> Result<SynthSubmodule> {
    let mut rng = Rng::new(seed, 7);
    let (w, d) = (rng.range(2, 4) as i32, rng.range(2, 4) as i32);
    let sub_cfg = SynthConfig {
        components: cfg.submodule_bricks,
        ..cfg.clone()
    };
    let target = rng.range(cfg.submodule_bricks.0 as i64, cfg.submodule_bricks.1 as i64) as usize;
    let bbox = Region {
        x0: -w,
        x1: w - 1,
        z0: -d,
        z1: d - 1,
    };
    let mut fw = Forward {
        cfg: &sub_cfg,
        rng,
        asm: Assembly::new(),
        instances: Vec::new(),
        units: Vec::new(),
        bbox,
        height: rng_height(seed),
        target,
        submodules: Vec::new(),
        allow_submodules: false,
        primitives: HashMap::new(),
    };
    let mut failures = 0;
    while fw.instances.len() < target && failures < 12 {
        let p = fw.random_point(&bbox);
        // single primitives only: a stack inside a submodule would just be a taller submodule
        let part = fw.random_part();
        let comp = fw.primitive(part);
        match fw.place(&comp, p, &bbox) {
            Some(pose) => {
                let colour = fw.random_colour();
                match fw.try_add(ComponentRef::Part(part), comp, pose, colour) {
                    Some(id) => fw.units.push(vec![id]),
                    None => failures += 1,
                }
            }
            None => failures += 1,
        }
    }
    if fw.instances.len() < 2 {
        return Err(BrickGeomError::InvalidArgument(
            "submodule too small".into(),
        ));
    }
    let bricks: Vec<Brick> = fw
        .instances
        .iter()
        .map(|i| Brick {
            part: match i.cref {
                ComponentRef::Part(p) => p,
                ComponentRef::Submodule(_) => unreachable!("submodules hold primitives only"),
            },
            pose: i.pose,
            colour: i.colour,
        })
        .collect();
    let name = format!("submodule_{index}");
    let component = Arc::new(Component::from_bricks(name.clone(), bricks)?);
    let mut rng = Rng::new(seed, 11);
    let view = ViewSampler::new(cfg, &mut rng);
    let build = backward(cfg, &mut rng, &view, fw.instances, fw.units, true)?;
    Ok(SynthSubmodule {
        name,
        component,
        build,
    })
}

fn rng_height(seed: u64) -> i32 {
    Rng::new(seed, 13).range(4, 9) as i32
}

/// Camera orientation fixed per build, framing re-fitted per step.
struct ViewSampler {
    elevation: f64,
    azimuth: f64,
    fill: (f64, f64),
}

impl ViewSampler {
    fn new(cfg: &SynthConfig, rng: &mut Rng) -> Self {
        ViewSampler {
            elevation: rng.around(cfg.elevation.0, cfg.elevation.1),
            azimuth: rng.around(cfg.azimuth.0, cfg.azimuth.1),
            fill: cfg.fill,
        }
    }

    /// A camera for the current shape; `turn` degrees added to the azimuth (a manual turns
    /// the model around to show its back).
    fn camera(&self, rng: &mut Rng, asm: &Assembly, turn: f64) -> Result<Camera> {
        let base = Camera::new(self.elevation, self.azimuth + turn, 0.0, 1.0, [0.0, 0.0])?;
        let (lo, hi) = asm.bounds().unwrap_or(([0; 3], [0; 3]));
        let mut corners = Vec::with_capacity(8);
        for x in [lo[0], hi[0] + 1] {
            for y in [lo[1], hi[1] + 1] {
                for z in [lo[2], hi[2] + 1] {
                    corners.push([x as f64 * 10.0, y as f64 * 8.0, z as f64 * 10.0]);
                }
            }
        }
        let fill = self.fill.0 + (self.fill.1 - self.fill.0) * rng.f64();
        let mut cam = base.fitted(&corners, fill)?;
        let slack = 1.0 - fill;
        cam.translation[0] += rng.around(0.0, 0.8 * slack);
        cam.translation[1] += rng.around(0.0, 0.8 * slack);
        Ok(cam)
    }
}

/// Connection graph of a build's instances: an edge where an anti-stud of one sits on a stud of
/// another, kept only when no third instance occupies a cell around the connection point (on
/// either side). Such an edge is a valid connection whatever order the two and everything else
/// are added in, which is what the backward stage needs; it is exactly the assembly's rule when
/// the cells are empty or the two parts' own.
fn connection_graph(instances: &[PlacedInstance]) -> (Vec<Vec<usize>>, Vec<bool>) {
    let mut studs: HashMap<u64, Vec<usize>> = HashMap::new();
    let mut owner: HashMap<u64, usize> = HashMap::new();
    let mut placed = Vec::with_capacity(instances.len());
    for (i, inst) in instances.iter().enumerate() {
        let (v, s, a) = inst.component.placed(&inst.pose);
        for p in &s {
            studs.entry(pack(*p)).or_default().push(i);
        }
        for c in &v {
            owner.insert(pack(*c), i);
        }
        placed.push((v, a));
    }
    let clear = |p: crate::lattice::Lattice, layer: i32, a: usize, b: usize| {
        cells_around(p, layer)
            .iter()
            .all(|c| owner.get(&pack(*c)).is_none_or(|&o| o == a || o == b))
    };
    let mut adj: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); instances.len()];
    for (i, (_, anti)) in placed.iter().enumerate() {
        for a in anti {
            if let Some(js) = studs.get(&pack(*a)) {
                for &j in js {
                    if j != i && clear(*a, a[1], i, j) && clear(*a, a[1] - 1, i, j) {
                        adj[i].insert(j);
                        adj[j].insert(i);
                    }
                }
            }
        }
    }
    let ground = placed
        .iter()
        .map(|(v, _)| v.iter().map(|c| c[1]).min() == Some(0))
        .collect();
    (
        adj.into_iter().map(|s| s.into_iter().collect()).collect(),
        ground,
    )
}

/// Are all of `alive` reachable from the ground through edges among `alive`?
fn grounded(alive: &HashSet<usize>, adj: &[Vec<usize>], ground: &[bool]) -> bool {
    let mut seen: HashSet<usize> = alive.iter().copied().filter(|&i| ground[i]).collect();
    let mut stack: Vec<usize> = seen.iter().copied().collect();
    while let Some(i) = stack.pop() {
        for &j in &adj[i] {
            if alive.contains(&j) && seen.insert(j) {
                stack.push(j);
            }
        }
    }
    seen.len() == alive.len()
}

/// Can the units of `chunk` be taken away together: the rest stays connected to the ground,
/// and every member hangs on the rest (or the ground) through members?
fn removable_units(
    chunk: &[usize],
    units: &[Vec<usize>],
    alive: &HashSet<usize>,
    adj: &[Vec<usize>],
    ground: &[bool],
) -> bool {
    let members: HashSet<usize> = chunk
        .iter()
        .flat_map(|&u| units[u].iter().copied())
        .collect();
    let rest: HashSet<usize> = alive.difference(&members).copied().collect();
    if !grounded(&rest, adj, ground) {
        return false;
    }
    let mut ok: HashSet<usize> = rest;
    let mut changed = true;
    while changed {
        changed = false;
        for &m in &members {
            if !ok.contains(&m) && (ground[m] || adj[m].iter().any(|j| ok.contains(j))) {
                ok.insert(m);
                changed = true;
            }
        }
    }
    members.iter().all(|m| ok.contains(m))
}

/// Backward stage: steps from a finished shape. `units` are removed whole.
fn backward(
    cfg: &SynthConfig,
    rng: &mut Rng,
    view: &ViewSampler,
    instances: Vec<PlacedInstance>,
    mut units: Vec<Vec<usize>>,
    strict: bool,
) -> Result<Build> {
    let (adj, ground) = connection_graph(&instances);
    let build = Build {
        instances,
        steps: Vec::new(),
    };
    let mut asm = build.assembly()?;
    let mut alive: HashSet<usize> = (0..build.instances.len()).collect();
    let mut remaining: Vec<usize> = (0..units.len()).collect();
    let mut steps_rev: Vec<SynthStep> = Vec::new();
    let mut dropped: HashSet<usize> = HashSet::new();
    let colours = ColourTable::builtin();
    let source = MeshSource::builtin();
    // Visibility is measured at the size of the step images, so the recorded images agree
    // with the decision made here.
    let probe = RenderOptions {
        line_px: 0.0,
        ..RenderOptions::new(cfg.image_size, cfg.image_size)
    };
    let mut split = false;
    while !remaining.is_empty() {
        if std::mem::take(&mut split) {
            // Units added together can interleave with others (a tiling resting partly on a
            // later brick) so that no whole unit is removable: split them into single instances.
            let mut next = Vec::new();
            for &u in &remaining {
                for &m in &units[u].clone() {
                    units.push(vec![m]);
                    next.push(units.len() - 1);
                }
            }
            remaining = next;
        }
        // The usual view first; if it shows nothing removable, views turned by 90, 270 and
        // 180 degrees.
        let mut camera = view.camera(rng, &asm, 0.0)?;
        let mut vis = render_assembly(&asm, &camera, &probe, &colours, &source)?.visible_fraction();
        for turn in [90.0, 270.0, 180.0] {
            let shows_removable = remaining.iter().any(|&u| {
                units[u]
                    .iter()
                    .all(|&i| vis.get(i).copied().unwrap_or(0.0) >= cfg.visibility)
                    && removable_units(&[u], &units, &alive, &adj, &ground)
            });
            if shows_removable {
                break;
            }
            camera = view.camera(rng, &asm, turn)?;
            vis = render_assembly(&asm, &camera, &probe, &colours, &source)?.visible_fraction();
        }
        let unit_vis = |u: usize| -> f32 {
            units[u]
                .iter()
                .map(|&i| vis.get(i).copied().unwrap_or(0.0))
                .fold(1.0, f32::min)
        };
        let removable = |chunk: &[usize], alive: &HashSet<usize>| {
            removable_units(chunk, &units, alive, &adj, &ground)
        };
        let mut order = remaining.clone();
        rng.shuffle(&mut order);
        let mut cands: Vec<usize> = order
            .iter()
            .copied()
            .filter(|&u| unit_vis(u) >= cfg.visibility && removable(&[u], &alive))
            .collect();
        if cands.is_empty() {
            // Nothing is both removable and visible. Hidden removable units that nothing else
            // ever rested on (e.g. a tile under an overhang) are dropped from the shape: a manual
            // step that shows nothing new is useless. Otherwise take the most visible one.
            let hidden: Vec<usize> = order
                .iter()
                .copied()
                .filter(|&u| {
                    removable(&[u], &alive)
                        && units[u].iter().all(|&m| {
                            adj[m]
                                .iter()
                                .all(|j| alive.contains(j) || dropped.contains(j))
                        })
                })
                .collect();
            if let Some(&u) = hidden.first() {
                // one at a time: two hidden units may each be removable but not both
                for &m in &units[u] {
                    asm.remove(m as u32)?;
                    alive.remove(&m);
                    dropped.insert(m);
                }
                remaining.retain(|&r| r != u);
                continue;
            }
            if strict {
                return Err(BrickGeomError::InvalidArgument(format!(
                    "no removable component is visible with {} left",
                    remaining.len()
                )));
            }
            let mut best: Option<(f32, usize)> = None;
            for &u in &order {
                if removable(&[u], &alive) && best.is_none_or(|(v, _)| unit_vis(u) > v) {
                    best = Some((unit_vis(u), u));
                }
            }
            match best {
                Some((_, u)) => cands.push(u),
                None if remaining.iter().any(|&u| units[u].len() > 1) => {
                    split = true;
                    continue;
                }
                None => {
                    return Err(BrickGeomError::InvalidArgument(
                        "backward stage found nothing removable".into(),
                    ))
                }
            }
        }
        // Target chunk size: mostly small steps, sometimes larger ones, as in real manuals.
        let target = match rng.below(10) {
            0..=4 => 1,
            5..=7 => rng.range(2, 3) as usize,
            _ => rng.range(4, cfg.max_step_instances as i64) as usize,
        };
        let mut chunk: Vec<usize> = Vec::new();
        let mut count = 0;
        let mut types: BTreeSet<ComponentRef> = BTreeSet::new();
        for &u in &cands {
            if count >= target {
                break;
            }
            let n = units[u].len();
            let mut t2 = types.clone();
            t2.extend(units[u].iter().map(|&i| build.instances[i].cref));
            if count + n > cfg.max_step_instances || t2.len() > cfg.max_step_types {
                continue;
            }
            let mut trial = chunk.clone();
            trial.push(u);
            if removable(&trial, &alive) {
                chunk = trial;
                count += n;
                types = t2;
            }
        }
        if chunk.is_empty() {
            chunk.push(cands[0]);
        }
        let mut members: Vec<usize> = chunk
            .iter()
            .flat_map(|&u| units[u].iter().copied())
            .collect();
        members.sort_unstable();
        for &m in &members {
            asm.remove(m as u32)?;
            alive.remove(&m);
        }
        // attach kinds against the base shape of the step
        let items: Vec<(Arc<Component>, Pose)> = members
            .iter()
            .map(|&m| {
                (
                    build.instances[m].component.clone(),
                    build.instances[m].pose,
                )
            })
            .collect();
        let attach = asm
            .check_step(&items)
            .into_iter()
            .map(|r| r.unwrap_or(AttachKind::Ground))
            .collect();
        steps_rev.push(SynthStep {
            instances: members,
            attach,
            camera,
        });
        remaining.retain(|u| !chunk.contains(u));
    }
    steps_rev.reverse();
    // Compact away dropped instances, keeping build order.
    let mut new_index = vec![usize::MAX; build.instances.len()];
    let mut instances = Vec::with_capacity(build.instances.len() - dropped.len());
    for (i, inst) in build.instances.into_iter().enumerate() {
        if !dropped.contains(&i) {
            new_index[i] = instances.len();
            instances.push(inst);
        }
    }
    for step in &mut steps_rev {
        for i in &mut step.instances {
            *i = new_index[*i];
        }
    }
    Ok(Build {
        instances,
        steps: steps_rev,
    })
}

/// Generate one manual from a seed. Deterministic: the same seed and settings give the same
/// manual on any machine and with any number of threads.
pub fn generate(cfg: &SynthConfig, seed: u64) -> Result<SynthManual> {
    cfg.validate()?;
    // Rejection at the manual level: a shape that ends up too small is regenerated from the
    // next sub-seed (deterministically).
    const ATTEMPTS: u64 = 8;
    for attempt in 0..ATTEMPTS {
        let mut rng = Rng::new(seed, 1 + attempt);
        let w = rng.range(cfg.footprint.0 as i64, cfg.footprint.1 as i64) as i32;
        let d = rng.range(cfg.footprint.0 as i64, cfg.footprint.1 as i64) as i32;
        let height = rng.range(cfg.height.0 as i64, cfg.height.1 as i64) as i32;
        let target = rng.range(cfg.components.0 as i64, cfg.components.1 as i64) as usize;
        let mut fw = Forward {
            cfg,
            rng: rng.clone(),
            asm: Assembly::new(),
            instances: Vec::new(),
            units: Vec::new(),
            bbox: Region {
                x0: -w,
                x1: w - 1,
                z0: -d,
                z1: d - 1,
            },
            height,
            target,
            submodules: Vec::new(),
            allow_submodules: cfg.p_submodule > 0.0,
            primitives: HashMap::new(),
        };
        fw.run();
        if fw.instances.len() < cfg.components.0.min(8) {
            continue;
        }
        let mut rng = Rng::new(seed, 100 + attempt);
        let view = ViewSampler::new(cfg, &mut rng);
        let submodules = std::mem::take(&mut fw.submodules);
        // Every component must be visible in its step image; a shape where the backward stage
        // cannot manage that is regenerated (the last attempt accepts the least hidden one).
        let Ok(mut main) = backward(
            cfg,
            &mut rng,
            &view,
            fw.instances,
            fw.units,
            attempt + 1 < ATTEMPTS,
        ) else {
            continue;
        };
        // Submodules dropped with hidden units are not part of the manual.
        let mut used: Vec<Option<usize>> = vec![None; submodules.len()];
        let mut kept = Vec::new();
        for inst in &mut main.instances {
            if let ComponentRef::Submodule(k) = inst.cref {
                let new = *used[k].get_or_insert_with(|| {
                    kept.push(submodules[k].clone());
                    kept.len() - 1
                });
                inst.cref = ComponentRef::Submodule(new);
            }
        }
        for (k, sub) in kept.iter_mut().enumerate() {
            sub.name = format!("submodule_{k}");
        }
        return Ok(SynthManual {
            seed,
            main,
            submodules: kept,
        });
    }
    Err(BrickGeomError::InvalidArgument(format!(
        "seed {seed}: could not build a shape with these settings"
    )))
}

/// Per-instance annotations of a rendered step.
#[derive(Debug, Clone)]
pub struct InstanceView {
    /// Keypoints in pixels: the top-face centre of each topmost brick (one for a primitive).
    pub keypoints: Vec<[f64; 2]>,
    /// Visible-pixel box `[x0, y0, x1, y1]` (exclusive max); None when nothing is visible.
    pub bbox: Option<[u32; 4]>,
    pub visible_fraction: f32,
}

/// A rendered step image with its instance-id map and annotations of its new instances.
#[derive(Debug, Clone)]
pub struct StepImage {
    pub rgb: Vec<u8>,
    pub ids: Vec<i32>,
    pub width: u32,
    pub height: u32,
    pub instances: Vec<InstanceView>,
}

/// Render every step of a build (state after the step) with its camera.
pub fn render_build(
    build: &Build,
    cfg: &SynthConfig,
    source: &MeshSource,
    colours: &ColourTable,
) -> Result<Vec<StepImage>> {
    let opts = RenderOptions {
        supersample: cfg.supersample,
        ..RenderOptions::new(cfg.image_size, cfg.image_size)
    };
    let mut out = Vec::with_capacity(build.steps.len());
    let mut added = vec![false; build.instances.len()];
    for step in &build.steps {
        for &i in &step.instances {
            added[i] = true;
        }
        let r = render_ids_aligned(build, &added, &step.camera, &opts, colours, source)?;
        let (w, h) = (r.width, r.height);
        let frac = r.visible_fraction();
        let mut views = Vec::with_capacity(step.instances.len());
        for &i in &step.instances {
            let inst = &build.instances[i];
            let keypoints = project_keypoints(&inst.component, &inst.pose, &step.camera, w, h);
            let mut bbox: Option<[u32; 4]> = None;
            for y in 0..h {
                for x in 0..w {
                    if r.ids[(y * w + x) as usize] == i as i32 {
                        bbox = Some(match bbox {
                            None => [x, y, x + 1, y + 1],
                            Some(b) => [b[0].min(x), b[1].min(y), b[2].max(x + 1), b[3].max(y + 1)],
                        });
                    }
                }
            }
            views.push(InstanceView {
                keypoints,
                bbox,
                visible_fraction: frac.get(i).copied().unwrap_or(0.0),
            });
        }
        out.push(StepImage {
            rgb: r.rgb,
            ids: r.ids,
            width: w,
            height: h,
            instances: views,
        });
    }
    Ok(out)
}

/// Render the instances marked in `added`, with ids equal to their build indices.
fn render_ids_aligned(
    build: &Build,
    added: &[bool],
    camera: &Camera,
    opts: &RenderOptions,
    colours: &ColourTable,
    source: &MeshSource,
) -> Result<crate::raster::Rendered> {
    let mut meshes = Vec::new();
    let mut placed = Vec::new();
    for (i, inst) in build.instances.iter().enumerate() {
        if !added[i] {
            continue;
        }
        for b in &inst.component.bricks {
            let colour = if b.colour == MAIN_COLOUR {
                inst.colour
            } else {
                b.colour
            };
            meshes.push(source.mesh(b.part)?);
            placed.push((inst.pose.compose(&b.pose), colours.rgb(colour), i as u32));
        }
    }
    let items: Vec<crate::raster::RenderItem> = meshes
        .iter()
        .zip(&placed)
        .map(|(m, &(pose, colour, id))| crate::raster::RenderItem {
            mesh: m,
            pose,
            colour,
            id,
        })
        .collect();
    crate::raster::render(&items, camera, opts)
}

/// Check a build's manual: every step valid against the shape before it (connected, no
/// collision), within the instance and type limits; the steps add every instance exactly once.
pub fn validate_build(build: &Build, cfg: &SynthConfig) -> Result<()> {
    let mut seen = vec![false; build.instances.len()];
    for (s, (step, checks)) in build.steps.iter().zip(build.step_checks()).enumerate() {
        let types: BTreeSet<ComponentRef> = step
            .instances
            .iter()
            .map(|&i| build.instances[i].cref)
            .collect();
        if step.instances.len() > cfg.max_step_instances || types.len() > cfg.max_step_types {
            return Err(BrickGeomError::InvalidArgument(format!(
                "step {}: {} instances of {} types exceed the limits",
                s + 1,
                step.instances.len(),
                types.len()
            )));
        }
        for (k, r) in checks.into_iter().enumerate() {
            if let Err(e) = r {
                return Err(BrickGeomError::InvalidArgument(format!(
                    "step {}: instance {} is invalid: {e}",
                    s + 1,
                    step.instances[k]
                )));
            }
        }
        for &i in &step.instances {
            if std::mem::replace(&mut seen[i], true) {
                return Err(BrickGeomError::InvalidArgument(format!(
                    "instance {i} is added twice"
                )));
            }
        }
    }
    if let Some(i) = seen.iter().position(|s| !s) {
        return Err(BrickGeomError::InvalidArgument(format!(
            "instance {i} is never added"
        )));
    }
    Ok(())
}

/// The keypoint candidates of a component placed at a pose, in pixels.
pub fn project_keypoints(
    comp: &Component,
    pose: &Pose,
    camera: &Camera,
    w: u32,
    h: u32,
) -> Vec<[f64; 2]> {
    comp.keypoints()
        .iter()
        .map(|k| {
            let p = pose.apply_ldu(*k);
            camera
                .project([p[0] as f64, p[1] as f64, p[2] as f64], w, h)
                .0
        })
        .collect()
}
