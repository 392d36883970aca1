//! Camera estimation kernels (DESIGN §4: a manual in the wild does not state its camera).
//!
//! mepnet fits each step's weak-perspective camera to the step picture from what it already
//! knows: the shape built so far. Which shape, which picture and which hypotheses is decided in
//! Python (`mepnet.cameras`); this module holds the loops that must be fast:
//!
//! - [`foreground`]: the drawing's pixels: everything that is not page, the page being the
//!   colour of the image border and connected to it (so white faces enclosed by outlines count
//!   as drawing), small specks removed.
//! - [`box_silhouette`] and [`search_orientations`]: coarse silhouettes (each brick's voxel box
//!   plus a slab for its studs, as convex polygons) to rank orientation hypotheses by IoU with
//!   the foreground, the shape framed to the foreground's bounding box.
//! - [`fit_camera`]: the fine fit. The shape is rendered with the current camera by the
//!   manual renderer; each rendered pixel keeps its colour and its 3D surface point. A robust
//!   (Tukey) Gauss-Newton / Levenberg-Marquardt loop then moves the camera so that the picture,
//!   sampled where each surface point projects, shows the rendered colour (mapped onto the
//!   picture's tones by a per-channel gain and bias and a shade factor per face axis: other
//!   renderers light faces differently), coarse to fine over box-blurred copies of picture and
//!   template. Pixels of the shape that something new hides are outliers and drop
//!   out, so the same fit serves a picture of exactly the shape and a picture of the shape with
//!   new parts on it. Sub-pixel: it uses every outline and face edge of the shape, not only its
//!   silhouette.
//!
//! Parameters of the fit, in this order ([`Params`]): elevation, azimuth, roll (degrees),
//! ln scale, translation x, y (NDC).

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use crate::assembly::Assembly;
use crate::camera::Camera;
use crate::colours::ColourTable;
use crate::component::MAIN_COLOUR;
use crate::error::{BrickGeomError, Result};
use crate::library::part;
use crate::raster::RenderOptions;
use crate::scene::{render_assembly, MeshSource};

/// Camera parameters as the fit moves them: elevation, azimuth, roll (degrees), ln scale,
/// translation x, y (NDC).
pub type Params = [f64; 6];

/// A ranked placement of [`search_placements`]: IoU, yaw, translation and the framed camera.
pub type RankedPlacement = (f64, u8, crate::lattice::Lattice, Camera);

/// A 2x4 projection to pixels, as rows.
type PixelMatrix = [[f64; 4]; 2];

/// What one Gauss-Newton step needs: tone, mean robust cost, J^T W J, J^T W r and the samples
/// that fell on the picture.
type NormalEquations = (Tone, f64, DMatrix<f64>, DVector<f64>, usize);

/// The fit's parameters of a camera.
pub fn params_of(c: &Camera) -> Params {
    [
        c.elevation,
        c.azimuth,
        c.roll,
        c.scale.ln(),
        c.translation[0],
        c.translation[1],
    ]
}

/// The camera of fit parameters (an error for a non-finite or out-of-range value).
pub fn camera_of(p: &Params) -> Result<Camera> {
    Camera::new(p[0], p[1], p[2], p[3].exp(), [p[4], p[5]])
}

fn check_image(len: usize, width: u32, height: u32, channels: usize, what: &str) -> Result<()> {
    if width < 3 || height < 3 || width > 8192 || height > 8192 {
        return Err(BrickGeomError::InvalidArgument(format!(
            "{what}: image size must be 3..=8192 pixels per side, got {width}x{height}"
        )));
    }
    let n = width as usize * height as usize * channels;
    if len != n {
        return Err(BrickGeomError::InvalidArgument(format!(
            "{what}: expected {width}x{height}x{channels} = {n} values, got {len}"
        )));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Foreground

/// The drawing's pixels of a picture.
#[derive(Debug, Clone)]
pub struct Foreground {
    /// `height * width`, row major: true on the drawing.
    pub mask: Vec<bool>,
    /// The page colour (per-channel median of the border pixels).
    pub background: [u8; 3],
    /// Drawing pixels.
    pub area: usize,
}

/// The drawing's pixels of an RGB picture (`height * width * 3` bytes, row major): pixels
/// whose largest channel difference from the page colour exceeds `threshold` (0..255), plus
/// every page-coloured region the border cannot reach (faces enclosed by outlines); then
/// 4-connected groups of drawing pixels smaller than `min_area` pixels (specks, noise) are
/// page again.
pub fn foreground(
    rgb: &[u8],
    width: u32,
    height: u32,
    threshold: f32,
    min_area: usize,
) -> Result<Foreground> {
    check_image(rgb.len(), width, height, 3, "foreground")?;
    if !(0.0..=255.0).contains(&threshold) {
        return Err(BrickGeomError::InvalidArgument(format!(
            "foreground threshold must be within [0, 255], got {threshold}"
        )));
    }
    let (w, h) = (width as usize, height as usize);
    let mut border: [Vec<u8>; 3] = [Vec::new(), Vec::new(), Vec::new()];
    for y in 0..h {
        for x in 0..w {
            if x == 0 || y == 0 || x + 1 == w || y + 1 == h {
                for (c, b) in border.iter_mut().enumerate() {
                    b.push(rgb[(y * w + x) * 3 + c]);
                }
            }
        }
    }
    let mut background = [0u8; 3];
    for (c, b) in border.iter_mut().enumerate() {
        b.sort_unstable();
        background[c] = b[b.len() / 2];
    }
    let page: Vec<bool> = rgb
        .chunks_exact(3)
        .map(|px| {
            (0..3)
                .map(|c| (px[c] as f32 - background[c] as f32).abs())
                .fold(0.0, f32::max)
                <= threshold
        })
        .collect();
    // The page is what the border reaches through page-coloured pixels.
    let mut outside = vec![false; w * h];
    let mut stack: Vec<usize> = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if (x == 0 || y == 0 || x + 1 == w || y + 1 == h) && page[i] && !outside[i] {
                outside[i] = true;
                stack.push(i);
            }
        }
    }
    flood(&mut stack, w, h, |i| page[i], &mut outside);
    let mut mask: Vec<bool> = outside.iter().map(|&o| !o).collect();
    // Specks: small groups of drawing pixels.
    if min_area > 1 {
        let mut seen = vec![false; w * h];
        let mut group = Vec::new();
        for start in 0..w * h {
            if !mask[start] || seen[start] {
                continue;
            }
            group.clear();
            seen[start] = true;
            stack.push(start);
            while let Some(i) = stack.pop() {
                group.push(i);
                for j in neighbours(i, w, h) {
                    if mask[j] && !seen[j] {
                        seen[j] = true;
                        stack.push(j);
                    }
                }
            }
            if group.len() < min_area {
                for &i in &group {
                    mask[i] = false;
                }
            }
        }
    }
    let area = mask.iter().filter(|&&m| m).count();
    Ok(Foreground {
        mask,
        background,
        area,
    })
}

/// The 4-neighbours of pixel `i` inside a `w` x `h` image.
fn neighbours(i: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (x, y) = (i % w, i / w);
    [
        (x > 0).then(|| i - 1),
        (x + 1 < w).then(|| i + 1),
        (y > 0).then(|| i - w),
        (y + 1 < h).then(|| i + w),
    ]
    .into_iter()
    .flatten()
}

