//! brickgeom's CPU triangle rasterizer (DESIGN §4): in one pass, a manual-style RGB image (flat
//! part colours, soft shading, dark outlines at depth, crease and part boundaries, white
//! background), depth, per-pixel instance ids, and per-instance visible / unoccluded pixel counts.
//! How the RGB image is drawn is `RenderOptions::style` (`render_style.rs`); depth, ids and counts
//! do not depend on it.
//!
//! Pixel conventions are the camera's (`camera.rs`): samples at pixel centres. With
//! supersampling factor `ss` (odd: 1 or 3) the image is rasterized at `ss` times the size; colour
//! is box-filtered down, and ids and depth are taken from the centre sample of each pixel.

use rayon::prelude::*;

use crate::camera::Camera;
use crate::error::{BrickGeomError, Result};
use crate::lattice::Pose;
use crate::mesh::Mesh;
use crate::render_style::{LineMode, Mark, RenderStyle};

/// One thing to draw: a mesh (LDU, y up) placed by a lattice pose, its colour, and the id it
/// reports in the id image. Several items may share an id (the bricks of one submodule); items of
/// one id must be consecutive.
#[derive(Debug, Clone, Copy)]
pub struct RenderItem<'a> {
    pub mesh: &'a Mesh,
    pub pose: Pose,
    pub colour: [u8; 3],
    pub id: u32,
}

impl<'a> RenderItem<'a> {
    /// An item drawn where its mesh already is, with id 0.
    pub fn new(mesh: &'a Mesh, colour: [u8; 3]) -> Self {
        RenderItem {
            mesh,
            pose: Pose::identity(),
            colour,
            id: 0,
        }
    }

    /// The same item with another id.
    pub fn with_id(mut self, id: u32) -> Self {
        self.id = id;
        self
    }
}

/// Rendering options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    /// Supersampling factor for anti-aliasing: 1 (off) or 3.
    pub supersample: u32,
    /// Outline width in output pixels (0 = no outlines).
    pub line_px: f32,
    pub background: [u8; 3],
    /// Offset (LDU) between two parallel faces of one item that counts as an outline (a step,
    /// such as a stud top above a plate top).
    pub plane_edge: f32,
    /// Cosine of the largest angle between neighbouring face normals that is not a crease.
    pub crease_cos: f32,
    /// Lighting, shading, lines, palette and emphasis (default: the renderer's own look).
    pub style: RenderStyle,
    /// Also the colours without outlines ([`Rendered::rgb_unlined`]: the picture `line_px` 0
    /// draws), from the same pass.
    pub unlined: bool,
}

impl RenderOptions {
    /// Defaults for a `width` x `height` image: no anti-aliasing, 1 px lines per 256 px.
    pub fn new(width: u32, height: u32) -> Self {
        RenderOptions {
            width,
            height,
            supersample: 1,
            line_px: (width.max(height) as f32 / 256.0).max(1.0),
            background: [255, 255, 255],
            plane_edge: 1.0,
            crease_cos: 0.8,
            style: RenderStyle::default(),
            unlined: false,
        }
    }

    /// Check the sizes and settings.
    pub fn validate(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 || self.width > 8192 || self.height > 8192 {
            return Err(BrickGeomError::InvalidArgument(format!(
                "image size must be 1..=8192 pixels per side, got {}x{}",
                self.width, self.height
            )));
        }
        if !matches!(self.supersample, 1 | 3) {
            return Err(BrickGeomError::InvalidArgument(format!(
                "supersample must be 1 or 3, got {}",
                self.supersample
            )));
        }
        if !(self.line_px >= 0.0 && self.line_px <= 16.0) {
            return Err(BrickGeomError::InvalidArgument(format!(
                "line width must be within [0, 16] pixels, got {}",
                self.line_px
            )));
        }
        if !(self.plane_edge >= 0.0 && self.plane_edge <= 1000.0) {
            return Err(BrickGeomError::InvalidArgument(format!(
                "plane_edge must be within [0, 1000] LDU, got {}",
                self.plane_edge
            )));
        }
        if !(self.crease_cos >= -1.0 && self.crease_cos <= 1.0) {
            return Err(BrickGeomError::InvalidArgument(format!(
                "crease_cos must be within [-1, 1], got {}",
                self.crease_cos
            )));
        }
        self.style.validate()
    }
}

/// The result of a render. Images are row major, `height` rows of `width` pixels.
#[derive(Debug, Clone)]
pub struct Rendered {
    pub width: u32,
    pub height: u32,
    /// RGB, `height * width * 3`.
    pub rgb: Vec<u8>,
    /// With [`RenderOptions::unlined`]: the RGB without outlines (as `line_px` 0 draws it);
    /// else empty.
    pub rgb_unlined: Vec<u8>,
    /// Depth along the view axis (LDU, larger = farther); `f32::INFINITY` on the background.
    pub depth: Vec<f32>,
    /// Id of the item seen at each pixel; -1 on the background.
    pub ids: Vec<i32>,
    /// The world axis (0 x, 1 y, 2 z) the visible face's normal lies closest to, per pixel; -1
    /// on the background. Faces of one axis are lit alike: another renderer's lighting differs
    /// by axis (what [`crate::camfit::fit_camera`] models).
    pub axes: Vec<i8>,
    /// Per id (0..=max id): samples where it is the visible surface (supersampled resolution).
    pub visible_samples: Vec<u64>,
    /// Per id: samples its triangles cover, ignoring occlusion.
    pub total_samples: Vec<u64>,
}

