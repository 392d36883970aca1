//! The one error type of brickgeom. Variants carry the data a user needs to fix the input.

use crate::lattice::Lattice;

/// Every failure brickgeom reports. Bad input never panics; it becomes one of these.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BrickGeomError {
    /// A part id that is neither a library part nor a known alias of one.
    #[error("unknown part id '{id}'")]
    UnknownPart { id: String },
    /// A lattice position outside the range brickgeom accepts (absurd coordinates).
    #[error("position {pos:?} is outside the supported lattice range (|x|,|z| <= {limit} half-studs, 0 <= y <= {limit} plates)")]
    OutOfRange { pos: Lattice, limit: i32 },
    /// A placement whose voxels overlap an already placed instance.
    #[error("placement collides with instance {instance}")]
    Collision { instance: u32 },
    /// A placement below the ground plane (y < 0).
    #[error("placement reaches below the ground (lowest voxel y = {y})")]
    BelowGround { y: i32 },
    /// A placement that touches no free stud, no free anti-stud and not the ground.
    #[error("placement is not connected to the assembly (no stud, anti-stud or ground contact)")]
    NotConnected,
    /// An instance id that is not (or no longer) in the assembly.
    #[error("no instance with id {id} in the assembly")]
    NoSuchInstance { id: u32 },
    /// A yaw outside 0..=3 quarter turns.
    #[error("yaw must be 0..=3 quarter turns, got {yaw}")]
    InvalidYaw { yaw: i64 },
    /// A component that would contain nothing (e.g. a submodule from an empty assembly).
    #[error("empty component: {what}")]
    EmptyComponent { what: String },
    /// A syntax or value error in an LDraw file, with the 1-based line number.
    #[error("{file}:{line}: {message}")]
    Parse {
        file: String,
        line: usize,
        message: String,
    },
    /// A submodel or subfile reference that cannot be resolved.
    #[error("{file}:{line}: reference to missing file '{name}'")]
    MissingReference {
        file: String,
        line: usize,
        name: String,
    },
    /// An LDraw file, model or reference built in memory that the reader would not read back
    /// (an empty name, a non-finite or huge number, a singular matrix, an empty step).
    #[error("{what}: {message}")]
    InvalidLdraw { what: String, message: String },
    /// A submodel that (directly or indirectly) references itself.
    #[error("{file}: cyclic submodel reference: {chain}")]
    CyclicReference { file: String, chain: String },
    /// A file that cannot be read or written.
    #[error("{path}: {message}")]
    Io { path: String, message: String },
    /// Any other invalid argument, with the reason.
    #[error("{0}")]
    InvalidArgument(String),
}

/// Result alias used across the crate.
pub type Result<T> = std::result::Result<T, BrickGeomError>;