/// Grow `reached` from the pixels on `stack` through pixels where `open` holds.
fn flood(
    stack: &mut Vec<usize>,
    w: usize,
    h: usize,
    open: impl Fn(usize) -> bool,
    reached: &mut [bool],
) {
    while let Some(i) = stack.pop() {
        for j in neighbours(i, w, h) {
            if !reached[j] && open(j) {
                reached[j] = true;
                stack.push(j);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Edge directions

/// Separable filter of a `w` x `h` image: `ky` along columns (down the rows), `kx` along rows
/// (edges clamped).
fn separable(img: &[f32], w: usize, h: usize, ky: &[f32], kx: &[f32]) -> Vec<f32> {
    let (ry, rx) = (ky.len() / 2, kx.len() / 2);
    let mut tmp = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0.0;
            for (i, k) in ky.iter().enumerate() {
                let yy = (y + i).saturating_sub(ry).min(h - 1);
                acc += k * img[yy * w + x];
            }
            tmp[y * w + x] = acc;
        }
    }
    let mut out = vec![0.0f32; w * h];
    for y in 0..h {
        let row = &tmp[y * w..(y + 1) * w];
        for x in 0..w {
            let mut acc = 0.0;
            for (i, k) in kx.iter().enumerate() {
                acc += k * row[(x + i).saturating_sub(rx).min(w - 1)];
            }
            out[y * w + x] = acc;
        }
    }
    out
}

fn gaussian(sigma: f32, derivative: bool) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as i32 + 1;
    let g: Vec<f32> = (-r..=r)
        .map(|x| (-0.5 * (x as f32 / sigma).powi(2)).exp())
        .collect();
    let sum: f32 = g.iter().sum();
    if derivative {
        // d/dx of the normalised Gaussian, as a correlation kernel
        (-r..=r)
            .zip(&g)
            .map(|(x, v)| x as f32 / (sigma * sigma) * v / sum)
            .collect()
    } else {
        g.iter().map(|v| v / sum).collect()
    }
}

/// The directions of a picture's edges: a histogram over [0, 180) degrees (`bins` bins,
/// counter-clockwise from the picture's x axis, y up) of the dominant local direction of the
/// grey image's structure tensor (Gaussian derivatives of scale `sigma`, averaged over
/// `rho`), each pixel weighted by its edge strength times its coherence (one direction, not a
/// corner). Under weak perspective the edges along the lattice's x, y and z axes fall into
/// three directions that depend only on the camera's orientation.
pub fn edge_directions(
    rgb: &[u8],
    width: u32,
    height: u32,
    bins: usize,
    sigma: f32,
    rho: f32,
) -> Result<Vec<f64>> {
    check_image(rgb.len(), width, height, 3, "edge_directions")?;
    if !(1..=3600).contains(&bins) || !(0.3..=20.0).contains(&sigma) || !(0.3..=20.0).contains(&rho)
    {
        return Err(BrickGeomError::InvalidArgument(format!(
            "edge_directions: bins 1..=3600, sigma and rho within [0.3, 20], got {bins}, {sigma}, {rho}"
        )));
    }
    let (w, h) = (width as usize, height as usize);
    let grey: Vec<f32> = rgb
        .chunks_exact(3)
        .map(|p| (p[0] as f32 + p[1] as f32 + p[2] as f32) / (3.0 * 255.0))
        .collect();
    let (g, d) = (gaussian(sigma, false), gaussian(sigma, true));
    let gx = separable(&grey, w, h, &g, &d);
    // rows run down: d/dy (y up) is minus the derivative down the rows
    let gy: Vec<f32> = separable(&grey, w, h, &d, &g).iter().map(|v| -v).collect();
    let r = gaussian(rho, false);
    let prod = |f: &dyn Fn(usize) -> f32| -> Vec<f32> { (0..w * h).map(f).collect() };
    let jxx = separable(&prod(&|i| gx[i] * gx[i]), w, h, &r, &r);
    let jyy = separable(&prod(&|i| gy[i] * gy[i]), w, h, &r, &r);
    let jxy = separable(&prod(&|i| gx[i] * gy[i]), w, h, &r, &r);
    let mut hist = vec![0.0f64; bins];
    for i in 0..w * h {
        let (a, b, c) = (jxx[i] as f64, jyy[i] as f64, jxy[i] as f64);
        let trace = a + b;
        let aniso = ((a - b).powi(2) + 4.0 * c * c).sqrt();
        if trace <= 1e-12 {
            continue;
        }
        let weight = aniso * aniso / trace;
        if weight < 1e-4 {
            continue;
        }
        // the gradient's direction, turned a quarter: the edge's
        let edge = (0.5 * (2.0 * c).atan2(a - b)).to_degrees() + 90.0;
        let bin = ((edge.rem_euclid(180.0)) / 180.0 * bins as f64) as usize;
        hist[bin.min(bins - 1)] += weight;
    }
    let total: f64 = hist.iter().sum();
    if total > 0.0 {
        hist.iter_mut().for_each(|v| *v /= total);
    }
    Ok(hist)
}

// ---------------------------------------------------------------------------------------------
// Coarse silhouettes

/// Boxes (LDU min, max corners) standing in for an assembly's shape: each brick's voxel box,
/// and a 4 LDU slab over the extent of its studs.
fn shape_boxes(asm: &Assembly) -> Result<Vec<([f64; 3], [f64; 3])>> {
    bricks_boxes(&asm.bricks())
}

/// [`shape_boxes`] of placed bricks.
fn bricks_boxes(bricks: &[crate::component::Brick]) -> Result<Vec<([f64; 3], [f64; 3])>> {
    let mut out = Vec::new();
    for b in bricks {
        let def = part(b.part)?;
        let mut lo = [f64::MAX; 3];
        let mut hi = [f64::MIN; 3];
        for v in &def.voxels {
            let c = b.pose.apply_cell(*v);
            for a in 0..3 {
                let unit = if a == 1 { 8.0 } else { 10.0 };
                lo[a] = lo[a].min(c[a] as f64 * unit);
                hi[a] = hi[a].max((c[a] + 1) as f64 * unit);
            }
        }
        if lo[0] <= hi[0] {
            out.push((lo, hi));
        }
        if !def.studs.is_empty() {
            let mut slo = [f64::MAX; 3];
            let mut shi = [f64::MIN; 3];
            for s in &def.studs {
                let p = b.pose.apply_point(*s);
                let q = [p[0] as f64 * 10.0, p[1] as f64 * 8.0, p[2] as f64 * 10.0];
                for a in [0, 2] {
                    slo[a] = slo[a].min(q[a] - 6.0);
                    shi[a] = shi[a].max(q[a] + 6.0);
                }
                slo[1] = slo[1].min(q[1]);
                shi[1] = shi[1].max(q[1] + 4.0);
            }
            out.push((slo, shi));
        }
    }
    Ok(out)
}

/// The 2D convex hull (counter-clockwise) of up to a few dozen points.
fn hull(points: &mut [[f64; 2]]) -> Vec<[f64; 2]> {
    points.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut out: Vec<[f64; 2]> = Vec::with_capacity(points.len() + 1);
    for pass in 0..2 {
        let start = out.len();
        let iter: Box<dyn Iterator<Item = &[f64; 2]>> = if pass == 0 {
            Box::new(points.iter())
        } else {
            Box::new(points.iter().rev())
        };
        for &p in iter {
            while out.len() >= start + 2 && cross(out[out.len() - 2], out[out.len() - 1], p) <= 0.0
            {
                out.pop();
            }
            out.push(p);
        }
        out.pop();
    }
    out
}

/// Fill the pixels whose centres lie inside a convex polygon (pixel coordinates).
fn fill_convex(poly: &[[f64; 2]], w: usize, h: usize, mask: &mut [bool]) {
    if poly.len() < 3 {
        return;
    }
    let y_lo = poly.iter().map(|p| p[1]).fold(f64::MAX, f64::min);
    let y_hi = poly.iter().map(|p| p[1]).fold(f64::MIN, f64::max);
    let r0 = ((y_lo - 0.5).ceil().max(0.0)) as usize;
    let r1 = ((y_hi - 0.5).floor()).min(h as f64 - 1.0);
    if r1 < 0.0 {
        return;
    }
    for row in r0..=(r1 as usize) {
        let yc = row as f64 + 0.5;
        let (mut xl, mut xr) = (f64::MAX, f64::MIN);
        for k in 0..poly.len() {
            let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
            if (a[1] <= yc && b[1] >= yc) || (b[1] <= yc && a[1] >= yc) {
                let x = if (b[1] - a[1]).abs() < 1e-12 {
                    xl = xl.min(a[0].min(b[0]));
                    a[0].max(b[0])
                } else {
                    a[0] + (yc - a[1]) / (b[1] - a[1]) * (b[0] - a[0])
                };
                xl = xl.min(x);
                xr = xr.max(x);
            }
        }
        if xl > xr {
            continue;
        }
        let c0 = ((xl - 0.5).ceil().max(0.0)) as usize;
        let c1 = (xr - 0.5).floor().min(w as f64 - 1.0);
        if c1 < 0.0 {
            continue;
        }
        for c in c0..=(c1 as usize) {
            mask[row * w + c] = true;
        }
    }
}

/// Rasterize boxes with a camera into a `w` x `h` mask.
fn rasterize_boxes(
    boxes: &[([f64; 3], [f64; 3])],
    camera: &Camera,
    w: usize,
    h: usize,
) -> Vec<bool> {
    let m = camera.pixel_matrix(w as u32, h as u32);
    let mut mask = vec![false; w * h];
    let mut corners = [[0.0f64; 2]; 8];
    for (lo, hi) in boxes {
        for (k, c) in corners.iter_mut().enumerate() {
            let p = [
                if k & 1 == 0 { lo[0] } else { hi[0] },
                if k & 2 == 0 { lo[1] } else { hi[1] },
                if k & 4 == 0 { lo[2] } else { hi[2] },
            ];
            for (a, v) in c.iter_mut().enumerate() {
                *v = m[(a, 0)] * p[0] + m[(a, 1)] * p[1] + m[(a, 2)] * p[2] + m[(a, 3)];
            }
        }
        let poly = hull(&mut corners);
        fill_convex(&poly, w, h, &mut mask);
    }
    mask
}

/// The coarse silhouette of an assembly (bricks as voxel boxes, studs as slabs) seen by a
/// camera, `height * width` row major.
pub fn box_silhouette(
    asm: &Assembly,
    camera: &Camera,
    width: u32,
    height: u32,
) -> Result<Vec<bool>> {
    camera.validate()?;
    check_image(
        width as usize * height as usize,
        width,
        height,
        1,
        "box_silhouette",
    )?;
    let boxes = shape_boxes(asm)?;
    Ok(rasterize_boxes(
        &boxes,
        camera,
        width as usize,
        height as usize,
    ))
}

/// A mask reduced to at most `work` pixels on its longer side (a cell is set when at least half
/// of it is), with its new size.
fn reduce(mask: &[bool], w: usize, h: usize, work: usize) -> (Vec<bool>, usize, usize) {
    let f = w.max(h).div_ceil(work.max(1)).max(1);
    let (rw, rh) = (w.div_ceil(f), h.div_ceil(f));
    let mut count = vec![0u32; rw * rh];
    let mut total = vec![0u32; rw * rh];
    for y in 0..h {
        for x in 0..w {
            let j = (y / f) * rw + x / f;
            total[j] += 1;
            count[j] += u32::from(mask[y * w + x]);
        }
    }
    let out = count
        .iter()
        .zip(&total)
        .map(|(&c, &t)| 2 * c >= t && c > 0)
        .collect();
    (out, rw, rh)
}

fn bbox(mask: &[bool], w: usize) -> Option<[f64; 4]> {
    let mut b: Option<[f64; 4]> = None;
    for (i, &m) in mask.iter().enumerate() {
        if m {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            b = Some(match b {
                None => [x, y, x + 1.0, y + 1.0],
                Some(b) => [
                    b[0].min(x),
                    b[1].min(y),
                    b[2].max(x + 1.0),
                    b[3].max(y + 1.0),
                ],
            });
        }
    }
    b
}

/// Rank orientation hypotheses `(elevation, azimuth, roll)` for a picture that shows exactly
/// the assembly: for each, the coarse silhouette ([`box_silhouette`]) is framed to the
/// foreground's bounding box (scale and translation) and scored by IoU with the foreground,
/// both at most `work` pixels on a side. Returns `(iou, camera)` per hypothesis, in the order
/// given (the camera for the full `width` x `height` picture). An empty foreground or shape
/// scores 0 with the hypothesis' orientation at scale 1.
pub fn search_orientations(
    asm: &Assembly,
    fg: &[bool],
    width: u32,
    height: u32,
    candidates: &[[f64; 3]],
    work: u32,
) -> Result<Vec<(f64, Camera)>> {
    check_image(fg.len(), width, height, 1, "search_orientations")?;
    let (w, h) = (width as usize, height as usize);
    let (small, sw, sh) = reduce(fg, w, h, work as usize);
    let boxes = shape_boxes(asm)?;
    let target = bbox(&small, sw);
    let area_fg = small.iter().filter(|&&m| m).count();
    candidates
        .par_iter()
        .map(|&[el, az, roll]| framed_iou(&boxes, [el, az, roll], target, &small, sw, sh, area_fg))
        .collect()
}

/// The coarse silhouette of `boxes` seen from an orientation, framed to the foreground's box
/// `target` (reduced picture `small`, `sw` x `sh`), and its IoU with the foreground.
#[allow(clippy::too_many_arguments)]
fn framed_iou(
    boxes: &[([f64; 3], [f64; 3])],
    [el, az, roll]: [f64; 3],
    target: Option<[f64; 4]>,
    small: &[bool],
    sw: usize,
    sh: usize,
    area_fg: usize,
) -> Result<(f64, Camera)> {
    let unit = Camera::new(el, az, roll, 1.0, [0.0, 0.0])?;
    let (Some(t), false) = (target, boxes.is_empty()) else {
        return Ok((0.0, unit));
    };
    // the boxes' projected extent at scale 1 (image axes u right, v up)
    let r = unit.rotation();
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for (blo, bhi) in boxes {
        for k in 0..8 {
            let p = [
                if k & 1 == 0 { blo[0] } else { bhi[0] },
                if k & 2 == 0 { blo[1] } else { bhi[1] },
                if k & 4 == 0 { blo[2] } else { bhi[2] },
            ];
            for a in 0..2 {
                let c = r[(a, 0)] * p[0] + r[(a, 1)] * p[1] + r[(a, 2)] * p[2];
                lo[a] = lo[a].min(c);
                hi[a] = hi[a].max(c);
            }
        }
    }
    // foreground box in NDC (x right, y up); a side on the picture's border may be cut
    let (fx0, fx1) = (2.0 * t[0] / sw as f64 - 1.0, 2.0 * t[2] / sw as f64 - 1.0);
    let (fy0, fy1) = (1.0 - 2.0 * t[3] / sh as f64, 1.0 - 2.0 * t[1] / sh as f64);
    let cut = [
        t[0] <= 0.0,
        t[2] >= sw as f64,
        t[3] >= sh as f64,
        t[1] <= 0.0,
    ];
    let sx = (fx1 - fx0) / (hi[0] - lo[0]).max(1e-9);
    let sy = (fy1 - fy0) / (hi[1] - lo[1]).max(1e-9);
    let s = match (cut[0] || cut[1], cut[2] || cut[3]) {
        (false, false) => (sx * sy).sqrt(),
        (true, false) => sy,
        (false, true) => sx,
        (true, true) => sx.max(sy),
    }
    .clamp(1e-6, 1e3);
    // align the sides that are not cut (centres when neither or both are)
    let place = |f0: f64, f1: f64, l: f64, h: f64, c0: bool, c1: bool| match (c0, c1) {
        (true, false) => f1 - s * h,
        (false, true) => f0 - s * l,
        _ => (f0 + f1) / 2.0 - s * (l + h) / 2.0,
    };
    let tx = place(fx0, fx1, lo[0], hi[0], cut[0], cut[1]);
    let ty = place(fy0, fy1, lo[1], hi[1], cut[2], cut[3]);
    let cam = Camera::new(el, az, roll, s, [tx, ty])?;
    let sil = rasterize_boxes(boxes, &cam, sw, sh);
    let inter = sil.iter().zip(small).filter(|(&a, &b)| a && b).count();
    let union = sil.iter().filter(|&&a| a).count() + area_fg - inter;
    Ok((inter as f64 / union.max(1) as f64, cam))
}

/// Rank the valid placements of `comp` on `base` (every yaw; stud, anti-stud and ground
/// contacts) for a picture that shows exactly the base with that component added, as seen from
/// one of `orientations`: per placement and orientation, the coarse silhouette of the whole
/// framed to the foreground's box and scored by IoU with it ([`search_orientations`]).
/// Returns the `k` best `(iou, yaw, t, camera)`, best first.
#[allow(clippy::too_many_arguments)]
pub fn search_placements(
    base: &Assembly,
    comp: &std::sync::Arc<crate::component::Component>,
    fg: &[bool],
    width: u32,
    height: u32,
    orientations: &[[f64; 3]],
    work: u32,
    k: usize,
) -> Result<Vec<RankedPlacement>> {
    check_image(fg.len(), width, height, 1, "search_placements")?;
    let (w, h) = (width as usize, height as usize);
    let (small, sw, sh) = reduce(fg, w, h, work as usize);
    let target = bbox(&small, sw);
    let area_fg = small.iter().filter(|&&m| m).count();
    let base_boxes = shape_boxes(base)?;
    let mut poses = Vec::new();
    for yaw in 0..4u8 {
        for c in base.candidates(comp, yaw, crate::assembly::GroundSearch::Auto)? {
            poses.push(c.pose);
        }
    }
    let scored: Vec<Result<Vec<RankedPlacement>>> = poses
        .par_iter()
        .map(|pose| {
            let bricks: Vec<_> = comp
                .bricks
                .iter()
                .map(|b| b.placed_by(pose, MAIN_COLOUR))
                .collect();
            let mut boxes = base_boxes.clone();
            boxes.extend(bricks_boxes(&bricks)?);
            orientations
                .iter()
                .map(|&o| {
                    let (iou, cam) = framed_iou(&boxes, o, target, &small, sw, sh, area_fg)?;
                    Ok((iou, pose.yaw, pose.t, cam))
                })
                .collect()
        })
        .collect();
    let mut all = Vec::new();
    for r in scored {
        all.extend(r?);
    }
    all.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    all.truncate(k);
    Ok(all)
}

// ---------------------------------------------------------------------------------------------
// The fine fit

/// Settings of [`fit_camera`].
#[derive(Debug, Clone, PartialEq)]
pub struct FitOptions {
    /// Which parameters move ([`Params`] order); the others keep their initial values.
    pub free: [bool; 6],
    /// The levels, coarse to fine: box-blur radii (pixels) of picture and template. A level
    /// renders the shape anew at the current camera (visibility and the renderer's pixel
    /// sampling move with it) when the camera moved by more than `rerender_px` since the last
    /// render, and the last level always does, so repeating the finest level refines.
    pub levels: Vec<u32>,
    /// Camera motion (RMS over the shape's pixels) that makes a level render the shape anew.
    pub rerender_px: f64,
    /// Gauss-Newton iterations per level at most.
    pub iterations: u32,
    /// Tukey cut-off of a colour residual (colours in [0, 1]): larger residuals are outliers.
    pub tukey: f64,
    /// Template pixels used at most (an even subsample of the shape's pixels).
    pub samples: usize,
    /// A Gaussian prior on the parameters: centre and weight per parameter (0: none), in units
    /// of the mean robust cost per sample.
    pub prior: Option<(Params, Params)>,
    /// Outline width of the template render, as a share of the renderer's own (0: faces only:
    /// pictures whose lines are drawn otherwise then align by their colour regions).
    pub lines: f32,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            free: [true; 6],
            levels: vec![4, 2, 1, 0, 0],
            rerender_px: 0.0,
            iterations: 8,
            tukey: 0.3,
            samples: 6000,
            prior: None,
            lines: 1.0,
        }
    }
}