impl Rendered {
    /// Fraction of each item's own silhouette that is visible (0 for an item off screen).
    pub fn visible_fraction(&self) -> Vec<f32> {
        self.visible_samples
            .iter()
            .zip(&self.total_samples)
            .map(|(&v, &t)| if t == 0 { 0.0 } else { v as f32 / t as f32 })
            .collect()
    }
}

/// A triangle in sample space: (x, y, depth) per corner, item index, and its face.
#[derive(Clone, Copy)]
struct ScreenTri {
    p: [[f32; 3]; 3],
    /// Index into `items`.
    item: u32,
    /// Index into the face table (normal + shade).
    face: u32,
}

/// Rows per parallel band. 16 rows of a 256..1536 px image is a few thousand samples: enough
/// work per task that binning and rayon overhead stay small.
const BAND: usize = 16;

/// Render items with a camera.
pub fn render(items: &[RenderItem], camera: &Camera, opts: &RenderOptions) -> Result<Rendered> {
    render_marked(items, camera, opts, &[])
}

/// Render items with a camera, each id emphasised by its mark (`marks[id]`; ids beyond the end
/// are plain): how the marks show is up to `opts.style` (a highlight outline for new ones, a fade
/// for old ones; nothing with the default style).
pub fn render_marked(
    items: &[RenderItem],
    camera: &Camera,
    opts: &RenderOptions,
    marks: &[Mark],
) -> Result<Rendered> {
    render_passes(items, camera, opts, marks, true)
}

