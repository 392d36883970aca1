//! Error mapping: one Python exception class per core error variant, under `BrickGeomError`.

use brickgeom::BrickGeomError as E;
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

create_exception!(
    _brickgeom,
    BrickGeomError,
    PyException,
    "Base class of every brickgeom error."
);
create_exception!(
    _brickgeom,
    UnknownPartError,
    BrickGeomError,
    "A part id that is not in the library."
);
create_exception!(
    _brickgeom,
    PlacementError,
    BrickGeomError,
    "A placement that is not allowed."
);
create_exception!(
    _brickgeom,
    CollisionError,
    PlacementError,
    "Voxels overlap a placed instance."
);
create_exception!(
    _brickgeom,
    BelowGroundError,
    PlacementError,
    "Voxels below the ground plane."
);
create_exception!(
    _brickgeom,
    NotConnectedError,
    PlacementError,
    "No stud, anti-stud or ground contact."
);
create_exception!(
    _brickgeom,
    OutOfRangeError,
    PlacementError,
    "Coordinates beyond the supported range."
);
create_exception!(
    _brickgeom,
    NoSuchInstanceError,
    BrickGeomError,
    "An instance id not in the assembly."
);
create_exception!(
    _brickgeom,
    LDrawError,
    BrickGeomError,
    "A malformed or inconsistent LDraw file."
);
create_exception!(
    _brickgeom,
    FileError,
    BrickGeomError,
    "A file that cannot be read or written."
);
create_exception!(
    _brickgeom,
    InvalidArgumentError,
    BrickGeomError,
    "An invalid argument value."
);

/// Convert a core error to the matching Python exception. No catch-all arm: a new core variant
/// must be mapped here before the crate compiles.
pub fn to_py(err: E) -> PyErr {
    let msg = err.to_string();
    match err {
        E::UnknownPart { .. } => UnknownPartError::new_err(msg),
        E::OutOfRange { .. } => OutOfRangeError::new_err(msg),
        E::Collision { .. } => CollisionError::new_err(msg),
        E::BelowGround { .. } => BelowGroundError::new_err(msg),
        E::NotConnected => NotConnectedError::new_err(msg),
        E::NoSuchInstance { .. } => NoSuchInstanceError::new_err(msg),
        E::InvalidYaw { .. } => InvalidArgumentError::new_err(msg),
        E::EmptyComponent { .. } => InvalidArgumentError::new_err(msg),
        E::Parse { .. } => LDrawError::new_err(msg),
        E::MissingReference { .. } => LDrawError::new_err(msg),
        E::CyclicReference { .. } => LDrawError::new_err(msg),
        E::InvalidLdraw { .. } => LDrawError::new_err(msg),
        E::Io { .. } => FileError::new_err(msg),
        E::InvalidArgument(_) => InvalidArgumentError::new_err(msg),
    }
}

/// Run `f`, a call into the core, with the GIL released, and map its error to the matching
/// Python exception. The one way binding code runs fallible core work that can take longer than
/// about a millisecond (as polars' `enter_polars`); infallible work uses `py.detach` directly.
pub fn detach_core<T: Send>(
    py: Python<'_>,
    f: impl FnOnce() -> brickgeom::error::Result<T> + Send,
) -> PyResult<T> {
    py.detach(f).map_err(to_py)
}

/// `Result<T, BrickGeomError>` -> `PyResult<T>`, for quick core calls made holding the GIL.
pub trait IntoPyResult<T> {
    fn py(self) -> PyResult<T>;
}

impl<T> IntoPyResult<T> for Result<T, E> {
    fn py(self) -> PyResult<T> {
        self.map_err(to_py)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("BrickGeomError", py.get_type::<BrickGeomError>())?;
    m.add("UnknownPartError", py.get_type::<UnknownPartError>())?;
    m.add("PlacementError", py.get_type::<PlacementError>())?;
    m.add("CollisionError", py.get_type::<CollisionError>())?;
    m.add("BelowGroundError", py.get_type::<BelowGroundError>())?;
    m.add("NotConnectedError", py.get_type::<NotConnectedError>())?;
    m.add("OutOfRangeError", py.get_type::<OutOfRangeError>())?;
    m.add("NoSuchInstanceError", py.get_type::<NoSuchInstanceError>())?;
    m.add("LDrawError", py.get_type::<LDrawError>())?;
    m.add("FileError", py.get_type::<FileError>())?;
    m.add(
        "InvalidArgumentError",
        py.get_type::<InvalidArgumentError>(),
    )?;
    Ok(())
}