impl FitOptions {
    fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(BrickGeomError::InvalidArgument(m));
        if self.levels.is_empty() || self.levels.iter().any(|&b| b > 64) {
            return bad(format!(
                "fit levels: give 1 or more blur radii within 0..=64, got {:?}",
                self.levels
            ));
        }
        if self.rerender_px.is_nan() || self.rerender_px < 0.0 {
            return bad(format!(
                "fit rerender_px must be >= 0, got {}",
                self.rerender_px
            ));
        }
        if !(self.tukey > 0.0 && self.tukey <= 3.0) {
            return bad(format!(
                "fit tukey cut-off must be in (0, 3], got {}",
                self.tukey
            ));
        }
        if self.samples < 16 || self.iterations > 1000 {
            return bad(format!(
                "fit needs >= 16 samples and <= 1000 iterations, got {} and {}",
                self.samples, self.iterations
            ));
        }
        if !(0.0..=4.0).contains(&self.lines) {
            return bad(format!(
                "fit lines must be within [0, 4], got {}",
                self.lines
            ));
        }
        if let Some((c, wgt)) = &self.prior {
            if c.iter().chain(wgt).any(|v| !v.is_finite()) || wgt.iter().any(|&v| v < 0.0) {
                return bad("fit prior: centre and weights must be finite, weights >= 0".into());
            }
        }
        Ok(())
    }
}