/// [`render_marked`]; `near_only`: the per-sample passes (lines, highlight, shading) limited to
/// the drawn box (the same picture, faster; false: over the whole image, as tests compare).
fn render_passes(
    items: &[RenderItem],
    camera: &Camera,
    opts: &RenderOptions,
    marks: &[Mark],
    near_only: bool,
) -> Result<Rendered> {
    camera.validate()?;
    opts.validate()?;
    if items.windows(2).any(|p| p[1].id < p[0].id) {
        return Err(BrickGeomError::InvalidArgument(
            "render items must be sorted by id (items of one id consecutive)".into(),
        ));
    }
    let n_ids = items.iter().map(|i| i.id as usize + 1).max().unwrap_or(0);
    let ss = opts.supersample as usize;
    let (w, h) = (opts.width as usize * ss, opts.height as usize * ss);
    let m = camera.pixel_matrix(w as u32, h as u32);
    let rot = camera.rotation();
    let view = [rot[(2, 0)], rot[(2, 1)], rot[(2, 2)]];
    let style = &opts.style;
    // The style's light is in view space; faces are shaded in world space.
    let light = {
        let l = rot.transpose() * nalgebra::Vector3::from(style.light);
        let l = l.normalize();
        [l[0] as f32, l[1] as f32, l[2] as f32]
    };
    let eye = view.map(|v| -v as f32);

    // Triangle setup, in parallel over items (hundreds of thousands of triangles for big
    // scenes); per item: screen triangles and faces (unit normal facing the camera, plane offset
    // n . p in LDU, shade factor, white highlight). Concatenated in item order, so the result is
    // deterministic.
    type Face = ([f32; 3], f32, f32, f32);
    let per_item: Vec<Result<(Vec<ScreenTri>, Vec<Face>)>> = items
        .par_iter()
        .enumerate()
        .map(|(item, it)| {
            let world: Vec<[f32; 3]> = it
                .mesh
                .vertices
                .iter()
                .map(|v| it.pose.apply_ldu(*v))
                .collect();
            let proj: Vec<[f32; 3]> = world
                .iter()
                .map(|v| {
                    let (x, y, z) = (v[0] as f64, v[1] as f64, v[2] as f64);
                    [
                        (m[(0, 0)] * x + m[(0, 1)] * y + m[(0, 2)] * z + m[(0, 3)]) as f32,
                        (m[(1, 0)] * x + m[(1, 1)] * y + m[(1, 2)] * z + m[(1, 3)]) as f32,
                        (view[0] * x + view[1] * y + view[2] * z) as f32,
                    ]
                })
                .collect();
            let mut tris = Vec::with_capacity(it.mesh.triangles.len());
            let mut faces = Vec::with_capacity(it.mesh.triangles.len());
            for t in &it.mesh.triangles {
                let idx = [t[0] as usize, t[1] as usize, t[2] as usize];
                if idx.iter().any(|&i| i >= proj.len()) {
                    return Err(BrickGeomError::InvalidArgument(format!(
                        "mesh of item {item} has a triangle index beyond its {} vertices",
                        proj.len()
                    )));
                }
                let [a, b, c] = idx.map(|i| world[i]);
                let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
                let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
                let mut n = [
                    u[1] * v[2] - u[2] * v[1],
                    u[2] * v[0] - u[0] * v[2],
                    u[0] * v[1] - u[1] * v[0],
                ];
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                if len.is_nan() || len <= 1e-12 {
                    continue;
                }
                n = [n[0] / len, n[1] / len, n[2] / len];
                // Two-sided: real LDraw meshes are not consistently wound.
                let towards_camera =
                    -(n[0] * view[0] as f32 + n[1] * view[1] as f32 + n[2] * view[2] as f32);
                if towards_camera < 0.0 {
                    n = [-n[0], -n[1], -n[2]];
                }
                let (shade, spec) = style.face_shade(n, light, eye);
                let offset = n[0] * a[0] + n[1] * a[1] + n[2] * a[2];
                faces.push((n, offset, shade, spec));
                tris.push(ScreenTri {
                    p: idx.map(|i| proj[i]),
                    item: item as u32,
                    face: (faces.len() - 1) as u32,
                });
            }
            Ok((tris, faces))
        })
        .collect();
    let mut tris: Vec<ScreenTri> = Vec::new();
    let mut faces: Vec<Face> = Vec::new();
    for r in per_item {
        let (t, f) = r?;
        let base = faces.len() as u32;
        tris.extend(t.into_iter().map(|mut x| {
            x.face += base;
            x
        }));
        faces.extend(f);
    }

    // Bin triangles into bands of rows.
    let n_bands = h.div_ceil(BAND);
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); n_bands];
    for (i, t) in tris.iter().enumerate() {
        let ymin = t.p.iter().map(|p| p[1]).fold(f32::MAX, f32::min);
        let ymax = t.p.iter().map(|p| p[1]).fold(f32::MIN, f32::max);
        if !(ymax >= 0.0 && ymin <= h as f32) {
            continue;
        }
        let r0 = ((ymin - 0.5).floor().max(0.0) as usize).min(h - 1);
        let r1 = ((ymax - 0.5).ceil().max(0.0) as usize).min(h - 1);
        for b in bins.iter_mut().take(r1 / BAND + 1).skip(r0 / BAND) {
            b.push(i as u32);
        }
    }

    struct Band {
        depth: Vec<f32>,
        face: Vec<u32>,
        item: Vec<i32>,
        total: Vec<u64>,
    }
    let bands: Vec<Band> = bins
        .par_iter()
        .enumerate()
        .map(|(b, bin)| {
            let y0 = b * BAND;
            let rows = BAND.min(h - y0);
            let mut band = Band {
                depth: vec![f32::INFINITY; rows * w],
                face: vec![u32::MAX; rows * w],
                item: vec![-1; rows * w],
                total: vec![0; n_ids],
            };
            // Union coverage per item: triangles come in item order, so a stamp per sample
            // counts each sample once per item.
            let mut stamp = vec![u32::MAX; rows * w];
            for &ti in bin {
                let t = &tris[ti as usize];
                let id = items[t.item as usize].id;
                raster_triangle(t, y0, rows, w, |idx, z| {
                    if stamp[idx] != id {
                        stamp[idx] = id;
                        band.total[id as usize] += 1;
                    }
                    if z < band.depth[idx] {
                        band.depth[idx] = z;
                        band.face[idx] = t.face;
                        band.item[idx] = t.item as i32;
                    }
                });
            }
            band
        })
        .collect();
    let mut depth = Vec::with_capacity(w * h);
    let mut face = Vec::with_capacity(w * h);
    let mut item = Vec::with_capacity(w * h);
    let mut total = vec![0u64; n_ids];
    for b in bands {
        depth.extend_from_slice(&b.depth);
        face.extend_from_slice(&b.face);
        item.extend_from_slice(&b.item);
        for (t, x) in total.iter_mut().zip(&b.total) {
            *t += x;
        }
    }
    let mut visible = vec![0u64; n_ids];
    let id_at = |i: usize| -> i32 {
        match item[i] {
            -1 => -1,
            k => items[k as usize].id as i32,
        }
    };
    for i in 0..item.len() {
        if item[i] >= 0 {
            visible[id_at(i) as usize] += 1;
        }
    }

    // Outlines at the sample resolution: a sample is on an edge when a neighbour shows another
    // item, a crease, or a parallel face at another level; then the edge is thickened. Comparing
    // planes rather than depths keeps faces seen at a grazing angle (whose depth changes fast
    // from sample to sample) free of false outlines. Kinds: 0 none, 1 a crease or step inside
    // a part, 2 between two parts, 3 between a part and the page.
    let edge_kind = |a: usize, b: usize| -> u8 {
        let (ia, ib) = (id_at(a), id_at(b));
        if ia != ib {
            return if ia < 0 || ib < 0 { 3 } else { 2 };
        }
        if item[a] < 0 || face[a] == face[b] {
            return 0;
        }
        let (fa, fb) = (&faces[face[a] as usize], &faces[face[b] as usize]);
        let dot = fa.0[0] * fb.0[0] + fa.0[1] * fb.0[1] + fa.0[2] * fb.0[2];
        u8::from(dot < opts.crease_cos || (dot > 0.999 && (fa.1 - fb.1).abs() > opts.plane_edge))
    };
    let least_kind = match style.lines {
        LineMode::All => 1,
        LineMode::Parts => 2,
        LineMode::Silhouette => 3,
        LineMode::None => u8::MAX,
    };
    // With front lines, the sample of a pair that draws the line is the nearer one (ties: the
    // left or upper one); the page is infinitely far.
    let owns = |a: usize, b: usize| depth[a] < depth[b] || (depth[a] == depth[b] && a < b);
    let front_edge = |i: usize, x: usize, y: usize, least: u8| -> bool {
        let hit = |j: usize| edge_kind(i, j) >= least && owns(i, j);
        (x + 1 < w && hit(i + 1))
            || (y + 1 < h && hit(i + w))
            || (x > 0 && hit(i - 1))
            || (y > 0 && hit(i - w))
    };
    let line = (opts.line_px * ss as f32).round() as usize;
    // The per-sample passes below only change samples near what was drawn: the samples of
    // the drawn box widened by the thickest line or highlight band (everything outside it is
    // page, with no line).
    let hl_radius = ((style.highlight_px * ss as f32 - 1.0) / 2.0)
        .round()
        .max(0.0) as usize;
    let near = if near_only {
        drawn_box(&item, w, h, line.max(1) + hl_radius + 2)
    } else {
        NearBox {
            rows: 0..h,
            cols: 0..w,
        }
    };
    let mut edge = vec![false; w * h];
    if line > 0 && style.lines != LineMode::None {
        edge.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let Some(xs) = near.cols(y) else {
                return;
            };
            for (x, e) in row.iter_mut().enumerate().take(xs.end).skip(xs.start) {
                let i = y * w + x;
                *e = if style.front_lines {
                    front_edge(i, x, y, least_kind)
                } else {
                    (x + 1 < w && edge_kind(i, i + 1) >= least_kind)
                        || (y + 1 < h && edge_kind(i, i + w) >= least_kind)
                };
            }
        });
        if line > 1 {
            edge = dilate(&edge, w, h, line - 1);
        }
    }
    // Per item: its colour after the palette change, and its mark.
    let colours: Vec<[f32; 3]> = items
        .iter()
        .map(|it| style.part_colour(it.colour))
        .collect();
    let item_marks: Vec<Mark> = items
        .iter()
        .map(|it| marks.get(it.id as usize).copied().unwrap_or_default())
        .collect();
    // The highlight: the outline (against other parts and the page) that new items own.
    let highlight = match style.highlight {
        Some(c) if item_marks.contains(&Mark::New) => {
            let mut hl = vec![false; w * h];
            hl.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
                let Some(xs) = near.cols(y) else {
                    return;
                };
                for (x, e) in row.iter_mut().enumerate().take(xs.end).skip(xs.start) {
                    let i = y * w + x;
                    *e = item[i] >= 0
                        && item_marks[item[i] as usize] == Mark::New
                        && front_edge(i, x, y, 2);
                }
            });
            // a band about `highlight_px` wide, centred on the outline
            if hl_radius > 0 {
                hl = dilate(&hl, w, h, hl_radius);
            }
            Some((hl, c.map(|x| x as f32)))
        }
        _ => None,
    };

    // Shade samples, then box-filter to the output size.
    // `lined`: outlines drawn (false: the colours `line_px` 0 gives, for `opts.unlined`)
    let shade_sample = |i: usize, lined: bool| -> [f32; 3] {
        if let Some((hl, c)) = &highlight {
            if hl[i] {
                return *c;
            }
        }
        if item[i] < 0 {
            return opts.background.map(|c| c as f32);
        }
        let k = item[i] as usize;
        let base = colours[k];
        let c = if lined && edge[i] {
            style.line_colour.on(base)
        } else {
            let (_, _, s, spec) = faces[face[i] as usize];
            if spec > 0.0 {
                base.map(|c| (c * s + 255.0 * spec).min(255.0))
            } else {
                base.map(|c| (c * s).min(255.0))
            }
        };
        style.marked(c, item_marks[k])
    };
    let (ow, oh) = (opts.width as usize, opts.height as usize);
    let mut rgb = vec![0u8; ow * oh * 3];
    // the unlined colours: a row each when asked for, else a byte a row (zipped, not written)
    let unlined_row = if opts.unlined { ow * 3 } else { 1 };
    let mut rgb_unlined = vec![0u8; oh * unlined_row];
    let mut out_depth = vec![f32::INFINITY; ow * oh];
    let mut out_ids = vec![-1i32; ow * oh];
    let mut out_axes = vec![-1i8; ow * oh];
    let axis_of = |i: usize| -> i8 {
        if item[i] < 0 {
            return -1;
        }
        let n = faces[face[i] as usize].0.map(f32::abs);
        if n[0] >= n[1] && n[0] >= n[2] {
            0
        } else if n[1] >= n[2] {
            1
        } else {
            2
        }
    };
    rgb.par_chunks_mut(ow * 3)
        .zip(out_depth.par_chunks_mut(ow))
        .zip(out_ids.par_chunks_mut(ow))
        .zip(out_axes.par_chunks_mut(ow))
        .zip(rgb_unlined.par_chunks_mut(unlined_row))
        .enumerate()
        .for_each(
            |(y, ((((rgb_row, d_row), id_row), axis_row), unlined_out))| {
                // output pixels whose samples all lie outside the drawn box are page
                let xs = (y * ss..(y + 1) * ss)
                    .filter_map(|sy| near.cols(sy))
                    .reduce(|a, b| a.start.min(b.start)..a.end.max(b.end))
                    .map_or(0..0, |r| r.start / ss..r.end.div_ceil(ss));
                let page = opts.background;
                for x in (0..ow).filter(|x| !xs.contains(x)) {
                    rgb_row[x * 3..x * 3 + 3].copy_from_slice(&page);
                    if opts.unlined {
                        unlined_out[x * 3..x * 3 + 3].copy_from_slice(&page);
                    }
                }
                for x in xs {
                    let mut acc = [0f32; 3];
                    let mut plain = [0f32; 3];
                    for sy in 0..ss {
                        for sx in 0..ss {
                            let i = (y * ss + sy) * w + x * ss + sx;
                            let c = shade_sample(i, true);
                            for k in 0..3 {
                                acc[k] += c[k];
                            }
                            if opts.unlined {
                                let c = if edge[i] { shade_sample(i, false) } else { c };
                                for k in 0..3 {
                                    plain[k] += c[k];
                                }
                            }
                        }
                    }
                    let n = (ss * ss) as f32;
                    for k in 0..3 {
                        rgb_row[x * 3 + k] = round_byte(acc[k] / n);
                        if opts.unlined {
                            unlined_out[x * 3 + k] = round_byte(plain[k] / n);
                        }
                    }
                    let centre = (y * ss + ss / 2) * w + x * ss + ss / 2;
                    d_row[x] = depth[centre];
                    id_row[x] = id_at(centre);
                    axis_row[x] = axis_of(centre);
                }
            },
        );
    if !opts.unlined {
        rgb_unlined = Vec::new();
    }
    Ok(Rendered {
        width: opts.width,
        height: opts.height,
        rgb,
        rgb_unlined,
        depth: out_depth,
        ids: out_ids,
        axes: out_axes,
        visible_samples: visible,
        total_samples: total,
    })
}

