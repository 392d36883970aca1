//! The part table: the 72 primitive types of DESIGN §3, built from a few procedural shapes, and
//! the types that define a part ([`PartDef`], [`Category`]). `library` re-exports the types and
//! serves the lookup API over the table; this module does not use `library`.
//!
//! Frame: the LDraw part origin converted to the y-up lattice (LDraw (x, y, z) LDU -> lattice
//! (x/10, -y/8, -z/10), half a turn about x, DESIGN §2). For every part here but two that is
//! the centre of the body's top face; the corner parts 2420/2357 have it at the centre of the
//! corner stud, and the 31° slopes 54200/85984 at the centre of the bottom face.
//!
//! The shapes below are written in the *drawing frame* (x, -y, z) of LDraw's part files (y up,
//! x and z as LDraw has them), where LDraw's own files read: 1xN and 2xN parts are long along x;
//! slopes face -z (their studs are on the back row at z = 0); the corners' missing quadrant is
//! +x/+z. [`finish`] then turns each into the lattice frame by negating z (LDraw -z is lattice
//! +z): in the lattice, slopes face +z and the corners' missing quadrant is +x/-z.
//! `tests/library_vs_ldraw.rs` checks every part against the real LDraw geometry cell by cell.
//!
//! Occupancy rule (all parts): a voxel is occupied when more than half of its volume is inside
//! the body (measured on a 1-LDU sample grid, see `shapes::voxelize`). Slopes therefore keep
//! the cells their sloped body fills mostly, round parts lose the corner cells their circle
//! only clips, and two physically disjoint parts can never claim the same cell.
//!
//! Anti-studs are the stud grid under the part plus the points between studs where the
//! underside grips a stud or a pin (tubes of >=2x2 parts, half positions of 1xN parts), as the
//! LDraw geometry shows them; exceptions are noted where a part is built.

use crate::lattice::{lattice_to_ldu, Lattice};
use crate::mesh::Mesh;
use crate::shapes::{cuboid, side_stud_mesh_neg_z, stud_mesh, voxelize, Axis, Solid};

/// The reference code's part groups.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Category {
    /// Simple bricks and plates (45 types).
    Simple,
    /// Tiles (9).
    Tile,
    /// Plates with one centre stud (2).
    Jumper,
    /// Corner bricks and plates (2).
    Corner,
    /// Slopes (11).
    Slope,
    /// Everything else (3).
    Misc,
}

impl Category {
    /// Lower-case name used in JSON and the Python API.
    pub fn name(&self) -> &'static str {
        match self {
            Category::Simple => "simple",
            Category::Tile => "tile",
            Category::Jumper => "jumper",
            Category::Corner => "corner",
            Category::Slope => "slope",
            Category::Misc => "misc",
        }
    }
}

/// One primitive part type.
#[derive(Debug, Clone)]
pub struct PartDef {
    /// Canonical LDraw id without `.dat`, lower case (e.g. `"3001"`, `"3062b"`).
    pub id: &'static str,
    /// LDraw description (e.g. `"Brick  2 x  4"`).
    pub name: &'static str,
    pub category: Category,
    /// Occupied voxels (cell min corners), part-local.
    pub voxels: Vec<Lattice>,
    /// Stud points (top connection points), part-local; a stud at p engages an anti-stud at p.
    pub studs: Vec<Lattice>,
    /// Anti-stud points (bottom connection points), part-local.
    pub anti_studs: Vec<Lattice>,
    /// Order of the yaw symmetry group about the origin: 1, 2 or 4.
    pub symmetry: u8,
    /// Keypoint (centre of the top face) in LDU, y up, part-local.
    pub keypoint: [f32; 3],
    /// Triangle mesh with studs in LDU, y up, part-local.
    pub mesh: Mesh,
    /// Studs that are not vertical lattice connections (e.g. the side stud of 87087): they are
    /// part of `mesh` but not of `studs`, and take no part in lattice connections. 0 for most
    /// parts.
    pub side_studs: u8,
    /// Centres (LDU, y up, part-local) of the side studs: where they point tells yaws apart
    /// that the lattice geometry alone does not (87087 turned a quarter about its centre).
    pub side_stud_points: Vec<[f32; 3]>,
    /// Centres (LDU, y up, part-local) of faces drawn unlike their opposite (2877's ridges along
    /// its length): no geometry, but where they face is part of a placement
    /// (`Component::same_placement`), not of its shape (`Component::same_shape`).
    pub face_marks: Vec<[f32; 3]>,
}

