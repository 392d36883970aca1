//! Stage 2: exact 3D poses from 2D detections (paper §4.2 and the supplementary's "Details of
//! 3D Pose Inference"), and the pure analysis-by-synthesis baseline.
//!
//! Translation. Under weak perspective the image offset between a component's keypoint and any
//! of its points does not depend on depth, so a detected keypoint fixes the component up to a
//! line along the view direction. We enumerate the lattice translations whose projected keypoint
//! lies within a few pixels of the detection (at every height, or across the view when the camera
//! looks horizontally), keep the valid ones (collision-free and attached on studs, from below or
//! on the ground, whichever the geometry gives: the attach kind comes from the evidence, never
//! from ground truth), and choose the one whose keypoint projects closest. Placements that
//! project equally close (a depth ambiguity) are told apart by the instance mask when there is
//! one (the synthesized visible silhouette over the base shape with the best IoU), else the one
//! nearest the camera wins. This is the paper's stud/anti-stud matching and voting, made exact:
//! a candidate that matches the keypoint also matches all of its connection points.
//!
//! Rotation. Primitives take the yaw from the 7-way symmetry-aware class; with a predicted mask,
//! each distinct yaw's best placement is rasterized and the yaw with the highest mask IoU plus
//! class probability wins (analysis-by-synthesis backing up the classifier). Submodules are
//! rotated by synthesis: every yaw x every topmost brick as the keypoint's anchor, the candidate
//! mask rasterized over the current assembly and compared with the predicted mask (IoU).
//!
//! Several instances: placed one after another, most confident match first, so later ones can
//! rest on earlier ones of the same step; a detection that fits nowhere is a failure for that
//! component and the step goes on.

use std::sync::Arc;
use std::time::Instant;

use rayon::prelude::*;

use crate::assembly::{Assembly, AttachKind, GroundSearch};
use crate::camera::Camera;
use crate::component::Component;
use crate::error::{BrickGeomError, Result};
use crate::lattice::Pose;
use crate::library::part;
use crate::mesh::Mesh;
use crate::raster::{render, silhouette_iou, MaskTarget, RenderItem, RenderOptions};

/// One detected instance of a component type.
#[derive(Debug, Clone)]
pub struct Detection {
    /// Keypoint in pixels.
    pub keypoint: [f64; 2],
    /// Detector confidence (higher is better).
    pub score: f32,
    /// Probabilities of the 7 symmetry-aware rotation classes (ignored for submodules).
    pub rotation: Option<[f32; 7]>,
    /// Predicted instance mask, `width * height` row major (used for submodule rotation and to
    /// resolve depth ambiguities).
    pub mask: Option<Vec<bool>>,
}

/// The detections of one component type of a step.
#[derive(Debug, Clone)]
pub struct TypeDetections {
    pub component: Arc<Component>,
    /// Number of instances the manual says this step adds.
    pub count: usize,
    pub detections: Vec<Detection>,
}

/// Settings of stage 2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InferOptions {
    /// Largest keypoint reprojection error (pixels) of an accepted placement.
    pub max_error_px: f64,
    /// Placements this close (pixels) to the best are ambiguous and compared by mask/depth.
    pub tie_px: f64,
    /// Primitives with a mask: choose the yaw by mask IoU plus the rotation class probability
    /// (analysis-by-synthesis, as for submodules) instead of the most probable class alone.
    pub rotation_by_mask: bool,
}

impl Default for InferOptions {
    fn default() -> Self {
        InferOptions {
            max_error_px: 6.0,
            tie_px: 2.5,
            rotation_by_mask: true,
        }
    }
}

/// The outcome for one instance.
#[derive(Debug, Clone, PartialEq)]
pub struct InstancePrediction {
    /// Index into the step's types.
    pub type_index: usize,
    /// Index of the detection used (None when the type had fewer detections than instances).
    pub detection: Option<usize>,
    pub pose: Option<Pose>,
    pub attach: Option<AttachKind>,
    /// Keypoint reprojection error (pixels) of the chosen pose.
    pub error_px: f64,
    /// Mask IoU of the chosen pose, when a mask was used.
    pub iou: Option<f64>,
    /// Why no pose was found.
    pub failure: Option<String>,
}

/// The 7-way symmetry-aware rotation class of a yaw (supplementary): 0 for 4-fold symmetric
/// parts; 1 + yaw mod 2 for 2-fold; 3 + yaw otherwise.
pub fn rotation_class(symmetry: u8, yaw: u8) -> u8 {
    match symmetry {
        4 => 0,
        2 => 1 + yaw % 2,
        _ => 3 + yaw % 4,
    }
}

