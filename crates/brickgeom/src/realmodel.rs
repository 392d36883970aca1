//! Real LDraw models on the lattice: each reference resolved against the library (part,
//! submodel, or unknown), its pose converted, and each build step checked for physical validity.

use std::collections::HashMap;
use std::sync::Arc;

use crate::assembly::{Assembly, AttachKind};
use crate::colours::resolve_colour;
use crate::component::{Brick, Component};
use crate::error::{BrickGeomError, Result};
use crate::lattice::Pose;
use crate::ldraw::{lattice_pose, normalise_name, LdrawFile, LdrawRef};
use crate::library::library;

/// What a reference points at.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ItemKind {
    /// A library part (canonical id).
    Part(&'static str),
    /// A submodel of the same file (index into `LdrawFile::models`).
    Submodel(usize),
    /// A part outside the library.
    Unknown,
}

/// One reference of a step, resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct StepItem {
    /// The name as referenced (normalised).
    pub name: String,
    pub kind: ItemKind,
    pub colour: i32,
    /// Lattice pose in the model's own frame (nearest lattice pose when flagged).
    pub pose: Pose,
    pub off_lattice: bool,
    pub non_yaw: bool,
    /// Line of the reference in the file.
    pub line: usize,
}

/// A model's steps with resolved items.
#[derive(Debug, Clone, PartialEq)]
pub struct LatticeModel {
    pub name: String,
    pub steps: Vec<Vec<StepItem>>,
    /// Where the model's lattice sits in its LDraw frame (LDU, y down): real files often place a
    /// whole model a few LDU off the origin's lattice (e.g. every y = 3 mod 8), which is not an
    /// error. The most common offset of its part references is taken.
    pub offset: [f64; 3],
}

/// The lattice residual (x mod 10, y mod 8, z mod 10) of a placement, in hundredths of an LDU
/// (so float noise does not split votes); None for non-finite positions.
fn residual(position: [f64; 3]) -> Option<[i64; 3]> {
    let unit = [10.0, 8.0, 10.0];
    position.iter().all(|v| v.is_finite()).then(|| {
        [0, 1, 2].map(|a| {
            ((position[a].rem_euclid(unit[a]) * 100.0).round() as i64) % (unit[a] as i64 * 100)
        })
    })
}

/// Models in an order where each comes after the submodels it references: a depth-first
/// post-order, iterative because the nesting of a hand-built file is unbounded and must not
/// become recursion. `subs[m]` lists the submodels model `m` references. The parser rejects
/// cycles; in a hand-built file with one, the reference that closes it points at a model that
/// comes later, which callers treat as unresolved.
fn submodels_first(subs: &[Vec<usize>]) -> Vec<usize> {
    let mut order = Vec::with_capacity(subs.len());
    let mut seen = vec![false; subs.len()];
    for root in 0..subs.len() {
        if std::mem::replace(&mut seen[root], true) {
            continue;
        }
        // (model, next entry of subs[model] to visit)
        let mut stack = vec![(root, 0usize)];
        while let Some(&mut (m, ref mut next)) = stack.last_mut() {
            if let Some(&s) = subs[m].get(*next) {
                *next += 1;
                if !std::mem::replace(&mut seen[s], true) {
                    stack.push((s, 0));
                }
            } else {
                order.push(m);
                stack.pop();
            }
        }
    }
    order
}