/// The result of [`fit_camera`].
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFit {
    pub camera: Camera,
    /// Share of the shape's sampled pixels whose colour the picture shows where the camera
    /// puts them (every channel within half the Tukey cut-off): near 1 when the picture shows
    /// the shape as drawn, lower where new parts hide it, near 0 for a picture of something
    /// else.
    pub agree: f64,
    /// Share of the shape's silhouette (rendered at the result) on the picture's foreground.
    pub inside: f64,
    /// IoU of the shape's silhouette with the foreground.
    pub iou: f64,
    /// Mean robust cost per sample at the finest level.
    pub cost: f64,
    /// Samples used.
    pub samples: usize,
    /// Root mean square motion of the shape's sampled pixels from the initial camera (px).
    pub moved_px: f64,
}

/// A float image, `c` planes of `w * h`.
struct Planes {
    w: usize,
    h: usize,
    data: Vec<Vec<f32>>,
}

impl Planes {
    fn from_rgb(rgb: &[u8], w: usize, h: usize) -> Planes {
        let data = (0..3)
            .map(|c| {
                rgb.iter()
                    .skip(c)
                    .step_by(3)
                    .map(|&v| v as f32 / 255.0)
                    .collect()
            })
            .collect();
        Planes { w, h, data }
    }

    /// Separable box blur of radius `r` (edges clamped).
    fn blurred(&self, r: usize) -> Planes {
        if r == 0 {
            return Planes {
                w: self.w,
                h: self.h,
                data: self.data.clone(),
            };
        }
        let (w, h) = (self.w, self.h);
        let norm = 1.0 / (2 * r + 1) as f32;
        let data = self
            .data
            .iter()
            .map(|plane| {
                let mut tmp = vec![0.0f32; w * h];
                for y in 0..h {
                    let row = &plane[y * w..(y + 1) * w];
                    let at = |x: isize| row[x.clamp(0, w as isize - 1) as usize];
                    let mut acc: f32 = (-(r as isize)..=r as isize).map(at).sum();
                    for x in 0..w {
                        tmp[y * w + x] = acc * norm;
                        acc += at(x as isize + r as isize + 1) - at(x as isize - r as isize);
                    }
                }
                let mut out = vec![0.0f32; w * h];
                for x in 0..w {
                    let at = |y: isize| tmp[y.clamp(0, h as isize - 1) as usize * w + x];
                    let mut acc: f32 = (-(r as isize)..=r as isize).map(at).sum();
                    for y in 0..h {
                        out[y * w + x] = acc * norm;
                        acc += at(y as isize + r as isize + 1) - at(y as isize - r as isize);
                    }
                }
                out
            })
            .collect();
        Planes { w, h, data }
    }

    /// Central-difference gradients (x, y) of every plane.
    fn gradients(&self) -> (Planes, Planes) {
        let (w, h) = (self.w, self.h);
        let mut gx = Vec::new();
        let mut gy = Vec::new();
        for p in &self.data {
            let mut ax = vec![0.0f32; w * h];
            let mut ay = vec![0.0f32; w * h];
            for y in 0..h {
                for x in 0..w {
                    let (xl, xr) = (x.saturating_sub(1), (x + 1).min(w - 1));
                    let (yu, yd) = (y.saturating_sub(1), (y + 1).min(h - 1));
                    ax[y * w + x] = (p[y * w + xr] - p[y * w + xl]) / (xr - xl).max(1) as f32;
                    ay[y * w + x] = (p[yd * w + x] - p[yu * w + x]) / (yd - yu).max(1) as f32;
                }
            }
            gx.push(ax);
            gy.push(ay);
        }
        (Planes { w, h, data: gx }, Planes { w, h, data: gy })
    }

    /// Bilinear sample of the first three planes at pixel coordinates (pixel centres at +0.5).
    fn sample3(&self, x: f64, y: f64) -> [f32; 3] {
        let (w, h) = (self.w, self.h);
        let fx = (x - 0.5).clamp(0.0, (w - 1) as f64);
        let fy = (y - 0.5).clamp(0.0, (h - 1) as f64);
        let x0 = (fx as usize).min(w.saturating_sub(2));
        let y0 = (fy as usize).min(h.saturating_sub(2));
        let (ax, ay) = ((fx - x0 as f64) as f32, (fy - y0 as f64) as f32);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (i00, i01, i10, i11) = (y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1);
        [0, 1, 2].map(|c| {
            let p = &self.data[c];
            let top = p[i00] + (p[i01] - p[i00]) * ax;
            let bot = p[i10] + (p[i11] - p[i10]) * ax;
            top + (bot - top) * ay
        })
    }
}

/// A picture prepared for [`fit_camera`]: its colours as floats, and per blur radius the
/// blurred picture and its gradients, made on first use and kept (a step's picture is fitted
/// several times: hypotheses, the check after prediction, the next step's anchor).
pub struct FitPicture {
    planes: Planes,
    levels: std::sync::Mutex<Vec<(usize, std::sync::Arc<[Planes; 3]>)>>,
}

impl FitPicture {
    /// A picture of `height * width * 3` bytes (RGB, row major).
    pub fn new(rgb: &[u8], width: u32, height: u32) -> Result<FitPicture> {
        check_image(rgb.len(), width, height, 3, "fit picture")?;
        Ok(FitPicture {
            planes: Planes::from_rgb(rgb, width as usize, height as usize),
            levels: std::sync::Mutex::default(),
        })
    }

    /// Width and height in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.planes.w as u32, self.planes.h as u32)
    }

    /// The picture box-blurred by `blur` pixels and its x and y gradients.
    fn level(&self, blur: usize) -> std::sync::Arc<[Planes; 3]> {
        // a poisoned lock only means another thread panicked while adding a level; the list
        // itself is still valid
        let mut levels = self.levels.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, l)) = levels.iter().find(|(b, _)| *b == blur) {
            return l.clone();
        }
        let pb = self.planes.blurred(blur);
        let (gx, gy) = pb.gradients();
        let l = std::sync::Arc::new([pb, gx, gy]);
        levels.push((blur, l.clone()));
        l
    }
}