/// Yaws to try for a component, most probable first, one per symmetry-equivalent group.
pub fn yaws_from_classes(symmetry: u8, probs: Option<&[f32; 7]>) -> Vec<u8> {
    let Some(p) = probs else {
        return match symmetry {
            4 => vec![0],
            2 => vec![0, 1],
            _ => vec![0, 1, 2, 3],
        };
    };
    let mut scored: Vec<(f32, u8)> = match symmetry {
        4 => vec![(1.0, 0)],
        2 => vec![(p[1], 0), (p[2], 1)],
        _ => (0..4u8).map(|y| (p[3 + y as usize], y)).collect(),
    };
    scored.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    scored.into_iter().map(|(_, y)| y).collect()
}

/// A scored candidate placement.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    pose: Pose,
    attach: AttachKind,
    error_px: f64,
    depth: f64,
}

/// Per-step geometry shared by all queries: the camera's projection.
struct Projector {
    /// Pixel matrix (2x4) and view row.
    m: [[f64; 4]; 2],
    view: [f64; 3],
}

impl Projector {
    fn new(camera: &Camera, w: u32, h: u32) -> Self {
        let pm = camera.pixel_matrix(w, h);
        let r = camera.rotation();
        Projector {
            m: [
                [pm[(0, 0)], pm[(0, 1)], pm[(0, 2)], pm[(0, 3)]],
                [pm[(1, 0)], pm[(1, 1)], pm[(1, 2)], pm[(1, 3)]],
            ],
            view: [r[(2, 0)], r[(2, 1)], r[(2, 2)]],
        }
    }

    fn pixel(&self, p: [f64; 3]) -> [f64; 2] {
        let f = |r: &[f64; 4]| r[0] * p[0] + r[1] * p[1] + r[2] * p[2] + r[3];
        [f(&self.m[0]), f(&self.m[1])]
    }

    fn depth(&self, p: [f64; 3]) -> f64 {
        self.view[0] * p[0] + self.view[1] * p[1] + self.view[2] * p[2]
    }
}

const UNIT: [f64; 3] = [10.0, 8.0, 10.0];

/// Valid placements of `comp` at `yaw` whose anchor point (component frame, LDU) projects
/// within `max_err` pixels of `k`.
#[allow(clippy::too_many_arguments)]
fn ray_candidates(
    asm: &Assembly,
    comp: &Component,
    yaw: u8,
    anchor: [f32; 3],
    k: [f64; 2],
    proj: &Projector,
    max_err: f64,
) -> Vec<Candidate> {
    let rot = Pose::new(yaw, [0, 0, 0]);
    let a = rot.apply_ldu(anchor).map(|v| v as f64);
    let base = proj.pixel(a);
    // pixel(t) = base + J t, J = M[:, :3] * diag(UNIT)
    let j = [
        [
            proj.m[0][0] * UNIT[0],
            proj.m[0][1] * UNIT[1],
            proj.m[0][2] * UNIT[2],
        ],
        [
            proj.m[1][0] * UNIT[0],
            proj.m[1][1] * UNIT[1],
            proj.m[1][2] * UNIT[2],
        ],
    ];
    // Iterate over heights (a bounded range: from the ground to the top of the shape) unless the
    // camera looks nearly horizontally; then over the better conditioned horizontal axis.
    let det = |p: usize, q: usize| j[0][p] * j[1][q] - j[0][q] * j[1][p];
    let best = [det(0, 2), det(1, 2), det(0, 1)]
        .iter()
        .map(|d| d.abs())
        .fold(0.0, f64::max);
    let (it, p, q) = if det(0, 2).abs() >= 0.2 * best {
        (1usize, 0usize, 2usize)
    } else if det(1, 2).abs() >= det(0, 1).abs() {
        (0, 1, 2)
    } else {
        (2, 0, 1)
    };
    let d = det(p, q);
    if d.abs() < 1e-12 {
        return Vec::new();
    }
    let (lo, hi) = asm.bounds().unwrap_or(([0; 3], [0; 3]));
    let cv: Vec<[i32; 3]> = comp.voxels.iter().map(|&v| rot.apply_cell(v)).collect();
    let cmin = cv.iter().fold([i32::MAX; 3], |m, v| {
        [m[0].min(v[0]), m[1].min(v[1]), m[2].min(v[2])]
    });
    let cmax = cv.iter().fold([i32::MIN; 3], |m, v| {
        [m[0].max(v[0]), m[1].max(v[1]), m[2].max(v[2])]
    });
    let (r0, r1) = if it == 1 {
        // from standing on the ground up to resting on top of everything
        (-cmin[1], hi[1] + 1 - cmin[1] + 1)
    } else {
        // horizontally: anywhere the component touches the shape, or on the ground around it
        (lo[it] - cmax[it] - 64, hi[it] - cmin[it] + 64)
    };
    let mut poses = Vec::new();
    for v in r0..=r1 {
        // Solve for the other two coordinates: J[:, p] x + J[:, q] y = k - base - J[:, it] v.
        let rhs = [
            k[0] - base[0] - j[0][it] * v as f64,
            k[1] - base[1] - j[1][it] * v as f64,
        ];
        let xp = (rhs[0] * j[1][q] - rhs[1] * j[0][q]) / d;
        let xq = (j[0][p] * rhs[1] - j[1][p] * rhs[0]) / d;
        // A window of lattice points around the exact solution; the reprojection filter below
        // keeps the ones within the error bound.
        for dp in -2..=2 {
            for dq in -2..=2 {
                let mut t = [0i32; 3];
                t[it] = v;
                t[p] = xp.round() as i32 + dp;
                t[q] = xq.round() as i32 + dq;
                poses.push(Pose::new(yaw, t));
            }
        }
    }
    let checks = asm.check_many(comp, &poses);
    poses
        .into_iter()
        .zip(checks)
        .filter_map(|(pose, r)| {
            let attach = r.ok()?;
            let world = [
                a[0] + pose.t[0] as f64 * UNIT[0],
                a[1] + pose.t[1] as f64 * UNIT[1],
                a[2] + pose.t[2] as f64 * UNIT[2],
            ];
            let px = proj.pixel(world);
            let err = ((px[0] - k[0]).powi(2) + (px[1] - k[1]).powi(2)).sqrt();
            (err <= max_err).then_some(Candidate {
                pose,
                attach,
                error_px: err,
                depth: proj.depth(world),
            })
        })
        .collect()
}

