//! The forward stage of the supplementary: sample a shape in a bounding box. In a few rounds the
//! box is partitioned into boxes, and each box is filled, or has its edges grown and is then
//! filled, with components placed by rejection sampling over the valid (connected,
//! collision-free) placements: single primitives, submodules (a few bricks in a small box, with
//! their own manual: `generate_submodule`) or several instances of one primitive stacked or
//! tiled. The backward stage turns the finished shape into steps; a submodule's own manual is
//! made here, so this module uses `backward` (never the other way round).

use std::collections::{HashMap, HashSet};
use std::sync::Arc;

use crate::assembly::{Assembly, GroundSearch};
use crate::component::{Brick, Component, MAIN_COLOUR};
use crate::error::{BrickGeomError, Result};
use crate::lattice::Pose;

use super::backward::{backward, connection_graph, grounded};
use super::build::{ComponentRef, PlacedInstance, SynthSubmodule};
use super::config::SynthConfig;
use super::rng::Rng;
use super::views::ViewSampler;

/// Inclusive lattice box in x/z (half-studs) with a height limit (plates).
#[derive(Debug, Clone, Copy)]
struct Region {
    x0: i32,
    x1: i32,
    z0: i32,
    z1: i32,
}

impl Region {
    /// The box `w` x `d` studs (2w x 2d half-studs) centred on the origin.
    fn centred(w: i32, d: i32) -> Region {
        Region {
            x0: -w,
            x1: w - 1,
            z0: -d,
            z1: d - 1,
        }
    }
}

/// A finished shape of the forward stage, the input of the backward stage.
pub(super) struct Shape {
    /// Placed instances, in the order they were added.
    pub instances: Vec<PlacedInstance>,
    /// Groups added together (a stack or tiling), removed together by the backward stage.
    pub units: Vec<Vec<usize>>,
    /// The submodules the instances refer to (`ComponentRef::Submodule` indices).
    pub submodules: Vec<SynthSubmodule>,
}

/// The forward stage of a manual: a shape in a box `w` x `d` studs centred on the origin, below
/// `height` plates, aiming for `target` component instances.
pub(super) fn forward(
    cfg: &SynthConfig,
    rng: Rng,
    (w, d): (i32, i32),
    height: i32,
    target: usize,
) -> Shape {
    let mut fw = Forward::new(
        cfg,
        rng,
        Region::centred(w, d),
        height,
        target,
        cfg.p_submodule > 0.0,
    );
    fw.run();
    Shape {
        instances: fw.instances,
        units: fw.units,
        submodules: fw.submodules,
    }
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
    /// An empty build in `bbox`, below `height` plates.
    fn new(
        cfg: &'a SynthConfig,
        rng: Rng,
        bbox: Region,
        height: i32,
        target: usize,
        allow_submodules: bool,
    ) -> Self {
        Forward {
            cfg,
            rng,
            asm: Assembly::new(),
            instances: Vec::new(),
            units: Vec::new(),
            bbox,
            height,
            target,
            submodules: Vec::new(),
            allow_submodules,
            primitives: HashMap::new(),
        }
    }

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
        let tries = 1 + self.rng.below(comp.shape_symmetry.max(1) as usize).min(3);
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
pub(super) fn generate_submodule(
    cfg: &SynthConfig,
    seed: u64,
    index: usize,
) -> Result<SynthSubmodule> {
    let mut rng = Rng::new(seed, 7);
    let (w, d) = (rng.range(2, 4) as i32, rng.range(2, 4) as i32);
    let sub_cfg = SynthConfig {
        components: cfg.submodule_bricks,
        ..cfg.clone()
    };
    let target = rng.range(cfg.submodule_bricks.0 as i64, cfg.submodule_bricks.1 as i64) as usize;
    let bbox = Region::centred(w, d);
    let mut fw = Forward::new(&sub_cfg, rng, bbox, rng_height(seed), target, false);
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
    // The backward stage drops hidden units that nothing rests on (see `backward`); the
    // submodule's shape is made from the instances its manual keeps, so that its steps add
    // exactly its bricks.
    let mut rng = Rng::new(seed, 11);
    let view = ViewSampler::new(cfg, &mut rng);
    let build = backward(cfg, &mut rng, &view, fw.instances, fw.units, true)?;
    if build.instances.len() < 2 {
        return Err(BrickGeomError::InvalidArgument(
            "submodule too small".into(),
        ));
    }
    let bricks: Vec<Brick> = build
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
    Ok(SynthSubmodule {
        name,
        component,
        build,
    })
}

fn rng_height(seed: u64) -> i32 {
    Rng::new(seed, 13).range(4, 9) as i32
}