/// Part references used in real LDraw files that mean a library part: LDraw "~Moved to"
/// targets, newer or older moulds of the same shape and connections, and printed variants.
pub const ALIASES: &[(&str, &str)] = &[
    // "~Moved to" stubs: the library keeps the paper's id, files use the target.
    ("3023b", "3023"),
    ("6141", "4073"),
    ("3070a", "3070"),
    ("3660a", "3660"),
    ("3665a", "3665"),
    ("60481a", "60481"),
    // Other moulds of the same part (same footprint, height and connection points).
    ("3068a", "3068b"),
    ("3069a", "3069b"),
    ("3062a", "3062b"),
    ("3794b", "3794a"),
    ("15573", "3794a"),
    ("4032b", "4032a"),
    ("3245b", "3245a"),
    ("3245c", "3245a"),
    ("4460a", "4460b"),
    ("3660b", "3660"),
    ("3665b", "3665"),
    ("3040a", "3040b"),
    ("4589", "59900"),
    ("6143", "3941"),
    ("85861", "4073"),
    // 1xN bricks without bottom tubes: the 12-LDU cavity grips a stud at the same points.
    ("3065", "3004"),
    ("3066", "3010"),
    ("3067a", "3009"),
    // Printed variants in the bundled LDraw library.
    ("3004p20", "3004"),
    ("3004p90", "3004"),
    ("3010p04", "3010"),
    ("3010p928", "3010"),
    ("3024p01", "3024"),
    ("3039p23", "3039"),
    ("3039p34", "3039"),
    ("3039ps1", "3039"),
    ("3068bps1", "3068b"),
    ("3069bp03", "3069b"),
    ("3069bps1", "3069b"),
    ("3298p90", "3298"),
    ("4150ps5", "4150"),
];

/// A rectangular footprint in lattice cells: x in [x0, x1), z in [z0, z1) (even sizes).
#[derive(Clone, Copy)]
struct Rect {
    x0: i32,
    x1: i32,
    z0: i32,
    z1: i32,
}

impl Rect {
    /// `l` studs along x by `w` studs along z, centred on the origin.
    fn centred(l: i32, w: i32) -> Rect {
        Rect {
            x0: -l,
            x1: l,
            z0: -w,
            z1: w,
        }
    }

    /// Stud-centre points of the footprint at height `y`.
    fn grid(&self, y: i32) -> Vec<Lattice> {
        let mut v = Vec::new();
        for x in (self.x0 + 1..self.x1).step_by(2) {
            for z in (self.z0 + 1..self.z1).step_by(2) {
                v.push([x, y, z]);
            }
        }
        v
    }

    /// Points between stud centres at height `y`: tube positions of a >=2x2 footprint, half
    /// positions along a 1xN footprint, none for 1x1.
    fn between(&self, y: i32) -> Vec<Lattice> {
        let inner = |a0: i32, a1: i32| (a0 + 2..a1 - 1).step_by(2).collect::<Vec<_>>();
        let (xs, zs) = (inner(self.x0, self.x1), inner(self.z0, self.z1));
        let (xs, zs) = match (self.x1 - self.x0, self.z1 - self.z0) {
            (2, 2) => (vec![], vec![]),
            (2, _) => (vec![self.x0 + 1], zs),
            (_, 2) => (xs, vec![self.z0 + 1]),
            _ => (xs, zs),
        };
        let mut v = Vec::new();
        for &x in &xs {
            for &z in &zs {
                v.push([x, y, z]);
            }
        }
        v
    }

    /// Grid plus between points: the anti-studs of a hollow underside at height `y`.
    fn underside(&self, y: i32) -> Vec<Lattice> {
        let mut v = self.grid(y);
        v.extend(self.between(y));
        v
    }

    /// Extent along x in LDU.
    fn x_ldu(&self) -> [f32; 2] {
        [self.x0 as f32 * 10.0, self.x1 as f32 * 10.0]
    }

    /// Extent along z in LDU.
    fn z_ldu(&self) -> [f32; 2] {
        [self.z0 as f32 * 10.0, self.z1 as f32 * 10.0]
    }
}

