//! LDraw model files (.ldr and .mpd): parsing into steps of part / submodel references.
//!
//! Reading rules (the choices LDraw leaves open are written here):
//! - `.mpd` (any file with `0 FILE` lines): each `0 FILE name` starts a block, `0 NOFILE` or the
//!   next `0 FILE` ends it. The first *model* block is the main model. Outside blocks only type-0
//!   and blank lines are allowed. `0 !DATA` blocks (embedded images) are skipped.
//! - A block whose `0 !LDRAW_ORG` header names a part type (`Part`, `Subpart`, `Primitive`,
//!   `Shortcut`, also `Unofficial_*`), or a `.dat` block with geometry lines and no such header,
//!   is an embedded part: kept verbatim in [`LdrawFile::embedded_parts`], referenced as a part.
//! - A file without `0 FILE` lines is one model named after the file.
//! - `0 STEP` and `0 ROTSTEP ...` end a step; the lines after the last one form a final step.
//!   Steps without type-1 lines are dropped, so step indices count non-empty steps only.
//! - Type-1 lines `1 colour x y z a b c d e f g h i name` (the name is everything after the 14th
//!   field, spaces included) are the content. Geometry lines (types 2-5) inside a model and all
//!   other meta commands are ignored; a line starting with anything but 0-5 is an error.
//! - A reference is a submodel when its name matches a model block (case-insensitive); a
//!   reference to an `.ldr`/`.mpd` that is not in the file is a `MissingReference` (external
//!   files are not chased); other names are parts.
//! - The title of a model is its first line when that is a plain `0 text` comment.
//!
//! - Submodels may nest at most [`MAX_NESTING`] levels below any model (the main model's own
//!   references are level 1).
//!
//! Bad input (binary, empty, malformed numbers, NaN, |value| > 1e6 LDU, singular matrices,
//! cycles, submodels nested deeper than [`MAX_NESTING`] levels, a model expanding to more than
//! [`MAX_FLAT_PARTS`] parts) is an error, never a panic.

use std::collections::HashMap;
use std::path::Path;

use super::text::{decode, det3, parse_err, split_fields, type1_numbers, MAX_ABS_VALUE};
use crate::error::{BrickGeomError, Result};

/// Largest number of parts a model may expand to when all submodel references are flattened.
pub const MAX_FLAT_PARTS: u64 = 10_000_000;

/// Deepest nesting accepted: a chain of submodel references may go at most this many levels
/// below the model it starts from (a model's own references are one level below it); for part
/// geometry (`load_part_geometry`), a chain of subfiles may hold at most this many files, the
/// part included. Real files nest fewer than 10 levels. Reading checks the bound, and the walks
/// over the model tree are iterative besides, so no nesting in the data can overflow the stack.
pub const MAX_NESTING: usize = 64;

/// A parsed .ldr/.mpd file.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LdrawFile {
    /// The file name (no directories), e.g. `"plan.mpd"`.
    pub name: String,
    /// The models; `models[0]` is the main model, the rest are submodels in file order.
    pub models: Vec<LdrawModel>,
    /// Parts embedded in an .mpd as `0 FILE x.dat` blocks, kept verbatim for writing back.
    pub embedded_parts: Vec<EmbeddedPart>,
}

/// One model (the main model or a submodel): its name and its non-empty build steps.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LdrawModel {
    /// Name as written in its `0 FILE` line (or the file name for a plain .ldr).
    pub name: String,
    /// The description line (`0 text` first line of the model); may be empty.
    pub title: String,
    /// Build steps in order, each the references added in that step (never empty).
    pub steps: Vec<Vec<LdrawRef>>,
}