/// `x.round().clamp(0.0, 255.0) as u8` (halves away from zero) without a call to libm's
/// `roundf`, which the final pass spent a tenth of a render in.
#[inline]
fn round_byte(x: f32) -> u8 {
    let c = x.clamp(0.0, 255.0); // NaN stays NaN and casts to 0, as before
    let i = c as u32; // truncation: the floor of a non-negative value
    (i + u32::from(c - i as f32 >= 0.5)) as u8
}

/// Rows `rows` and per row the columns `cols` of an image that may differ from the page.
struct NearBox {
    rows: std::ops::Range<usize>,
    cols: std::ops::Range<usize>,
}

impl NearBox {
    /// The columns of row `y` inside the box, None for a row outside it.
    fn cols(&self, y: usize) -> Option<std::ops::Range<usize>> {
        self.rows.contains(&y).then(|| self.cols.clone())
    }
}

/// The bounding box of the drawn samples (`item >= 0`) widened by `margin`, clipped to the
/// image; empty when nothing is drawn.
fn drawn_box(item: &[i32], w: usize, h: usize, margin: usize) -> NearBox {
    let (mut x0, mut x1, mut y0, mut y1) = (usize::MAX, 0, usize::MAX, 0);
    for (y, row) in item.chunks(w).enumerate() {
        let Some(first) = row.iter().position(|&i| i >= 0) else {
            continue;
        };
        let last = row.iter().rposition(|&i| i >= 0).unwrap_or(first);
        x0 = x0.min(first);
        x1 = x1.max(last);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0 == usize::MAX {
        return NearBox {
            rows: 0..0,
            cols: 0..0,
        };
    }
    NearBox {
        rows: y0.saturating_sub(margin)..(y1 + margin + 1).min(h),
        cols: x0.saturating_sub(margin)..(x1 + margin + 1).min(w),
    }
}

/// Square dilation of a boolean image by `r` samples.
fn dilate(src: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    // Separable: horizontal then vertical.
    let mut tmp = vec![false; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
            *o = src[y * w + a..=y * w + b].iter().any(|&e| e);
        }
    });
    let mut out = vec![false; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
        for (x, o) in row.iter_mut().enumerate() {
            *o = (a..=b).any(|yy| tmp[yy * w + x]);
        }
    });
    out
}

