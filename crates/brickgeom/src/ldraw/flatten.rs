//! Flattening a model tree into world-placed parts.

use std::collections::HashMap;

use super::model::{normalise_name, LdrawFile, LdrawRef};
use crate::colours::resolve_colour;

/// A part of a flattened file: its placement after composing every submodel transform above it.
///
/// Equality ignores `line` (provenance, as for [`LdrawRef`]).
#[derive(Debug, Clone)]
pub struct FlatPart {
    /// Part name as referenced (normalised, e.g. `"3001.dat"`, `"s/3001s01.dat"`).
    pub name: String,
    /// Colour after LDraw's inheritance through every submodel above it
    /// ([`resolve_colour`](crate::colours::resolve_colour)): 16 is the colour of the reference
    /// that places its submodel (itself resolved the same way, up to the main model), 24 that
    /// colour's edge colour; both stay as written when nothing above sets a colour.
    pub colour: i32,
    /// World position in LDU, LDraw's y-down frame.
    pub position: [f64; 3],
    /// World rotation/scale matrix rows.
    pub matrix: [[f64; 3]; 3],
    /// Names of the submodels from just below the main model down to the one holding the part
    /// (as written in their `0 FILE` lines); empty for parts placed in the main model.
    pub path: Vec<String>,
    /// Index (into `models[0].steps`) of the main-model step holding the top-level reference.
    pub step: usize,
    /// Line of the part's own type-1 reference.
    pub line: usize,
}

impl PartialEq for FlatPart {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name
            && self.colour == other.colour
            && self.position == other.position
            && self.matrix == other.matrix
            && self.path == other.path
            && self.step == other.step
    }
}

/// One model being walked: its references, the transform and colour it was placed with.
struct Frame<'a> {
    refs: Vec<(usize, &'a LdrawRef)>,
    model: usize,
    next: usize,
    matrix: [[f64; 3]; 3],
    position: [f64; 3],
    colour: i32,
    top_step: usize,
}

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

impl LdrawFile {
    /// All parts of the main model with world placements, in file order (depth first).
    ///
    /// World transform of a nested part: `M_parent * M_child`, `M_parent * p_child + p_parent`.
    /// References marked `is_submodel` whose model is missing, or that would re-enter a model
    /// already being expanded (only possible in hand-built files; parsing rejects cycles), are
    /// skipped. The walk is iterative, so deep nesting cannot overflow the stack.
    ///
    /// Colours follow LDraw's inheritance: the main model is walked in colour 16, and every
    /// reference's colour is resolved against the colour its model was placed with.
    pub fn flatten(&self) -> Vec<FlatPart> {
        if self.models.is_empty() {
            return Vec::new();
        }
        let mut index = HashMap::new();
        for (i, m) in self.models.iter().enumerate() {
            index.entry(normalise_name(&m.name)).or_insert(i);
        }
        let refs_of = |model: usize| -> Vec<(usize, &LdrawRef)> {
            self.models[model]
                .steps
                .iter()
                .enumerate()
                .flat_map(|(s, step)| step.iter().map(move |r| (s, r)))
                .collect()
        };
        let mut out = Vec::new();
        let mut path: Vec<String> = Vec::new();
        let mut stack = vec![Frame {
            refs: refs_of(0),
            model: 0,
            next: 0,
            matrix: IDENTITY,
            position: [0.0; 3],
            colour: 16,
            top_step: 0,
        }];
        loop {
            let depth = stack.len();
            let Some(frame) = stack.last_mut() else {
                break;
            };
            let Some(&(step, r)) = frame.refs.get(frame.next) else {
                stack.pop();
                path.truncate(stack.len().saturating_sub(1));
                continue;
            };
            frame.next += 1;
            let top_step = if depth == 1 { step } else { frame.top_step };
            let matrix = mat_mul(&frame.matrix, &r.matrix);
            let position = add(mat_vec(&frame.matrix, &r.position), frame.position);
            let colour = resolve_colour(r.colour, frame.colour);
            if !r.is_submodel {
                out.push(FlatPart {
                    name: r.name.clone(),
                    colour,
                    position,
                    matrix,
                    path: path.clone(),
                    step: top_step,
                    line: r.line,
                });
                continue;
            }
            let Some(&child) = index.get(&r.name) else {
                continue;
            };
            if stack.iter().any(|f| f.model == child) {
                continue;
            }
            path.push(self.models[child].name.clone());
            stack.push(Frame {
                refs: refs_of(child),
                model: child,
                next: 0,
                matrix,
                position,
                colour,
                top_step,
            });
        }
        out
    }
}

fn mat_mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    out
}

fn mat_vec(a: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    a.map(|row| row[0] * v[0] + row[1] * v[1] + row[2] * v[2])
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
