//! How the rasterizer draws a picture (`raster::RenderOptions::style`): lighting and the
//! shading model of faces, which edges become lines and in what colour, part colours (palette
//! saturation and lightness), and how instances marked new or old in a step are emphasised (a
//! highlight outline, a fade toward white), as instruction tools do.
//!
//! The default is the renderer's own look, bit for bit. Other styles exist so that training
//! pictures vary the way other renderers' pictures do (DESIGN §4): a detector trained on them
//! learns what a part is, not how brickgeom draws it. Everything here is a per-face, per-line or
//! per-instance decision; page-level effects (paper texture, blur, JPEG) belong to the image,
//! not to the rasterizer.

use crate::error::{BrickGeomError, Result};

/// How a face's brightness follows the light.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shading {
    /// `ambient + diffuse * max(0, n . l)` (the default).
    Lambert,
    /// No shading: every face at `ambient + diffuse`, flat part colours.
    Flat,
    /// Cartoon shading: `n . l` quantised to three bands (0, 0.5, 1).
    Bands,
    /// Lambert plus a white Blinn-Phong highlight, `specular * max(0, n . h)^shininess`.
    Specular,
}

impl Shading {
    /// The name used on the Python side.
    pub fn name(self) -> &'static str {
        match self {
            Shading::Lambert => "lambert",
            Shading::Flat => "flat",
            Shading::Bands => "bands",
            Shading::Specular => "specular",
        }
    }

    /// The shading of a name (`lambert`, `flat`, `bands`, `specular`).
    pub fn from_name(name: &str) -> Result<Self> {
        Ok(match name {
            "lambert" => Shading::Lambert,
            "flat" => Shading::Flat,
            "bands" => Shading::Bands,
            "specular" => Shading::Specular,
            other => {
                return Err(BrickGeomError::InvalidArgument(format!(
                    "shading must be lambert, flat, bands or specular, got '{other}'"
                )))
            }
        })
    }
}

/// Which edges are drawn as lines.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineMode {
    /// Where the visible part changes, at creases and at steps between parallel faces (default).
    All,
    /// Only where the visible part changes (each part's outline; no creases, no stud tops).
    Parts,
    /// Only where the model meets the page (the outer contour).
    Silhouette,
    /// No lines.
    None,
}

impl LineMode {
    /// The name used on the Python side.
    pub fn name(self) -> &'static str {
        match self {
            LineMode::All => "all",
            LineMode::Parts => "parts",
            LineMode::Silhouette => "silhouette",
            LineMode::None => "none",
        }
    }

    /// The mode of a name (`all`, `parts`, `silhouette`, `none`).
    pub fn from_name(name: &str) -> Result<Self> {
        Ok(match name {
            "all" => LineMode::All,
            "parts" => LineMode::Parts,
            "silhouette" => LineMode::Silhouette,
            "none" => LineMode::None,
            other => {
                return Err(BrickGeomError::InvalidArgument(format!(
                    "lines must be all, parts, silhouette or none, got '{other}'"
                )))
            }
        })
    }
}

/// The colour of a line, given the colour of the part it belongs to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LineColour {
    /// Near black (the part colour x 0.18), a mid grey on dark parts (default).
    Auto,
    /// A darker shade of the part colour (x `darken`); dark parts get a lighter shade.
    Part { darken: f32 },
    /// One colour for every line.
    Fixed([u8; 3]),
}

/// Luma (Rec. 601) below which a part counts as dark: its lines are drawn lighter.
const DARK_LUMA: f32 = 60.0;

fn luma(c: [f32; 3]) -> f32 {
    0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]
}

impl LineColour {
    /// The line colour on a part of colour `base`.
    pub fn on(self, base: [f32; 3]) -> [f32; 3] {
        match self {
            LineColour::Auto => {
                if luma(base) < DARK_LUMA {
                    // Dark parts get lighter lines, as printed manuals draw them.
                    [95.0, 95.0, 95.0]
                } else {
                    base.map(|c| c * 0.18)
                }
            }
            LineColour::Part { darken } => {
                if luma(base) < DARK_LUMA {
                    base.map(|c| c + (255.0 - c) * 0.35)
                } else {
                    base.map(|c| c * darken)
                }
            }
            LineColour::Fixed(c) => c.map(|x| x as f32),
        }
    }
}

/// How an instance is emphasised in a step picture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Mark {
    /// Drawn as any other.
    #[default]
    Plain,
    /// Added in this step: outlined in the highlight colour (when the style has one).
    New,
    /// Added in an earlier step: faded toward white by the style's `fade`.
    Old,
}

