//! Assemblies: placed components on the lattice, with exact collision and connection rules.
//!
//! The occupancy is a dense grid of instance ids that grows to fit what is placed. Studs and
//! anti-studs of placed instances are indexed by lattice point; whether one is *free* is decided
//! from the grid (the four cells next to the point on the side it faces are empty), so the answer
//! is always consistent with the voxels, whatever order things were added and removed in.

use std::sync::{Arc, OnceLock};

use ndarray::Array3;
use rayon::prelude::*;

use crate::component::{cells_around, Brick, Component, MAIN_COLOUR};
use crate::error::{BrickGeomError, Result};
use crate::lattice::{check_range, pack, Lattice, PointMap, PointSet, Pose};

/// How a placement is held by the assembly (DESIGN §3), in order of preference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum AttachKind {
    /// At least one of its anti-studs sits on a free stud of the assembly.
    OnStuds,
    /// At least one of its studs goes into a free anti-stud of the assembly (attached below).
    FromBelow,
    /// It stands on the ground plane (lowest voxel at y = 0).
    Ground,
}

impl AttachKind {
    /// Lower-case name used in JSON and the Python API.
    pub fn name(&self) -> &'static str {
        match self {
            AttachKind::OnStuds => "on_studs",
            AttachKind::FromBelow => "from_below",
            AttachKind::Ground => "ground",
        }
    }
}

/// A valid placement found by candidate enumeration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Placement {
    pub pose: Pose,
    pub kind: AttachKind,
}

/// A component placed in an assembly, with its world geometry cached.
#[derive(Debug, Clone)]
pub struct Instance {
    pub component: Arc<Component>,
    pub pose: Pose,
    /// LDraw colour code the instance is placed with (applies to its main-colour bricks).
    pub colour: i32,
    /// World voxels, sorted.
    pub voxels: Vec<Lattice>,
    /// World stud points, sorted.
    pub studs: Vec<Lattice>,
    /// World anti-stud points, sorted.
    pub anti_studs: Vec<Lattice>,
}

/// Where ground placements are searched during candidate enumeration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GroundSearch {
    /// No ground placements.
    Off,
    /// Translations with x in `[x0, x1]` and z in `[z0, z1]` (inclusive, lattice units).
    Region { x0: i32, x1: i32, z0: i32, z1: i32 },
    /// The assembly's footprint grown by the component's size on every side (a fixed region of
    /// +-16 half-studs around the origin when the assembly is empty).
    Auto,
}

/// Dense grid of instance ids (`0` = empty, otherwise id + 1) covering a box of cells.
#[derive(Debug, Clone, Default)]
struct Grid {
    origin: Lattice,
    dims: [usize; 3],
    cells: Vec<u32>,
    /// One bit per cell (filled or not): collision tests touch this 32x smaller array, which
    /// stays in cache on large assemblies; `cells` is read only to name the occupant.
    bits: Vec<u64>,
}

/// Extra cells added on every side when the grid grows, so growth is rare.
const GROW_MARGIN: i32 = 16;

impl Grid {
    #[inline]
    fn index(&self, c: Lattice) -> Option<usize> {
        let x = c[0].checked_sub(self.origin[0])?;
        let y = c[1].checked_sub(self.origin[1])?;
        let z = c[2].checked_sub(self.origin[2])?;
        if x < 0 || y < 0 || z < 0 {
            return None;
        }
        let (x, y, z) = (x as usize, y as usize, z as usize);
        if x >= self.dims[0] || y >= self.dims[1] || z >= self.dims[2] {
            return None;
        }
        Some((x * self.dims[1] + y) * self.dims[2] + z)
    }

    #[inline]
    fn get(&self, c: Lattice) -> u32 {
        self.index(c).map_or(0, |i| self.cells[i])
    }

    #[inline]
    fn filled(&self, c: Lattice) -> bool {
        self.index(c)
            .is_some_and(|i| self.bits[i >> 6] & (1u64 << (i & 63)) != 0)
    }

