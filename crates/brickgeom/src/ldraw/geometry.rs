//! LDraw part geometry loader (PLACEHOLDER: being written).
use std::path::Path;

use crate::error::Result;
use crate::mesh::Mesh;

/// A part's real geometry from an LDraw library.
#[derive(Debug, Clone)]
pub struct PartGeometry {
    /// Triangles and quads (split) of the part and all its subfiles, in LDU, y UP (converted).
    pub mesh: Mesh,
    /// Number of top-stud primitives referenced (recursively).
    pub stud_count: usize,
}

/// Load a part (id like "3001" or "3001.dat") from an LDraw library root.
pub fn load_part_geometry(_root: &Path, _id: &str) -> Result<PartGeometry> {
    unimplemented!()
}
