//! brickgeom: the geometry core of mepnet.
//!
//! Units and frames (DESIGN §2): world geometry in LDraw units (LDU); the lattice has x and z in
//! half-studs (10 LDU) and y in plates (8 LDU), y up. LDraw's y-down frame appears only at the
//! LDraw I/O boundary (`ldraw`).

pub mod assembly;
pub mod camera;
pub mod camfit;
pub mod colours;
pub mod component;
pub mod error;
pub mod lattice;
pub mod ldraw;
pub mod library;
pub mod mesh;
pub mod metrics;
mod parts;
pub mod raster;
pub mod realmodel;
pub mod render_style;
pub mod scene;
mod shapes;
pub mod stage2;
pub mod synth;

pub use assembly::{Assembly, AttachKind, GroundSearch, Instance, Placement, Snapshot};
pub use component::Component;
pub use error::{BrickGeomError, Result};
pub use lattice::{Lattice, Pose};
pub use library::{library, part, Category, Library, PartDef};
pub use mesh::Mesh;