/// A template render: the sampled pixels (the shape's, and a ring of page around it) with their
/// 3D points (LDU; a page pixel takes the depth of the shape pixel next to it), the rendered
/// image and the shape's silhouette.
struct Template {
    pixels: Vec<usize>,
    points: Vec<[f64; 3]>,
    /// Per sample its lighting class: the face's axis (0..=2,
    /// [`crate::raster::Rendered::axes`]) or the page ([`PAGE`]).
    classes: Vec<u8>,
    image: Planes,
    silhouette: Vec<bool>,
}

#[allow(clippy::too_many_arguments)]
fn render_template(
    asm: &Assembly,
    camera: &Camera,
    w: usize,
    h: usize,
    samples: usize,
    lines: f32,
    source: &MeshSource,
    colours: &ColourTable,
) -> Result<Template> {
    let mut opts = RenderOptions::new(w as u32, h as u32);
    opts.line_px *= lines;
    let r = render_assembly(asm, camera, &opts, colours, source)?;
    let silhouette: Vec<bool> = r.ids.iter().map(|&i| i >= 0).collect();
    // The page around the shape: a ring of background pixels, each with the depth of the shape
    // pixel it was reached from (under weak perspective depth only matters through rotation).
    let mut depth: Vec<f32> = r.depth.clone();
    let mut frontier: Vec<usize> = (0..w * h)
        .filter(|&i| silhouette[i] && depth[i].is_finite())
        .collect();
    let mut ring: Vec<usize> = Vec::new();
    let ring_px = (w.max(h) / 85).max(2);
    for _ in 0..ring_px {
        let mut next = Vec::new();
        for &i in &frontier {
            for j in neighbours(i, w, h) {
                if !depth[j].is_finite() {
                    depth[j] = depth[i];
                    next.push(j);
                }
            }
        }
        ring.extend_from_slice(&next);
        frontier = next;
    }
    let shape: Vec<usize> = (0..w * h)
        .filter(|&i| silhouette[i] && r.depth[i].is_finite())
        .collect();
    // an even subsample of shape and ring pixels, in proportion
    let total = shape.len() + ring.len();
    let stride = total.div_ceil(samples.max(1)).max(1);
    ring.sort_unstable();
    let pixels: Vec<usize> = shape
        .into_iter()
        .step_by(stride)
        .chain(ring.into_iter().step_by(stride))
        .collect();
    // the renderer gives the page no axis (-1)
    let classes = pixels
        .iter()
        .map(|&i| u8::try_from(r.axes[i]).unwrap_or(PAGE))
        .collect();
    let rot = camera.rotation();
    let (s, [tx, ty]) = (camera.scale, camera.translation);
    let points = pixels
        .iter()
        .map(|&i| {
            let (col, row) = ((i % w) as f64, (i / w) as f64);
            let u = ((col + 0.5) / w as f64 * 2.0 - 1.0 - tx) / s;
            let v = (1.0 - (row + 0.5) / h as f64 * 2.0 - ty) / s;
            let d = depth[i] as f64;
            [0, 1, 2].map(|a| u * rot[(0, a)] + v * rot[(1, a)] + d * rot[(2, a)])
        })
        .collect();
    Ok(Template {
        pixels,
        points,
        classes,
        image: Planes::from_rgb(&r.rgb, w, h),
        silhouette,
    })
}

/// The pixel matrix of parameters and its derivatives (finite differences) per parameter.
fn projection(p: &Params, w: usize, h: usize) -> Result<(PixelMatrix, [PixelMatrix; 6])> {
    let m = |q: &Params| -> Result<[[f64; 4]; 2]> {
        let pm = camera_of(q)?.pixel_matrix(w as u32, h as u32);
        Ok([0, 1].map(|a| [0, 1, 2, 3].map(|b| pm[(a, b)])))
    };
    let m0 = m(p)?;
    let eps = [1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6];
    let mut d = [[[0.0; 4]; 2]; 6];
    for i in 0..6 {
        let mut q = *p;
        q[i] += eps[i];
        let mi = m(&q)?;
        for a in 0..2 {
            for b in 0..4 {
                d[i][a][b] = (mi[a][b] - m0[a][b]) / eps[i];
            }
        }
    }
    Ok((m0, d))
}

fn tukey_rho(r: f64, k: f64) -> f64 {
    if r.abs() >= k {
        k * k / 6.0
    } else {
        let u = 1.0 - (r / k) * (r / k);
        k * k / 6.0 * (1.0 - u * u * u)
    }
}

fn tukey_weight(r: f64, k: f64) -> f64 {
    if r.abs() >= k {
        0.0
    } else {
        let u = 1.0 - (r / k) * (r / k);
        u * u
    }
}

/// One level's data: template colours and lighting classes at the samples, picture and its
/// gradients.
struct Level<'a> {
    points: &'a [[f64; 3]],
    template: Vec<[f32; 3]>,
    classes: &'a [u8],
    picture: &'a Planes,
    gx: &'a Planes,
    gy: &'a Planes,
}

/// The lighting class of page samples (faces are 0..=2, their axis).
const PAGE: u8 = 3;

/// Camera motion (RMS over the samples, pixels) below which a fit's last level has converged.
const CONVERGED_PX: f64 = 0.002;
/// The same for the levels before it: a finer level refines what they leave, so they stop
/// earlier (at 0.002 px a blur-4 level of a step's fit ran to its iteration limit on 89% of
/// fits, moving 0.5 px per iteration at the median).
const CONVERGED_COARSE_PX: f64 = 0.05;

/// Samples per parallel task of a fit's per-sample sums (fixed, so that the sums do not depend
/// on the number of threads).
const CHUNK: usize = 512;

/// How template colours map onto the picture's: per channel a gain and bias (another renderer's
/// tone curve and page tint), and per lighting class a shade factor (another renderer lights
/// faces of each axis differently: LeoCAD draws the faces mepnet darkens most at 1.6 times
/// mepnet's brightness); the page's shade is 1. A sample of colour `t` and class `k` is drawn
/// as `gain * shade[k] * t + bias`.
#[derive(Clone, Copy, Debug)]
struct Tone {
    channels: [[f64; 2]; 3],
    shade: [f64; 4],
}

impl Tone {
    const IDENTITY: Tone = Tone {
        channels: [[1.0, 0.0]; 3],
        shade: [1.0; 4],
    };

    /// The template colour `t` of channel `c` and class `k` as the picture should show it.
    fn model(&self, c: usize, k: u8, t: f32) -> f64 {
        self.channels[c][0] * self.shade[k as usize] * t as f64 + self.channels[c][1]
    }
}

/// The range of the tone's per-channel gain and bias: another renderer's tone curve, page tint
/// and shading, but not the freedom to map one part colour onto another.
const TONE_GAIN: (f64, f64) = (0.7, 1.4);
const TONE_BIAS: f64 = 0.25;
/// The range of a lighting class's shade factor, and the samples a class needs to fit one.
const SHADE: (f64, f64) = (0.55, 1.8);
const SHADE_MIN_SAMPLES: usize = 24;
/// The least mean square of a class's (gain x template) values that fits its shade: below it the
/// class's colours are all darker than about 6% of white and show no shade.
const SHADE_MIN_SQUARE: f64 = 0.003_125;

/// Where a sample projects and the picture's colour there (None: off the picture).
type Seen = Option<([f64; 2], [f32; 3])>;

/// The samples a tone is fitted to: those that fell on the picture, template and picture colour
/// per channel and the lighting class, in the samples' order.
struct ToneSamples {
    template: Vec<[f64; 3]>,
    picture: Vec<[f64; 3]>,
    classes: Vec<u8>,
}

impl ToneSamples {
    fn new(seen: &[Seen], template: &[[f32; 3]], classes: &[u8]) -> ToneSamples {
        let n = seen.len();
        let mut out = ToneSamples {
            template: Vec::with_capacity(n),
            picture: Vec::with_capacity(n),
            classes: Vec::with_capacity(n),
        };
        for ((s, tv), &cl) in seen.iter().zip(template).zip(classes) {
            if let Some((_, pv)) = s {
                out.template.push(tv.map(f64::from));
                out.picture.push(pv.map(f64::from));
                out.classes.push(cl);
            }
        }
        out
    }

    /// Per channel, gain and bias by weighted least squares (the template shaded by `shade`);
    /// starts from the identity shifted by the median difference and from plain least squares,
    /// keeps the one more samples follow, refits on its inliers. The channels in parallel.
    fn channel_tone(&self, shade: &[f64; 4], k: f64) -> [[f64; 2]; 3] {
        let mut tone = [[1.0, 0.0]; 3];
        tone.par_iter_mut()
            .enumerate()
            .for_each(|(c, t)| *t = self.channel(c, shade, k));
        tone
    }

