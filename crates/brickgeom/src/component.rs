//! Components: what a step adds. A primitive brick, or a submodule built from an assembly.

use std::collections::BTreeSet;

use crate::error::{BrickGeomError, Result};
use crate::lattice::{rotate_cell, rotate_point, Lattice, Pose};
use crate::library::part;
use crate::mesh::Mesh;
use crate::parts::PartDef;

/// LDraw's "main colour" code: the brick takes the colour of whatever places it.
pub const MAIN_COLOUR: i32 = 16;

/// One brick inside a component: its library id, its pose in the component frame and its LDraw
/// colour code (`MAIN_COLOUR` = inherit the colour the component is placed with).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Brick {
    pub part: &'static str,
    pub pose: Pose,
    pub colour: i32,
}

impl Brick {
    /// This brick as placed by its component standing at `pose` in `colour`: the poses compose,
    /// and LDraw's colour inheritance ([`resolve_colour`](crate::colours::resolve_colour)): a
    /// brick in `MAIN_COLOUR` takes the colour its component is placed with, a brick in 24 that
    /// colour's edge colour; any other colour is the brick's own.
    pub fn placed_by(&self, pose: &Pose, colour: i32) -> Brick {
        Brick {
            part: self.part,
            pose: pose.compose(&self.pose),
            colour: crate::colours::resolve_colour(self.colour, colour),
        }
    }
}

/// A placeable unit: a primitive part or a submodule (a union of placed bricks).
///
/// All geometry is in the component frame (lattice units, y up). For a primitive this is the
/// part frame; for a submodule it is the frame of the assembly it was built in.
#[derive(Debug, Clone)]
pub struct Component {
    /// Part id for a primitive, the submodule's name otherwise.
    pub name: String,
    /// True for a submodule.
    pub is_submodule: bool,
    pub bricks: Vec<Brick>,
    /// Occupied voxels, sorted, no duplicates.
    pub voxels: Vec<Lattice>,
    /// Stud points of the union that are not covered by its own bricks, sorted.
    pub studs: Vec<Lattice>,
    /// Anti-stud points of the union that are not blocked by its own bricks, sorted.
    pub anti_studs: Vec<Lattice>,
    /// Yaw symmetry order (1, 2 or 4): how many quarter turns map the component onto itself up
    /// to a translation: its geometry and, for a submodule, every brick's part, colour and
    /// placement (two bricks of different colours swapped by a turn are a different look).
    pub symmetry: u8,
    /// The same count for the geometry alone (voxels, connection points, side studs), blind to
    /// which brick is where: what the generator's placement search needs.
    pub shape_symmetry: u8,
    /// Indices into `bricks` of the topmost bricks (highest top face); their keypoints are the
    /// component's keypoint candidates.
    pub topmost: Vec<usize>,
    /// Centres of the bricks' side studs (LDU, rounded, component frame), sorted: no lattice
    /// connections, but they tell apart poses with the same voxels and connection points.
    pub side_studs: Vec<[i32; 3]>,
    /// Centres of the bricks' faces drawn unlike their opposite ([`PartDef::face_marks`]; LDU,
    /// rounded, component frame), sorted: part of a placement, not of its shape.
    pub face_marks: Vec<[i32; 3]>,
}

/// A brick as [`Component::placed_bricks`] describes it: part, colour, and its voxels, studs,
/// anti-studs and side studs, each sorted.
type PlacedBrick = (
    &'static str,
    i32,
    Vec<Lattice>,
    Vec<Lattice>,
    Vec<Lattice>,
    Vec<Lattice>,
    Vec<Lattice>,
);

/// Points of every brick's part (`of`: LDU, part frame) placed with the brick, rounded, sorted.
fn bricks_points(bricks: &[Brick], of: fn(&PartDef) -> &Vec<[f32; 3]>) -> Vec<[i32; 3]> {
    let mut out: Vec<[i32; 3]> = bricks
        .iter()
        .flat_map(|b| {
            let def = part(b.part).expect("bricks are library parts");
            of(def).iter().map(move |&p| round_ldu(b.pose.apply_ldu(p)))
        })
        .collect();
    out.sort_unstable();
    out
}

/// The four cells around a connection point, on the layer `y` (the layer above a stud is the
/// point's y; the layer below an anti-stud is y - 1).
pub(crate) fn cells_around(p: Lattice, layer: i32) -> [Lattice; 4] {
    [
        [p[0] - 1, layer, p[2] - 1],
        [p[0], layer, p[2] - 1],
        [p[0] - 1, layer, p[2]],
        [p[0], layer, p[2]],
    ]
}

impl Component {
    /// The component of a single library part (id or alias).
    pub fn primitive(id: &str) -> Result<Component> {
        let def = part(id)?;
        let mut c = Component::from_bricks(
            def.id.to_string(),
            vec![Brick {
                part: def.id,
                pose: Pose::identity(),
                colour: MAIN_COLOUR,
            }],
        )?;
        c.is_submodule = false;
        c.symmetry = def.symmetry;
        c.shape_symmetry = if def.face_marks.is_empty() {
            def.symmetry
        } else {
            c.detect_symmetry(false, false)
        };
        Ok(c)
    }