/// Meshes of a component's bricks (library meshes) with their poses in the component frame.
fn brick_meshes(comp: &Component) -> Vec<(&'static Mesh, Pose)> {
    comp.bricks
        .iter()
        .map(|b| (&part(b.part).expect("library part").mesh, b.pose))
        .collect()
}

/// Mask IoU of a component placed at `pose` against a target.
fn pose_iou(comp: &Component, pose: &Pose, camera: &Camera, target: &MaskTarget) -> Result<f64> {
    let meshes: Vec<(&Mesh, Pose)> = brick_meshes(comp)
        .into_iter()
        .map(|(m, p)| (m, pose.compose(&p)))
        .collect();
    Ok(silhouette_iou(&meshes, camera, target)?.0)
}

/// Depth image of an assembly (`f32::INFINITY` where empty), built-in meshes.
fn base_depth(asm: &Assembly, camera: &Camera, w: u32, h: u32) -> Result<Vec<f32>> {
    let mut items = Vec::new();
    for (id, inst) in asm.instances() {
        for (mesh, p) in brick_meshes(&inst.component) {
            items.push(RenderItem {
                mesh,
                pose: inst.pose.compose(&p),
                colour: [0, 0, 0],
                id,
            });
        }
    }
    let opts = RenderOptions {
        line_px: 0.0,
        ..RenderOptions::new(w, h)
    };
    Ok(render(&items, camera, &opts)?.depth)
}

/// The best placement of one detection against the current assembly.
#[allow(clippy::too_many_arguments)]
fn best_placement(
    asm: &Assembly,
    comp: &Component,
    det: &Detection,
    camera: &Camera,
    proj: &Projector,
    target: Option<&MaskTarget>,
    opts: &InferOptions,
) -> Result<Option<(Candidate, Option<f64>)>> {
    if comp.is_submodule {
        // Rotation by synthesis: every yaw x every topmost brick as the anchor.
        let mut best: Option<(f64, f64, Candidate)> = None; // (iou, -error, cand)
        for yaw in 0..4u8 {
            for kp in comp.keypoints() {
                let cands =
                    ray_candidates(asm, comp, yaw, kp, det.keypoint, proj, opts.max_error_px);
                for c in resolve_ties(comp, cands, camera, target, opts)?
                    .into_iter()
                    .take(1)
                {
                    let (cand, iou) = c;
                    let key = (iou.unwrap_or(0.0), -cand.error_px);
                    if best.is_none_or(|(bi, be, _)| key > (bi, be)) {
                        best = Some((key.0, key.1, cand));
                    }
                }
            }
        }
        return Ok(best.map(|(iou, _, c)| (c, target.map(|_| iou))));
    }
    let anchor = comp.keypoints()[0];
    // With a mask, every distinct yaw's best placement is scored by mask IoU + class probability
    // (both in [0, 1], so a confident class decides unless the silhouettes clearly disagree);
    // without one, the most probable yaw that has a valid placement wins.
    let by_mask = match (opts.rotation_by_mask, target, det.rotation.as_ref()) {
        (true, Some(_), Some(p)) => Some(p),
        _ => None,
    };
    let mut best: Option<(f64, f64, Candidate, Option<f64>)> = None;
    for yaw in yaws_from_classes(comp.symmetry, det.rotation.as_ref()) {
        let cands = ray_candidates(
            asm,
            comp,
            yaw,
            anchor,
            det.keypoint,
            proj,
            opts.max_error_px,
        );
        let Some((cand, iou)) = resolve_ties(comp, cands, camera, target, opts)?
            .into_iter()
            .next()
        else {
            continue;
        };
        let Some(probs) = by_mask else {
            return Ok(Some((cand, iou)));
        };
        let prob = probs[rotation_class(comp.symmetry, yaw) as usize] as f64;
        let key = (iou.unwrap_or(0.0) + prob, -cand.error_px);
        if best.is_none_or(|(bk, be, _, _)| key > (bk, be)) {
            best = Some((key.0, key.1, cand, iou));
        }
    }
    Ok(best.map(|(_, _, c, iou)| (c, iou)))
}