/// A type-1 line: a part or submodel placed with a colour and a transform (LDraw frame, y down).
///
/// Equality ignores `line`: it records where the reference was read, not what it is.
#[derive(Debug, Clone)]
pub struct LdrawRef {
    /// 1-based line in the file it was read from (0 when built in memory).
    pub line: usize,
    /// LDraw colour code (16 = inherit the parent's colour).
    pub colour: i32,
    /// Position in LDU, LDraw's y-down frame.
    pub position: [f64; 3],
    /// Rotation/scale matrix rows `[[a, b, c], [d, e, f], [g, h, i]]`.
    pub matrix: [[f64; 3]; 3],
    /// Referenced file, normalised: lower case, `\` replaced by `/` (e.g. `"3001.dat"`).
    pub name: String,
    /// Whether `name` is a model block of the same file (else a part).
    pub is_submodel: bool,
}

impl PartialEq for LdrawRef {
    fn eq(&self, other: &Self) -> bool {
        self.colour == other.colour
            && self.position == other.position
            && self.matrix == other.matrix
            && self.name == other.name
            && self.is_submodel == other.is_submodel
    }
}

/// A part defined inside the .mpd itself (`0 FILE x.dat` with geometry), kept as text.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EmbeddedPart {
    /// Name as written in its `0 FILE` line.
    pub name: String,
    /// The block's lines (without the `0 FILE`/`0 NOFILE` lines), joined by `\n`.
    pub text: String,
}

// Values built in memory (by a program, not the reader) are checked against the reader's rules,
// so that what is written reads back: the reader rejects blank names, non-finite or huge numbers
// and singular matrices, and drops empty steps.

/// An `InvalidLdraw` error about `what`.
fn invalid(what: String, message: impl Into<String>) -> BrickGeomError {
    BrickGeomError::InvalidLdraw {
        what,
        message: message.into(),
    }
}

impl LdrawRef {
    /// Check a reference built in memory by the reader's rules: a name that is not blank,
    /// finite numbers of magnitude at most [`MAX_ABS_VALUE`], a non-singular matrix.
    pub fn validate(&self) -> Result<()> {
        let what = || format!("LDraw reference '{}'", self.name);
        if self.name.trim().is_empty() {
            return Err(invalid(what(), "the name is empty"));
        }
        let fields = [
            ("position", &self.position[..]),
            ("matrix", self.matrix.as_flattened()),
        ];
        for (field, values) in fields {
            if let Some(v) = values
                .iter()
                .find(|v| !v.is_finite() || v.abs() > MAX_ABS_VALUE)
            {
                return Err(invalid(
                    what(),
                    format!(
                        "{field} value {v} is not a finite number within +-{MAX_ABS_VALUE:e} LDU"
                    ),
                ));
            }
        }
        let det = det3(&self.matrix);
        if det.abs() < 1e-6 {
            return Err(invalid(
                what(),
                format!("singular transformation matrix (determinant {det:e})"),
            ));
        }
        Ok(())
    }
}

impl LdrawModel {
    /// Check a model built in memory by the reader's rules: a name that is not blank, no empty
    /// step, every reference valid ([`LdrawRef::validate`]).
    pub fn validate(&self) -> Result<()> {
        if self.name.trim().is_empty() {
            return Err(invalid("LDraw model".into(), "the name is empty"));
        }
        if let Some(i) = self.steps.iter().position(Vec::is_empty) {
            return Err(invalid(
                format!("LDraw model '{}'", self.name),
                format!(
                    "step {} is empty (a step holds at least one reference)",
                    i + 1
                ),
            ));
        }
        self.steps.iter().flatten().try_for_each(LdrawRef::validate)
    }
}

/// Normalise a reference or block name: trimmed, lower case, `\` -> `/`.
pub fn normalise_name(name: &str) -> String {
    name.trim().to_lowercase().replace('\\', "/")
}

/// Read and parse an .ldr/.mpd file. Errors name the path as given.
pub fn read_ldraw(path: &Path) -> Result<LdrawFile> {
    let shown = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| BrickGeomError::Io {
        path: shown.clone(),
        message: e.to_string(),
    })?;
    parse_ldraw(&bytes, &shown)
}