    /// A submodule from placed components `(component, pose, colour)` in its own frame: every
    /// brick of every component, placed with it (:meth:`Brick::placed_by`).
    pub fn from_placed<'a>(
        name: String,
        placed: impl IntoIterator<Item = (&'a Component, Pose, i32)>,
    ) -> Result<Component> {
        let bricks = placed
            .into_iter()
            .flat_map(|(c, pose, colour)| c.bricks.iter().map(move |b| b.placed_by(&pose, colour)))
            .collect();
        Component::from_bricks(name, bricks)
    }

    /// A submodule from placed bricks (e.g. an assembly's instances). Connection points that its
    /// own bricks engage are internal and dropped.
    pub fn from_bricks(name: String, bricks: Vec<Brick>) -> Result<Component> {
        if bricks.is_empty() {
            return Err(BrickGeomError::EmptyComponent {
                what: format!("submodule '{name}' has no bricks"),
            });
        }
        let mut voxels = BTreeSet::new();
        let mut studs = BTreeSet::new();
        let mut anti = BTreeSet::new();
        for b in &bricks {
            let def = part(b.part)?;
            voxels.extend(def.voxels.iter().map(|&v| b.pose.apply_cell(v)));
            studs.extend(def.studs.iter().map(|&s| b.pose.apply_point(s)));
            anti.extend(def.anti_studs.iter().map(|&a| b.pose.apply_point(a)));
        }
        let studs: Vec<Lattice> = studs
            .into_iter()
            .filter(|&s| !cells_around(s, s[1]).iter().all(|c| voxels.contains(c)))
            .filter(|s| !anti.contains(s))
            .collect();
        let anti_studs: Vec<Lattice> = anti
            .iter()
            .copied()
            .filter(|&a| !cells_around(a, a[1] - 1).iter().all(|c| voxels.contains(c)))
            .collect();
        // Studs engaged by an anti-stud of the same component are internal; drop the matching
        // anti-studs too.
        let all_studs: BTreeSet<Lattice> = bricks
            .iter()
            .flat_map(|b| {
                let def = part(b.part).expect("checked above");
                def.studs.iter().map(move |&s| b.pose.apply_point(s))
            })
            .collect();
        let anti_studs: Vec<Lattice> = anti_studs
            .into_iter()
            .filter(|a| !all_studs.contains(a))
            .collect();
        let tops: Vec<f32> = bricks
            .iter()
            .map(|b| {
                let def = part(b.part).expect("checked above");
                b.pose.apply_ldu(def.keypoint)[1]
            })
            .collect();
        let top = tops.iter().cloned().fold(f32::MIN, f32::max);
        let topmost = (0..bricks.len()).filter(|&i| tops[i] == top).collect();
        let voxels: Vec<Lattice> = voxels.into_iter().collect();
        let side_studs = bricks_points(&bricks, |d| &d.side_stud_points);
        let face_marks = bricks_points(&bricks, |d| &d.face_marks);
        let mut c = Component {
            name,
            is_submodule: true,
            bricks,
            voxels,
            studs,
            anti_studs,
            symmetry: 1,
            shape_symmetry: 1,
            topmost,
            side_studs,
            face_marks,
        };
        c.shape_symmetry = c.detect_symmetry(false, false);
        c.symmetry = c.detect_symmetry(true, true);
        Ok(c)
    }

    /// Geometry (voxels, studs, anti-studs) after a pose, each list sorted.
    pub fn placed(&self, pose: &Pose) -> (Vec<Lattice>, Vec<Lattice>, Vec<Lattice>) {
        let mut v: Vec<Lattice> = self.voxels.iter().map(|&c| pose.apply_cell(c)).collect();
        let mut s: Vec<Lattice> = self.studs.iter().map(|&p| pose.apply_point(p)).collect();
        let mut a: Vec<Lattice> = self
            .anti_studs
            .iter()
            .map(|&p| pose.apply_point(p))
            .collect();
        v.sort_unstable();
        s.sort_unstable();
        a.sort_unstable();
        (v, s, a)
    }

    /// Points (LDU, rounded: side-stud centres, face marks) after a pose, sorted.
    fn placed_ldu(points: &[[i32; 3]], pose: &Pose) -> Vec<[i32; 3]> {
        let mut s: Vec<[i32; 3]> = points
            .iter()
            .map(|&[x, y, z]| round_ldu(pose.apply_ldu([x as f32, y as f32, z as f32])))
            .collect();
        s.sort_unstable();
        s
    }