/// Lattice offsets of every model: the residual with the most parts behind it. A submodel
/// reference votes with its flattened part count at its own offset carried into the parent
/// (P = M off_sub + pos), so a main model follows its biggest submodel rather than a few wheels.
/// Submodels are solved first; a reference closing a cycle (hand-built files only) votes with
/// nothing.
fn model_offsets(file: &LdrawFile, index: &HashMap<String, usize>) -> Vec<[f64; 3]> {
    let sub_of = |r: &LdrawRef| -> Option<usize> {
        if r.is_submodel {
            index.get(&normalise_name(&r.name)).copied()
        } else {
            None
        }
    };
    let subs: Vec<Vec<usize>> = file
        .models
        .iter()
        .map(|m| m.steps.iter().flatten().filter_map(sub_of).collect())
        .collect();
    let mut solved: Vec<Option<([f64; 3], u64)>> = vec![None; file.models.len()];
    for m in submodels_first(&subs) {
        solved[m] = Some(vote_offset(file, m, sub_of, &solved));
    }
    solved
        .into_iter()
        .map(|s| s.map_or([0.0; 3], |(off, _)| off))
        .collect()
}

/// The offset of model `m` and its flattened part count, given its submodels' (`solved`).
fn vote_offset(
    file: &LdrawFile,
    m: usize,
    sub_of: impl Fn(&LdrawRef) -> Option<usize>,
    solved: &[Option<([f64; 3], u64)>],
) -> ([f64; 3], u64) {
    let mut votes: HashMap<[i64; 3], u64> = HashMap::new();
    let mut size = 0u64;
    for r in file.models[m].steps.iter().flatten() {
        let (pos, weight) = match sub_of(r) {
            Some(s) => {
                let (off, n) = solved[s].unwrap_or(([0.0; 3], 0));
                let mut p = r.position;
                for (a, v) in p.iter_mut().enumerate() {
                    *v += (0..3).map(|b| r.matrix[a][b] * off[b]).sum::<f64>();
                }
                (p, n)
            }
            None => (r.position, 1),
        };
        size += weight;
        // tilted references (display stands, sideways building) say nothing about the lattice
        let m32 = r.matrix.map(|row| row.map(|v| v as f32));
        if crate::lattice::yaw_from_matrix(&m32, 1e-3).is_none() {
            continue;
        }
        if let Some(key) = residual(pos) {
            *votes.entry(key).or_default() += weight;
        }
    }
    let off = votes
        .into_iter()
        .max_by_key(|&(k, n)| (n, std::cmp::Reverse(k)))
        .map_or([0.0; 3], |(k, _)| k.map(|v| v as f64 / 100.0));
    (off, size)
}

/// Why an item cannot be placed as a component.
fn blocker(item: &StepItem, known: &[bool]) -> Option<String> {
    if item.off_lattice {
        return Some(format!(
            "{} is off the lattice (line {})",
            item.name, item.line
        ));
    }
    if item.non_yaw {
        return Some(format!(
            "{} is not a pure yaw rotation (line {})",
            item.name, item.line
        ));
    }
    match item.kind {
        ItemKind::Part(_) => None,
        ItemKind::Submodel(m) if known[m] => None,
        ItemKind::Submodel(_) => Some(format!(
            "submodel {} has parts that are not placeable",
            item.name
        )),
        ItemKind::Unknown => Some(format!("{} is not a library part", item.name)),
    }
}

/// Resolve every model of a file.
pub fn lattice_models(file: &LdrawFile) -> Vec<LatticeModel> {
    let index: HashMap<String, usize> = file
        .models
        .iter()
        .enumerate()
        .map(|(i, m)| (normalise_name(&m.name), i))
        .collect();
    let lib = library();
    let offsets = model_offsets(file, &index);
    file.models
        .iter()
        .enumerate()
        .map(|(mi, m)| LatticeModel {
            name: m.name.clone(),
            offset: offsets[mi],
            steps: m
                .steps
                .iter()
                .map(|step| {
                    step.iter()
                        .map(|r| {
                            let kind = match (r.is_submodel, index.get(&normalise_name(&r.name))) {
                                (true, Some(&i)) => ItemKind::Submodel(i),
                                _ => lib
                                    .resolve(&r.name)
                                    .map_or(ItemKind::Unknown, ItemKind::Part),
                            };
                            // Position relative to this model's lattice; a submodel's own offset
                            // moves with it: P = M (L_sub + off_sub) + pos.
                            let inner = match kind {
                                ItemKind::Submodel(i) => offsets[i],
                                _ => [0.0; 3],
                            };
                            let mut pos = [0.0; 3];
                            for (a, p) in pos.iter_mut().enumerate() {
                                let moved: f64 = (0..3).map(|b| r.matrix[a][b] * inner[b]).sum();
                                *p = r.position[a] + moved - offsets[mi][a];
                            }
                            let lp = lattice_pose(pos, r.matrix);
                            StepItem {
                                name: r.name.clone(),
                                kind,
                                colour: r.colour,
                                pose: lp.pose,
                                off_lattice: lp.off_lattice,
                                non_yaw: lp.non_yaw,
                                line: r.line,
                            }
                        })
                        .collect()
                })
                .collect(),
        })
        .collect()
}