    #[inline]
    fn set(&mut self, i: usize, value: u32) {
        self.cells[i] = value;
        if value == 0 {
            self.bits[i >> 6] &= !(1u64 << (i & 63));
        } else {
            self.bits[i >> 6] |= 1u64 << (i & 63);
        }
    }

    /// Grow (reallocating) so that the box [lo, hi] (inclusive cells) is covered.
    fn ensure(&mut self, lo: Lattice, hi: Lattice) {
        let cur_hi = [
            self.origin[0] + self.dims[0] as i32 - 1,
            self.origin[1] + self.dims[1] as i32 - 1,
            self.origin[2] + self.dims[2] as i32 - 1,
        ];
        let empty = self.cells.is_empty();
        if !empty && (0..3).all(|a| lo[a] >= self.origin[a] && hi[a] <= cur_hi[a]) {
            return;
        }
        let mut new_lo = [0; 3];
        let mut new_hi = [0; 3];
        for a in 0..3 {
            if empty {
                new_lo[a] = lo[a] - GROW_MARGIN;
                new_hi[a] = hi[a] + GROW_MARGIN;
                continue;
            }
            // Only the sides that must move do, and by at least half the current extent, so a
            // shape that keeps growing one way (a tall column) costs amortised linear copying
            // instead of a reallocation of the whole box at every step.
            let step = GROW_MARGIN.max(self.dims[a] as i32 / 2);
            new_lo[a] = if lo[a] < self.origin[a] {
                lo[a] - step
            } else {
                self.origin[a]
            };
            new_hi[a] = if hi[a] > cur_hi[a] {
                hi[a] + step
            } else {
                cur_hi[a]
            };
        }
        // Nothing is ever below the ground, so the grid starts at y = 0 at the lowest.
        new_lo[1] = new_lo[1].max(0);
        let dims = [
            (new_hi[0] - new_lo[0] + 1) as usize,
            (new_hi[1] - new_lo[1] + 1) as usize,
            (new_hi[2] - new_lo[2] + 1) as usize,
        ];
        let mut grid = Grid {
            origin: new_lo,
            dims,
            cells: vec![0; dims[0] * dims[1] * dims[2]],
            bits: vec![0; (dims[0] * dims[1] * dims[2]).div_ceil(64)],
        };
        for x in 0..self.dims[0] {
            for y in 0..self.dims[1] {
                let src = (x * self.dims[1] + y) * self.dims[2];
                let c = [
                    self.origin[0] + x as i32,
                    self.origin[1] + y as i32,
                    self.origin[2],
                ];
                let dst = grid.index(c).expect("new grid covers the old one");
                for k in 0..self.dims[2] {
                    grid.set(dst + k, self.cells[src + k]);
                }
            }
        }
        *self = grid;
    }
}

/// Placed components on the lattice.
#[derive(Debug, Clone, Default)]
pub struct Assembly {
    grid: Grid,
    instances: Vec<Option<Instance>>,
    /// Stud point (packed) -> instances with a stud there.
    stud_index: PointMap<(Lattice, Vec<u32>)>,
    /// Anti-stud point (packed) -> instances with an anti-stud there.
    anti_stud_index: PointMap<(Lattice, Vec<u32>)>,
    /// Free studs and anti-studs (sorted lists and packed sets), computed on first use after
    /// every change: stage 2 and candidate enumeration ask many questions of one state.
    free_cache: OnceLock<Arc<FreePoints>>,
}

#[derive(Debug, Default)]
struct FreePoints {
    /// Occupied cell bounds (cached with the free points: stage 2 asks for them per query).
    bounds: Option<(Lattice, Lattice)>,
    studs: Vec<Lattice>,
    anti_studs: Vec<Lattice>,
    stud_set: PointSet,
    anti_stud_set: PointSet,
}

