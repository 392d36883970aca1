//! The views of a manual: the camera of each step (orientation sampled once per build, framing
//! fitted per step), and the step images rendered with their instance-id maps and annotations.

use crate::assembly::Assembly;
use crate::camera::Camera;
use crate::colours::ColourTable;
use crate::component::{Component, MAIN_COLOUR};
use crate::error::Result;
use crate::lattice::Pose;
use crate::raster::RenderOptions;
use crate::render_style::Mark;
use crate::scene::MeshSource;

use super::build::Build;
use super::config::SynthConfig;
use super::rng::Rng;

/// Camera orientation fixed per build, framing re-fitted per step.
pub(super) struct ViewSampler {
    elevation: f64,
    azimuth: f64,
    fill: (f64, f64),
}

impl ViewSampler {
    pub(super) fn new(cfg: &SynthConfig, rng: &mut Rng) -> Self {
        let elevation = rng.around(cfg.elevation.0, cfg.elevation.1);
        let azimuth = rng.around(cfg.azimuth.0, cfg.azimuth.1);
        let mirrored = rng.f64() < cfg.p_mirror_view;
        ViewSampler {
            elevation,
            azimuth: if mirrored { 360.0 - azimuth } else { azimuth },
            fill: cfg.fill,
        }
    }

    /// A camera for the current shape; `turn` degrees added to the azimuth (a manual turns
    /// the model around to show its back).
    pub(super) fn camera(&self, rng: &mut Rng, asm: &Assembly, turn: f64) -> Result<Camera> {
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

/// Render every step of a build (state after the step) with its camera, as the generator's
/// settings say (size, anti-aliasing; the renderer's own style).
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
    render_build_with(build, &opts, &opts, source, colours)
}

/// Render every step of a build: the id images and annotations with `opts` (size and
/// anti-aliasing), the pictures with `look` (the same size; its own anti-aliasing, lines and
/// style). In each step the instances it adds are marked new and those of earlier steps old, for
/// the style's highlight and fade. A style changes colours only, so the id images and
/// annotations are those `opts` alone gives: one render per step when both sample alike, two
/// when `look` anti-aliases differently.
pub fn render_build_with(
    build: &Build,
    opts: &RenderOptions,
    look: &RenderOptions,
    source: &MeshSource,
    colours: &ColourTable,
) -> Result<Vec<StepImage>> {
    opts.validate()?;
    look.validate()?;
    if (look.width, look.height) != (opts.width, opts.height) {
        return Err(crate::error::BrickGeomError::InvalidArgument(format!(
            "pictures ({}x{}) and id images ({}x{}) must have one size",
            look.width, look.height, opts.width, opts.height
        )));
    }
    let mut out = Vec::with_capacity(build.steps.len());
    let mut added = vec![false; build.instances.len()];
    for step in &build.steps {
        let mut marks: Vec<Mark> = added
            .iter()
            .map(|&a| if a { Mark::Old } else { Mark::Plain })
            .collect();
        for &i in &step.instances {
            added[i] = true;
            marks[i] = Mark::New;
        }
        let (r, rgb) = if look.supersample == opts.supersample {
            let mut r =
                render_ids_aligned(build, &added, &marks, &step.camera, look, colours, source)?;
            let rgb = std::mem::take(&mut r.rgb);
            (r, rgb)
        } else {
            let r = render_ids_aligned(build, &added, &[], &step.camera, opts, colours, source)?;
            let pic =
                render_ids_aligned(build, &added, &marks, &step.camera, look, colours, source)?;
            (r, pic.rgb)
        };
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
            rgb,
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
    marks: &[Mark],
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
    crate::raster::render_marked(&items, camera, opts, marks)
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