/// Parse .ldr/.mpd bytes. `file_name` names the file in errors; its last path component
/// becomes [`LdrawFile::name`] (and the model name of a file without `0 FILE` lines).
pub fn parse_ldraw(bytes: &[u8], file_name: &str) -> Result<LdrawFile> {
    let text = decode(bytes, file_name)?;
    if text.trim().is_empty() {
        return Err(parse_err(file_name, 1, "empty file"));
    }
    let lines: Vec<&str> = text.split('\n').map(|l| l.trim_end_matches('\r')).collect();
    let blocks = split_blocks(&lines, file_name)?;
    let mut models = Vec::new();
    let mut embedded_parts = Vec::new();
    let mut first_lines = Vec::new();
    for block in &blocks {
        if is_embedded_part(&lines, block) {
            let body = &lines[block.body.0..block.body.1];
            let end = body
                .iter()
                .rposition(|l| !l.trim().is_empty())
                .map_or(0, |i| i + 1);
            embedded_parts.push(EmbeddedPart {
                name: block.name.clone(),
                text: body[..end].join("\n"),
            });
        } else {
            models.push(parse_model(&lines, block, file_name)?);
            first_lines.push(block.header_line);
        }
    }
    if models.is_empty() {
        return Err(parse_err(
            file_name,
            1,
            "no model in file (only embedded parts)",
        ));
    }
    let mut file = LdrawFile {
        name: base_name(file_name).to_string(),
        models,
        embedded_parts,
    };
    resolve_references(&mut file, file_name)?;
    if file.models[0].steps.is_empty() {
        return Err(parse_err(
            file_name,
            first_lines[0],
            "main model has no part or submodel references",
        ));
    }
    check_nesting(&file, file_name)?;
    check_expansion(&file, file_name)?;
    Ok(file)
}

/// The last path component of a file name.
fn base_name(file_name: &str) -> &str {
    file_name.rsplit(['/', '\\']).next().unwrap_or(file_name)
}

/// A `0 FILE` block: its name, the line of its FILE line (or 1), and its body line range.
struct Block {
    name: String,
    header_line: usize,
    body: (usize, usize),
}

/// Split lines into blocks; a file without `0 FILE` lines is one block named `file_name`.
fn split_blocks(lines: &[&str], file_name: &str) -> Result<Vec<Block>> {
    let meta = |line: &str| -> Option<(String, String)> {
        let (f, rest) = split_fields(line, 2)?;
        (f[0] == "0").then(|| (f[1].to_string(), rest.to_string()))
    };
    let has_files = lines
        .iter()
        .any(|l| matches!(meta(l), Some((k, _)) if k == "FILE"));
    if !has_files {
        return Ok(vec![Block {
            name: base_name(file_name).to_string(),
            header_line: 1,
            body: (0, lines.len()),
        }]);
    }
    let mut blocks: Vec<Block> = Vec::new();
    let mut open = false; // inside a FILE block (a skipped !DATA block counts as closed)
    let mut seen: HashMap<String, usize> = HashMap::new();
    for (i, line) in lines.iter().enumerate() {
        let kw = meta(line);
        let kind = kw.as_ref().map(|(k, _)| k.clone());
        if matches!(kind.as_deref(), Some("FILE" | "NOFILE" | "!DATA")) {
            if let (true, Some(last)) = (open, blocks.last_mut()) {
                last.body.1 = i;
            }
            open = false;
        }
        match (kind.as_deref(), kw) {
            (Some("FILE"), Some((_, name))) => {
                if name.is_empty() {
                    return Err(parse_err(file_name, i + 1, "0 FILE without a name"));
                }
                if let Some(prev) = seen.insert(normalise_name(&name), i + 1) {
                    return Err(parse_err(
                        file_name,
                        i + 1,
                        format!("duplicate 0 FILE '{name}' (first at line {prev})"),
                    ));
                }
                blocks.push(Block {
                    name,
                    header_line: i + 1,
                    body: (i + 1, lines.len()),
                });
                open = true;
            }
            _ if open => {}
            _ => {
                let first = line.split_whitespace().next();
                if !matches!(first, None | Some("0")) {
                    return Err(parse_err(
                        file_name,
                        i + 1,
                        "content outside any 0 FILE block",
                    ));
                }
            }
        }
    }
    Ok(blocks)
}

