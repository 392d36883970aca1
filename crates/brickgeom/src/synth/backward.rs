//! The backward stage of the supplementary: from a finished shape, repeatedly take away a chunk
//! of removable and visible components (<= 10 instances, <= 5 types); each chunk is a step, in
//! reverse. Which components can be taken away comes from the connection graph.

use std::collections::{BTreeSet, HashMap, HashSet};
use std::sync::Arc;

use crate::assembly::AttachKind;
use crate::colours::ColourTable;
use crate::component::{cells_around, Component};
use crate::error::{BrickGeomError, Result};
use crate::lattice::{pack, Pose};
use crate::raster::RenderOptions;
use crate::scene::{render_assembly, MeshSource};

use super::build::{Build, ComponentRef, PlacedInstance, SynthStep};
use super::config::SynthConfig;
use super::rng::Rng;
use super::views::ViewSampler;

/// Connection graph of a build's instances: an edge where an anti-stud of one sits on a stud of
/// another, kept only when no third instance occupies a cell around the connection point (on
/// either side). Such an edge is a valid connection whatever order the two and everything else
/// are added in, which is what the backward stage needs; it is exactly the assembly's rule when
/// the cells are empty or the two parts' own.
pub(super) fn connection_graph(instances: &[PlacedInstance]) -> (Vec<Vec<usize>>, Vec<bool>) {
    let mut studs: HashMap<u64, Vec<usize>> = HashMap::new();
    let mut owner: HashMap<u64, usize> = HashMap::new();
    let mut placed = Vec::with_capacity(instances.len());
    for (i, inst) in instances.iter().enumerate() {
        let (v, s, a) = inst.component.placed(&inst.pose);
        for p in &s {
            studs.entry(pack(*p)).or_default().push(i);
        }
        for c in &v {
            owner.insert(pack(*c), i);
        }
        placed.push((v, a));
    }
    let clear = |p: crate::lattice::Lattice, layer: i32, a: usize, b: usize| {
        cells_around(p, layer)
            .iter()
            .all(|c| owner.get(&pack(*c)).is_none_or(|&o| o == a || o == b))
    };
    let mut adj: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); instances.len()];
    for (i, (_, anti)) in placed.iter().enumerate() {
        for a in anti {
            if let Some(js) = studs.get(&pack(*a)) {
                for &j in js {
                    if j != i && clear(*a, a[1], i, j) && clear(*a, a[1] - 1, i, j) {
                        adj[i].insert(j);
                        adj[j].insert(i);
                    }
                }
            }
        }
    }
    let ground = placed
        .iter()
        .map(|(v, _)| v.iter().map(|c| c[1]).min() == Some(0))
        .collect();
    (
        adj.into_iter().map(|s| s.into_iter().collect()).collect(),
        ground,
    )
}

/// Are all of `alive` reachable from the ground through edges among `alive`?
pub(super) fn grounded(alive: &HashSet<usize>, adj: &[Vec<usize>], ground: &[bool]) -> bool {
    let mut seen: HashSet<usize> = alive.iter().copied().filter(|&i| ground[i]).collect();
    let mut stack: Vec<usize> = seen.iter().copied().collect();
    while let Some(i) = stack.pop() {
        for &j in &adj[i] {
            if alive.contains(&j) && seen.insert(j) {
                stack.push(j);
            }
        }
    }
    seen.len() == alive.len()
}

/// Can the units of `chunk` be taken away together: the rest stays connected to the ground,
/// and every member hangs on the rest (or the ground) through members?
fn removable_units(
    chunk: &[usize],
    units: &[Vec<usize>],
    alive: &HashSet<usize>,
    adj: &[Vec<usize>],
    ground: &[bool],
) -> bool {
    let members: HashSet<usize> = chunk
        .iter()
        .flat_map(|&u| units[u].iter().copied())
        .collect();
    let rest: HashSet<usize> = alive.difference(&members).copied().collect();
    if !grounded(&rest, adj, ground) {
        return false;
    }
    let mut ok: HashSet<usize> = rest;
    let mut changed = true;
    while changed {
        changed = false;
        for &m in &members {
            if !ok.contains(&m) && (ground[m] || adj[m].iter().any(|j| ok.contains(j))) {
                ok.insert(m);
                changed = true;
            }
        }
    }
    members.iter().all(|m| ok.contains(m))
}