/// A part before voxelization and meshing.
struct Shape {
    body: Vec<Solid>,
    studs: Vec<Lattice>,
    anti_studs: Vec<Lattice>,
    symmetry: u8,
    keypoint: [f32; 3],
    /// Base centres (LDU, drawing frame) of side studs on faces whose outward normal is -z.
    side_studs: Vec<[f32; 3]>,
    /// Centres (LDU, drawing frame) of faces drawn unlike their opposite (see
    /// [`PartDef::face_marks`]).
    face_marks: Vec<[f32; 3]>,
}

impl Shape {
    fn new(body: Vec<Solid>, studs: Vec<Lattice>, anti_studs: Vec<Lattice>, symmetry: u8) -> Shape {
        Shape {
            body,
            studs,
            anti_studs,
            symmetry,
            keypoint: [0.0; 3],
            side_studs: Vec::new(),
            face_marks: Vec::new(),
        }
    }
}

/// Mirror z of a point (drawing frame -> lattice frame, see the module header).
fn flip_z(p: Lattice) -> Lattice {
    [p[0], p[1], -p[2]]
}

/// Mirror z of a point in LDU (drawing frame -> lattice frame).
fn flip_z_ldu([x, y, z]: [f32; 3]) -> [f32; 3] {
    [x, y, -z + 0.0]
}

fn finish(id: &'static str, name: &'static str, category: Category, s: Shape) -> PartDef {
    // Drawing frame (LDraw's x and z, y up) -> lattice frame: z negated. The cell with min
    // corner k along z covers [k, k+1), mirrored [-k-1, -k).
    let mut voxels: Vec<Lattice> = voxelize(&s.body)
        .into_iter()
        .map(|[i, j, k]| [i, j, -k - 1])
        .collect();
    voxels.sort_unstable();
    let mut mesh = Mesh::new();
    for solid in &s.body {
        mesh.append(&solid.mesh());
    }
    for &p in &s.studs {
        let [x, y, z] = lattice_to_ldu(p);
        mesh.append(&stud_mesh(x, y, z));
    }
    for &b in &s.side_studs {
        mesh.append(&side_stud_mesh_neg_z(b));
    }
    // A mirror: negate z and reverse every triangle so the winding stays outward.
    for v in &mut mesh.vertices {
        v[2] = -v[2] + 0.0;
    }
    for t in &mut mesh.triangles {
        t.swap(1, 2);
    }
    PartDef {
        id,
        name,
        category,
        voxels,
        studs: s.studs.into_iter().map(flip_z).collect(),
        anti_studs: s.anti_studs.into_iter().map(flip_z).collect(),
        symmetry: s.symmetry,
        keypoint: flip_z_ldu(s.keypoint),
        mesh,
        side_studs: s.side_studs.len() as u8,
        side_stud_points: s.side_studs.iter().map(|&p| flip_z_ldu(p)).collect(),
        face_marks: s.face_marks.iter().map(|&p| flip_z_ldu(p)).collect(),
    }
}

/// Height in LDU of `h` plates.
fn plates(h: i32) -> f32 {
    8.0 * h as f32
}

/// A rectangular brick, plate or tile: `l` studs along x, `w` along z, `h` plates tall, with
/// top studs when `studded`, and a hollow underside.
fn rect(l: i32, w: i32, h: i32, studded: bool) -> Shape {
    let r = Rect::centred(l, w);
    let body = vec![cuboid(r.x_ldu(), [-plates(h), 0.0], r.z_ldu())];
    let studs = if studded { r.grid(0) } else { Vec::new() };
    Shape::new(body, studs, r.underside(-h), if l == w { 4 } else { 2 })
}

/// A brick or plate.
fn brick(l: i32, w: i32, h: i32) -> Shape {
    rect(l, w, h, true)
}

/// A tile (one plate, no studs).
fn tile(l: i32, w: i32) -> Shape {
    rect(l, w, 1, false)
}

/// A jumper: an `l` x `w` plate with a single stud at the centre of its top.
fn jumper(l: i32, w: i32) -> Shape {
    let mut s = rect(l, w, 1, false);
    s.studs = vec![[0, 0, 0]];
    s
}

/// A round part: a body of revolution about the y axis (profile `(r, y)` in LDU, see
/// `Solid::Lathe`) over an `n` x `n` stud footprint that is `h` plates tall, studs on the grid.
fn round(n: i32, h: i32, profile: &[[f32; 2]], studded: bool) -> Shape {
    let r = Rect::centred(n, n);
    let body = vec![Solid::Lathe {
        centre: [0.0, 0.0],
        profile: profile.to_vec(),
        segments: 16 * n as u32,
    }];
    let studs = if studded { r.grid(0) } else { Vec::new() };
    Shape::new(body, studs, r.underside(-h), 4)
}

