//! LDraw part geometry: load a part from an LDraw library folder as one triangle mesh.
//!
//! Resolution follows LDraw tools: a reference name is lower-cased, `\` becomes `/`, and the file
//! is looked for under `parts/`, then `p/`, then `parts/s/` (the last for subparts that name a
//! sibling without the `s\` prefix). `s\x.dat` therefore finds `parts/s/x.dat` and `48\x.dat`
//! finds `p/48/x.dat`. File names on disk are matched case-insensitively (the folders are
//! indexed once per [`PartLoader`]).
//!
//! Lines: type 1 (subfile, transform `p + M v`), 3 (triangle) and 4 (quad, split along its
//! 1-3 diagonal) make the mesh; 0 (comments and meta commands), 2 and 5 (lines) are skipped.
//! BFC winding is honoured (`CERTIFY CW/CCW`, `CW`, `CCW`, `INVERTNEXT`, mirrored matrices), so
//! for certified parts every triangle is counter-clockwise seen from outside in the output frame.
//! Output vertices are LDU in brickgeom's y-up frame (LDraw y and z negated: a rotation, so windings
//! keep their sense), identical vertices merged.
//!
//! Studs: every reference to one of [`TOP_STUD_PRIMITIVES`] is a stud, found recursively (a stud
//! inside a subpart or stud-group primitive `stug*.dat` referenced twice counts twice). A stud
//! counts as a *top* stud when its axis (the primitive's -y) points up in the part frame within
//! ~25°; side studs (e.g. 87087) and upside-down ones are not counted. Underside tubes and
//! fillers (`stud3*`, `stud4*`, `2-4stud4`, `stud12`, `stud16`, `stud23*`, `stud2s*`,
//! `filstud3`) and minifig `hipstud` are never studs.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::model::MAX_NESTING;
use super::text::{decode, det3, parse_err, points, split_fields, type1_numbers};
use crate::error::{BrickGeomError, Result};
use crate::mesh::Mesh;

/// Stud primitives (file names in `p/`) that form a part's top studs when they point up:
/// plain (`stud`, `studa`), hollow/open (`stud2`, `stud2a`), round-part variants (`stud6`,
/// `stud6a`, `stud10`) and the logo-dot stud `studp01`.
pub const TOP_STUD_PRIMITIVES: &[&str] = &[
    "stud.dat",
    "studa.dat",
    "stud2.dat",
    "stud2a.dat",
    "stud6.dat",
    "stud6a.dat",
    "stud10.dat",
    "studp01.dat",
];

/// Deepest subfile nesting accepted: [`MAX_NESTING`] files in a chain, the part itself
/// included (real parts nest fewer than 10 levels). Bounds the recursion of `flatten`.
const MAX_DEPTH: usize = MAX_NESTING;

/// A part's real geometry from an LDraw library.
#[derive(Debug, Clone)]
pub struct PartGeometry {
    /// Triangles and quads (split) of the part and all its subfiles, in LDU, y UP (converted).
    pub mesh: Mesh,
    /// Number of top-stud primitives referenced (recursively).
    pub stud_count: usize,
    /// Base centre of each top stud (where the stud meets the surface), LDU, y up, in the order
    /// found; `stud_positions.len() == stud_count`.
    pub stud_positions: Vec<[f32; 3]>,
}

/// Load a part (id like "3001" or "3001.dat") from an LDraw library root.
///
/// Convenience for one part; use [`PartLoader`] to load many parts with shared caches.
pub fn load_part_geometry(root: &Path, id: &str) -> Result<PartGeometry> {
    PartLoader::new(root)?.load(id)
}

/// A subfile flattened into its own frame (LDraw y-down), cached per file.
#[derive(Debug, Default)]
struct Flat {
    /// Triangles, counter-clockwise (for BFC-certified files).
    tris: Vec<[[f64; 3]; 3]>,
    /// Studs as (base centre, axis) where axis is the stud's outward direction (unnormalised).
    studs: Vec<([f64; 3], [f64; 3])>,
}

/// Loads parts from one LDraw library root, caching every flattened subfile (primitives such as
/// `stud.dat` or `4-4cyli.dat` are read and flattened once per loader).
#[derive(Debug)]
pub struct PartLoader {
    root: PathBuf,
    /// Lower-case path relative to the root (`parts/s/3001s01.dat`) -> real path.
    index: HashMap<String, PathBuf>,
    cache: HashMap<String, Arc<Flat>>,
}