/// Order candidates: smallest reprojection error; among those within `tie_px` of it, the best
/// mask IoU when there is a mask, else nearest the camera.
fn resolve_ties(
    comp: &Component,
    mut cands: Vec<Candidate>,
    camera: &Camera,
    target: Option<&MaskTarget>,
    opts: &InferOptions,
) -> Result<Vec<(Candidate, Option<f64>)>> {
    cands.sort_by(|a, b| a.error_px.total_cmp(&b.error_px).then(a.pose.cmp(&b.pose)));
    let Some(first) = cands.first().copied() else {
        return Ok(Vec::new());
    };
    let mut tied: Vec<(Candidate, Option<f64>)> = cands
        .iter()
        .filter(|c| c.error_px <= first.error_px + opts.tie_px)
        .map(|c| -> Result<_> {
            let iou = match target {
                Some(t) => Some(pose_iou(comp, &c.pose, camera, t)?),
                None => None,
            };
            Ok((*c, iou))
        })
        .collect::<Result<_>>()?;
    tied.sort_by(|(a, ia), (b, ib)| {
        ib.unwrap_or(0.0)
            .total_cmp(&ia.unwrap_or(0.0))
            .then(a.depth.total_cmp(&b.depth))
            .then(a.error_px.total_cmp(&b.error_px))
            .then(a.pose.cmp(&b.pose))
    });
    Ok(tied)
}

/// Stage 2 for one step: poses for every instance of every component type, placed one after
/// another on a copy of `base`. Always collision-free; never fails as a whole.
pub fn infer_step(
    base: &Assembly,
    camera: &Camera,
    width: u32,
    height: u32,
    types: &[TypeDetections],
    opts: &InferOptions,
) -> Result<Vec<InstancePrediction>> {
    camera.validate()?;
    if width == 0 || height == 0 || width > 8192 || height > 8192 {
        return Err(BrickGeomError::InvalidArgument(format!(
            "image size must be 1..=8192 pixels per side, got {width}x{height}"
        )));
    }
    let n_px = width as usize * height as usize;
    let mut out = Vec::new();
    // The detections to use: the `count` most confident of each type; missing ones fail.
    let mut pending: Vec<(usize, usize)> = Vec::new();
    for (ti, t) in types.iter().enumerate() {
        for (di, d) in t.detections.iter().enumerate() {
            if !(d.keypoint[0].is_finite() && d.keypoint[1].is_finite()) {
                return Err(BrickGeomError::InvalidArgument(format!(
                    "type {ti} detection {di}: keypoint {:?} is not finite",
                    d.keypoint
                )));
            }
            if let Some(m) = &d.mask {
                if m.len() != n_px {
                    return Err(BrickGeomError::InvalidArgument(format!(
                        "type {ti} detection {di}: mask has {} pixels, the image {width}x{height} has {n_px}",
                        m.len()
                    )));
                }
            }
        }
        let mut order: Vec<usize> = (0..t.detections.len()).collect();
        order.sort_by(|&a, &b| {
            t.detections[b]
                .score
                .total_cmp(&t.detections[a].score)
                .then(a.cmp(&b))
        });
        for &di in order.iter().take(t.count) {
            pending.push((ti, di));
        }
        for _ in t.detections.len()..t.count {
            out.push(InstancePrediction {
                type_index: ti,
                detection: None,
                pose: None,
                attach: None,
                error_px: f64::INFINITY,
                iou: None,
                failure: Some("fewer detections than instances".into()),
            });
        }
    }
    let proj = Projector::new(camera, width, height);
    let mut asm = base.clone();
    let uses_masks = pending
        .iter()
        .any(|&(ti, di)| types[ti].detections[di].mask.is_some());
    while !pending.is_empty() {
        let depth = if uses_masks {
            Some(base_depth(&asm, camera, width, height)?)
        } else {
            None
        };
        // best placement of every pending detection against the current shape
        let found: Vec<Option<(Candidate, Option<f64>)>> = pending
            .par_iter()
            .map(|&(ti, di)| -> Result<_> {
                let det = &types[ti].detections[di];
                let target = match (&det.mask, &depth) {
                    (Some(m), Some(d)) => {
                        Some(MaskTarget::new(width, height, d.clone(), m.clone())?)
                    }
                    _ => None,
                };
                best_placement(
                    &asm,
                    &types[ti].component,
                    det,
                    camera,
                    &proj,
                    target.as_ref(),
                    opts,
                )
            })
            .collect::<Result<_>>()?;
        // place the one that fits best (smallest reprojection error); others wait for it
        let pick = found
            .iter()
            .enumerate()
            .filter_map(|(i, f)| f.as_ref().map(|(c, _)| (c.error_px, i)))
            .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let Some((_, i)) = pick else {
            for (ti, di) in pending.drain(..) {
                out.push(InstancePrediction {
                    type_index: ti,
                    detection: Some(di),
                    pose: None,
                    attach: None,
                    error_px: f64::INFINITY,
                    iou: None,
                    failure: Some(format!(
                        "no valid placement projects within {} px of the keypoint",
                        opts.max_error_px
                    )),
                });
            }
            break;
        };
        let (ti, di) = pending.remove(i);
        let (cand, iou) = found[i].expect("picked a found placement");
        asm.add(types[ti].component.clone(), cand.pose)?;
        out.push(InstancePrediction {
            type_index: ti,
            detection: Some(di),
            pose: Some(cand.pose),
            attach: Some(cand.attach),
            error_px: cand.error_px,
            iou,
            failure: None,
        });
    }
    Ok(out)
}