    /// [`ToneSamples::channel_tone`] of channel `c`.
    fn channel(&self, c: usize, shade: &[f64; 4], k: f64) -> [f64; 2] {
        let pairs: Vec<(f64, f64)> = self
            .template
            .iter()
            .zip(&self.picture)
            .zip(&self.classes)
            .map(|((tv, pv), &cl)| (shade[cl as usize] * tv[c], pv[c]))
            .collect();
        if pairs.len() < 16 {
            return [1.0, 0.0];
        }
        let pairs = &pairs;
        let mut diffs: Vec<f64> = pairs.iter().map(|(a, b)| b - a).collect();
        let mid = diffs.len() / 2;
        let median = *diffs.select_nth_unstable_by(mid, f64::total_cmp).1;
        let mut starts = vec![[1.0, median]];
        if let Some(g) = weighted_line(pairs, |_, _| 1.0) {
            starts.push(g);
        }
        let follows = |g: &[f64; 2]| {
            pairs
                .iter()
                .filter(|(a, b)| (b - (g[0] * a + g[1])).abs() < k / 2.0)
                .count()
        };
        let mut best = *starts
            .iter()
            .max_by_key(|g| follows(g))
            .unwrap_or(&[1.0, 0.0]);
        for _ in 0..2 {
            let g = best;
            let weight = |a: f64, b: f64| tukey_weight(b - (g[0] * a + g[1]), k);
            let Some(mut n) = weighted_line(pairs, weight) else {
                break;
            };
            // a renderer draws its own tones, but not the page and the parts all in one
            // colour: a flat gain would let the shape shrink into one face of the picture
            if !(TONE_GAIN.0..=TONE_GAIN.1).contains(&n[0]) {
                n[0] = n[0].clamp(TONE_GAIN.0, TONE_GAIN.1);
                let (mut sw, mut sr) = (0.0, 0.0);
                for &(a, b) in pairs.iter() {
                    let w = weight(a, b);
                    sw += w;
                    sr += w * (b - n[0] * a);
                }
                if sw <= 0.0 {
                    break;
                }
                n[1] = sr / sw;
            }
            best = n;
        }
        [
            best[0].clamp(TONE_GAIN.0, TONE_GAIN.1),
            best[1].clamp(-TONE_BIAS, TONE_BIAS),
        ]
    }

    /// Each face class's shade factor for the channels' gain and bias of `tone`: robust
    /// (Tukey-weighted) least squares over the class's samples and channels, from its current
    /// shade; a class with few samples, or dark ones only (that say nothing of it), keeps it.
    /// The classes in parallel.
    fn shades(&self, tone: &Tone, k: f64) -> [f64; 4] {
        let mut shade = tone.shade;
        shade[..PAGE as usize]
            .par_iter_mut()
            .enumerate()
            .for_each(|(class, sh)| *sh = self.shade(class, *sh, tone, k));
        shade
    }

    /// [`ToneSamples::shades`] of class `class`, from its shade `sh`.
    fn shade(&self, class: usize, sh: f64, tone: &Tone, k: f64) -> f64 {
        // per sample and channel: (gain * template, picture - bias)
        let mut pairs: Vec<(f64, f64)> = Vec::new();
        for ((tv, pv), _) in self
            .template
            .iter()
            .zip(&self.picture)
            .zip(&self.classes)
            .filter(|(_, &cl)| cl as usize == class)
        {
            for c in 0..3 {
                let [g, b] = tone.channels[c];
                pairs.push((g * tv[c], pv[c] - b));
            }
        }
        if pairs.len() < 3 * SHADE_MIN_SAMPLES {
            return sh;
        }
        let mut s = sh;
        for _ in 0..3 {
            let (mut num, mut den) = (0.0, 0.0);
            for &(a, y) in pairs.iter() {
                let w = tukey_weight(y - s * a, k);
                num += w * a * y;
                den += w * a * a;
            }
            // a face class of dark colours only: its shade hardly shows
            if den < SHADE_MIN_SQUARE * pairs.len() as f64 {
                break;
            }
            s = (num / den).clamp(SHADE.0, SHADE.1);
        }
        s
    }
}

impl Level<'_> {
    /// Picture colours where the samples project with the pixel matrix `m`.
    fn sampled(&self, m: &[[f64; 4]; 2]) -> Vec<Seen> {
        let (w, h) = (self.picture.w as f64, self.picture.h as f64);
        self.points
            .par_iter()
            .with_min_len(CHUNK)
            .map(|x| {
                let q = [0, 1].map(|a| m[a][0] * x[0] + m[a][1] * x[1] + m[a][2] * x[2] + m[a][3]);
                if q[0] < 0.0 || q[1] < 0.0 || q[0] > w || q[1] > h {
                    return None;
                }
                Some((q, self.picture.sample3(q[0], q[1])))
            })
            .collect()
    }

    /// The tone mapping template colours onto picture colours: the channels' gain and bias
    /// with the shades as they stand, then each lighting class's shade with those, twice, and
    /// the channels once more.
    fn tone(&self, seen: &[Seen], k: f64) -> Tone {
        let samples = ToneSamples::new(seen, &self.template, self.classes);
        let mut tone = Tone::IDENTITY;
        for round in 0..3 {
            tone.channels = samples.channel_tone(&tone.shade, k);
            if round < 2 {
                tone.shade = samples.shades(&tone, k);
            }
        }
        tone
    }

    /// Mean robust cost of sampled colours.
    fn cost_of(&self, seen: &[Seen], tone: &Tone, k: f64) -> f64 {
        let partial: Vec<f64> = seen
            .par_chunks(CHUNK)
            .zip(self.template.par_chunks(CHUNK))
            .zip(self.classes.par_chunks(CHUNK))
            .map(|((seen, template), classes)| {
                let mut cost = 0.0;
                for ((s, tv), &cl) in seen.iter().zip(template).zip(classes) {
                    cost += match s {
                        None => 3.0 * k * k / 6.0,
                        Some((_, pv)) => (0..3)
                            .map(|c| tukey_rho(pv[c] as f64 - tone.model(c, cl, tv[c]), k))
                            .sum(),
                    };
                }
                cost
            })
            .collect();
        partial.iter().sum::<f64>() / self.points.len().max(1) as f64
    }

    /// Mean robust cost at parameters `p` with a given tone.
    fn cost(&self, p: &Params, tone: &Tone, k: f64) -> Result<f64> {
        let (m, _) = projection(p, self.picture.w, self.picture.h)?;
        Ok(self.cost_of(&self.sampled(&m), tone, k))
    }

    /// At parameters `p`: the tone, the mean robust cost, and the normal equations
    /// (J^T W J, J^T W r) over the free parameters, and how many samples fell on the picture.
    fn normal_equations(&self, p: &Params, free: &[usize], k: f64) -> Result<NormalEquations> {
        let (m, dm) = projection(p, self.picture.w, self.picture.h)?;
        let seen = self.sampled(&m);
        let tone = self.tone(&seen, k);
        let cost = self.cost_of(&seen, &tone, k);
        let n = free.len();
        // per chunk of samples: J^T W J, J^T W r and the samples used; summed in chunk order
        let partial: Vec<([[f64; 6]; 6], [f64; 6], usize)> = self
            .points
            .par_chunks(CHUNK)
            .zip(seen.par_chunks(CHUNK))
            .zip(self.template.par_chunks(CHUNK))
            .zip(self.classes.par_chunks(CHUNK))
            .map(|(((points, seen), template), classes)| {
                self.normal_sums(points, seen, template, classes, &tone, &dm, free, k)
            })
            .collect();
        let mut jtj = [[0.0f64; 6]; 6];
        let mut jtr = [0.0f64; 6];
        let mut used = 0;
        for (pj, pr, pu) in &partial {
            for a in 0..n {
                jtr[a] += pr[a];
                for b in a..n {
                    jtj[a][b] += pj[a][b];
                }
            }
            used += pu;
        }
        let jtj = DMatrix::from_fn(n, n, |a, b| if a <= b { jtj[a][b] } else { jtj[b][a] });
        let jtr = DVector::from_fn(n, |a, _| jtr[a]);
        Ok((tone, cost, jtj, jtr, used))
    }

    /// [`Level::normal_equations`]' sums over some samples (`points` with what they `seen`,
    /// their `template` colours and `classes`), the pixel matrix's derivatives `dm`.
    #[allow(clippy::too_many_arguments)]
    fn normal_sums(
        &self,
        points: &[[f64; 3]],
        seen: &[Seen],
        template: &[[f32; 3]],
        classes: &[u8],
        tone: &Tone,
        dm: &[PixelMatrix; 6],
        free: &[usize],
        k: f64,
    ) -> ([[f64; 6]; 6], [f64; 6], usize) {
        let n = free.len();
        let mut jtj = [[0.0f64; 6]; 6];
        let mut jtr = [0.0f64; 6];
        let mut used = 0;
        for (((x, s), tv), &cl) in points.iter().zip(seen).zip(template).zip(classes) {
            let Some((q, pv)) = s else {
                continue;
            };
            used += 1;
            // motion of the projected point per free parameter
            let mut dq = [[0.0f64; 2]; 6];
            for (j, &i) in free.iter().enumerate() {
                for a in 0..2 {
                    dq[j][a] =
                        dm[i][a][0] * x[0] + dm[i][a][1] * x[1] + dm[i][a][2] * x[2] + dm[i][a][3];
                }
            }
            let gx = self.gx.sample3(q[0], q[1]);
            let gy = self.gy.sample3(q[0], q[1]);
            for c in 0..3 {
                let r = pv[c] as f64 - tone.model(c, cl, tv[c]);
                let wgt = tukey_weight(r, k);
                if wgt == 0.0 {
                    continue;
                }
                let mut jac = [0.0f64; 6];
                for j in 0..n {
                    jac[j] = gx[c] as f64 * dq[j][0] + gy[c] as f64 * dq[j][1];
                }
                for a in 0..n {
                    jtr[a] += wgt * jac[a] * r;
                    for b in a..n {
                        jtj[a][b] += wgt * jac[a] * jac[b];
                    }
                }
            }
        }
        (jtj, jtr, used)
    }
}