/// A file resolved on the lattice, with the components of its placeable submodels.
pub struct LatticeFile {
    pub models: Vec<LatticeModel>,
    /// Per model: every item (recursively) is a library part on the lattice.
    pub placeable: Vec<bool>,
    /// Per placeable model: its bricks in its own frame.
    bricks: Vec<Option<Vec<Brick>>>,
}

impl LatticeFile {
    /// Resolve a parsed file. Submodel cycles were rejected by the parser; a reference to a
    /// model that is still being resolved is treated as not placeable.
    pub fn new(file: &LdrawFile) -> LatticeFile {
        let models = lattice_models(file);
        let n = models.len();
        let mut placeable = vec![false; n];
        let mut bricks: Vec<Option<Vec<Brick>>> = vec![None; n];
        let subs: Vec<Vec<usize>> = models
            .iter()
            .map(|m| {
                m.steps
                    .iter()
                    .flatten()
                    .filter_map(|it| match it.kind {
                        ItemKind::Submodel(s) => Some(s),
                        _ => None,
                    })
                    .collect()
            })
            .collect();
        // Submodels first, so one pass resolves every model whose submodels are placeable.
        for m in submodels_first(&subs) {
            let items = models[m].steps.iter().flatten();
            if items.clone().any(|it| blocker(it, &placeable).is_some()) {
                continue;
            }
            let mut out = Vec::new();
            for it in items {
                match it.kind {
                    ItemKind::Part(id) => out.push(Brick {
                        part: id,
                        pose: it.pose,
                        colour: it.colour,
                    }),
                    ItemKind::Submodel(s) => {
                        for b in bricks[s].as_ref().expect("placeable submodel has bricks") {
                            out.push(Brick {
                                part: b.part,
                                pose: it.pose.compose(&b.pose),
                                // LDraw's inheritance: 16 takes the reference's
                                // colour, 24 its edge colour; where the reference is
                                // itself 16, the model above decides.
                                colour: resolve_colour(b.colour, it.colour),
                            });
                        }
                    }
                    ItemKind::Unknown => unreachable!("blocker() rejects unknown items"),
                }
            }
            placeable[m] = true;
            bricks[m] = Some(out);
        }
        LatticeFile {
            models,
            placeable,
            bricks,
        }
    }

    /// The bricks of a placeable model in its own frame.
    pub fn bricks(&self, model: usize) -> Option<&[Brick]> {
        self.bricks.get(model)?.as_deref()
    }

    /// Why an item cannot become a component, if it cannot.
    pub fn blocker(&self, item: &StepItem) -> Option<String> {
        blocker(item, &self.placeable)
    }

    /// The component an item places (a part, or a submodel as one component).
    pub fn component(&self, item: &StepItem) -> Result<Component> {
        if let Some(why) = self.blocker(item) {
            return Err(BrickGeomError::InvalidArgument(why));
        }
        match item.kind {
            ItemKind::Part(id) => Component::primitive(id),
            ItemKind::Submodel(m) => Component::from_bricks(
                self.models[m].name.clone(),
                self.bricks(m).expect("placeable").to_vec(),
            ),
            ItemKind::Unknown => unreachable!("blocker() rejects unknown items"),
        }
    }
}