/// Pure analysis-by-synthesis (the paper's ablation): for each instance, every valid pose of
/// its component (4 yaws x every stud/anti-stud/ground placement) is rasterized over the
/// current shape and scored by IoU with the instance's mask; the best is placed. Components are
/// placed one after another in the order given; each has a time limit, past which the best pose
/// found so far is used (and the result says it hit the limit).
pub fn abys_step(
    base: &Assembly,
    camera: &Camera,
    width: u32,
    height: u32,
    instances: &[(Arc<Component>, Vec<bool>)],
    time_limit_s: f64,
) -> Result<Vec<(Option<Pose>, f64, bool)>> {
    let mut asm = base.clone();
    let mut out = Vec::new();
    for (comp, mask) in instances {
        let (ranked, timed_out) = abys_ranked(
            &asm,
            comp,
            camera,
            width,
            height,
            mask,
            1,
            time_limit_s,
            false,
        )?;
        let best = ranked.first().copied();
        if let Some((pose, _)) = best {
            asm.add(comp.clone(), pose)?;
        }
        out.push((best.map(|b| b.0), best.map_or(0.0, |b| b.1), timed_out));
    }
    Ok(out)
}

/// How far (lattice units) a ground placement may stand from the base shape's footprint: the
/// generator stands parts on the ground anywhere in its build region, not only beside the base.
const GROUND_REACH: i32 = 24;