/// A component's geometry rotated by one yaw, ready to be translated many times.
struct Prepared<'a> {
    component: &'a Component,
    yaw: u8,
    voxels: Vec<Lattice>,
    studs: Vec<Lattice>,
    anti_studs: Vec<Lattice>,
    lo: Lattice,
    hi: Lattice,
}

impl<'a> Prepared<'a> {
    fn new(component: &'a Component, yaw: u8) -> Self {
        let rot = Pose::new(yaw, [0, 0, 0]);
        let voxels: Vec<Lattice> = component
            .voxels
            .iter()
            .map(|&v| rot.apply_cell(v))
            .collect();
        let (lo, hi) = bounds(&voxels).unwrap_or(([0; 3], [0; 3]));
        Prepared {
            component,
            yaw,
            studs: component
                .studs
                .iter()
                .map(|&p| rot.apply_point(p))
                .collect(),
            anti_studs: component
                .anti_studs
                .iter()
                .map(|&p| rot.apply_point(p))
                .collect(),
            voxels,
            lo,
            hi,
        }
    }
}

#[inline]
fn add(p: Lattice, t: Lattice) -> Lattice {
    [p[0] + t[0], p[1] + t[1], p[2] + t[2]]
}

/// A comparable description of an assembly's state (for tests and equality).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Snapshot {
    /// (id, component name, pose) of every instance, by id.
    pub instances: Vec<(u32, String, Pose)>,
    /// (cell, id) of every occupied cell, sorted.
    pub cells: Vec<(Lattice, u32)>,
    pub free_studs: Vec<Lattice>,
    pub free_anti_studs: Vec<Lattice>,
}

fn bounds(cells: &[Lattice]) -> Option<(Lattice, Lattice)> {
    let first = *cells.first()?;
    Some(cells.iter().fold((first, first), |(lo, hi), c| {
        (
            [lo[0].min(c[0]), lo[1].min(c[1]), lo[2].min(c[2])],
            [hi[0].max(c[0]), hi[1].max(c[1]), hi[2].max(c[2])],
        )
    }))
}

impl Assembly {
    /// An empty assembly.
    pub fn new() -> Self {
        Assembly::default()
    }

    /// Number of placed instances.
    pub fn len(&self) -> usize {
        self.instances.iter().filter(|i| i.is_some()).count()
    }

    /// True when nothing is placed.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The instance with this id.
    pub fn instance(&self, id: u32) -> Result<&Instance> {
        self.instances
            .get(id as usize)
            .and_then(|i| i.as_ref())
            .ok_or(BrickGeomError::NoSuchInstance { id })
    }

    /// `(id, instance)` for every placed instance, by id.
    pub fn instances(&self) -> impl Iterator<Item = (u32, &Instance)> {
        self.instances
            .iter()
            .enumerate()
            .filter_map(|(i, x)| x.as_ref().map(|x| (i as u32, x)))
    }

    /// Instance id occupying a cell, if any.
    pub fn occupant(&self, cell: Lattice) -> Option<u32> {
        match self.grid.get(cell) {
            0 => None,
            v => Some(v - 1),
        }
    }

    fn geometry_checks(&self, voxels: &[Lattice]) -> Result<()> {
        for &v in voxels {
            check_range(v)?;
        }
        if let Some(y) = voxels.iter().map(|v| v[1]).min() {
            if y < 0 {
                return Err(BrickGeomError::BelowGround { y });
            }
        }
        Ok(())
    }

    /// The first instance the placement's voxels overlap, if any.
    pub fn collision(&self, component: &Component, pose: &Pose) -> Option<u32> {
        component
            .voxels
            .iter()
            .find_map(|&v| self.occupant(pose.apply_cell(v)))
    }

    /// True if a stud at `p` has nothing on it.
    pub fn stud_is_free(&self, p: Lattice) -> bool {
        cells_around(p, p[1]).iter().all(|&c| !self.grid.filled(c))
    }

