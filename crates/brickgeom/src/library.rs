//! The brick library: the 72 primitive part types of the paper (DESIGN §3), defined by the
//! package itself (no LDraw library needed), and the aliases real LDraw files use for them.
//!
//! Part-local frame: the LDraw part origin, converted to the y-up lattice. For nearly every part
//! that is the centre of the top face of the body, so a brick's voxels have y < 0 and its studs
//! sit at y = 0.

use std::collections::HashMap;
use std::sync::OnceLock;

use crate::error::{BrickGeomError, Result};
use crate::lattice::Lattice;
use crate::mesh::Mesh;

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
}

/// The part table plus alias resolution.
pub struct Library {
    parts: Vec<PartDef>,
    index: HashMap<&'static str, usize>,
    aliases: HashMap<&'static str, &'static str>,
}

impl Library {
    fn build() -> Library {
        let parts = crate::parts::build_parts();
        let index = parts.iter().enumerate().map(|(i, p)| (p.id, i)).collect();
        let aliases = crate::parts::ALIASES.iter().copied().collect();
        Library {
            parts,
            index,
            aliases,
        }
    }

    /// All parts in table order.
    pub fn parts(&self) -> &[PartDef] {
        &self.parts
    }

    /// Canonical ids in table order.
    pub fn ids(&self) -> Vec<&'static str> {
        self.parts.iter().map(|p| p.id).collect()
    }

    /// Normalise a reference as written in LDraw files: lower case, no `.dat`, no `parts\`.
    pub fn normalise(raw: &str) -> String {
        let s = raw.trim().to_ascii_lowercase().replace('\\', "/");
        let s = s.strip_prefix("parts/").unwrap_or(&s);
        s.strip_suffix(".dat").unwrap_or(s).to_string()
    }

    /// The canonical library id for a part reference or alias, if it maps to a library part.
    pub fn resolve(&self, raw: &str) -> Option<&'static str> {
        let id = Self::normalise(raw);
        if let Some(&i) = self.index.get(id.as_str()) {
            return Some(self.parts[i].id);
        }
        self.aliases.get(id.as_str()).copied()
    }

    /// Look a part up by id or alias.
    pub fn get(&self, raw: &str) -> Result<&PartDef> {
        let id = self
            .resolve(raw)
            .ok_or_else(|| BrickGeomError::UnknownPart {
                id: raw.to_string(),
            })?;
        Ok(&self.parts[self.index[id]])
    }
}

/// The process-wide library (built once, on first use).
pub fn library() -> &'static Library {
    static LIB: OnceLock<Library> = OnceLock::new();
    LIB.get_or_init(Library::build)
}

/// Convenience: look a part up in the global library.
pub fn part(id: &str) -> Result<&'static PartDef> {
    library().get(id)
}