/// Where on the ground to look for placements of `comp` at `yaw` on a non-empty `base`: the
/// base's footprint grown by the part's size (a part standing beside the base), together with
/// every ground position whose part may project into the mask (its pixel box `mask_box`, from
/// [`mask_box`], cast onto the ground and onto the part's top height, grown by the part's
/// size), within
/// [`GROUND_REACH`] of the footprint. A part standing on its own, away from the base, is found
/// where the picture shows it.
fn ground_search(
    base: &Assembly,
    comp: &Component,
    yaw: u8,
    camera: &Camera,
    width: u32,
    height: u32,
    mask_box: Option<[usize; 4]>,
) -> (GroundSearch, Option<[i32; 4]>) {
    let Some((lo, hi)) = base.bounds() else {
        return (GroundSearch::Auto, None);
    };
    let pose = Pose::new(yaw, [0, 0, 0]);
    let cells: Vec<[i32; 3]> = comp.voxels.iter().map(|&v| pose.apply_cell(v)).collect();
    if cells.is_empty() {
        return (GroundSearch::Auto, None);
    }
    let c_lo = [0, 2].map(|a| cells.iter().map(|c| c[a]).min().unwrap_or(0));
    let c_hi = [0, 2].map(|a| cells.iter().map(|c| c[a]).max().unwrap_or(0));
    let top = cells.iter().map(|c| c[1]).max().unwrap_or(0)
        - cells.iter().map(|c| c[1]).min().unwrap_or(0)
        + 1;
    // the footprint grown by the part (GroundSearch::Auto)
    let beside = [
        lo[0] - c_hi[0] - 1,
        hi[0] - c_lo[0] + 1,
        lo[2] - c_hi[1] - 1,
        hi[2] - c_lo[1] + 1,
    ];
    let Some([u0, v0, u1, v1]) = mask_box else {
        return (GroundSearch::Auto, None);
    };
    let m = camera.pixel_matrix(width, height);
    let det = m[(0, 0)] * m[(1, 2)] - m[(0, 2)] * m[(1, 0)];
    if det.abs() < 1e-9 {
        return (GroundSearch::Auto, None); // looking along the ground: it casts nowhere
    }
    let unit = crate::lattice::LDU_PER_UNIT;
    let (mut x_lo, mut x_hi, mut z_lo, mut z_hi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (u, v) in [(u0, v0), (u1, v0), (u0, v1), (u1, v1)] {
        for y in [0.0, top as f64 * unit[1] as f64] {
            let a = u as f64 - m[(0, 3)] - m[(0, 1)] * y;
            let b = v as f64 - m[(1, 3)] - m[(1, 1)] * y;
            let x = (a * m[(1, 2)] - m[(0, 2)] * b) / det;
            let z = (m[(0, 0)] * b - m[(1, 0)] * a) / det;
            x_lo = x_lo.min(x / unit[0] as f64);
            x_hi = x_hi.max(x / unit[0] as f64);
            z_lo = z_lo.min(z / unit[2] as f64);
            z_hi = z_hi.max(z / unit[2] as f64);
        }
    }
    let clamp = |v: f64, a: i32, b: i32| (v.max(a as f64).min(b as f64)) as i32;
    let (fx0, fx1) = (lo[0] - GROUND_REACH, hi[0] + GROUND_REACH);
    let (fz0, fz1) = (lo[2] - GROUND_REACH, hi[2] + GROUND_REACH);
    let mx0 = clamp(x_lo.floor(), fx0, fx1) - c_hi[0] - 1;
    let mx1 = clamp(x_hi.ceil(), fx0, fx1) - c_lo[0] + 1;
    let mz0 = clamp(z_lo.floor(), fz0, fz1) - c_hi[1] - 1;
    let mz1 = clamp(z_hi.ceil(), fz0, fz1) - c_lo[1] + 1;
    let r = [
        beside[0].min(mx0),
        beside[1].max(mx1),
        beside[2].min(mz0),
        beside[3].max(mz1),
    ];
    (
        GroundSearch::Region {
            x0: r[0],
            x1: r[1],
            z0: r[2],
            z1: r[3],
        },
        Some(beside),
    )
}

/// The bounding box `[u0, v0, u1, v1)` of a mask's set pixels (row major, `width` wide);
/// None when none is set.
fn mask_box(mask: &[bool], width: u32) -> Option<[usize; 4]> {
    let w = width as usize;
    let mut b: Option<[usize; 4]> = None;
    for (i, _) in mask.iter().enumerate().filter(|(_, &m)| m) {
        let (u, v) = (i % w, i / w);
        b = Some(match b {
            None => [u, v, u + 1, v + 1],
            Some([u0, v0, u1, v1]) => [u0.min(u), v0.min(v), u1.max(u + 1), v1.max(v + 1)],
        });
    }
    b
}

/// Taken off the score of a placement standing on the ground away from the base (outside the
/// footprint grown by the part): seen along the camera's rays, a part standing far behind the
/// shape draws the same silhouette as one fixed onto it; the one on the shape is preferred
/// unless the picture clearly says otherwise.
pub const DETACHED_PENALTY: f64 = 0.15;

/// An upper bound on a placement's mask IoU (`abys_ranked`): the mask pixels inside the box its
/// meshes project to (widened by a pixel against rounding), over the mask's area. Its visible
/// pixels lie in that box and the IoU is at most their overlap with the mask over the mask.
struct ScoreBound {
    /// Summed-area table of the mask, `(w + 1) * (h + 1)`.
    sums: Vec<u32>,
    w: usize,
    h: usize,
    area: f64,
    /// Per yaw, the projected box `[x0, y0, x1, y1]` of the component at translation zero.
    boxes: [[f64; 4]; 4],
    /// Pixels moved by one lattice unit along x, y and z: `[[dx, dy]; 3]`.
    step: [[f64; 2]; 3],
}

impl ScoreBound {
    fn new(
        comp: &Component,
        camera: &Camera,
        width: u32,
        height: u32,
        target: &MaskTarget,
    ) -> Self {
        let (w, h) = (width as usize, height as usize);
        let mut sums = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += target.mask[y * w + x] as u32;
                sums[(y + 1) * (w + 1) + x + 1] = sums[y * (w + 1) + x + 1] + row;
            }
        }
        let m = camera.pixel_matrix(width, height);
        let px = |v: [f32; 3]| -> [f64; 2] {
            let (x, y, z) = (v[0] as f64, v[1] as f64, v[2] as f64);
            [
                m[(0, 0)] * x + m[(0, 1)] * y + m[(0, 2)] * z + m[(0, 3)],
                m[(1, 0)] * x + m[(1, 1)] * y + m[(1, 2)] * z + m[(1, 3)],
            ]
        };
        let mut boxes = [[
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ]; 4];
        for (yaw, b) in boxes.iter_mut().enumerate() {
            let at = Pose::new(yaw as u8, [0, 0, 0]);
            for (mesh, p) in brick_meshes(comp) {
                let pose = at.compose(&p);
                for v in &mesh.vertices {
                    let [x, y] = px(pose.apply_ldu(*v));
                    *b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
                }
            }
        }
        let origin = px([0.0; 3]);
        let step = [0, 1, 2].map(|a| {
            let mut t = [0; 3];
            t[a] = 1;
            let q = px(Pose::new(0, t).apply_ldu([0.0; 3]));
            [q[0] - origin[0], q[1] - origin[1]]
        });
        ScoreBound {
            sums,
            w,
            h,
            area: target.mask_area as f64,
            boxes,
            step,
        }
    }

    /// The bound for a placement at `pose`: 1 when the mask is empty (no pruning).
    fn of(&self, pose: &Pose) -> f64 {
        if self.area == 0.0 {
            return 1.0;
        }
        let b = self.boxes[pose.yaw as usize % 4];
        let t = pose.t.map(|v| v as f64);
        let dx = self.step[0][0] * t[0] + self.step[1][0] * t[1] + self.step[2][0] * t[2];
        let dy = self.step[0][1] * t[0] + self.step[1][1] * t[1] + self.step[2][1] * t[2];
        let clamp = |v: f64, n: usize| (v.max(0.0) as usize).min(n);
        let x0 = clamp((b[0] + dx).floor() - 1.0, self.w);
        let y0 = clamp((b[1] + dy).floor() - 1.0, self.h);
        let x1 = clamp((b[2] + dx).ceil() + 1.0, self.w);
        let y1 = clamp((b[3] + dy).ceil() + 1.0, self.h);
        if x1 <= x0 || y1 <= y0 {
            return 0.0;
        }
        let s = |x: usize, y: usize| self.sums[y * (self.w + 1) + x] as i64;
        let inside = s(x1, y1) - s(x0, y1) - s(x1, y0) + s(x0, y0);
        inside as f64 / self.area
    }
}