    /// True if an anti-stud at `p` has nothing under it and is above the ground.
    pub fn anti_stud_is_free(&self, p: Lattice) -> bool {
        p[1] > 0
            && cells_around(p, p[1] - 1)
                .iter()
                .all(|&c| !self.grid.filled(c))
    }

    /// Every way the placement connects (empty: not connected). Does not check collision.
    pub fn attach_kinds(&self, component: &Component, pose: &Pose) -> Vec<AttachKind> {
        let prep = Prepared::new(component, pose.yaw);
        self.kinds_of(
            &prep,
            pose.t,
            |p| self.is_free_stud(p),
            |p| self.is_free_anti_stud(p),
        )
    }

    fn is_free_stud(&self, p: Lattice) -> bool {
        self.free_points().stud_set.contains(&pack(p))
    }

    fn is_free_anti_stud(&self, p: Lattice) -> bool {
        self.free_points().anti_stud_set.contains(&pack(p))
    }

    fn kinds_of(
        &self,
        prep: &Prepared,
        t: Lattice,
        free_stud: impl Fn(Lattice) -> bool,
        free_anti: impl Fn(Lattice) -> bool,
    ) -> Vec<AttachKind> {
        let mut kinds = Vec::new();
        if prep.anti_studs.iter().any(|&a| free_stud(add(a, t))) {
            kinds.push(AttachKind::OnStuds);
        }
        if prep.studs.iter().any(|&s| free_anti(add(s, t))) {
            kinds.push(AttachKind::FromBelow);
        }
        if prep.lo[1] + t[1] == 0 {
            kinds.push(AttachKind::Ground);
        }
        kinds
    }

    /// The shared check: range, ground, collision (early exit), then connection.
    fn check_prepared(
        &self,
        prep: &Prepared,
        t: Lattice,
        free_stud: impl Fn(Lattice) -> bool,
        free_anti: impl Fn(Lattice) -> bool,
    ) -> Result<AttachKind> {
        check_range(t)?;
        check_range(add(prep.lo, t))?;
        check_range(add(prep.hi, t))?;
        if prep.lo[1] + t[1] < 0 {
            return Err(BrickGeomError::BelowGround {
                y: prep.lo[1] + t[1],
            });
        }
        if prep.voxels.iter().any(|&v| self.grid.filled(add(v, t))) {
            let instance = prep
                .voxels
                .iter()
                .find_map(|&v| self.occupant(add(v, t)))
                .expect("a filled cell has an occupant");
            return Err(BrickGeomError::Collision { instance });
        }
        // Preference order: on studs, from below, ground.
        if prep.anti_studs.iter().any(|&a| free_stud(add(a, t))) {
            Ok(AttachKind::OnStuds)
        } else if prep.studs.iter().any(|&s| free_anti(add(s, t))) {
            Ok(AttachKind::FromBelow)
        } else if prep.lo[1] + t[1] == 0 {
            Ok(AttachKind::Ground)
        } else {
            Err(BrickGeomError::NotConnected)
        }
    }

    /// Full validity of a placement: in range, above ground, collision-free and connected.
    /// Returns the preferred attach kind.
    pub fn check(&self, component: &Component, pose: &Pose) -> Result<AttachKind> {
        if pose.yaw > 3 {
            return Err(BrickGeomError::InvalidYaw {
                yaw: pose.yaw as i64,
            });
        }
        let prep = Prepared::new(component, pose.yaw);
        self.check_prepared(
            &prep,
            pose.t,
            |p| self.is_free_stud(p),
            |p| self.is_free_anti_stud(p),
        )
    }