impl PartLoader {
    /// Index the library at `root` (which must contain `parts/` or `p/`).
    pub fn new(root: &Path) -> Result<PartLoader> {
        let mut index = HashMap::new();
        for top in ["parts", "p"] {
            index_dir(&root.join(top), top, 0, &mut index);
        }
        if index.is_empty() {
            return Err(BrickGeomError::Io {
                path: root.display().to_string(),
                message: "not an LDraw library (no .dat files under parts/ or p/)".into(),
            });
        }
        Ok(PartLoader {
            root: root.to_path_buf(),
            index,
            cache: HashMap::new(),
        })
    }

    /// Load one part by id (`"3001"`, `"3001.dat"`, `"parts\\3001.dat"`, any case).
    pub fn load(&mut self, id: &str) -> Result<PartGeometry> {
        let mut name = normalise(id);
        if let Some(rest) = name.strip_prefix("parts/") {
            name = rest.to_string();
        }
        if !name.ends_with(".dat") {
            name.push_str(".dat");
        }
        let root = self.root.display().to_string();
        let flat = self.flatten(&name, &root, 0, &mut Vec::new())?;
        Ok(to_part_geometry(&flat))
    }

    fn resolve(&self, name: &str) -> Option<&PathBuf> {
        ["parts/", "p/", "parts/s/"]
            .iter()
            .find_map(|dir| self.index.get(&format!("{dir}{name}")))
    }