/// A render style. `RenderStyle::default()` is the renderer's own look.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderStyle {
    /// Direction toward the light in view space: x right, y up, z along the view direction
    /// (negative: from the viewer's side). Need not be unit length (it is normalised).
    pub light: [f64; 3],
    /// Brightness of a face turned away from the light (a multiple of the part colour).
    pub ambient: f32,
    /// Brightness added for a face facing the light.
    pub diffuse: f32,
    pub shading: Shading,
    /// Strength of the white highlight of [`Shading::Specular`] (0..=1).
    pub specular: f32,
    /// Exponent of the highlight of [`Shading::Specular`] (1..=256).
    pub shininess: f32,
    pub lines: LineMode,
    pub line_colour: LineColour,
    /// Lines lie on the nearer of the two surfaces they separate (so a part's outline is drawn
    /// on the part on every side). Off by default: the renderer's own lines lie on the left or
    /// upper pixel of each pair, so 1-pixel lines on the page side of a left or top contour
    /// are not drawn.
    pub front_lines: bool,
    /// Saturation of part colours (1: LDraw's own colours; < 1 muted, > 1 saturated).
    pub saturation: f32,
    /// Part colours mixed toward white (> 0) or black (< 0) by this fraction (-1..=1).
    pub lighten: f32,
    /// Outline colour of instances marked [`Mark::New`]; None: no highlight.
    pub highlight: Option<[u8; 3]>,
    /// Width of the highlight outline, output pixels (0.5..=16): a band centred on the outline
    /// (unlike `RenderOptions::line_px`, whose lines are `2 * round(line_px * ss) - 1` samples
    /// wide).
    pub highlight_px: f32,
    /// Instances marked [`Mark::Old`] are mixed toward white by this fraction (0..1).
    pub fade: f32,
}

impl Default for RenderStyle {
    fn default() -> Self {
        RenderStyle {
            // Light from the upper left of the viewer, slightly from the front.
            light: [-0.45, 0.75, -0.5],
            ambient: 0.62,
            diffuse: 0.38,
            shading: Shading::Lambert,
            specular: 0.0,
            shininess: 16.0,
            lines: LineMode::All,
            line_colour: LineColour::Auto,
            front_lines: false,
            saturation: 1.0,
            lighten: 0.0,
            highlight: None,
            highlight_px: 2.0,
            fade: 0.0,
        }
    }
}