/// Validity of one step.
#[derive(Debug, Clone, PartialEq)]
pub struct StepCheck {
    /// 1-based step number within its model.
    pub step: usize,
    pub items: usize,
    /// Items that are placeable components.
    pub placeable: usize,
    /// Per item, when every item of the step is placeable: attach kind or why it fails.
    pub results: Option<Vec<Result<AttachKind>>>,
    /// Every item of this and all earlier steps is placeable, so "not connected" is a real
    /// finding (otherwise the part may rest on something outside the library).
    pub complete_base: bool,
}

/// A placeable item: its component, pose and colour.
type Placed = (Arc<Component>, Pose, i32);

/// Check the steps of one model, built in its own frame with its lowest voxel on the ground.
/// Items that cannot be placed are left out of the assembly (so a later step resting on them
/// may be reported not connected). Components of a step may hang on each other in any order.
pub fn check_model_steps(lf: &LatticeFile, model: usize) -> Result<Vec<StepCheck>> {
    let m = lf
        .models
        .get(model)
        .ok_or_else(|| BrickGeomError::InvalidArgument(format!("no model {model}")))?;
    // Components and poses of the placeable items; lowest voxel over the whole model.
    let mut cache: HashMap<String, Arc<Component>> = HashMap::new();
    let mut placed: Vec<Vec<Option<Placed>>> = Vec::new();
    let mut min_y = i32::MAX;
    for step in &m.steps {
        let mut row = Vec::new();
        for it in step {
            if lf.blocker(it).is_some() {
                row.push(None);
                continue;
            }
            let key = format!("{:?}", it.kind);
            let comp = match cache.get(&key) {
                Some(c) => c.clone(),
                None => {
                    let c = Arc::new(lf.component(it)?);
                    cache.insert(key, c.clone());
                    c
                }
            };
            let (v, _, _) = comp.placed(&it.pose);
            if let Some(y) = v.iter().map(|c| c[1]).min() {
                min_y = min_y.min(y);
            }
            row.push(Some((comp, it.pose, it.colour)));
        }
        placed.push(row);
    }
    let shift = if min_y == i32::MAX { 0 } else { -min_y };
    let mut asm = Assembly::new();
    let mut out = Vec::new();
    let mut complete = true;
    for (s, row) in placed.into_iter().enumerate() {
        complete &= row.iter().all(|x| x.is_some());
        let items: Vec<Placed> = row
            .iter()
            .flatten()
            .map(|(c, p, col)| {
                (
                    c.clone(),
                    Pose::new(p.yaw, [p.t[0], p.t[1] + shift, p.t[2]]),
                    *col,
                )
            })
            .collect();
        let all = items.len() == row.len();
        let results = if all {
            let list: Vec<(Arc<Component>, Pose)> =
                items.iter().map(|(c, p, _)| (c.clone(), *p)).collect();
            if asm.is_empty() && !list.is_empty() {
                // The first part of a model is its base: the builder holds it (or it stands on
                // the table) wherever it sits in the model's frame. The rest of the step must
                // connect to it.
                let mut base = Assembly::new();
                let first = base.add(list[0].0.clone(), list[0].1);
                let mut res = vec![first.map(|_| AttachKind::Ground)];
                res.extend(base.check_step(&list[1..]));
                Some(res)
            } else {
                Some(asm.check_step(&list))
            }
        } else {
            None
        };
        for (c, p, col) in items {
            // Overlapping real parts (e.g. flexible or mis-modelled ones) are left out.
            if let Ok(id) = asm.add(c, p) {
                asm.set_colour(id, col)?;
            }
        }
        out.push(StepCheck {
            step: s + 1,
            items: row.len(),
            placeable: row.iter().flatten().count(),
            results,
            complete_base: complete,
        });
    }
    Ok(out)
}