/// Whether a block is an embedded part rather than a model (see the module docs).
fn is_embedded_part(lines: &[&str], block: &Block) -> bool {
    let body = &lines[block.body.0..block.body.1];
    for line in body {
        if let Some((f, rest)) = split_fields(line, 2) {
            if f[0] == "0" && f[1] == "!LDRAW_ORG" {
                let kind = rest.split_whitespace().next().unwrap_or("").to_lowercase();
                let kind = kind.strip_prefix("unofficial_").unwrap_or(&kind);
                return kind.contains("part")
                    || kind.contains("primitive")
                    || kind.contains("shortcut");
            }
        }
    }
    normalise_name(&block.name).ends_with(".dat")
        && body
            .iter()
            .any(|l| matches!(l.split_whitespace().next(), Some("2" | "3" | "4" | "5")))
}

/// First words of `0` lines that are meta commands, not a title.
const META_WORDS: &[&str] = &[
    "STEP", "ROTSTEP", "FILE", "NOFILE", "BFC", "CLEAR", "PAUSE", "PRINT", "WRITE", "SAVE",
    "ROTATION", "GHOST", "MLCAD", "LPUB", "BUFEXCHG", "Name:", "Author:", "Author",
];

/// Whether the text after `0 ` would be read as a meta command rather than a title.
pub(crate) fn is_meta(text: &str) -> bool {
    let first = text.split_whitespace().next().unwrap_or("");
    first.is_empty()
        || first.starts_with('!')
        || first.starts_with("//")
        || META_WORDS.contains(&first)
}

fn parse_model(lines: &[&str], block: &Block, file: &str) -> Result<LdrawModel> {
    let mut model = LdrawModel {
        name: block.name.clone(),
        ..Default::default()
    };
    let mut step: Vec<LdrawRef> = Vec::new();
    let mut first = true;
    for (line_no, line) in (block.body.0..block.body.1).map(|i| (i + 1, lines[i].trim())) {
        let Some(kind) = line.split_whitespace().next() else {
            continue;
        };
        let is_first = std::mem::replace(&mut first, false);
        match kind {
            "0" => {
                let text = line[1..].trim();
                if is_first && !is_meta(text) {
                    model.title = text.to_string();
                }
                let word = text.split_whitespace().next();
                if matches!(word, Some("STEP" | "ROTSTEP")) && !step.is_empty() {
                    model.steps.push(std::mem::take(&mut step));
                }
            }
            "1" => step.push(parse_ref(line, line_no, file)?),
            "2" | "3" | "4" | "5" => {}
            other => {
                let shown: String = other.chars().take(20).collect();
                return Err(parse_err(
                    file,
                    line_no,
                    format!("unknown line type '{shown}' (expected 0-5)"),
                ));
            }
        }
    }
    if !step.is_empty() {
        model.steps.push(step);
    }
    Ok(model)
}

fn parse_ref(line: &str, line_no: usize, file: &str) -> Result<LdrawRef> {
    let (fields, name) = split_fields(line, 14)
        .filter(|(_, rest)| !rest.is_empty())
        .ok_or_else(|| {
            parse_err(
                file,
                line_no,
                "type-1 line needs 15 fields: 1 colour x y z a b c d e f g h i file",
            )
        })?;
    let t = type1_numbers(&fields[1..], file, line_no)?;
    let det = det3(&t.matrix);
    if det.abs() < 1e-6 {
        return Err(parse_err(
            file,
            line_no,
            format!("singular transformation matrix (determinant {det:e})"),
        ));
    }
    Ok(LdrawRef {
        line: line_no,
        colour: t.colour,
        position: t.position,
        matrix: t.matrix,
        name: normalise_name(name),
        is_submodel: false,
    })
}

