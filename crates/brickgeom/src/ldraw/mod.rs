//! LDraw I/O: model files (.ldr/.mpd) and part geometry.
//!
//! LDraw's frame is y down; brickgeom's lattice is y up. The conversion happens here and only
//! here: LDU (x, y, z) in LDraw <-> lattice (x / 10, -y / 8, z / 10).

pub mod geometry;

pub use geometry::{load_part_geometry, PartGeometry};