    /// Flatten `name` (normalised), referenced from `from:line`; `stack` holds the files being
    /// flattened above it, for cycle detection.
    fn flatten(
        &mut self,
        name: &str,
        from: &str,
        line: usize,
        stack: &mut Vec<String>,
    ) -> Result<Arc<Flat>> {
        if let Some(flat) = self.cache.get(name) {
            return Ok(Arc::clone(flat));
        }
        if stack.iter().any(|s| s == name) {
            let mut chain = stack.clone();
            chain.push(name.to_string());
            return Err(BrickGeomError::CyclicReference {
                file: stack.first().cloned().unwrap_or_default(),
                chain: chain.join(" -> "),
            });
        }
        if stack.len() >= MAX_DEPTH {
            return Err(parse_err(
                from,
                line,
                format!("subfiles nested deeper than {MAX_DEPTH} levels"),
            ));
        }
        let path = self
            .resolve(name)
            .cloned()
            .ok_or_else(|| BrickGeomError::MissingReference {
                file: from.to_string(),
                line,
                name: name.to_string(),
            })?;
        let bytes = std::fs::read(&path).map_err(|e| BrickGeomError::Io {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        let text = decode(&bytes, name)?;
        stack.push(name.to_string());
        let result = self.flatten_text(name, &text, stack);
        stack.pop();
        let flat = Arc::new(result?);
        self.cache.insert(name.to_string(), Arc::clone(&flat));
        Ok(flat)
    }

    fn flatten_text(&mut self, file: &str, text: &str, stack: &mut Vec<String>) -> Result<Flat> {
        let mut out = Flat::default();
        let mut ccw = true;
        let mut invert_next = false;
        for (i, raw) in text.lines().enumerate() {
            let line_no = i + 1;
            let line = raw.trim();
            let Some(kind) = line.split_whitespace().next() else {
                continue;
            };
            match kind {
                "0" => {
                    let mut words = line.split_whitespace().skip(1);
                    if words.next() == Some("BFC") {
                        for w in words {
                            match w {
                                "CW" => ccw = false,
                                "CCW" => ccw = true,
                                "INVERTNEXT" => invert_next = true,
                                _ => {}
                            }
                        }
                    }
                }
                "1" => {
                    let (fields, sub) = split_fields(line, 14)
                        .filter(|(_, rest)| !rest.is_empty())
                        .ok_or_else(|| parse_err(file, line_no, "type-1 line needs 15 fields"))?;
                    let t = type1_numbers(&fields[1..], file, line_no)?;
                    let sub = normalise(sub);
                    let child = self.flatten(&sub, file, line_no, stack)?;
                    let reverse = (det3(&t.matrix) < 0.0) ^ invert_next;
                    invert_next = false;
                    let tf = |v: &[f64; 3]| apply(&t.matrix, t.position, v);
                    out.tris.extend(child.tris.iter().map(|tri| {
                        let [a, b, c] = tri;
                        if reverse {
                            [tf(a), tf(c), tf(b)]
                        } else {
                            [tf(a), tf(b), tf(c)]
                        }
                    }));
                    out.studs.extend(
                        child
                            .studs
                            .iter()
                            .map(|(p, axis)| (tf(p), apply(&t.matrix, [0.0; 3], axis))),
                    );
                    if TOP_STUD_PRIMITIVES.contains(&sub.as_str()) {
                        out.studs
                            .push((t.position, apply(&t.matrix, [0.0; 3], &[0.0, -1.0, 0.0])));
                    }
                }
                "3" | "4" => {
                    let toks: Vec<&str> = line.split_whitespace().collect();
                    let want = if kind == "3" { 11 } else { 14 };
                    if toks.len() != want {
                        return Err(parse_err(
                            file,
                            line_no,
                            format!("type-{kind} line needs {want} fields, found {}", toks.len()),
                        ));
                    }
                    super::text::colour(toks[1], file, line_no)?;
                    let mut push = |a: [f64; 3], b: [f64; 3], c: [f64; 3]| {
                        out.tris.push(if ccw { [a, b, c] } else { [a, c, b] });
                    };
                    if kind == "3" {
                        let [a, b, c] = points::<3>(&toks[2..], file, line_no)?;
                        push(a, b, c);
                    } else {
                        let [a, b, c, d] = points::<4>(&toks[2..], file, line_no)?;
                        push(a, b, c);
                        push(a, c, d);
                    }
                }
                "2" | "5" => {}
                other => {
                    return Err(parse_err(
                        file,
                        line_no,
                        format!("unknown line type '{other}'"),
                    ))
                }
            }
        }
        Ok(out)
    }
}

/// Lower case, `\` -> `/`, trimmed.
fn normalise(name: &str) -> String {
    name.trim().to_ascii_lowercase().replace('\\', "/")
}

/// `m v + p`.
fn apply(m: &[[f64; 3]; 3], p: [f64; 3], v: &[f64; 3]) -> [f64; 3] {
    let mut out = p;
    for (o, row) in out.iter_mut().zip(m) {
        *o += row[0] * v[0] + row[1] * v[1] + row[2] * v[2];
    }
    out
}

/// Record every file under `dir` (relative name `rel`) in `index`, lower-cased.
fn index_dir(dir: &Path, rel: &str, depth: usize, index: &mut HashMap<String, PathBuf>) {
    // LDraw libraries are at most three levels deep (p/48, parts/s, parts/textures/...).
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().to_ascii_lowercase();
        let key = format!("{rel}/{name}");
        let path = entry.path();
        if path.is_dir() {
            if depth < 3 {
                index_dir(&path, &key, depth + 1, index);
            }
        } else {
            index.insert(key, path);
        }
    }
}

/// Convert a flattened part to the y-up output: negate y and z (half a turn about x, so windings
/// keep their sense), merge identical vertices, keep the studs whose axis points up.
fn to_part_geometry(flat: &Flat) -> PartGeometry {
    let mut mesh = Mesh::new();
    let mut ids: HashMap<[u32; 3], u32> = HashMap::new();
    let mut vertex = |v: &[f64; 3]| -> u32 {
        // `+ 0.0` turns -0.0 into 0.0 so both merge.
        let p = [v[0] as f32 + 0.0, -v[1] as f32 + 0.0, -v[2] as f32 + 0.0];
        let key = p.map(f32::to_bits);
        *ids.entry(key).or_insert_with(|| {
            mesh.vertices.push(p);
            (mesh.vertices.len() - 1) as u32
        })
    };
    let mut triangles = Vec::with_capacity(flat.tris.len());
    for [a, b, c] in &flat.tris {
        let t = [vertex(a), vertex(b), vertex(c)];
        if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
            triangles.push(t);
        }
    }
    mesh.triangles = triangles;
    let stud_positions: Vec<[f32; 3]> = flat
        .studs
        .iter()
        .filter(|(_, axis)| {
            let len = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
            // LDraw up is -y; cos 25° ~ 0.9.
            len > 0.0 && -axis[1] / len > 0.9
        })
        .map(|(p, _)| [p[0] as f32 + 0.0, -p[1] as f32 + 0.0, -p[2] as f32 + 0.0])
        .collect();
    PartGeometry {
        mesh,
        stud_count: stud_positions.len(),
        stud_positions,
    }
}
