//! LDraw I/O: model files (.ldr/.mpd) and part geometry.
//!
//! LDraw's frame is y down; brickgeom's lattice is y up. The conversion happens here and only
//! here: LDU (x, y, z) in LDraw <-> lattice (x / 10, -y / 8, -z / 10), a rotation (half a turn
//! about x), never a mirror: seen from LDraw's front (camera on LDraw's -z side, -y up), LDraw +x
//! is on the right, in mepnet's pictures as in every LDraw tool's.
//!
//! - Models: [`read_ldraw`] / [`parse_ldraw`] give an [`LdrawFile`] (models, steps, references
//!   in LDraw's frame); [`LdrawFile::flatten`] composes submodel transforms into world-placed
//!   [`FlatPart`]s; [`write_ldraw`] / [`write_ldraw_string`] write it back losslessly.
//! - Poses: [`lattice_pose`] maps an LDraw placement to a lattice [`Pose`](crate::Pose) (with
//!   off-lattice / non-yaw flags), [`ldraw_placement`] is its inverse.
//! - Part geometry: [`load_part_geometry`] / [`PartLoader`] read a part and its subfiles from an
//!   LDraw library folder into a y-up [`Mesh`](crate::Mesh) and its top studs.

mod flatten;
pub mod geometry;
mod model;
mod pose;
mod text;
mod writer;

pub use flatten::FlatPart;
pub use geometry::{load_part_geometry, PartGeometry, PartLoader, TOP_STUD_PRIMITIVES};
pub use model::{
    normalise_name, parse_ldraw, read_ldraw, EmbeddedPart, LdrawFile, LdrawModel, LdrawRef,
    MAX_FLAT_PARTS, MAX_NESTING,
};
pub use pose::{lattice_pose, ldraw_placement, LatticePose};
pub use text::MAX_ABS_VALUE;
pub use writer::{write_ldraw, write_ldraw_string};