/// Index of each model by normalised name.
fn model_index(file: &LdrawFile) -> HashMap<String, usize> {
    let mut index = HashMap::new();
    for (i, m) in file.models.iter().enumerate() {
        index.entry(normalise_name(&m.name)).or_insert(i);
    }
    index
}

/// Mark submodel references, reject missing model files and cycles.
fn resolve_references(file: &mut LdrawFile, file_name: &str) -> Result<()> {
    let index = model_index(file);
    let embedded: Vec<String> = file
        .embedded_parts
        .iter()
        .map(|p| normalise_name(&p.name))
        .collect();
    for model in &mut file.models {
        for r in model.steps.iter_mut().flatten() {
            r.is_submodel = index.contains_key(&r.name);
            let external = r.name.ends_with(".ldr") || r.name.ends_with(".mpd");
            if !r.is_submodel && external && !embedded.contains(&r.name) {
                return Err(BrickGeomError::MissingReference {
                    file: file_name.to_string(),
                    line: r.line,
                    name: r.name.clone(),
                });
            }
        }
    }
    // Depth-first search; state 1 = on the stack, 2 = done. Iterative, so deep chains of
    // submodels cannot overflow the call stack.
    let children = submodel_children(file, &index);
    let mut state = vec![0u8; file.models.len()];
    for start in 0..file.models.len() {
        if state[start] != 0 {
            continue;
        }
        let mut stack: Vec<(usize, usize)> = vec![(start, 0)];
        state[start] = 1;
        while let Some(&mut (node, ref mut next)) = stack.last_mut() {
            if let Some(&child) = children[node].get(*next) {
                *next += 1;
                match state[child] {
                    0 => {
                        state[child] = 1;
                        stack.push((child, 0));
                    }
                    1 => {
                        let from = stack.iter().position(|&(n, _)| n == child).unwrap_or(0);
                        let mut chain: Vec<&str> = stack[from..]
                            .iter()
                            .map(|&(n, _)| file.models[n].name.as_str())
                            .collect();
                        chain.push(&file.models[child].name);
                        return Err(BrickGeomError::CyclicReference {
                            file: file_name.to_string(),
                            chain: chain.join(" -> "),
                        });
                    }
                    _ => {}
                }
            } else {
                state[node] = 2;
                stack.pop();
            }
        }
    }
    Ok(())
}

/// For each model, the indices of the submodels it references (once per reference).
fn submodel_children(file: &LdrawFile, index: &HashMap<String, usize>) -> Vec<Vec<usize>> {
    file.models
        .iter()
        .map(|m| {
            m.steps
                .iter()
                .flatten()
                .filter(|r| r.is_submodel)
                .filter_map(|r| index.get(&r.name).copied())
                .collect()
        })
        .collect()
}