/// Weighted least-squares line `b = g a + o` through pairs; None when degenerate.
fn weighted_line(pairs: &[(f64, f64)], weight: impl Fn(f64, f64) -> f64) -> Option<[f64; 2]> {
    let (mut sw, mut sa, mut sb, mut saa, mut sab) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(a, b) in pairs {
        let w = weight(a, b);
        sw += w;
        sa += w * a;
        sb += w * b;
        saa += w * a * a;
        sab += w * a * b;
    }
    if sw < 16.0 {
        return None;
    }
    let var = saa / sw - (sa / sw).powi(2);
    if var < 1e-4 {
        return None;
    }
    let g = (sab / sw - sa / sw * sb / sw) / var;
    Some([g, sb / sw - g * sa / sw])
}

/// Fit a camera to a picture (`height * width * 3` bytes) of `asm`, from `init`: see the module
/// docs. `fg` (the picture's [`foreground`], `height * width`) only scores the result
/// (`inside`, `iou`).
#[allow(clippy::too_many_arguments)]
pub fn fit_camera(
    asm: &Assembly,
    picture: &FitPicture,
    fg: &[bool],
    init: &Camera,
    opts: &FitOptions,
    source: &MeshSource,
    colours: &ColourTable,
) -> Result<CameraFit> {
    let (width, height) = picture.size();
    check_image(fg.len(), width, height, 1, "fit_camera foreground")?;
    init.validate()?;
    opts.validate()?;
    if asm.is_empty() {
        return Err(BrickGeomError::InvalidArgument(
            "cannot fit a camera to an empty shape".into(),
        ));
    }
    let (w, h) = (width as usize, height as usize);
    let free: Vec<usize> = (0..6).filter(|&i| opts.free[i]).collect();
    let k = opts.tukey;
    let p0 = params_of(init);
    let mut p = p0;
    let mut last_cost = f64::NAN;
    let mut agree = 0.0;
    let render = |p: &Params| -> Result<(Template, Params)> {
        let t = render_template(
            asm,
            &camera_of(p)?,
            w,
            h,
            opts.samples,
            opts.lines,
            source,
            colours,
        )?;
        Ok((t, *p))
    };
    let (mut template, mut rendered_at) = render(&p)?;
    for (n, &blur) in opts.levels.iter().enumerate() {
        let blur = blur as usize;
        let last_level = n + 1 == opts.levels.len();
        if n > 0
            && (last_level || {
                let (a, _) = projection(&rendered_at, w, h)?;
                let (b, _) = projection(&p, w, h)?;
                rms_motion(&template.points, &a, &b) > opts.rerender_px
            })
        {
            (template, rendered_at) = render(&p)?;
        }
        if template.points.is_empty() {
            break;
        }
        let (lw, lh) = (w, h);
        let tb = template.image.blurred(blur);
        let pyramid = picture.level(blur);
        let [pb, gx, gy] = &*pyramid;
        let level = Level {
            points: &template.points,
            classes: &template.classes,
            template: template
                .pixels
                .iter()
                .map(|&i| [0, 1, 2].map(|c| tb.data[c][i]))
                .collect(),
            picture: pb,
            gx,
            gy,
        };
        let n_s = level.points.len().max(1) as f64;
        let prior_cost = |q: &Params| -> f64 {
            opts.prior.map_or(0.0, |(c, wgt)| {
                (0..6).map(|i| wgt[i] * (q[i] - c[i]).powi(2)).sum::<f64>()
            })
        };
        let mut lambda = 1e-3;
        for _ in 0..opts.iterations {
            let (tone, cost, mut jtj, mut jtr, used) = level.normal_equations(&p, &free, k)?;
            last_cost = cost;
            if used < 8 || free.is_empty() {
                break;
            }
            // the normal equations sum over samples; the prior is per mean sample
            if let Some((c, wgt)) = opts.prior {
                for (a, &i) in free.iter().enumerate() {
                    jtj[(a, a)] += 2.0 * n_s * wgt[i];
                    jtr[a] += 2.0 * n_s * wgt[i] * (p[i] - c[i]);
                }
            }
            let total = cost + prior_cost(&p);
            let mut moved = 0.0;
            for _ in 0..6 {
                let mut a = jtj.clone();
                for d in 0..free.len() {
                    a[(d, d)] += lambda * jtj[(d, d)].max(1e-9);
                }
                let Some(step) = a.lu().solve(&(-&jtr)) else {
                    lambda *= 10.0;
                    continue;
                };
                let mut q = p;
                for (a, &i) in free.iter().enumerate() {
                    q[i] += step[a];
                }
                if camera_of(&q).is_err() {
                    lambda *= 10.0;
                    continue;
                }
                if level.cost(&q, &tone, k)? + prior_cost(&q) < total {
                    moved = motion_px(&level, &p, &q)?;
                    p = q;
                    lambda = (lambda / 4.0).max(1e-7);
                    break;
                }
                lambda *= 8.0;
            }
            // converged (in this level's pixels) or no step lowers the cost
            let converged = if last_level {
                CONVERGED_PX
            } else {
                CONVERGED_COARSE_PX
            };
            if moved < converged {
                break;
            }
        }
        if !last_level {
            continue;
        }
        // how many samples the fitted camera explains: of the last level only
        let (m, _) = projection(&p, lw, lh)?;
        let seen = level.sampled(&m);
        let tone = level.tone(&seen, k);
        let good = seen
            .iter()
            .zip(&level.template)
            .zip(level.classes)
            .filter(|((s, tv), &cl)| {
                s.is_some_and(|(_, pv)| {
                    (0..3).all(|c| (pv[c] as f64 - tone.model(c, cl, tv[c])).abs() < k / 2.0)
                })
            })
            .count();
        agree = good as f64 / n_s;
    }
    let camera = camera_of(&p)?;
    // silhouette statistics from the last render (at the camera the last level started from)
    let sil = &template.silhouette;
    let inter = sil.iter().zip(fg).filter(|(&a, &b)| a && b).count();
    let area_s = sil.iter().filter(|&&a| a).count();
    let area_f = fg.iter().filter(|&&b| b).count();
    let (mi, _) = projection(&p0, w, h)?;
    let (mf, _) = projection(&p, w, h)?;
    let (inside, iou, samples, moved_px) = (
        inter as f64 / area_s.max(1) as f64,
        inter as f64 / (area_s + area_f - inter).max(1) as f64,
        template.points.len(),
        rms_motion(&template.points, &mi, &mf),
    );
    Ok(CameraFit {
        camera,
        agree,
        inside,
        iou,
        cost: last_cost,
        samples,
        moved_px,
    })
}

fn rms_motion(points: &[[f64; 3]], a: &[[f64; 4]; 2], b: &[[f64; 4]; 2]) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    let sum: f64 = points
        .iter()
        .map(|x| {
            (0..2)
                .map(|r| {
                    let d = (a[r][0] - b[r][0]) * x[0]
                        + (a[r][1] - b[r][1]) * x[1]
                        + (a[r][2] - b[r][2]) * x[2]
                        + (a[r][3] - b[r][3]);
                    d * d
                })
                .sum::<f64>()
        })
        .sum();
    (sum / points.len() as f64).sqrt()
}