/// Visit the samples of band rows [y0, y0 + rows) covered by a triangle, with interpolated depth.
/// Samples are at (x + 0.5, y + 0.5); a top-left rule keeps shared edges from being drawn twice.
#[inline]
fn raster_triangle(
    t: &ScreenTri,
    y0: usize,
    rows: usize,
    w: usize,
    mut visit: impl FnMut(usize, f32),
) {
    let [a, b, c] = t.p;
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    if area.abs() < 1e-9 || !area.is_finite() {
        return;
    }
    // Orient counter-clockwise in sample space.
    let (b, c, area) = if area < 0.0 {
        (c, b, -area)
    } else {
        (b, c, area)
    };
    let xmin = a[0].min(b[0]).min(c[0]);
    let xmax = a[0].max(b[0]).max(c[0]);
    let ymin = a[1].min(b[1]).min(c[1]);
    let ymax = a[1].max(b[1]).max(c[1]);
    let x0 = ((xmin - 0.5).ceil().max(0.0)) as usize;
    let x1 = ((xmax - 0.5).floor().min(w as f32 - 1.0)) as i64;
    let ya = ((ymin - 0.5).ceil().max(y0 as f32)) as usize;
    let yb = ((ymax - 0.5).floor().min((y0 + rows) as f32 - 1.0)) as i64;
    if x1 < x0 as i64 || yb < ya as i64 {
        return;
    }
    // Edge function of edge p->q at point s; with the top-left rule, a sample exactly on an edge
    // belongs to the triangle only for top or left edges.
    let edge = |p: [f32; 3], q: [f32; 3]| {
        let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
        // A shared edge runs in opposite directions in its two triangles, so exactly one of
        // them includes samples lying on it.
        let inclusive = dy < 0.0 || (dy == 0.0 && dx > 0.0);
        (p, dx, dy, inclusive)
    };
    let edges = [edge(b, c), edge(c, a), edge(a, b)];
    let inv = 1.0 / area;
    for y in ya..=(yb as usize) {
        let sy = y as f32 + 0.5;
        for x in x0..=(x1 as usize) {
            let sx = x as f32 + 0.5;
            let mut wts = [0f32; 3];
            let mut inside = true;
            for (k, (p, dx, dy, inclusive)) in edges.iter().enumerate() {
                // cross(q - p, s - p): >= 0 inside, given cross(b - a, c - a) > 0.
                let e = dx * (sy - p[1]) - dy * (sx - p[0]);
                if e < 0.0 || (e == 0.0 && !inclusive) {
                    inside = false;
                    break;
                }
                wts[k] = e;
            }
            if !inside {
                continue;
            }
            let z = (wts[0] * a[2] + wts[1] * b[2] + wts[2] * c[2]) * inv;
            visit((y - y0) * w + x, z);
        }
    }
}

/// A binary target mask and the depth of the scene it is compared against, for scoring
/// candidate placements by analysis-by-synthesis.
#[derive(Debug, Clone)]
pub struct MaskTarget {
    pub width: u32,
    pub height: u32,
    /// Depth of the base shape at each pixel (`f32::INFINITY` where empty).
    pub base_depth: Vec<f32>,
    /// The predicted instance mask.
    pub mask: Vec<bool>,
    /// Number of set pixels in `mask`.
    pub mask_area: u64,
    /// The mask's pixel box `[x0, y0, x1, y1)` (None when the mask is empty).
    pub mask_box: Option<[usize; 4]>,
}