    /// `check` for many poses of one component, in parallel; results in input order.
    pub fn check_many(&self, component: &Component, poses: &[Pose]) -> Vec<Result<AttachKind>> {
        let preps: Vec<Prepared> = (0..4).map(|yaw| Prepared::new(component, yaw)).collect();
        let free = self.free_points();
        let (fs, fa) = (&free.stud_set, &free.anti_stud_set);
        // See `candidates` for the chunk size.
        poses
            .par_iter()
            .with_min_len(64)
            .map(|p| {
                if p.yaw > 3 {
                    return Err(BrickGeomError::InvalidYaw { yaw: p.yaw as i64 });
                }
                self.check_prepared(
                    &preps[p.yaw as usize],
                    p.t,
                    |q| fs.contains(&pack(q)),
                    |q| fa.contains(&pack(q)),
                )
            })
            .collect()
    }

    /// Place a component. Checks range, ground and collision; connection is *not* required
    /// (real models and tests place floating parts). Returns the new instance id.
    pub fn add(&mut self, component: Arc<Component>, pose: Pose) -> Result<u32> {
        if pose.yaw > 3 {
            return Err(BrickGeomError::InvalidYaw {
                yaw: pose.yaw as i64,
            });
        }
        check_range(pose.t)?;
        let (voxels, studs, anti_studs) = component.placed(&pose);
        self.geometry_checks(&voxels)?;
        if let Some(instance) = voxels.iter().find_map(|&v| self.occupant(v)) {
            return Err(BrickGeomError::Collision { instance });
        }
        let id = self.instances.len() as u32;
        self.free_cache = OnceLock::new();
        if let Some((lo, hi)) = bounds(&voxels) {
            self.grid.ensure(lo, hi);
        }
        for &v in &voxels {
            let i = self
                .grid
                .index(v)
                .expect("grid was grown to cover the voxels");
            self.grid.set(i, id + 1);
        }
        for &s in &studs {
            self.stud_index
                .entry(pack(s))
                .or_insert((s, Vec::new()))
                .1
                .push(id);
        }
        for &a in &anti_studs {
            self.anti_stud_index
                .entry(pack(a))
                .or_insert((a, Vec::new()))
                .1
                .push(id);
        }
        self.instances.push(Some(Instance {
            component,
            pose,
            colour: MAIN_COLOUR,
            voxels,
            studs,
            anti_studs,
        }));
        Ok(id)
    }

    /// Set the LDraw colour code of a placed instance.
    pub fn set_colour(&mut self, id: u32, colour: i32) -> Result<()> {
        self.instances
            .get_mut(id as usize)
            .and_then(|slot| slot.as_mut())
            .ok_or(BrickGeomError::NoSuchInstance { id })?
            .colour = colour;
        Ok(())
    }

    /// Place a component only if `check` accepts it; returns the id and the attach kind.
    pub fn add_checked(
        &mut self,
        component: Arc<Component>,
        pose: Pose,
    ) -> Result<(u32, AttachKind)> {
        let kind = self.check(&component, &pose)?;
        let id = self.add(component, pose)?;
        Ok((id, kind))
    }

    /// Remove an instance; the assembly returns exactly to the state it would have without it.
    pub fn remove(&mut self, id: u32) -> Result<Instance> {
        let inst = self
            .instances
            .get_mut(id as usize)
            .and_then(|slot| slot.take())
            .ok_or(BrickGeomError::NoSuchInstance { id })?;
        self.free_cache = OnceLock::new();
        for &v in &inst.voxels {
            if let Some(i) = self.grid.index(v) {
                self.grid.set(i, 0);
            }
        }
        for (index, points) in [
            (&mut self.stud_index, &inst.studs),
            (&mut self.anti_stud_index, &inst.anti_studs),
        ] {
            for &p in points {
                let k = pack(p);
                if let Some((_, ids)) = index.get_mut(&k) {
                    ids.retain(|&x| x != id);
                    if ids.is_empty() {
                        index.remove(&k);
                    }
                }
            }
        }
        // Trailing empty slots are dropped so ids are reused exactly as before the add.
        while matches!(self.instances.last(), Some(None)) {
            self.instances.pop();
        }
        Ok(inst)
    }