/// Reject files with a chain of submodel references more than [`MAX_NESTING`] levels deep
/// (from any model, used or not). Cycles were rejected before, so the models form a DAG.
fn check_nesting(file: &LdrawFile, file_name: &str) -> Result<()> {
    let index = model_index(file);
    let children = submodel_children(file, &index);
    // height[m]: the longest chain of submodel references below model m, memoised by an
    // iterative post-order walk (the data may nest deeper than the call stack allows).
    let mut height: Vec<Option<usize>> = vec![None; file.models.len()];
    for start in 0..file.models.len() {
        let mut stack = vec![start];
        while let Some(&node) = stack.last() {
            if height[node].is_some() {
                stack.pop();
                continue;
            }
            let pending: Vec<usize> = children[node]
                .iter()
                .copied()
                .filter(|&c| height[c].is_none())
                .collect();
            if pending.is_empty() {
                let below = children[node].iter().map(|&c| height[c].unwrap_or(0) + 1);
                height[node] = Some(below.max().unwrap_or(0));
                stack.pop();
            } else {
                stack.extend(pending);
            }
        }
    }
    let height: Vec<usize> = height.into_iter().map(|h| h.unwrap_or(0)).collect();
    let Some(top) = (0..file.models.len()).find(|&m| height[m] > MAX_NESTING) else {
        return Ok(());
    };
    // Follow a deepest chain down to the first model past the limit, for the message.
    let (mut model, mut line) = (top, 1);
    for _ in 0..=MAX_NESTING {
        let next = file.models[model]
            .steps
            .iter()
            .flatten()
            .filter(|r| r.is_submodel)
            .find_map(|r| {
                let c = *index.get(&r.name)?;
                (height[c] + 1 == height[model]).then_some((c, r.line))
            });
        let Some((child, at)) = next else {
            break;
        };
        (model, line) = (child, at);
    }
    Err(parse_err(
        file_name,
        line,
        format!(
            "submodels nested deeper than {MAX_NESTING} levels (model '{}' is {} levels below \
             '{}')",
            file.models[model].name,
            MAX_NESTING + 1,
            file.models[top].name
        ),
    ))
}

/// Reject files whose main model expands to more than [`MAX_FLAT_PARTS`] parts.
fn check_expansion(file: &LdrawFile, file_name: &str) -> Result<()> {
    let index = model_index(file);
    let children = submodel_children(file, &index);
    // Models in reverse topological order: a DAG (cycles were rejected), so repeated passes
    // converge; memoise with an explicit order from a post-order walk.
    let mut count: Vec<Option<u64>> = vec![None; file.models.len()];
    let mut stack = vec![0usize];
    while let Some(&node) = stack.last() {
        if count[node].is_some() {
            stack.pop();
            continue;
        }
        let pending: Vec<usize> = children[node]
            .iter()
            .copied()
            .filter(|&c| count[c].is_none())
            .collect();
        if pending.is_empty() {
            let direct = file.models[node]
                .steps
                .iter()
                .flatten()
                .filter(|r| !r.is_submodel)
                .count() as u64;
            let total = children[node]
                .iter()
                .fold(direct, |acc, &c| acc.saturating_add(count[c].unwrap_or(0)));
            count[node] = Some(total);
            stack.pop();
        } else {
            stack.extend(pending);
        }
    }
    let total = count[0].unwrap_or(0);
    if total > MAX_FLAT_PARTS {
        return Err(parse_err(
            file_name,
            1,
            format!("model expands to {total} parts (more than {MAX_FLAT_PARTS})"),
        ));
    }
    Ok(())
}

impl LdrawFile {
    /// Check a file built in memory by the reader's rules: every model valid
    /// ([`LdrawModel::validate`]) and no embedded part with a blank name.
    pub fn validate(&self) -> Result<()> {
        self.models.iter().try_for_each(LdrawModel::validate)?;
        if self.embedded_parts.iter().any(|p| p.name.trim().is_empty()) {
            return Err(invalid("LDraw embedded part".into(), "the name is empty"));
        }
        Ok(())
    }

    /// The main model (`models[0]`), if any.
    pub fn main(&self) -> Option<&LdrawModel> {
        self.models.first()
    }

    /// A model by name (case-insensitive, `\` and `/` alike).
    pub fn model(&self, name: &str) -> Option<&LdrawModel> {
        let key = normalise_name(name);
        self.models.iter().find(|m| normalise_name(&m.name) == key)
    }

    /// Whether writing needs the multi-part (.mpd) layout: more than one block, an `.mpd` name,
    /// or a main model named differently from the file.
    pub fn is_mpd_content(&self) -> bool {
        self.models.len() != 1
            || !self.embedded_parts.is_empty()
            || normalise_name(&self.name).ends_with(".mpd")
            || self
                .models
                .first()
                .is_some_and(|m| normalise_name(&m.name) != normalise_name(&self.name))
    }
}