/// A corner brick or plate `h` plates tall: three studs in an L around the origin stud, the
/// +x/+z quadrant missing. The underside has the three stud positions and the two half
/// positions between them (LDraw: `stud3` tubes at (10, 0) and (0, 10)).
fn corner(h: i32) -> Shape {
    let body = vec![Solid::Prism {
        profile: vec![
            [-10.0, -10.0],
            [30.0, -10.0],
            [30.0, 10.0],
            [10.0, 10.0],
            [10.0, 30.0],
            [-10.0, 30.0],
        ],
        axis: Axis::Y,
        range: [-plates(h), 0.0],
    }];
    let studs = vec![[0, 0, 0], [2, 0, 0], [0, 0, 2]];
    let anti = vec![[0, -h, 0], [2, -h, 0], [0, -h, 2], [1, -h, 0], [0, -h, 1]];
    Shape::new(body, studs, anti, 1)
}

/// A body with a constant cross-section along x: `profile` is `(z, y)` in LDU, extruded over
/// x in [-10 w, 10 w] (`w` studs wide).
fn extruded(w: i32, profile: &[[f32; 2]]) -> Vec<Solid> {
    vec![Solid::Prism {
        profile: profile.to_vec(),
        axis: Axis::X,
        range: [-10.0 * w as f32, 10.0 * w as f32],
    }]
}

/// A plain slope `w` studs wide: flat top row (studs) at z in [-10, 10], then the slope down
/// to a 4-LDU lip at z = -10 - 20 (d - 1), `h` plates tall, `d` studs deep.
fn slope(w: i32, d: i32, h: i32) -> Shape {
    let front = -10.0 - 20.0 * (d - 1) as f32;
    let bottom = -plates(h);
    let body = extruded(
        w,
        &[
            [10.0, 0.0],
            [-10.0, 0.0],
            [front, bottom + 4.0],
            [front, bottom],
            [10.0, bottom],
        ],
    );
    let foot = Rect {
        x0: -w,
        x1: w,
        z0: 1 - 2 * d,
        z1: 1,
    };
    Shape::new(
        body,
        foot.grid(0).into_iter().filter(|p| p[2] == 0).collect(),
        foot.underside(-h),
        1,
    )
}

/// An inverted 45° slope `w` studs wide, 2 deep, 3 plates tall: full 2-deep top with studs,
/// bottom only under the back row (z in [-10, 10]), where the anti-studs are (with the half
/// position of the `stud3` between them for w = 2). LDraw draws the front row as a well open
/// at the top around the hollow front studs; the body here is solid up to the stud plane.
fn inverted_slope(w: i32) -> Shape {
    let body = extruded(
        w,
        &[
            [10.0, 0.0],
            [-30.0, 0.0],
            [-30.0, -4.0],
            [-10.0, -24.0],
            [10.0, -24.0],
        ],
    );
    let top = Rect {
        x0: -w,
        x1: w,
        z0: -3,
        z1: 1,
    };
    let bottom = Rect {
        x0: -w,
        x1: w,
        z0: -1,
        z1: 1,
    };
    Shape::new(body, top.grid(0), bottom.underside(-3), 1)
}

/// A 31° slope, `w` studs wide, 1 deep, 2 plates tall, no studs. Its LDraw origin is the
/// centre of the bottom face, so the body is y in [0, 15.6] and the keypoint (centre of the top
/// of the body box) is 2 plates up.
fn slope31(w: i32) -> Shape {
    let body = extruded(
        w,
        &[
            [-10.0, 0.0],
            [10.0, 0.0],
            [10.0, 15.6],
            [9.33, 15.6],
            [-10.0, 4.0],
        ],
    );
    let mut s = Shape::new(body, Vec::new(), Rect::centred(w, 1).underside(0), 1);
    s.keypoint = [0.0, 16.0, 0.0];
    s
}

