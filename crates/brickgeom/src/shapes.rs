//! Procedural solids for the part library (LDU, y up, part frame).
//!
//! Every body is a union of a few [`Solid`]s: an extruded 2D profile ([`Solid::Prism`]), a
//! surface of revolution about a vertical axis ([`Solid::Lathe`]) or a convex polyhedron
//! ([`Solid::Convex`]). Each solid gives a closed triangle mesh with outward, counter-clockwise
//! triangles and the fraction of any box inside it (exact for prisms, sampled for the others);
//! [`voxelize`] uses those fractions, so a part's occupancy comes from the same shape as its
//! mesh.

use crate::lattice::Lattice;
use crate::mesh::Mesh;

/// Stud radius in LDU.
const STUD_RADIUS: f32 = 6.0;
/// Height of a stud above the face it stands on, in LDU.
const STUD_HEIGHT: f32 = 4.0;
/// Segments of a stud cylinder (a multiple of 4 keeps the mesh yaw symmetric).
const STUD_SEGMENTS: u32 = 16;

/// Axis along which a [`Solid::Prism`] profile is extruded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Axis {
    /// Profile points are `(z, y)`.
    X,
    /// Profile points are `(x, z)`.
    Y,
}

impl Axis {
    /// 3D point of profile point `(u, v)` at extrusion coordinate `w`.
    fn point(self, u: f32, v: f32, w: f32) -> [f32; 3] {
        match self {
            Axis::X => [w, v, u],
            Axis::Y => [u, w, v],
        }
    }

    /// `(u, v, w)` of a 3D point (inverse of [`Axis::point`]).
    fn coords(self, p: [f32; 3]) -> (f32, f32, f32) {
        match self {
            Axis::X => (p[2], p[1], p[0]),
            Axis::Y => (p[0], p[2], p[1]),
        }
    }
}

/// A closed solid of the part body.
#[derive(Debug, Clone)]
pub(crate) enum Solid {
    /// A simple polygon (either orientation) extruded along `axis` over `range`.
    Prism {
        profile: Vec<[f32; 2]>,
        axis: Axis,
        range: [f32; 2],
    },
    /// A surface of revolution about the vertical line through `centre` (`[x, z]`). `profile`
    /// is `(r, y)` from the axis at the bottom, outwards, up, and back to the axis at the top
    /// (counter-clockwise in the (r, y) half plane).
    Lathe {
        centre: [f32; 2],
        profile: Vec<[f32; 2]>,
        segments: u32,
    },
    /// A convex polyhedron: vertices and faces (vertex indices, counter-clockwise seen from
    /// outside).
    Convex {
        vertices: Vec<[f32; 3]>,
        faces: Vec<Vec<usize>>,
    },
}

/// An axis-aligned box `[x0, x1] x [y0, y1] x [z0, z1]` (LDU).
pub(crate) fn cuboid(x: [f32; 2], y: [f32; 2], z: [f32; 2]) -> Solid {
    Solid::Prism {
        profile: vec![[x[0], z[0]], [x[1], z[0]], [x[1], z[1]], [x[0], z[1]]],
        axis: Axis::Y,
        range: y,
    }
}

/// Twice the signed area of a polygon (positive when counter-clockwise).
fn signed_area2(poly: &[[f32; 2]]) -> f32 {
    (0..poly.len())
        .map(|i| {
            let a = poly[i];
            let b = poly[(i + 1) % poly.len()];
            a[0] * b[1] - b[0] * a[1]
        })
        .sum()
}

/// Even-odd point-in-polygon test.
fn in_polygon(poly: &[[f32; 2]], p: [f32; 2]) -> bool {
    let mut inside = false;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[j]);
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
            if p[0] < x {
                inside = !inside;
            }
        }
        j = i;
    }
    inside
}

