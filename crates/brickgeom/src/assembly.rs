//! Assembly (placeholder, being written).
/// How a placement connects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AttachKind { OnStuds, FromBelow, Ground }
/// A placement.
pub struct Placement;
/// An assembly.
pub struct Assembly;