/// Slope 45 1x2 triple (15571): a 4-LDU base slab under a pyramid whose apex is at the top of
/// the vertical back face (0, 0, 10); front and sides slope at 45°. The underside holds one
/// stud at each grid position and at the centre: its opening is one 32 x 12 LDU slot whose
/// walls are 6 LDU from each of the three points (LDraw's inverted `box2-9p` at |x| in
/// [6.5, 16] are recesses, not blocks), like the cavity of a 1x2 brick.
fn triple_slope() -> Shape {
    let v = vec![
        [-20.0, -24.0, -10.0],
        [20.0, -24.0, -10.0],
        [20.0, -24.0, 10.0],
        [-20.0, -24.0, 10.0],
        [-20.0, -20.0, -10.0],
        [20.0, -20.0, -10.0],
        [20.0, -20.0, 10.0],
        [-20.0, -20.0, 10.0],
        [0.0, 0.0, 10.0],
    ];
    let faces = vec![
        vec![0, 1, 2, 3],
        vec![0, 4, 5, 1],
        vec![1, 5, 6, 2],
        vec![0, 3, 7, 4],
        vec![3, 2, 6, 8, 7],
        vec![4, 8, 5],
        vec![5, 8, 6],
        vec![7, 8, 4],
    ];
    let body = vec![Solid::Convex { vertices: v, faces }];
    Shape::new(body, Vec::new(), Rect::centred(2, 1).underside(-3), 1)
}

/// Brick 1x2 with curved top (37352): the top is a quarter circle of radius 20 centred at
/// (z, y) = (10, -20), from the front edge at y = -20 up to the back edge at y = 0. No studs;
/// the underside holds studs at the grid and at the centre (stud-holder ribs).
fn curved_top() -> Shape {
    let mut profile = vec![[10.0, -24.0], [10.0, 0.0]];
    for k in 1..=12 {
        let a = std::f32::consts::FRAC_PI_2 * (1.0 + k as f32 / 12.0);
        profile.push([10.0 + 20.0 * a.cos(), -20.0 + 20.0 * a.sin()]);
    }
    profile.push([-10.0, -24.0]);
    Shape::new(
        extruded(2, &profile),
        Vec::new(),
        Rect::centred(2, 1).underside(-3),
        1,
    )
}

/// Panel 1x1x1 corner (6231): a one-plate base with two 4-LDU walls on the -x and +z sides
/// (rounded wall ends not modelled), no studs, one anti-stud.
fn corner_panel() -> Shape {
    let body = vec![
        cuboid([-10.0, 10.0], [-24.0, -16.0], [-10.0, 10.0]),
        Solid::Prism {
            profile: vec![
                [-10.0, -10.0],
                [-6.0, -10.0],
                [-6.0, 6.0],
                [10.0, 6.0],
                [10.0, 10.0],
                [-10.0, 10.0],
            ],
            axis: Axis::Y,
            range: [-16.0, 0.0],
        },
    ];
    Shape::new(body, Vec::new(), vec![[0, -3, 0]], 1)
}

/// Brick 1x1 with a stud on its -z side (87087), centred 10 LDU below the top. The side stud is
/// in the mesh and counted in `side_studs`; it is no lattice connection (its axis is
/// horizontal), and it makes the part yaw-asymmetric.
fn side_stud_brick() -> Shape {
    let mut s = brick(1, 1, 3);
    s.symmetry = 1;
    s.side_studs = vec![[0.0, -10.0, -10.0]];
    s
}

/// Brick 1x2 with grille (2877): a sawtooth on both long faces, ridges running along x on the
/// -z face and up and down on the +z face, as LDraw draws it. The teeth stand out of a 16-LDU
/// core no further than the 1x2 footprint, so the occupancy is a 1x2 brick's; the two faces
/// differ, so the part has no yaw symmetry in its look: a mark on the ridged face makes which
/// face a picture shows part of its placement, though not of its shape.
///
/// Drawn, not copied: LDraw's teeth are 2 LDU deep every 4 LDU (6 and 10 of them), finer than a
/// pixel in a manual's picture, where the rasterizer turned them into speckle; and so steep that
/// Lambert shading darkened the faces far more than instruction tools draw them (flat faces with
/// a line per edge). Here: half as many teeth, half as steep.
fn grille_brick() -> Shape {
    const PERIOD: f32 = 8.0;
    const TOOTH: f32 = 2.0;
    let mut s = brick(2, 1, 3);
    // Core with the vertical teeth on +z: (x, z) profile from x = 20 to -20, valleys on the
    // core at x = 20 - 8k, peaks between.
    let mut profile = vec![[-20.0, -8.0], [20.0, -8.0]];
    let half_teeth = (40.0 / PERIOD * 2.0) as i32;
    profile.extend((0..=half_teeth).map(|i| {
        let x = 20.0 - PERIOD / 2.0 * i as f32;
        [x, if i % 2 == 1 { 8.0 + TOOTH } else { 8.0 }]
    }));
    let mut body = vec![Solid::Prism {
        profile,
        axis: Axis::Y,
        range: [-plates(3), 0.0],
    }];
    // The horizontal teeth on -z: (z, y) triangles extruded along x.
    let mut y0 = -plates(3);
    while y0 < 0.0 {
        body.push(Solid::Prism {
            profile: vec![
                [-8.0, y0],
                [-8.0 - TOOTH, y0 + PERIOD / 2.0],
                [-8.0, y0 + PERIOD],
            ],
            axis: Axis::X,
            range: [-20.0, 20.0],
        });
        y0 += PERIOD;
    }
    s.body = body;
    s.symmetry = 1;
    s.face_marks = vec![[0.0, -12.0, -10.0]];
    s
}