    /// The bricks placed by `pose`, each as its part, colour and placed geometry (voxels,
    /// studs, anti-studs, side studs, and with `faces` its face marks), sorted: the component
    /// brick by brick, whatever order its bricks were listed in.
    fn placed_bricks(&self, pose: &Pose, faces: bool) -> Vec<PlacedBrick> {
        let sorted = |mut v: Vec<Lattice>| {
            v.sort_unstable();
            v
        };
        let mut out: Vec<PlacedBrick> = self
            .bricks
            .iter()
            .map(|b| {
                let at = pose.compose(&b.pose);
                let def = part(b.part).expect("bricks are library parts");
                let placed_ldu = |points: &[[f32; 3]]| {
                    sorted(points.iter().map(|&p| round_ldu(at.apply_ldu(p))).collect())
                };
                (
                    b.part,
                    b.colour,
                    sorted(def.voxels.iter().map(|&v| at.apply_cell(v)).collect()),
                    sorted(def.studs.iter().map(|&p| at.apply_point(p)).collect()),
                    sorted(def.anti_studs.iter().map(|&p| at.apply_point(p)).collect()),
                    placed_ldu(&def.side_stud_points),
                    if faces {
                        placed_ldu(&def.face_marks)
                    } else {
                        Vec::new()
                    },
                )
            })
            .collect();
        out.sort_unstable();
        out
    }

    /// Whether the component looks the same at two poses: its geometry (voxels, connection
    /// points, side studs), or with `bricks` every brick's part, colour and placement
    /// ([`Component::placed_bricks`], which implies the geometry); with `faces`, where its face
    /// marks land too.
    fn looks_same(&self, a: &Pose, b: &Pose, bricks: bool, faces: bool) -> bool {
        if bricks {
            self.placed_bricks(a, faces) == self.placed_bricks(b, faces)
        } else {
            self.placed(a) == self.placed(b)
                && Self::placed_ldu(&self.side_studs, a) == Self::placed_ldu(&self.side_studs, b)
                && (!faces
                    || Self::placed_ldu(&self.face_marks, a)
                        == Self::placed_ldu(&self.face_marks, b))
        }
    }

    /// Number of quarter turns (out of 4) under which the component looks the same up to a
    /// translation ([`Component::looks_same`]).
    fn detect_symmetry(&self, bricks: bool, faces: bool) -> u8 {
        // each quarter turn moved so that its lowest voxel corner is the origin
        let at = |yaw: u8| {
            let (v, _, _) = self.placed(&Pose::new(yaw, [0, 0, 0]));
            let m = v.iter().fold([i32::MAX; 3], |m, c| {
                [m[0].min(c[0]), m[1].min(c[1]), m[2].min(c[2])]
            });
            Pose::new(yaw, [-m[0], -m[1], -m[2]])
        };
        let base = at(0);
        (0..4u8)
            .filter(|&yaw| self.looks_same(&base, &at(yaw), bricks, faces))
            .count() as u8
    }

    /// Two poses are the same placement when they produce identical geometry: voxels,
    /// connection points, side studs and face marks, and for a submodule every brick (part,
    /// colour, placement) where a brick was (pose equality modulo the component's symmetry).
    pub fn same_placement(&self, a: &Pose, b: &Pose) -> bool {
        a == b || self.looks_same(a, b, self.is_submodule, true)
    }

    /// [`Component::same_placement`] blind to face marks: the same shape in the same place,
    /// whichever way a face drawn unlike its opposite (2877's grille) faces. What the
    /// evaluation scores, as the paper's symmetry-aware rotation classes do.
    pub fn same_shape(&self, a: &Pose, b: &Pose) -> bool {
        a == b || self.looks_same(a, b, self.is_submodule, false)
    }

    /// The keypoints (LDU, y up, component frame) of the topmost bricks.
    pub fn keypoints(&self) -> Vec<[f32; 3]> {
        self.topmost
            .iter()
            .map(|&i| {
                let b = &self.bricks[i];
                b.pose
                    .apply_ldu(part(b.part).expect("bricks are library parts").keypoint)
            })
            .collect()
    }

    /// The union mesh of the bricks (LDU, y up, component frame).
    pub fn mesh(&self) -> Mesh {
        let mut m = Mesh::new();
        for b in &self.bricks {
            let def = part(b.part).expect("bricks are library parts");
            m.append(&def.mesh.transformed(&b.pose));
        }
        m
    }

    /// Lowest voxel y.
    pub fn min_y(&self) -> i32 {
        self.voxels.iter().map(|v| v[1]).min().unwrap_or(0)
    }
}

/// Rotate a whole list of cells (helper for tests and callers).
pub fn rotate_cells(cells: &[Lattice], yaw: u8) -> Vec<Lattice> {
    cells.iter().map(|&c| rotate_cell(c, yaw)).collect()
}

/// Rotate a whole list of points.
pub fn rotate_points(points: &[Lattice], yaw: u8) -> Vec<Lattice> {
    points.iter().map(|&p| rotate_point(p, yaw)).collect()
}

/// A point in LDU rounded to whole LDU (side-stud centres lie on whole LDU).
fn round_ldu(p: [f32; 3]) -> [i32; 3] {
    [
        p[0].round() as i32,
        p[1].round() as i32,
        p[2].round() as i32,
    ]
}
