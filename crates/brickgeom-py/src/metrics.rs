//! Evaluation metrics: Chamfer distance between point sets and rectangular linear assignment.

use numpy::PyReadonlyArray2;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::errors::detach_core;

/// Copy an (N, 3) float32 array into points; ValueError naming the expected shape otherwise.
fn points(name: &str, a: &PyReadonlyArray2<'_, f32>) -> PyResult<Vec<[f32; 3]>> {
    let v = a.as_array();
    if v.ncols() != 3 {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape (N, 3), got {:?}",
            v.shape()
        )));
    }
    Ok(v.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect())
}

/// Chamfer distance between two (N, 3) float32 point sets: mean squared nearest-neighbour
/// distance from `a` to `b` plus from `b` to `a` (squared input units). Exact, deterministic;
/// InvalidArgumentError for an empty set or a non-finite coordinate.
#[pyfunction]
fn chamfer_distance(
    py: Python<'_>,
    a: PyReadonlyArray2<'_, f32>,
    b: PyReadonlyArray2<'_, f32>,
) -> PyResult<f64> {
    let a = points("a", &a)?;
    let b = points("b", &b)?;
    detach_core(py, || brickgeom::metrics::chamfer(&a, &b))
}

/// Minimum-cost assignment of a 2-D float64 cost matrix, like scipy's `linear_sum_assignment`:
/// `(rows, cols)` with `min(n, m)` pairs sorted by row. InvalidArgumentError for a non-finite
/// cost.
#[pyfunction]
fn linear_assignment(
    py: Python<'_>,
    cost: PyReadonlyArray2<'_, f64>,
) -> PyResult<(Vec<usize>, Vec<usize>)> {
    let c = cost.as_array();
    let rows: Vec<Vec<f64>> = c.rows().into_iter().map(|r| r.to_vec()).collect();
    // An (n, 0) matrix gives n empty rows, and no pairs.
    let asg = detach_core(py, || brickgeom::metrics::hungarian(&rows))?;
    Ok(asg
        .into_iter()
        .enumerate()
        .filter_map(|(i, j)| j.map(|j| (i, j)))
        .unzip())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(chamfer_distance, m)?)?;
    m.add_function(wrap_pyfunction!(linear_assignment, m)?)?;
    Ok(())
}
