//! `mepnet._brickgeom`: thin PyO3 wrappers over the brickgeom core.
//!
//! Each function extracts its arguments, releases the GIL around work that can take longer than
//! about a millisecond, calls the core and converts the result. No geometry lives here. Fallible
//! core work goes through one helper, `errors::detach_core`, which releases the GIL and maps the
//! core's error to its Python exception.

// Return types of PyO3 functions (tuples of bound numpy arrays) are long by nature.
#![allow(clippy::type_complexity)]

mod camfit;
mod errors;
mod geom;
mod ldraw;
mod metrics;
mod render;
mod stage2;
mod style;
mod synth;

use pyo3::prelude::*;

#[pymodule]
fn _brickgeom(m: &Bound<'_, PyModule>) -> PyResult<()> {
    camfit::register(m)?;
    errors::register(m)?;
    geom::register(m)?;
    ldraw::register(m)?;
    metrics::register(m)?;
    render::register(m)?;
    stage2::register(m)?;
    style::register(m)?;
    synth::register(m)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