/// The `k` valid placements of `comp` on `base` whose visible silhouettes best match `mask`
/// (IoU; less [`DETACHED_PENALTY`] for a placement standing on the ground away from the base),
/// best first (ties: smaller pose), and whether the time limit cut the search short. On a
/// non-empty base the ground is searched beside the base, and with `wide_ground` also wherever
/// the part may be seen in `mask` ([`ground_search`]). Placements are scored most promising
/// first ([`ScoreBound`]) and the search stops once none left can enter the ranking: the
/// result is [`abys_ranking`]'s with `exhaustive`, which scores them all.
#[allow(clippy::too_many_arguments)]
pub fn abys_ranked(
    base: &Assembly,
    comp: &Arc<Component>,
    camera: &Camera,
    width: u32,
    height: u32,
    mask: &[bool],
    k: usize,
    time_limit_s: f64,
    wide_ground: bool,
) -> Result<(Vec<(Pose, f64)>, bool)> {
    abys_ranking(
        base,
        comp,
        camera,
        width,
        height,
        mask,
        k,
        time_limit_s,
        wide_ground,
        false,
    )
}

/// [`abys_ranked`], or with `exhaustive` every valid placement scored, none skipped by its bound:
/// the reference the pruned search must equal (tests, benchmarks).
#[allow(clippy::too_many_arguments)]
pub fn abys_ranking(
    base: &Assembly,
    comp: &Arc<Component>,
    camera: &Camera,
    width: u32,
    height: u32,
    mask: &[bool],
    k: usize,
    time_limit_s: f64,
    wide_ground: bool,
    exhaustive: bool,
) -> Result<(Vec<(Pose, f64)>, bool)> {
    camera.validate()?;
    let n_px = width as usize * height as usize;
    if mask.len() != n_px {
        return Err(BrickGeomError::InvalidArgument(format!(
            "mask has {} pixels, the image {width}x{height} has {n_px}",
            mask.len()
        )));
    }
    let start = Instant::now();
    let depth = base_depth(base, camera, width, height)?;
    let target = MaskTarget::new(width, height, depth, mask.to_vec())?;
    let mut scored: Vec<(f64, Pose)> = Vec::new();
    let mut timed_out = false;
    let bounds = if wide_ground {
        mask_box(mask, width)
    } else {
        None
    };
    // every valid placement with the penalty its score takes
    let mut cands: Vec<(Pose, f64)> = Vec::new();
    for yaw in 0..4u8 {
        let (ground, beside) = if base.is_empty() {
            let all = GroundSearch::Region {
                x0: -40,
                x1: 40,
                z0: -40,
                z1: 40,
            };
            (all, None)
        } else if wide_ground {
            ground_search(base, comp, yaw, camera, width, height, bounds)
        } else {
            (GroundSearch::Auto, None)
        };
        let detached = |c: &crate::assembly::Placement| {
            c.kind == AttachKind::Ground
                && beside.is_some_and(|b| {
                    let t = c.pose.t;
                    t[0] < b[0] || t[0] > b[1] || t[2] < b[2] || t[2] > b[3]
                })
        };
        for c in base.candidates(comp, yaw, ground)? {
            let penalty = if detached(&c) { DETACHED_PENALTY } else { 0.0 };
            cands.push((c.pose, penalty));
        }
    }
    // Most promising first: no placement scores more than the share of the mask inside its
    // drawn box (its IoU is at most that, less its penalty). Once the best k found so far all
    // beat every bound left, the rest cannot enter the ranking: it is the ranking of scoring
    // them all.
    let order: Vec<(f64, usize)> = if !exhaustive {
        let bound = ScoreBound::new(comp, camera, width, height, &target);
        let mut order: Vec<(f64, usize)> = cands
            .iter()
            .enumerate()
            .map(|(i, (pose, penalty))| (bound.of(pose) - penalty, i))
            .collect();
        order.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        order
    } else {
        (0..cands.len()).map(|i| (f64::INFINITY, i)).collect()
    };
    let mut kth = f64::NEG_INFINITY; // the k-th best score so far
                                     // Score in parallel, in chunks so the time limit and the bound are checked between chunks.
    for chunk in order.chunks(64) {
        if scored.len() >= k && chunk[0].0 < kth {
            break;
        }
        if start.elapsed().as_secs_f64() > time_limit_s {
            timed_out = true;
            break;
        }
        let scores: Vec<Result<(f64, Pose)>> = chunk
            .par_iter()
            .map(|&(_, i)| {
                let (pose, penalty) = cands[i];
                let iou = pose_iou(comp, &pose, camera, &target)?;
                Ok((iou - penalty, pose))
            })
            .collect();
        for sc in scores {
            scored.push(sc?);
        }
        if scored.len() >= k {
            scored.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            scored.truncate(k);
            kth = scored[k - 1].0;
        }
    }
    scored.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    scored.truncate(k);
    Ok((
        scored.into_iter().map(|(iou, p)| (p, iou)).collect(),
        timed_out,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: u32 = 128;

    fn comp(id: &str) -> Arc<Component> {
        Arc::new(Component::primitive(id).unwrap())
    }

    /// Every valid placement of `c` on `base` scored against `mask`, best `k` first: the
    /// ranking `abys_ranked` must return. Also checks that no score beats its bound.
    fn every_placement(
        base: &Assembly,
        c: &Arc<Component>,
        cam: &Camera,
        mask: &[bool],
        k: usize,
    ) -> Vec<(Pose, f64)> {
        let depth = base_depth(base, cam, W, W).unwrap();
        let target = MaskTarget::new(W, W, depth, mask.to_vec()).unwrap();
        let bound = ScoreBound::new(c, cam, W, W, &target);
        let mut all = Vec::new();
        for yaw in 0..4u8 {
            for cand in base.candidates(c, yaw, GroundSearch::Auto).unwrap() {
                let iou = pose_iou(c, &cand.pose, cam, &target).unwrap();
                assert!(
                    iou <= bound.of(&cand.pose),
                    "{iou} > bound at {:?}",
                    cand.pose
                );
                all.push((iou, cand.pose));
            }
        }
        all.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        all.truncate(k);
        all.into_iter().map(|(s, p)| (p, s)).collect()
    }

    #[test]
    fn pruned_ranking_is_the_ranking_of_every_placement() {
        let mut base = Assembly::new();
        base.add(comp("3001"), Pose::new(0, [0, 3, 0])).unwrap();
        base.add(comp("3001"), Pose::new(1, [4, 6, 2])).unwrap();
        base.add(comp("3022"), Pose::new(0, [-4, 4, 0])).unwrap();
        let cam = Camera::new(30.0, 225.0, 0.0, 0.012, [0.0, -0.1]).unwrap();
        let c = comp("3040b");
        // masks: a placement's own silhouette, the same shifted, a blob, a corner, nothing
        let mut after = base.clone();
        let id = after.add(c.clone(), Pose::new(2, [0, 6, 0])).unwrap();
        let drawn = crate::scene::render_assembly(
            &after,
            &cam,
            &RenderOptions::new(W, W),
            &crate::colours::ColourTable::builtin(),
            &crate::scene::MeshSource::builtin(),
        )
        .unwrap();
        let own: Vec<bool> = drawn.ids.iter().map(|&i| i == id as i32).collect();
        assert!(own.iter().filter(|&&m| m).count() > 50, "test layout");
        let shifted: Vec<bool> = (0..own.len())
            .map(|i| i % W as usize >= 5 && own[i - 5])
            .collect();
        let blob: Vec<bool> = (0..own.len())
            .map(|i| {
                let (x, y) = ((i % W as usize) as i32 - 70, (i / W as usize) as i32 - 50);
                x * x + y * y < 150
            })
            .collect();
        let corner: Vec<bool> = (0..own.len()).map(|i| i < 3 * W as usize).collect();
        let none = vec![false; own.len()];
        for (name, mask) in [
            ("own", &own),
            ("shifted", &shifted),
            ("blob", &blob),
            ("corner", &corner),
            ("none", &none),
        ] {
            for k in [1, 8] {
                let (ranked, timed_out) =
                    abys_ranked(&base, &c, &cam, W, W, mask, k, 60.0, false).unwrap();
                assert!(!timed_out);
                assert_eq!(
                    ranked,
                    every_placement(&base, &c, &cam, mask, k),
                    "{name}, k {k}"
                );
            }
        }
    }
}