fn motion_px(level: &Level, p: &Params, q: &Params) -> Result<f64> {
    let (a, _) = projection(p, level.picture.w, level.picture.h)?;
    let (b, _) = projection(q, level.picture.w, level.picture.h)?;
    Ok(rms_motion(level.points, &a, &b))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::component::Component;
    use crate::lattice::Pose;
    use std::sync::Arc;

    fn shape() -> Assembly {
        let mut asm = Assembly::new();
        let b24 = Arc::new(Component::primitive("3001").unwrap());
        let b22 = Arc::new(Component::primitive("3003").unwrap());
        let slope = Arc::new(Component::primitive("3039").unwrap());
        asm.add(b24.clone(), Pose::new(0, [0, 3, 0])).unwrap();
        asm.add(b22, Pose::new(0, [-2, 6, 2])).unwrap();
        asm.add(slope, Pose::new(1, [2, 6, -2])).unwrap();
        asm.add(b24, Pose::new(1, [6, 3, 4])).unwrap();
        asm
    }

    fn truth() -> Camera {
        Camera::new(28.0, 312.0, 0.0, 1.0, [0.0, 0.0])
            .unwrap()
            .fitted(&corners(&shape()), 0.75)
            .unwrap()
    }

    fn corners(asm: &Assembly) -> Vec<[f64; 3]> {
        let (lo, hi) = asm.bounds().unwrap();
        let mut out = Vec::new();
        for x in [lo[0], hi[0] + 1] {
            for y in [lo[1], hi[1] + 1] {
                for z in [lo[2], hi[2] + 1] {
                    out.push([x as f64 * 10.0, y as f64 * 8.0, z as f64 * 10.0]);
                }
            }
        }
        out
    }

    fn picture(asm: &Assembly, cam: &Camera, size: u32) -> Vec<u8> {
        let opts = RenderOptions::new(size, size);
        render_assembly(
            asm,
            cam,
            &opts,
            &ColourTable::builtin(),
            &MeshSource::builtin(),
        )
        .unwrap()
        .rgb
    }

    /// Mean pixel distance between the projections of the shape's bounding-box corners.
    fn reprojection(a: &Camera, b: &Camera, size: u32) -> f64 {
        let pts = corners(&shape());
        pts.iter()
            .map(|p| {
                let (qa, _) = a.project(*p, size, size);
                let (qb, _) = b.project(*p, size, size);
                ((qa[0] - qb[0]).powi(2) + (qa[1] - qb[1]).powi(2)).sqrt()
            })
            .sum::<f64>()
            / pts.len() as f64
    }

    #[test]
    fn foreground_fills_enclosed_page_and_drops_specks() {
        let (w, h) = (40usize, 30usize);
        let mut rgb = vec![250u8; w * h * 3];
        let mut set = |x: usize, y: usize, v: u8| {
            for c in 0..3 {
                rgb[(y * w + x) * 3 + c] = v;
            }
        };
        // a dark square outline enclosing page-coloured pixels, and a one-pixel speck
        for i in 10..20 {
            set(i, 10, 0);
            set(i, 19, 0);
            set(10, i, 0);
            set(19, i, 0);
        }
        set(30, 5, 0);
        let fg = foreground(&rgb, w as u32, h as u32, 30.0, 4).unwrap();
        assert_eq!(fg.background, [250, 250, 250]);
        assert!(fg.mask[15 * w + 15], "the enclosed page is drawing");
        assert!(!fg.mask[5 * w + 30], "the speck is gone");
        assert_eq!(fg.area, 100);
        assert!(foreground(&rgb, w as u32, h as u32, 300.0, 4).is_err());
        assert!(foreground(&rgb[1..], w as u32, h as u32, 30.0, 4).is_err());
    }

    #[test]
    fn hull_and_fill_cover_a_square() {
        let mut pts = [[1.0, 1.0], [5.0, 1.0], [5.0, 5.0], [1.0, 5.0], [3.0, 3.0]];
        let poly = hull(&mut pts);
        assert_eq!(poly.len(), 4);
        let mut mask = vec![false; 64];
        fill_convex(&poly, 8, 8, &mut mask);
        assert_eq!(mask.iter().filter(|&&m| m).count(), 16);
    }

    #[test]
    fn orientation_search_prefers_the_true_view() {
        let asm = shape();
        let cam = truth();
        let size = 128;
        let fg = foreground(&picture(&asm, &cam, size), size, size, 30.0, 4).unwrap();
        let cands: Vec<[f64; 3]> = (0..36)
            .map(|k| [28.0, k as f64 * 10.0 + 2.0, 0.0])
            .collect();
        let scored = search_orientations(&asm, &fg.mask, size, size, &cands, 64).unwrap();
        let best = scored.iter().max_by(|a, b| a.0.total_cmp(&b.0)).unwrap();
        assert!(best.0 > 0.8, "best IoU {}", best.0);
        let d = (best.1.azimuth - 312.0 + 540.0).rem_euclid(360.0) - 180.0;
        assert!(d.abs() <= 10.0 + 1e-9, "azimuth {}", best.1.azimuth);
    }

    /// A fit of `asm` to `pic` (`size` a side) from `init` with the builtin parts and colours.
    fn fit_to(
        asm: &Assembly,
        pic: &[u8],
        size: u32,
        init: &Camera,
        opts: &FitOptions,
    ) -> CameraFit {
        let fg = foreground(pic, size, size, 30.0, 4).unwrap();
        fit_camera(
            asm,
            &FitPicture::new(pic, size, size).unwrap(),
            &fg.mask,
            init,
            opts,
            &MeshSource::builtin(),
            &ColourTable::builtin(),
        )
        .unwrap()
    }

    #[test]
    fn fit_recovers_a_perturbed_camera_to_a_fraction_of_a_pixel() {
        let asm = shape();
        let cam = truth();
        let size = 192;
        let pic = picture(&asm, &cam, size);
        let mut p = params_of(&cam);
        p[0] += 2.0;
        p[1] -= 2.5;
        p[2] += 1.0;
        p[3] += 0.03;
        p[4] += 0.02;
        p[5] -= 0.015;
        let init = camera_of(&p).unwrap();
        assert!(reprojection(&init, &cam, size) > 2.0);
        let fit = fit_to(&asm, &pic, size, &init, &FitOptions::default());
        let err = reprojection(&fit.camera, &cam, size);
        assert!(err < 0.2, "reprojection error {err} px");
        assert!(fit.agree > 0.9 && fit.iou > 0.9, "{fit:?}");
    }

    #[test]
    fn fit_does_not_depend_on_the_number_of_threads() {
        let asm = shape();
        let cam = truth();
        let size = 160;
        let pic = picture(&asm, &cam, size);
        let mut p = params_of(&cam);
        p[0] += 1.5;
        p[3] += 0.02;
        p[4] -= 0.03;
        let init = camera_of(&p).unwrap();
        let fit_with = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| fit_to(&asm, &pic, size, &init, &FitOptions::default()))
        };
        let (one, three) = (fit_with(1), fit_with(3));
        assert_eq!(params_of(&one.camera), params_of(&three.camera));
        assert_eq!((one.agree, one.cost), (three.agree, three.cost));
        assert!(one.samples > 2 * CHUNK, "the sums span several chunks");
    }

    #[test]
    fn fit_with_fixed_rotation_keeps_it_and_a_foreign_picture_scores_low() {
        let asm = shape();
        let cam = truth();
        let size = 128;
        // a picture of something else: stripes
        let pic: Vec<u8> = (0..size * size * 3)
            .map(|i| if (i / 3 / 7) % 2 == 0 { 30 } else { 220 })
            .collect();
        let fg = foreground(&pic, size, size, 30.0, 4).unwrap();
        let opts = FitOptions {
            free: [false, false, false, true, true, true],
            ..FitOptions::default()
        };
        let fit = fit_camera(
            &asm,
            &FitPicture::new(&pic, size, size).unwrap(),
            &fg.mask,
            &cam,
            &opts,
            &MeshSource::builtin(),
            &ColourTable::builtin(),
        )
        .unwrap();
        assert_eq!(
            (fit.camera.elevation, fit.camera.azimuth, fit.camera.roll),
            (cam.elevation, cam.azimuth, cam.roll)
        );
        assert!(fit.agree < 0.5, "agree {}", fit.agree);
        assert!(fit_camera(
            &Assembly::new(),
            &FitPicture::new(&pic, size, size).unwrap(),
            &fg.mask,
            &cam,
            &opts,
            &MeshSource::builtin(),
            &ColourTable::builtin()
        )
        .is_err());
    }
}
