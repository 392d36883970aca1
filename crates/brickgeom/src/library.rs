//! The brick library: the 72 primitive part types of the paper (DESIGN §3), defined by the
//! package itself (no LDraw library needed), and the aliases real LDraw files use for them.
//!
//! Part-local frame: the LDraw part origin, converted to the y-up lattice. For nearly every part
//! that is the centre of the top face of the body, so a brick's voxels have y < 0 and its studs
//! sit at y = 0.

use std::collections::HashMap;
use std::sync::OnceLock;

use crate::error::{BrickGeomError, Result};
pub use crate::parts::{Category, PartDef};

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