    fn free_points(&self) -> Arc<FreePoints> {
        self.free_cache
            .get_or_init(|| {
                let collect = |index: &PointMap<(Lattice, Vec<u32>)>,
                               free: &dyn Fn(Lattice) -> bool| {
                    let mut v: Vec<Lattice> = index
                        .values()
                        .map(|(p, _)| *p)
                        .filter(|&p| free(p))
                        .collect();
                    v.sort_unstable();
                    let set: PointSet = v.iter().map(|&p| pack(p)).collect();
                    (v, set)
                };
                let (studs, stud_set) = collect(&self.stud_index, &|p| self.stud_is_free(p));
                let (anti_studs, anti_stud_set) =
                    collect(&self.anti_stud_index, &|p| self.anti_stud_is_free(p));
                let cells: Vec<Lattice> = self
                    .instances()
                    .flat_map(|(_, i)| i.voxels.iter().copied())
                    .collect();
                Arc::new(FreePoints {
                    bounds: bounds(&cells),
                    studs,
                    anti_studs,
                    stud_set,
                    anti_stud_set,
                })
            })
            .clone()
    }

    /// Free studs of the assembly, sorted.
    pub fn free_studs(&self) -> Vec<Lattice> {
        self.free_points().studs.clone()
    }

    /// Free anti-studs of the assembly, sorted.
    pub fn free_anti_studs(&self) -> Vec<Lattice> {
        self.free_points().anti_studs.clone()
    }

    /// Occupied cell bounds `(lo, hi)` inclusive; `None` when empty.
    pub fn bounds(&self) -> Option<(Lattice, Lattice)> {
        self.free_points().bounds
    }

    /// The instance-id grid over `[lo, hi]` (inclusive), `-1` where empty.
    pub fn id_grid(&self, lo: Lattice, hi: Lattice) -> Array3<i32> {
        let dims = [
            (hi[0] - lo[0] + 1).max(0) as usize,
            (hi[1] - lo[1] + 1).max(0) as usize,
            (hi[2] - lo[2] + 1).max(0) as usize,
        ];
        Array3::from_shape_fn(dims, |(x, y, z)| {
            self.grid
                .get([lo[0] + x as i32, lo[1] + y as i32, lo[2] + z as i32]) as i32
                - 1
        })
    }

    /// Occupancy (1 = filled) over `[lo, hi]` (inclusive).
    pub fn occupancy(&self, lo: Lattice, hi: Lattice) -> Array3<u8> {
        self.id_grid(lo, hi).mapv(|v| u8::from(v >= 0))
    }

    /// All placed bricks flattened to (part, world pose, colour), by instance id; a brick of
    /// main colour takes its instance's colour.
    pub fn bricks(&self) -> Vec<Brick> {
        self.instances()
            .flat_map(|(_, inst)| {
                inst.component
                    .bricks
                    .iter()
                    .map(move |b| b.placed_by(&inst.pose, inst.colour))
            })
            .collect()
    }

    /// The assembly as a submodule component (union geometry, symmetry, topmost bricks).
    pub fn to_component(&self, name: &str) -> Result<Component> {
        Component::from_bricks(name.to_string(), self.bricks())
    }

    /// A comparable snapshot of the full state.
    pub fn snapshot(&self) -> Snapshot {
        let mut cells: Vec<(Lattice, u32)> = self
            .instances()
            .flat_map(|(id, i)| i.voxels.iter().map(move |&v| (v, id)))
            .collect();
        cells.sort_unstable();
        Snapshot {
            instances: self
                .instances()
                .map(|(id, i)| (id, i.component.name.clone(), i.pose))
                .collect(),
            cells,
            free_studs: self.free_studs(),
            free_anti_studs: self.free_anti_studs(),
        }
    }