impl MaskTarget {
    /// A target from a base render's depth and a mask (both `width * height`, row major).
    pub fn new(width: u32, height: u32, base_depth: Vec<f32>, mask: Vec<bool>) -> Result<Self> {
        let n = width as usize * height as usize;
        if base_depth.len() != n || mask.len() != n {
            return Err(BrickGeomError::InvalidArgument(format!(
                "mask and depth must have {width}x{height} = {n} pixels, got {} and {}",
                mask.len(),
                base_depth.len()
            )));
        }
        let mask_area = mask.iter().filter(|&&m| m).count() as u64;
        let w = width as usize;
        let mut mask_box: Option<[usize; 4]> = None;
        for (i, _) in mask.iter().enumerate().filter(|(_, &m)| m) {
            let (x, y) = (i % w, i / w);
            let b = mask_box.get_or_insert([x, y, x + 1, y + 1]);
            *b = [b[0].min(x), b[1].min(y), b[2].max(x + 1), b[3].max(y + 1)];
        }
        Ok(MaskTarget {
            width,
            height,
            base_depth,
            mask,
            mask_area,
            mask_box,
        })
    }
}

/// IoU between the visible silhouette of meshes placed at poses (in front of the target's base
/// depth) and the target mask; also returns the visible pixel count. Only the candidate's
/// screen bounding box is rasterized, so scoring thousands of candidates is cheap; a candidate
/// whose box misses the mask's box is not rasterized at all (IoU 0; its visible pixel count is
/// then reported as 0).
pub fn silhouette_iou(
    meshes: &[(&Mesh, Pose)],
    camera: &Camera,
    target: &MaskTarget,
) -> Result<(f64, u64)> {
    let (w, h) = (target.width as usize, target.height as usize);
    let m = camera.pixel_matrix(target.width, target.height);
    let rot = camera.rotation();
    let view = [rot[(2, 0)], rot[(2, 1)], rot[(2, 2)]];
    let mut tris: Vec<[[f32; 3]; 3]> = Vec::new();
    let (mut x_lo, mut y_lo, mut x_hi, mut y_hi) = (f32::MAX, f32::MAX, f32::MIN, f32::MIN);
    for (mesh, pose) in meshes {
        let proj: Vec<[f32; 3]> = mesh
            .vertices
            .iter()
            .map(|v| {
                let v = pose.apply_ldu(*v);
                let (x, y, z) = (v[0] as f64, v[1] as f64, v[2] as f64);
                [
                    (m[(0, 0)] * x + m[(0, 1)] * y + m[(0, 2)] * z + m[(0, 3)]) as f32,
                    (m[(1, 0)] * x + m[(1, 1)] * y + m[(1, 2)] * z + m[(1, 3)]) as f32,
                    (view[0] * x + view[1] * y + view[2] * z) as f32,
                ]
            })
            .collect();
        for p in &proj {
            x_lo = x_lo.min(p[0]);
            x_hi = x_hi.max(p[0]);
            y_lo = y_lo.min(p[1]);
            y_hi = y_hi.max(p[1]);
        }
        for t in &mesh.triangles {
            let idx = [t[0] as usize, t[1] as usize, t[2] as usize];
            if idx.iter().any(|&i| i >= proj.len()) {
                return Err(BrickGeomError::InvalidArgument(
                    "mesh has a triangle index beyond its vertices".into(),
                ));
            }
            let [a, b, c] = idx.map(|i| proj[i]);
            // faces turned away from the camera lie behind the faces turned towards it (the
            // meshes are closed and wound outwards; pixel y runs down): they neither add
            // pixels nor come nearer
            if (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]) >= 0.0 {
                continue;
            }
            tris.push([a, b, c]);
        }
    }
    let x0 = (x_lo.floor().max(0.0) as usize).min(w);
    let y0 = (y_lo.floor().max(0.0) as usize).min(h);
    let x1 = (x_hi.ceil().max(0.0) as usize).min(w);
    let y1 = (y_hi.ceil().max(0.0) as usize).min(h);
    let (bw, bh) = (x1.saturating_sub(x0), y1.saturating_sub(y0));
    if bw == 0 || bh == 0 {
        let iou = if target.mask_area == 0 { 1.0 } else { 0.0 };
        return Ok((iou, 0));
    }
    if let Some([mx0, my0, mx1, my1]) = target.mask_box {
        if x1 <= mx0 || mx1 <= x0 || y1 <= my0 || my1 <= y0 {
            return Ok((0.0, 0)); // no pixel in common: nothing to intersect
        }
    }
    let mut depth = vec![f32::INFINITY; bw * bh];
    for t in &tris {
        let shifted = ScreenTri {
            p: t.map(|p| [p[0] - x0 as f32, p[1] - y0 as f32, p[2]]),
            item: 0,
            face: 0,
        };
        raster_triangle(&shifted, 0, bh, bw, |i, z| {
            if z < depth[i] {
                depth[i] = z;
            }
        });
    }
    let (mut visible, mut inter) = (0u64, 0u64);
    for y in 0..bh {
        for x in 0..bw {
            let d = depth[y * bw + x];
            let g = (y + y0) * w + x + x0;
            if d < target.base_depth[g] {
                visible += 1;
                if target.mask[g] {
                    inter += 1;
                }
            }
        }
    }
    let union = visible + target.mask_area - inter;
    Ok((
        if union == 0 {
            1.0
        } else {
            inter as f64 / union as f64
        },
        visible,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An axis-aligned box [lo, hi] in LDU.
    fn cuboid(lo: [f32; 3], hi: [f32; 3]) -> Mesh {
        let v = |x: bool, y: bool, z: bool| {
            [
                if x { hi[0] } else { lo[0] },
                if y { hi[1] } else { lo[1] },
                if z { hi[2] } else { lo[2] },
            ]
        };
        let vertices = (0..8)
            .map(|i| v(i & 1 != 0, i & 2 != 0, i & 4 != 0))
            .collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let triangles = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        Mesh {
            vertices,
            triangles,
        }
    }

    /// A box and a smaller one standing on it.
    fn two_boxes() -> [Mesh; 2] {
        [
            cuboid([-40.0, 0.0, -20.0], [40.0, 24.0, 20.0]),
            cuboid([0.0, 24.0, -20.0], [20.0, 48.0, 0.0]),
        ]
    }

    /// [`two_boxes`] as render items: red id 0, blue id 1.
    fn two_items(boxes: &[Mesh; 2]) -> [RenderItem<'_>; 2] {
        [
            RenderItem::new(&boxes[0], [200, 30, 30]),
            RenderItem::new(&boxes[1], [30, 30, 200]).with_id(1),
        ]
    }

    #[test]
    fn passes_limited_to_the_drawn_box_draw_the_same_picture() {
        let boxes = two_boxes();
        let items = two_items(&boxes);
        let marks = [Mark::Old, Mark::New];
        let mut styles = vec![RenderStyle::default()];
        for lines in [LineMode::Parts, LineMode::Silhouette, LineMode::None] {
            styles.push(RenderStyle {
                lines,
                front_lines: true,
                highlight: Some([255, 200, 0]),
                highlight_px: 3.0,
                ..RenderStyle::default()
            });
        }
        let mut compared = 0;
        for style in styles {
            for (ss, line_px, scale, t) in [
                (1, 1.0, 0.01, [0.0, 0.0]),
                (3, 2.0, 0.006, [0.7, -0.6]), // small, near a corner
                (1, 3.0, 0.02, [-0.98, 0.9]), // cut by the image's edges
                (1, 1.0, 0.01, [5.0, 5.0]),   // nothing drawn
            ] {
                let cam = Camera::new(30.0, 225.0, 0.0, scale, t).unwrap();
                let mut opts = RenderOptions::new(96, 80);
                opts.supersample = ss;
                opts.line_px = line_px;
                opts.style = style;
                let near = render_passes(&items, &cam, &opts, &marks, true).unwrap();
                let whole = render_passes(&items, &cam, &opts, &marks, false).unwrap();
                assert_eq!(near.rgb, whole.rgb);
                assert_eq!(near.ids, whole.ids);
                assert_eq!(near.axes, whole.axes);
                assert_eq!(near.depth, whole.depth);
                compared += usize::from(whole.ids.iter().any(|&i| i >= 0));
            }
        }
        assert_eq!(compared, 12, "three of four views per style draw something");
    }

    #[test]
    fn unlined_colours_are_the_picture_without_lines_from_the_same_pass() {
        let boxes = two_boxes();
        let items = two_items(&boxes);
        let marks = [Mark::Old, Mark::New];
        let styled = RenderStyle {
            front_lines: true,
            highlight: Some([255, 200, 0]),
            highlight_px: 3.0,
            ..RenderStyle::default()
        };
        let mut lines_seen = 0;
        for style in [RenderStyle::default(), styled] {
            for (ss, line_px, scale) in [(1, 1.0, 0.01), (3, 2.0, 0.006), (1, 3.0, 0.02)] {
                let cam = Camera::new(30.0, 225.0, 0.0, scale, [0.1, -0.1]).unwrap();
                let mut opts = RenderOptions::new(96, 80);
                opts.supersample = ss;
                opts.line_px = line_px;
                opts.style = style;
                let lined = render_marked(&items, &cam, &opts, &marks).unwrap();
                assert!(lined.rgb_unlined.is_empty(), "only when asked for");
                opts.unlined = true;
                let both = render_marked(&items, &cam, &opts, &marks).unwrap();
                opts.unlined = false;
                opts.line_px = 0.0;
                let plain = render_marked(&items, &cam, &opts, &marks).unwrap();
                assert_eq!(both.rgb, lined.rgb);
                assert_eq!(both.ids, lined.ids);
                assert_eq!(both.rgb_unlined, plain.rgb);
                lines_seen += usize::from(lined.rgb != plain.rgb);
            }
        }
        assert_eq!(
            lines_seen, 6,
            "every view draws lines the unlined colours leave out"
        );
    }

    #[test]
    fn round_byte_rounds_halves_away_from_zero() {
        for x in [
            0.0f32, 0.49999997, 0.5, 1.5, 2.5, 127.5, 254.5, 254.99, 255.0, 300.0, -3.0,
        ] {
            assert_eq!(round_byte(x), x.round().clamp(0.0, 255.0) as u8, "{x}");
        }
        assert_eq!(round_byte(f32::NAN), 0);
    }

    #[test]
    fn box_mask_area_is_analytic() {
        let (x, y, z) = (80.0f64, 24.0, 40.0);
        let mesh = cuboid([-40.0, 0.0, -20.0], [40.0, 24.0, 20.0]);
        for (el, az) in [
            (30.0, 225.0),
            (20.0, 215.0),
            (40.0, 235.0),
            (0.0, 0.0),
            (89.0, 10.0),
        ] {
            let cam = Camera::new(el, az, 0.0, 0.02, [0.0, 0.0]).unwrap();
            let opts = RenderOptions::new(512, 512);
            let r = render(&[RenderItem::new(&mesh, [200, 0, 0])], &cam, &opts).unwrap();
            let w = cam.rotation().row(2).transpose();
            let area_ldu = x * y * w[2].abs() + y * z * w[0].abs() + x * z * w[1].abs();
            let px_per_ldu = 0.02 * 256.0;
            let expected = area_ldu * px_per_ldu * px_per_ldu;
            let got = r.ids.iter().filter(|&&i| i == 0).count() as f64;
            assert!(
                (got - expected).abs() / expected < 0.01,
                "el {el} az {az}: {got} vs {expected}"
            );
            assert_eq!(r.visible_samples[0], got as u64);
            assert_eq!(r.total_samples[0], got as u64);
        }
    }

    #[test]
    fn silhouette_iou_skips_only_candidates_that_miss_the_mask() {
        let mesh = cuboid([-40.0, 0.0, -20.0], [40.0, 24.0, 20.0]);
        let cam = Camera::new(30.0, 225.0, 0.0, 0.01, [0.0, 0.0]).unwrap();
        let (w, h) = (128u32, 128u32);
        let r = render(
            &[RenderItem::new(&mesh, [9, 9, 9])],
            &cam,
            &RenderOptions::new(w, h),
        )
        .unwrap();
        let drawn: Vec<bool> = r.ids.iter().map(|&i| i == 0).collect();
        let empty = vec![f32::INFINITY; (w * h) as usize];
        let at = |x: i32| Pose::new(0, [x, 0, 0]); // half-studs
        let target = MaskTarget::new(w, h, empty.clone(), drawn.clone()).unwrap();
        // the box where the mask was drawn: IoU about 1
        let (iou, visible) = silhouette_iou(&[(&mesh, at(0))], &cam, &target).unwrap();
        assert!(iou > 0.95 && visible > 0, "{iou}");
        // half a box off: the same IoU whether or not the mask's box is known
        let mut unboxed = target.clone();
        unboxed.mask_box = None;
        let half = [(&mesh, at(4))];
        let a = silhouette_iou(&half, &cam, &target).unwrap();
        let b = silhouette_iou(&half, &cam, &unboxed).unwrap();
        assert!(a.0 > 0.1 && a.0 < 0.9 && a == b, "{a:?} {b:?}");
        // far from the mask: IoU 0 either way
        let far = [(&mesh, at(200))];
        assert_eq!(silhouette_iou(&far, &cam, &target).unwrap().0, 0.0);
        assert_eq!(silhouette_iou(&far, &cam, &unboxed).unwrap().0, 0.0);
    }

    #[test]
    fn occlusion_ids_depth_and_visibility() {
        let front = cuboid([-20.0, 0.0, -20.0], [20.0, 24.0, 20.0]);
        let back = cuboid([-60.0, 0.0, -200.0], [60.0, 24.0, -160.0]);
        // Camera on +z looking down -z: `front` is nearer and hides part of `back`.
        let cam = Camera::new(0.0, 0.0, 0.0, 0.01, [0.0, 0.0]).unwrap();
        let items = [
            RenderItem::new(&back, [0, 0, 200]),
            RenderItem::new(&front, [200, 0, 0]).with_id(1),
        ];
        let r = render(&items, &cam, &RenderOptions::new(256, 256)).unwrap();
        let frac = r.visible_fraction();
        assert!((frac[1] - 1.0).abs() < 1e-6);
        assert!(
            (frac[0] - 2.0 / 3.0).abs() < 0.02,
            "back visible {}",
            frac[0]
        );
        // ids and depth agree: wherever the front box is seen, depth is its face at z=20
        for (i, &id) in r.ids.iter().enumerate() {
            match id {
                1 => assert!((r.depth[i] + 20.0).abs() < 1e-3),
                0 => assert!((r.depth[i] - 160.0).abs() < 1e-3),
                _ => assert!(r.depth[i].is_infinite()),
            }
        }
        // background stays white, parts are not
        assert_eq!(&r.rgb[0..3], &[255, 255, 255]);
    }

    #[test]
    fn supersampling_keeps_ids_at_pixel_centres() {
        let mesh = cuboid([-40.0, 0.0, -20.0], [40.0, 24.0, 20.0]);
        let cam = Camera::new(30.0, 225.0, 0.0, 0.015, [0.0, 0.0]).unwrap();
        let a = render(
            &[RenderItem::new(&mesh, [9, 9, 9])],
            &cam,
            &RenderOptions::new(128, 128),
        )
        .unwrap();
        let mut o = RenderOptions::new(128, 128);
        o.supersample = 3;
        let b = render(&[RenderItem::new(&mesh, [9, 9, 9])], &cam, &o).unwrap();
        assert_eq!(a.ids, b.ids);
        // anti-aliased colour has intermediate values on the silhouette
        let grey = |r: &Rendered| r.rgb.chunks(3).filter(|p| p[0] > 20 && p[0] < 240).count();
        assert!(grey(&b) > grey(&a));
    }

    #[test]
    fn bad_sizes_are_errors() {
        let cam = Camera::new(30.0, 225.0, 0.0, 0.015, [0.0, 0.0]).unwrap();
        assert!(render(&[], &cam, &RenderOptions::new(0, 256)).is_err());
        assert!(render(&[], &cam, &RenderOptions::new(100_000, 256)).is_err());
        let mut o = RenderOptions::new(64, 64);
        o.supersample = 2;
        assert!(render(&[], &cam, &o).is_err());
        let empty = render(&[], &cam, &RenderOptions::new(8, 8)).unwrap();
        assert!(empty.ids.iter().all(|&i| i == -1));
    }
}