/// Build every part of the table.
pub fn build_parts() -> Vec<PartDef> {
    table()
        .into_iter()
        .map(|(id, name, cat, shape)| finish(id, name, cat, shape))
        .collect()
}

/// The table: id (the paper's), LDraw description, category and shape of every part.
fn table() -> Vec<(&'static str, &'static str, Category, Shape)> {
    use Category::*;
    // Profiles (r, y) of the round parts, from their LDraw files: 1x1 round parts stand on a
    // radius-8 collar, the cone tapers to the radius-6.5 stop under its stud.
    let round1_plate = [
        [0.0, -8.0],
        [8.0, -8.0],
        [8.0, -3.0],
        [10.0, -3.0],
        [10.0, 0.0],
        [0.0, 0.0],
    ];
    let round1_brick = [
        [0.0, -24.0],
        [8.0, -24.0],
        [8.0, -19.0],
        [10.0, -19.0],
        [10.0, 0.0],
        [0.0, 0.0],
    ];
    let cone = [
        [0.0, -24.0],
        [8.0, -24.0],
        [8.0, -19.0],
        [10.0, -19.0],
        [8.0, -8.5],
        [7.0, -3.0],
        [6.5, 0.0],
        [0.0, 0.0],
    ];
    let round2_plate = [[0.0, -8.0], [20.0, -8.0], [20.0, 0.0], [0.0, 0.0]];
    let round2_brick = [[0.0, -24.0], [20.0, -24.0], [20.0, 0.0], [0.0, 0.0]];
    let round2_tile = [
        [0.0, -8.0],
        [19.0, -8.0],
        [20.0, -7.0],
        [20.0, 0.0],
        [0.0, 0.0],
    ];

    // 4286's underside has a rib at z in [-14, -10] where the half position (0, -10) would be;
    // only the stud3a at z = -30 makes a half position.
    let mut slope33_narrow = slope(1, 3, 3);
    slope33_narrow.anti_studs.retain(|p| p[2] != -1);
    // 4460b's 12-LDU cavity has no divider at stud height: ribs 5 LDU either side of the half
    // position hold a stud there, as at its two grid positions.
    let slope75 = slope(1, 2, 9);
    // 4150's cross-shaped underside stud fills the centre (its arms reach about 8 LDU out), so
    // no stud goes there; a stud fits at each grid position and at each edge midpoint (the
    // tile offset by half a stud, on two studs), between the cross and the 16-LDU inner ring.
    let mut round_tile = round(2, 1, &round2_tile, false);
    round_tile.anti_studs = Rect::centred(2, 2).grid(-1);
    round_tile
        .anti_studs
        .extend([[-1, -1, 0], [0, -1, -1], [0, -1, 1], [1, -1, 0]]);

    vec![
        ("3024", "Plate  1 x  1", Simple, brick(1, 1, 1)),
        ("3005", "Brick  1 x  1", Simple, brick(1, 1, 3)),
        ("3023", "Plate  1 x  2", Simple, brick(2, 1, 1)),
        ("3004", "Brick  1 x  2", Simple, brick(2, 1, 3)),
        ("3623", "Plate  1 x  3", Simple, brick(3, 1, 1)),
        ("3622", "Brick  1 x  3", Simple, brick(3, 1, 3)),
        ("3010", "Brick  1 x  4", Simple, brick(4, 1, 3)),
        ("3666", "Plate  1 x  6", Simple, brick(6, 1, 1)),
        ("3009", "Brick  1 x  6", Simple, brick(6, 1, 3)),
        ("3460", "Plate  1 x  8", Simple, brick(8, 1, 1)),
        ("3008", "Brick  1 x  8", Simple, brick(8, 1, 3)),
        ("3022", "Plate  2 x  2", Simple, brick(2, 2, 1)),
        ("3003", "Brick  2 x  2", Simple, brick(2, 2, 3)),
        ("3021", "Plate  2 x  3", Simple, brick(3, 2, 1)),
        ("3020", "Plate  2 x  4", Simple, brick(4, 2, 1)),
        ("3001", "Brick  2 x  4", Simple, brick(4, 2, 3)),
        ("3795", "Plate  2 x  6", Simple, brick(6, 2, 1)),
        ("2456", "Brick  2 x  6", Simple, brick(6, 2, 3)),
        ("3034", "Plate  2 x  8", Simple, brick(8, 2, 1)),
        ("3007", "Brick  2 x  8", Simple, brick(8, 2, 3)),
        ("3036", "Plate  6 x  8", Simple, brick(8, 6, 1)),
        ("41539", "Plate  8 x  8", Simple, brick(8, 8, 1)),
        ("3958", "Plate  6 x  6", Simple, brick(6, 6, 1)),
        ("3033", "Plate  6 x 10", Simple, brick(10, 6, 1)),
        ("3002", "Brick  2 x  3", Simple, brick(3, 2, 3)),
        ("2445", "Plate  2 x 12", Simple, brick(12, 2, 1)),
        ("3030", "Plate  4 x 10", Simple, brick(10, 4, 1)),
        ("3031", "Plate  4 x  4", Simple, brick(4, 4, 1)),
        ("3032", "Plate  4 x  6", Simple, brick(6, 4, 1)),
        ("3035", "Plate  4 x  8", Simple, brick(8, 4, 1)),
        ("3710", "Plate  1 x  4", Simple, brick(4, 1, 1)),
        ("3832", "Plate  2 x 10", Simple, brick(10, 2, 1)),
        (
            "4073",
            "Plate  1 x  1 Round",
            Simple,
            round(1, 1, &round1_plate, true),
        ),
        ("4477", "Plate  1 x 10", Simple, brick(10, 1, 1)),
        ("6112", "Brick  1 x 12", Simple, brick(12, 1, 3)),
        (
            "3062b",
            "Brick  1 x  1 Round with Hollow Stud",
            Simple,
            round(1, 3, &round1_brick, true),
        ),
        ("3245a", "Brick  1 x  2 x  2", Simple, brick(2, 1, 6)),
        (
            "4032a",
            "Plate  2 x  2 Round with Axlehole",
            Simple,
            round(2, 1, &round2_plate, true),
        ),
        ("60479", "Plate  1 x 12", Simple, brick(12, 1, 1)),
        ("4282", "Plate  2 x 16", Simple, brick(16, 2, 1)),
        // No understud, but stud-holder ribs grip a stud at the half position.
        (
            "22886",
            "Brick  1 x  2 x  3 without Understud",
            Simple,
            brick(2, 1, 9),
        ),
        (
            "3941",
            "Brick  2 x  2 Round without Reinforcement",
            Simple,
            round(2, 3, &round2_brick, true),
        ),
        ("2877", "Brick  1 x  2 with Grille", Simple, grille_brick()),
        (
            "59900",
            "Cone  1 x  1 with Stop",
            Simple,
            round(1, 3, &cone, true),
        ),
        ("3029", "Plate  4 x 12", Simple, brick(12, 4, 1)),
        ("3070", "Tile  1 x  1 without Groove", Tile, tile(1, 1)),
        ("2431", "Tile  1 x  4 with Groove", Tile, tile(4, 1)),
        (
            "4150",
            "Tile  2 x  2 Round with Cross Underside Stud",
            Tile,
            round_tile,
        ),
        ("6636", "Tile  1 x  6", Tile, tile(6, 1)),
        ("3068b", "Tile  2 x  2 with Groove", Tile, tile(2, 2)),
        // No understud: the 12-LDU cavity still grips a stud at the half position.
        ("3069b", "Tile  1 x  2 with Groove", Tile, tile(2, 1)),
        ("3070b", "Tile  1 x  1 with Groove", Tile, tile(1, 1)),
        ("63864", "Tile  1 x  3", Tile, tile(3, 1)),
        ("4162", "Tile  1 x  8", Tile, tile(8, 1)),
        (
            "3794a",
            "Plate  1 x  2 without Groove with 1 Centre Stud",
            Jumper,
            jumper(2, 1),
        ),
        (
            "87580",
            "Plate  2 x  2 with Groove with 1 Centre Stud",
            Jumper,
            jumper(2, 2),
        ),
        ("2420", "Plate  2 x  2 Corner", Corner, corner(1)),
        ("2357", "Brick  2 x  2 Corner", Corner, corner(3)),
        (
            "15571",
            "Slope Brick 45  1 x  2 Triple with Bottom Stud Holder",
            Slope,
            triple_slope(),
        ),
        ("3039", "Slope Brick 45  2 x  2", Slope, slope(2, 2, 3)),
        ("3040b", "Slope Brick 45  2 x  1", Slope, slope(1, 2, 3)),
        ("3298", "Slope Brick 33  3 x  2", Slope, slope(2, 3, 3)),
        (
            "3660",
            "Slope Brick 45  2 x  2 Inverted without Inner Stopper Ring",
            Slope,
            inverted_slope(2),
        ),
        (
            "3665",
            "Slope Brick 45  2 x  1 Inverted without Inner Stopper Ring",
            Slope,
            inverted_slope(1),
        ),
        (
            "37352",
            "Brick  1 x  2 with Curved Top",
            Slope,
            curved_top(),
        ),
        ("4286", "Slope Brick 33  3 x  1", Slope, slope33_narrow),
        (
            "4460b",
            "Slope Brick 75  2 x  1 x  3 with Hollow Stud",
            Slope,
            slope75,
        ),
        (
            "60481",
            "Slope Brick 65  2 x  1 x  2 with Symmetric Stud Holder",
            Slope,
            slope(1, 2, 6),
        ),
        (
            "85984",
            "Slope Brick 31  1 x  2 x  0.667",
            Slope,
            slope31(2),
        ),
        ("54200", "Slope Brick 31  1 x  1 x  0.667", Misc, slope31(1)),
        (
            "6231",
            "Panel  1 x  1 x  1 Corner with Rounded Corners",
            Misc,
            corner_panel(),
        ),
        (
            "87087",
            "Brick  1 x  1 with Stud on 1 Side",
            Misc,
            side_stud_brick(),
        ),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::cell_fractions;

    /// Every occupancy decision is clear-cut: no cell of any part is within 2% of half full
    /// (the closest, 4460b's, is 0.529), so the >1/2 rule does not hinge on sampling details.
    #[test]
    fn no_cell_is_borderline() {
        for (id, _, _, shape) in table() {
            for (c, f) in cell_fractions(&shape.body) {
                assert!((f - 0.5).abs() > 0.02, "{id}: cell {c:?} is {f:.3} full");
            }
        }
    }

    /// Every body solid is a closed, consistently wound surface.
    #[test]
    fn body_solids_are_closed() {
        for (id, _, _, shape) in table() {
            for solid in &shape.body {
                let m = solid.mesh();
                assert!(!m.triangles.is_empty(), "{id}");
                crate::shapes::assert_closed(&m);
            }
        }
    }

    #[test]
    fn aliases_point_at_library_parts() {
        let ids: Vec<&str> = table().iter().map(|t| t.0).collect();
        let mut keys = std::collections::HashSet::new();
        for &(alias, target) in ALIASES {
            assert!(ids.contains(&target), "{alias} -> {target}: no such part");
            assert!(!ids.contains(&alias), "{alias} is itself a library id");
            assert!(keys.insert(alias), "{alias} listed twice");
        }
    }

    #[test]
    fn footprint_helpers() {
        let r = Rect::centred(4, 2);
        assert_eq!(r.grid(0).len(), 8);
        assert_eq!(r.between(-3), vec![[-2, -3, 0], [0, -3, 0], [2, -3, 0]]);
        let r = Rect::centred(4, 1);
        assert_eq!(r.between(-3), vec![[-2, -3, 0], [0, -3, 0], [2, -3, 0]]);
        let r = Rect {
            x0: -1,
            x1: 1,
            z0: -5,
            z1: 1,
        };
        assert_eq!(r.between(0), vec![[0, 0, -3], [0, 0, -1]]);
        assert!(Rect::centred(1, 1).between(0).is_empty());
    }
}