/// Backward stage: steps from a finished shape. `units` are removed whole.
pub(super) fn backward(
    cfg: &SynthConfig,
    rng: &mut Rng,
    view: &ViewSampler,
    instances: Vec<PlacedInstance>,
    mut units: Vec<Vec<usize>>,
    strict: bool,
) -> Result<Build> {
    let (adj, ground) = connection_graph(&instances);
    let build = Build {
        instances,
        steps: Vec::new(),
    };
    let mut asm = build.assembly()?;
    let mut alive: HashSet<usize> = (0..build.instances.len()).collect();
    let mut remaining: Vec<usize> = (0..units.len()).collect();
    let mut steps_rev: Vec<SynthStep> = Vec::new();
    let mut dropped: HashSet<usize> = HashSet::new();
    let colours = ColourTable::builtin();
    let source = MeshSource::builtin();
    // Visibility is measured at the size of the step images, so the recorded images agree
    // with the decision made here.
    let probe = RenderOptions {
        line_px: 0.0,
        ..RenderOptions::new(cfg.image_size, cfg.image_size)
    };
    let mut split = false;
    while !remaining.is_empty() {
        if std::mem::take(&mut split) {
            // Units added together can interleave with others (a tiling resting partly on a
            // later brick) so that no whole unit is removable: split them into single instances.
            let mut next = Vec::new();
            for &u in &remaining {
                for &m in &units[u].clone() {
                    units.push(vec![m]);
                    next.push(units.len() - 1);
                }
            }
            remaining = next;
        }
        // The usual view first; if it shows nothing removable, views turned by 90, 270 and
        // 180 degrees.
        let mut camera = view.camera(rng, &asm, 0.0)?;
        let mut vis = render_assembly(&asm, &camera, &probe, &colours, &source)?.visible_fraction();
        for turn in [90.0, 270.0, 180.0] {
            let shows_removable = remaining.iter().any(|&u| {
                units[u]
                    .iter()
                    .all(|&i| vis.get(i).copied().unwrap_or(0.0) >= cfg.visibility)
                    && removable_units(&[u], &units, &alive, &adj, &ground)
            });
            if shows_removable {
                break;
            }
            camera = view.camera(rng, &asm, turn)?;
            vis = render_assembly(&asm, &camera, &probe, &colours, &source)?.visible_fraction();
        }
        let unit_vis = |u: usize| -> f32 {
            units[u]
                .iter()
                .map(|&i| vis.get(i).copied().unwrap_or(0.0))
                .fold(1.0, f32::min)
        };
        let removable = |chunk: &[usize], alive: &HashSet<usize>| {
            removable_units(chunk, &units, alive, &adj, &ground)
        };
        let mut order = remaining.clone();
        rng.shuffle(&mut order);
        let mut cands: Vec<usize> = order
            .iter()
            .copied()
            .filter(|&u| unit_vis(u) >= cfg.visibility && removable(&[u], &alive))
            .collect();
        if cands.is_empty() {
            // Nothing is both removable and visible. Hidden removable units that nothing else
            // ever rested on (e.g. a tile under an overhang) are dropped from the shape: a manual
            // step that shows nothing new is useless. Otherwise take the most visible one.
            let hidden: Vec<usize> = order
                .iter()
                .copied()
                .filter(|&u| {
                    removable(&[u], &alive)
                        && units[u].iter().all(|&m| {
                            adj[m]
                                .iter()
                                .all(|j| alive.contains(j) || dropped.contains(j))
                        })
                })
                .collect();
            if let Some(&u) = hidden.first() {
                // one at a time: two hidden units may each be removable but not both
                for &m in &units[u] {
                    asm.remove(m as u32)?;
                    alive.remove(&m);
                    dropped.insert(m);
                }
                remaining.retain(|&r| r != u);
                continue;
            }
            if strict {
                return Err(BrickGeomError::InvalidArgument(format!(
                    "no removable component is visible with {} left",
                    remaining.len()
                )));
            }
            let mut best: Option<(f32, usize)> = None;
            for &u in &order {
                if removable(&[u], &alive) && best.is_none_or(|(v, _)| unit_vis(u) > v) {
                    best = Some((unit_vis(u), u));
                }
            }
            match best {
                Some((_, u)) => cands.push(u),
                None if remaining.iter().any(|&u| units[u].len() > 1) => {
                    split = true;
                    continue;
                }
                None => {
                    return Err(BrickGeomError::InvalidArgument(
                        "backward stage found nothing removable".into(),
                    ))
                }
            }
        }
        // Target chunk size: mostly small steps, sometimes larger ones, as in real manuals.
        let target = match rng.below(10) {
            0..=4 => 1,
            5..=7 => rng.range(2, 3) as usize,
            _ => rng.range(4, cfg.max_step_instances as i64) as usize,
        };
        let mut chunk: Vec<usize> = Vec::new();
        let mut count = 0;
        let mut types: BTreeSet<ComponentRef> = BTreeSet::new();
        for &u in &cands {
            if count >= target {
                break;
            }
            let n = units[u].len();
            let mut t2 = types.clone();
            t2.extend(units[u].iter().map(|&i| build.instances[i].cref));
            if count + n > cfg.max_step_instances || t2.len() > cfg.max_step_types {
                continue;
            }
            let mut trial = chunk.clone();
            trial.push(u);
            if removable(&trial, &alive) {
                chunk = trial;
                count += n;
                types = t2;
            }
        }
        if chunk.is_empty() {
            chunk.push(cands[0]);
        }
        let mut members: Vec<usize> = chunk
            .iter()
            .flat_map(|&u| units[u].iter().copied())
            .collect();
        members.sort_unstable();
        for &m in &members {
            asm.remove(m as u32)?;
            alive.remove(&m);
        }
        // attach kinds against the base shape of the step
        let items: Vec<(Arc<Component>, Pose)> = members
            .iter()
            .map(|&m| {
                (
                    build.instances[m].component.clone(),
                    build.instances[m].pose,
                )
            })
            .collect();
        let attach = asm
            .check_step(&items)
            .into_iter()
            .map(|r| r.unwrap_or(AttachKind::Ground))
            .collect();
        steps_rev.push(SynthStep {
            instances: members,
            attach,
            camera,
        });
        remaining.retain(|u| !chunk.contains(u));
    }
    steps_rev.reverse();
    // Compact away dropped instances, keeping build order.
    let mut new_index = vec![usize::MAX; build.instances.len()];
    let mut instances = Vec::with_capacity(build.instances.len() - dropped.len());
    for (i, inst) in build.instances.into_iter().enumerate() {
        if !dropped.contains(&i) {
            new_index[i] = instances.len();
            instances.push(inst);
        }
    }
    for step in &mut steps_rev {
        for i in &mut step.instances {
            *i = new_index[*i];
        }
    }
    Ok(Build {
        instances,
        steps: steps_rev,
    })
}