impl RenderStyle {
    /// Check every value; the error names the setting and its range.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(BrickGeomError::InvalidArgument(m));
        let norm = self.light.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !(norm.is_finite() && norm > 1e-6) {
            return bad(format!(
                "style light must be a finite non-zero direction, got {:?}",
                self.light
            ));
        }
        let ranged = |name: &str, v: f32, lo: f32, hi: f32| -> Result<()> {
            if v >= lo && v <= hi {
                Ok(())
            } else {
                Err(BrickGeomError::InvalidArgument(format!(
                    "style {name} must be within [{lo}, {hi}], got {v}"
                )))
            }
        };
        ranged("ambient", self.ambient, 0.0, 2.0)?;
        ranged("diffuse", self.diffuse, 0.0, 2.0)?;
        ranged("specular", self.specular, 0.0, 1.0)?;
        ranged("shininess", self.shininess, 1.0, 256.0)?;
        ranged("saturation", self.saturation, 0.0, 3.0)?;
        ranged("lighten", self.lighten, -1.0, 1.0)?;
        ranged("highlight_px", self.highlight_px, 0.5, 16.0)?;
        ranged("fade", self.fade, 0.0, 0.99)?;
        if let LineColour::Part { darken } = self.line_colour {
            ranged("line darken", darken, 0.0, 1.0)?;
        }
        Ok(())
    }

    /// Whether part colours are drawn as they are (no palette change).
    pub fn keeps_colours(&self) -> bool {
        self.saturation == 1.0 && self.lighten == 0.0
    }

    /// A part colour after the palette change (saturation about the colour's luma, then
    /// lightening).
    pub fn part_colour(&self, rgb: [u8; 3]) -> [f32; 3] {
        let c = rgb.map(|x| x as f32);
        if self.keeps_colours() {
            return c;
        }
        let y = luma(c);
        let s = c.map(|x| (y + self.saturation * (x - y)).clamp(0.0, 255.0));
        if self.lighten >= 0.0 {
            s.map(|x| x + (255.0 - x) * self.lighten)
        } else {
            s.map(|x| x * (1.0 + self.lighten))
        }
    }

    /// Shade factor and white highlight (0..=1) of a face with unit normal `n` (facing the
    /// camera), unit direction to the light `light` and unit direction to the viewer `eye`.
    #[inline]
    pub fn face_shade(&self, n: [f32; 3], light: [f32; 3], eye: [f32; 3]) -> (f32, f32) {
        let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let diffuse = dot(n, light).max(0.0);
        match self.shading {
            Shading::Lambert => (self.ambient + self.diffuse * diffuse, 0.0),
            Shading::Flat => (self.ambient + self.diffuse, 0.0),
            Shading::Bands => {
                let band = if diffuse > 0.6 {
                    1.0
                } else if diffuse > 0.2 {
                    0.5
                } else {
                    0.0
                };
                (self.ambient + self.diffuse * band, 0.0)
            }
            Shading::Specular => {
                let h = [light[0] + eye[0], light[1] + eye[1], light[2] + eye[2]];
                let len = dot(h, h).sqrt();
                let spec = if len > 1e-6 {
                    let c = (dot(n, h) / len).max(0.0);
                    self.specular * c.powf(self.shininess)
                } else {
                    0.0
                };
                (self.ambient + self.diffuse * diffuse, spec)
            }
        }
    }

    /// A colour of an instance with its mark: old instances mixed toward white.
    #[inline]
    pub fn marked(&self, c: [f32; 3], mark: Mark) -> [f32; 3] {
        if mark == Mark::Old && self.fade > 0.0 {
            c.map(|x| x + (255.0 - x) * self.fade)
        } else {
            c
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_valid_and_keeps_colours() {
        let s = RenderStyle::default();
        s.validate().unwrap();
        assert!(s.keeps_colours());
        assert_eq!(s.part_colour([12, 200, 7]), [12.0, 200.0, 7.0]);
    }

    #[test]
    fn names_round_trip() {
        for s in [
            Shading::Lambert,
            Shading::Flat,
            Shading::Bands,
            Shading::Specular,
        ] {
            assert_eq!(Shading::from_name(s.name()).unwrap(), s);
        }
        for m in [
            LineMode::All,
            LineMode::Parts,
            LineMode::Silhouette,
            LineMode::None,
        ] {
            assert_eq!(LineMode::from_name(m.name()).unwrap(), m);
        }
        assert!(Shading::from_name("phong").is_err());
        assert!(LineMode::from_name("thin").is_err());
    }

    #[test]
    fn bad_values_are_errors() {
        let cases: [fn(&mut RenderStyle); 6] = [
            |s| s.light = [0.0, 0.0, 0.0],
            |s| s.light = [f64::NAN, 1.0, 0.0],
            |s| s.ambient = -0.1,
            |s| s.fade = 1.0,
            |s| s.saturation = f32::NAN,
            |s| s.line_colour = LineColour::Part { darken: 2.0 },
        ];
        for set in cases {
            let mut s = RenderStyle::default();
            set(&mut s);
            let e = s.validate().unwrap_err().to_string();
            assert!(e.contains("style"), "{e}");
        }
    }

    #[test]
    fn palette_muted_is_greyer_saturated_is_purer() {
        let red = [180u8, 30, 30];
        let spread = |c: [f32; 3]| c[0] - c[1];
        let muted = RenderStyle {
            saturation: 0.5,
            ..RenderStyle::default()
        };
        let vivid = RenderStyle {
            saturation: 1.3,
            ..RenderStyle::default()
        };
        let base = RenderStyle::default().part_colour(red);
        assert!(spread(muted.part_colour(red)) < spread(base));
        assert!(spread(vivid.part_colour(red)) > spread(base));
        let light = RenderStyle {
            lighten: 0.5,
            ..RenderStyle::default()
        };
        assert!(light.part_colour(red).iter().zip(&base).all(|(a, b)| a > b));
    }

    #[test]
    fn shading_models() {
        let s = RenderStyle::default();
        let up = [0.0, 1.0, 0.0];
        let side = [1.0, 0.0, 0.0];
        let light = [0.0, 1.0, 0.0];
        let eye = [0.0, 0.0, 1.0];
        assert!(s.face_shade(up, light, eye).0 > s.face_shade(side, light, eye).0);
        let flat = RenderStyle {
            shading: Shading::Flat,
            ..s
        };
        assert_eq!(
            flat.face_shade(up, light, eye),
            flat.face_shade(side, light, eye)
        );
        let spec = RenderStyle {
            shading: Shading::Specular,
            specular: 0.5,
            ..s
        };
        // the half vector between light (up) and eye (+z) lies between them
        let h = [
            0.0,
            std::f32::consts::FRAC_1_SQRT_2,
            std::f32::consts::FRAC_1_SQRT_2,
        ];
        assert!(spec.face_shade(h, light, eye).1 > 0.49);
        assert_eq!(spec.face_shade(side, light, eye).1, 0.0);
        let bands = RenderStyle {
            shading: Shading::Bands,
            ..s
        };
        let tilted = [0.0, 0.4, 0.9165];
        assert_eq!(
            bands.face_shade(tilted, light, eye).0,
            s.ambient + s.diffuse * 0.5
        );
    }

    #[test]
    fn fade_lightens_old_only() {
        let s = RenderStyle {
            fade: 0.5,
            ..RenderStyle::default()
        };
        let c = [100.0, 0.0, 255.0];
        assert_eq!(s.marked(c, Mark::Plain), c);
        assert_eq!(s.marked(c, Mark::New), c);
        assert_eq!(s.marked(c, Mark::Old), [177.5, 127.5, 255.0]);
    }
}