/// Ear-clipping triangulation of a simple counter-clockwise polygon (indices into `poly`).
fn triangulate(poly: &[[f32; 2]]) -> Vec<[usize; 3]> {
    let cross = |o: [f32; 2], a: [f32; 2], b: [f32; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut idx: Vec<usize> = (0..poly.len()).collect();
    let mut tris = Vec::new();
    while idx.len() > 3 {
        let n = idx.len();
        let ear = (0..n).find(|&k| {
            let (a, b, c) = (
                poly[idx[(k + n - 1) % n]],
                poly[idx[k]],
                poly[idx[(k + 1) % n]],
            );
            cross(a, b, c) > 1e-6
                && idx.iter().all(|&m| {
                    let p = poly[m];
                    p == a
                        || p == b
                        || p == c
                        || !(cross(a, b, p) >= 0.0
                            && cross(b, c, p) >= 0.0
                            && cross(c, a, p) >= 0.0)
                })
        });
        let k = ear.expect("profile polygon must be simple, without collinear runs");
        tris.push([idx[(k + n - 1) % n], idx[k], idx[(k + 1) % n]]);
        idx.remove(k);
    }
    tris.push([idx[0], idx[1], idx[2]]);
    tris
}

impl Solid {
    /// Whether a point (LDU) lies inside the solid.
    pub(crate) fn contains(&self, p: [f32; 3]) -> bool {
        match self {
            Solid::Prism {
                profile,
                axis,
                range,
            } => {
                let (u, v, w) = axis.coords(p);
                w > range[0] && w < range[1] && in_polygon(profile, [u, v])
            }
            Solid::Lathe {
                centre, profile, ..
            } => {
                let r = (p[0] - centre[0]).hypot(p[2] - centre[1]);
                in_polygon(profile, [r, p[1]])
            }
            Solid::Convex { vertices, faces } => faces.iter().all(|f| {
                let (a, b, c) = (vertices[f[0]], vertices[f[1]], vertices[f[2]]);
                let n = cross3(sub3(b, a), sub3(c, a));
                dot3(n, sub3(p, a)) < 0.0
            }),
        }
    }

    /// The closed surface mesh (outward counter-clockwise triangles).
    pub(crate) fn mesh(&self) -> Mesh {
        match self {
            Solid::Prism {
                profile,
                axis,
                range,
            } => prism_mesh(profile, *axis, *range),
            Solid::Lathe {
                centre,
                profile,
                segments,
            } => lathe_mesh(*centre, profile, *segments),
            Solid::Convex { vertices, faces } => {
                let mut m = Mesh::new();
                m.vertices = vertices.clone();
                for f in faces {
                    for k in 1..f.len() - 1 {
                        m.triangles
                            .push([f[0] as u32, f[k] as u32, f[k + 1] as u32]);
                    }
                }
                m
            }
        }
    }
}

fn sub3(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot3(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross3(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn prism_mesh(profile: &[[f32; 2]], axis: Axis, range: [f32; 2]) -> Mesh {
    // Build outward in (u, v, w) from a counter-clockwise profile, then flip the winding: both
    // maps to (x, y, z) swap two axes, i.e. are reflections.
    let mut poly = profile.to_vec();
    if signed_area2(&poly) < 0.0 {
        poly.reverse();
    }
    let n = poly.len() as u32;
    let mut m = Mesh::new();
    for w in range {
        m.vertices
            .extend(poly.iter().map(|p| axis.point(p[0], p[1], w)));
    }
    let (lo, hi) = (0u32, n);
    for [a, b, c] in triangulate(&poly).into_iter().map(|t| t.map(|i| i as u32)) {
        m.triangles.push([hi + a, hi + b, hi + c]);
        m.triangles.push([lo + a, lo + c, lo + b]);
    }
    for i in 0..n {
        let j = (i + 1) % n;
        m.triangles.push([lo + i, lo + j, hi + j]);
        m.triangles.push([lo + i, hi + j, hi + i]);
    }
    for t in &mut m.triangles {
        t.swap(1, 2);
    }
    m
}

fn lathe_mesh(centre: [f32; 2], profile: &[[f32; 2]], segments: u32) -> Mesh {
    let mut m = Mesh::new();
    // Ring (or single axis vertex) per profile point.
    let mut start = Vec::with_capacity(profile.len());
    for p in profile {
        start.push(m.vertices.len() as u32);
        if p[0] == 0.0 {
            m.vertices.push([centre[0], p[1], centre[1]]);
        } else {
            for s in 0..segments {
                let a = std::f32::consts::TAU * s as f32 / segments as f32;
                m.vertices
                    .push([centre[0] + p[0] * a.cos(), p[1], centre[1] + p[0] * a.sin()]);
            }
        }
    }
    let vid = |i: usize, s: u32| -> u32 {
        if profile[i][0] == 0.0 {
            start[i]
        } else {
            start[i] + s % segments
        }
    };
    for i in 0..profile.len() - 1 {
        let (on_a, on_b) = (profile[i][0] == 0.0, profile[i + 1][0] == 0.0);
        for s in 0..segments {
            let (a, b, c, d) = (vid(i, s), vid(i + 1, s), vid(i + 1, s + 1), vid(i, s + 1));
            if !on_b {
                m.triangles.push([a, b, c]);
            }
            if !on_a {
                m.triangles.push([a, c, d]);
            }
        }
    }
    m
}

/// A stud standing on the face at height `y` around `[x, z]`: an open-bottom cylinder (its
/// base is the face it stands on).
pub(crate) fn stud_mesh(x: f32, y: f32, z: f32) -> Mesh {
    lathe_mesh(
        [x, z],
        &[
            [STUD_RADIUS, y],
            [STUD_RADIUS, y + STUD_HEIGHT],
            [0.0, y + STUD_HEIGHT],
        ],
        STUD_SEGMENTS,
    )
}

/// A side stud whose base centre is `base` (LDU) on a vertical face with outward normal -z.
pub(crate) fn side_stud_mesh_neg_z(base: [f32; 3]) -> Mesh {
    // Build it standing on y = 0, then rotate -90° about x: (x, y, z) -> (x, z, -y), a proper
    // rotation, so the winding stays outward.
    let mut m = stud_mesh(0.0, 0.0, 0.0);
    for v in &mut m.vertices {
        *v = [v[0] + base[0], v[2] + base[1], -v[1] + base[2]];
    }
    m
}

/// Sample points per LDU for the solids whose cell fractions are sampled (lathes, convex).
const SAMPLES_PER_LDU: usize = 2;

/// Area of the part of a polygon inside the rectangle `[u0, u1] x [v0, v1]` (Sutherland-Hodgman
/// clipping; exact for any simple polygon).
fn clipped_area(poly: &[[f32; 2]], u: [f32; 2], v: [f32; 2]) -> f32 {
    let mut cur = poly.to_vec();
    for (axis, bound, keep_above) in [
        (0, u[0], true),
        (0, u[1], false),
        (1, v[0], true),
        (1, v[1], false),
    ] {
        let inside = |p: &[f32; 2]| {
            if keep_above {
                p[axis] >= bound
            } else {
                p[axis] <= bound
            }
        };
        let mut next = Vec::with_capacity(cur.len() + 4);
        for i in 0..cur.len() {
            let (a, b) = (cur[i], cur[(i + 1) % cur.len()]);
            if inside(&a) {
                next.push(a);
            }
            if inside(&a) != inside(&b) {
                let t = (bound - a[axis]) / (b[axis] - a[axis]);
                next.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
            }
        }
        cur = next;
        if cur.len() < 3 {
            return 0.0;
        }
    }
    0.5 * signed_area2(&cur).abs()
}

impl Solid {
    /// Axis-aligned bounds `(lo, hi)` in LDU.
    fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        self.mesh().bounds().expect("solids have vertices")
    }

    /// Fraction of the box `lo..hi` (LDU) inside the solid: exact for prisms (profile clipped
    /// to the box), sampled on a half-LDU grid for the others.
    fn fraction_in(&self, lo: [f32; 3], hi: [f32; 3]) -> f32 {
        if let Solid::Prism {
            profile,
            axis,
            range,
        } = self
        {
            let (u0, v0, w0) = axis.coords(lo);
            let (u1, v1, w1) = axis.coords(hi);
            let along = (w1.min(range[1]) - w0.max(range[0])).max(0.0) / (w1 - w0);
            return along * clipped_area(profile, [u0, u1], [v0, v1]) / ((u1 - u0) * (v1 - v0));
        }
        let n: Vec<usize> = (0..3)
            .map(|a| ((hi[a] - lo[a]) as usize * SAMPLES_PER_LDU).max(1))
            .collect();
        let at = |a: usize, k: usize| lo[a] + (k as f32 + 0.5) * (hi[a] - lo[a]) / n[a] as f32;
        let mut hits = 0usize;
        for i in 0..n[0] {
            for j in 0..n[1] {
                for k in 0..n[2] {
                    if self.contains([at(0, i), at(1, j), at(2, k)]) {
                        hits += 1;
                    }
                }
            }
        }
        hits as f32 / (n[0] * n[1] * n[2]) as f32
    }
}

/// Fraction of each lattice cell covered by `solids` (which must not overlap each other),
/// for every cell they touch.
pub(crate) fn cell_fractions(solids: &[Solid]) -> Vec<(Lattice, f32)> {
    let unit = crate::lattice::LDU_PER_UNIT;
    let mut lo = [f32::MAX; 3];
    let mut hi = [f32::MIN; 3];
    for (slo, shi) in solids.iter().map(Solid::bounds) {
        for a in 0..3 {
            lo[a] = lo[a].min(slo[a]);
            hi[a] = hi[a].max(shi[a]);
        }
    }
    let cmin: Vec<i32> = (0..3).map(|a| (lo[a] / unit[a]).floor() as i32).collect();
    let cmax: Vec<i32> = (0..3).map(|a| (hi[a] / unit[a]).ceil() as i32).collect();
    let mut out = Vec::new();
    for i in cmin[0]..cmax[0] {
        for j in cmin[1]..cmax[1] {
            for k in cmin[2]..cmax[2] {
                let c = [i, j, k];
                let clo: [f32; 3] = std::array::from_fn(|a| c[a] as f32 * unit[a]);
                let chi: [f32; 3] = std::array::from_fn(|a| clo[a] + unit[a]);
                let f: f32 = solids.iter().map(|s| s.fraction_in(clo, chi)).sum();
                if f > 1e-4 {
                    out.push((c, f.min(1.0)));
                }
            }
        }
    }
    out
}

/// Occupied voxels of a body: the cells whose volume is more than half inside it. With this
/// rule two physically disjoint bodies can never claim the same cell.
pub(crate) fn voxelize(solids: &[Solid]) -> Vec<Lattice> {
    cell_fractions(solids)
        .into_iter()
        .filter(|&(_, f)| f > 0.5)
        .map(|(c, _)| c)
        .collect()
}

/// Test helper: every directed edge of `m` appears once and its reverse once (a closed,
/// consistently wound surface).
#[cfg(test)]
pub(crate) fn assert_closed(m: &Mesh) {
    let mut edges: std::collections::HashMap<(u32, u32), i32> = std::collections::HashMap::new();
    for t in &m.triangles {
        for k in 0..3 {
            *edges.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
        }
    }
    for (&(a, b), &n) in &edges {
        assert_eq!(n, 1, "edge {a}-{b} used {n} times in one direction");
        assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}-{b} has no twin");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn signed_volume(m: &Mesh) -> f32 {
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.vertices[i as usize]);
                dot3(a, cross3(b, c)) / 6.0
            })
            .sum()
    }

    #[test]
    fn solids_are_closed_outward_and_match_their_inside_tests() {
        let l_shape = Solid::Prism {
            profile: vec![
                [-10.0, -10.0],
                [30.0, -10.0],
                [30.0, 10.0],
                [10.0, 10.0],
                [10.0, 30.0],
                [-10.0, 30.0],
            ],
            axis: Axis::Y,
            range: [-24.0, 0.0],
        };
        let slope = Solid::Prism {
            profile: vec![
                [10.0, 0.0],
                [-10.0, 0.0],
                [-30.0, -20.0],
                [-30.0, -24.0],
                [10.0, -24.0],
            ],
            axis: Axis::X,
            range: [-20.0, 20.0],
        };
        let cases = [
            (
                cuboid([-10.0, 10.0], [-8.0, 0.0], [-20.0, 20.0]),
                20.0 * 8.0 * 40.0,
            ),
            (l_shape, 24.0 * 1200.0),
            (slope, 40.0 * (20.0 * 24.0 + 20.0 * 4.0 + 200.0)),
            (
                Solid::Lathe {
                    centre: [0.0, 0.0],
                    profile: vec![[0.0, -24.0], [10.0, -24.0], [10.0, 0.0], [0.0, 0.0]],
                    segments: 64,
                },
                std::f32::consts::PI * 100.0 * 24.0,
            ),
        ];
        for (solid, volume) in cases {
            let m = solid.mesh();
            assert_closed(&m);
            let v = signed_volume(&m);
            assert!((v - volume).abs() < 0.01 * volume, "volume {v} vs {volume}");
            let sampled: f32 = cell_fractions(std::slice::from_ref(&solid))
                .iter()
                .map(|(_, f)| f * 800.0)
                .sum();
            assert!(
                (sampled - volume).abs() < 0.02 * volume,
                "{sampled} vs {volume}"
            );
        }
    }

    #[test]
    fn voxelize_keeps_cells_more_than_half_full() {
        // A wedge (z, y) = (0, 0), (10, 0), (0, 16) over two cells stacked in y: the lower one
        // is 3/4 full, the upper one 1/4.
        let wedge = Solid::Prism {
            profile: vec![[0.0, 0.0], [10.0, 0.0], [0.0, 16.0]],
            axis: Axis::X,
            range: [0.0, 10.0],
        };
        let f = cell_fractions(std::slice::from_ref(&wedge));
        assert_eq!(f.len(), 2);
        assert!(
            (f[0].1 - 0.75).abs() < 0.02 && (f[1].1 - 0.25).abs() < 0.02,
            "{f:?}"
        );
        assert_eq!(voxelize(&[wedge]), vec![[0, 0, 0]]);
    }

    #[test]
    fn studs_are_open_cylinders_on_their_face() {
        let m = stud_mesh(10.0, 0.0, -10.0);
        let (lo, hi) = m.bounds().unwrap();
        assert_eq!(lo, [4.0, 0.0, -16.0]);
        assert_eq!(hi, [16.0, 4.0, -4.0]);
        let side = side_stud_mesh_neg_z([0.0, -10.0, -10.0]);
        let (lo, hi) = side.bounds().unwrap();
        assert_eq!((lo[2], hi[2]), (-14.0, -10.0));
        assert_eq!((lo[1], hi[1]), (-16.0, -4.0));
    }
}