    /// Translations worth testing: every match of one of the component's anti-studs with a free
    /// stud, of one of its studs with a free anti-stud, and ground positions.
    fn candidate_translations(
        &self,
        prep: &Prepared,
        free_studs: &[Lattice],
        free_anti: &[Lattice],
        ground: GroundSearch,
    ) -> Vec<Lattice> {
        let mut ts = Vec::with_capacity(
            free_studs.len() * prep.anti_studs.len() + free_anti.len() * prep.studs.len(),
        );
        for s in free_studs {
            ts.extend(
                prep.anti_studs
                    .iter()
                    .map(|a| [s[0] - a[0], s[1] - a[1], s[2] - a[2]]),
            );
        }
        for f in free_anti {
            ts.extend(
                prep.studs
                    .iter()
                    .map(|b| [f[0] - b[0], f[1] - b[1], f[2] - b[2]]),
            );
        }
        let region = match ground {
            GroundSearch::Off => None,
            GroundSearch::Region { x0, x1, z0, z1 } => Some((x0, x1, z0, z1)),
            GroundSearch::Auto => Some(match self.bounds() {
                None => (-16, 16, -16, 16),
                Some((lo, hi)) => (
                    lo[0] - prep.hi[0] - 1,
                    hi[0] - prep.lo[0] + 1,
                    lo[2] - prep.hi[2] - 1,
                    hi[2] - prep.lo[2] + 1,
                ),
            }),
        };
        if let Some((x0, x1, z0, z1)) = region {
            for x in x0..=x1 {
                for z in z0..=z1 {
                    ts.push([x, -prep.lo[1], z]);
                }
            }
        }
        ts.sort_unstable();
        ts.dedup();
        ts
    }

    /// Every valid (connected, collision-free, above ground) placement of `component` at `yaw`,
    /// sorted by translation. Candidates are checked in parallel; the result is deterministic.
    pub fn candidates(
        &self,
        component: &Component,
        yaw: u8,
        ground: GroundSearch,
    ) -> Result<Vec<Placement>> {
        if yaw > 3 {
            return Err(BrickGeomError::InvalidYaw { yaw: yaw as i64 });
        }
        let prep = Prepared::new(component, yaw);
        let free = self.free_points();
        let ts = self.candidate_translations(&prep, &free.studs, &free.anti_studs, ground);
        let (fs, fa) = (&free.stud_set, &free.anti_stud_set);
        // One candidate check is ~100 grid lookups (well under a microsecond); chunks of 256
        // keep rayon's per-task overhead small against that.
        let found: Vec<Option<Placement>> = ts
            .par_iter()
            .with_min_len(256)
            .map(|&t| {
                self.check_prepared(
                    &prep,
                    t,
                    |q| fs.contains(&pack(q)),
                    |q| fa.contains(&pack(q)),
                )
                .ok()
                .map(|kind| Placement {
                    pose: Pose::new(prep.yaw, t),
                    kind,
                })
            })
            .collect();
        let _ = prep.component;
        Ok(found.into_iter().flatten().collect())
    }

    /// Validity of a step: the components are added in an order where each is connected when
    /// placed (later ones may hang on earlier ones of the same step, in any order). Returns, for
    /// each component in input order, its attach kind or why it fails. The assembly is unchanged.
    pub fn check_step(&self, items: &[(Arc<Component>, Pose)]) -> Vec<Result<AttachKind>> {
        let mut work = self.clone();
        let mut results: Vec<Option<Result<AttachKind>>> = vec![None; items.len()];
        loop {
            let mut progress = false;
            for (i, (c, p)) in items.iter().enumerate() {
                if results[i].is_some() {
                    continue;
                }
                match work.check(c, p) {
                    Ok(kind) => {
                        work.add(c.clone(), *p).expect("check passed");
                        results[i] = Some(Ok(kind));
                        progress = true;
                    }
                    Err(BrickGeomError::NotConnected) => {}
                    Err(e) => {
                        results[i] = Some(Err(e));
                        progress = true;
                    }
                }
            }
            if !progress {
                break;
            }
        }
        results
            .into_iter()
            .map(|r| r.unwrap_or(Err(BrickGeomError::NotConnected)))
            .collect()
    }
}
