//! Stage 2 (pose inference, `brickgeom::stage2`) and the analysis-by-synthesis baseline.

use brickgeom::stage2::{
    abys_ranked, abys_step, infer_step, rotation_class, Detection, InferOptions, TypeDetections,
};
use numpy::PyReadonlyArray2;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::errors::detach_core;
use crate::geom::{PyAssembly, PyComponent};
use crate::render::PyCamera;

fn mask_vec(mask: &Bound<'_, PyAny>, w: u32, h: u32, what: &str) -> PyResult<Vec<bool>> {
    let arr: PyReadonlyArray2<'_, bool> = mask.extract().map_err(|_| {
        PyValueError::new_err(format!(
            "{what}: mask must be a 2-D bool array of shape ({h}, {w})"
        ))
    })?;
    let a = arr.as_array();
    if a.shape() != [h as usize, w as usize] {
        return Err(PyValueError::new_err(format!(
            "{what}: mask has shape {:?}, the image is ({h}, {w})",
            a.shape()
        )));
    }
    Ok(a.iter().copied().collect())
}

/// The 7-way symmetry-aware rotation class of a yaw for a component of this symmetry order.
#[pyfunction(name = "rotation_class")]
fn rotation_class_py(symmetry: u8, yaw: u8) -> u8 {
    rotation_class(symmetry, yaw % 4)
}

/// Stage 2 for one step. `types`: list of dicts {component, count, detections: [{keypoint:
/// (x, y) px, score, rotation: 7 probabilities or None, mask: (H, W) bool array or None}]}.
/// Returns one dict per instance: {type, detection, yaw, t, attach, error_px, iou, failure}
/// (yaw/t/attach None on failure). `rotation_by_mask`: primitives with a mask choose the yaw by
/// mask IoU plus class probability.
#[pyfunction(name = "infer_step")]
#[pyo3(signature = (base, camera, width, height, types, max_error_px=6.0, tie_px=2.5, rotation_by_mask=true))]
#[allow(clippy::too_many_arguments)]
fn infer_step_py<'py>(
    py: Python<'py>,
    base: &PyAssembly,
    camera: &PyCamera,
    width: u32,
    height: u32,
    types: &Bound<'py, PyList>,
    max_error_px: f64,
    tie_px: f64,
    rotation_by_mask: bool,
) -> PyResult<Bound<'py, PyList>> {
    let mut tds = Vec::new();
    for (ti, t) in types.iter().enumerate() {
        let t = t.cast::<PyDict>()?;
        let get = |k: &str| -> PyResult<Bound<'py, PyAny>> {
            t.get_item(k)?
                .ok_or_else(|| PyValueError::new_err(format!("type {ti}: missing '{k}'")))
        };
        let comp = get("component")?;
        let comp = comp.cast::<PyComponent>()?;
        let count: usize = get("count")?.extract()?;
        if count > 1000 {
            return Err(PyValueError::new_err(format!(
                "type {ti}: count {count} is absurd"
            )));
        }
        let mut dets = Vec::new();
        for (di, d) in get("detections")?.try_iter()?.enumerate() {
            let d = d?;
            let d = d.cast::<PyDict>()?;
            let what = format!("type {ti} detection {di}");
            let kp: (f64, f64) = d
                .get_item("keypoint")?
                .ok_or_else(|| PyValueError::new_err(format!("{what}: missing 'keypoint'")))?
                .extract()?;
            let score: f32 = d
                .get_item("score")?
                .map(|v| v.extract())
                .transpose()?
                .unwrap_or(1.0);
            let rotation: Option<[f32; 7]> = match d.get_item("rotation")? {
                None => None,
                Some(v) if v.is_none() => None,
                Some(v) => Some(v.extract().map_err(|_| {
                    PyValueError::new_err(format!("{what}: rotation must be 7 class probabilities"))
                })?),
            };
            let mask = match d.get_item("mask")? {
                None => None,
                Some(v) if v.is_none() => None,
                Some(v) => Some(mask_vec(&v, width, height, &what)?),
            };
            dets.push(Detection {
                keypoint: [kp.0, kp.1],
                score,
                rotation,
                mask,
            });
        }
        tds.push(TypeDetections {
            component: comp.get().inner.clone(),
            count,
            detections: dets,
        });
    }
    let opts = InferOptions {
        max_error_px,
        tie_px,
        rotation_by_mask,
    };
    let asm = &base.inner;
    let cam = camera.inner;
    let preds = detach_core(py, || infer_step(asm, &cam, width, height, &tds, &opts))?;
    let out = PyList::empty(py);
    for p in preds {
        let d = PyDict::new(py);
        d.set_item("type", p.type_index)?;
        d.set_item("detection", p.detection)?;
        d.set_item("yaw", p.pose.map(|x| x.yaw))?;
        d.set_item("t", p.pose.map(|x| (x.t[0], x.t[1], x.t[2])))?;
        d.set_item("attach", p.attach.map(|a| a.name()))?;
        d.set_item("error_px", p.error_px)?;
        d.set_item("iou", p.iou)?;
        d.set_item("failure", p.failure)?;
        out.append(d)?;
    }
    Ok(out)
}

/// Pure analysis-by-synthesis: `instances` is a list of (component, mask (H, W) bool); returns
/// per instance `(yaw, t) or None, iou, timed_out`, placing them one after another.
#[pyfunction(name = "abys_step")]
#[pyo3(signature = (base, camera, width, height, instances, time_limit_s=60.0))]
#[allow(clippy::type_complexity)]
fn abys_step_py<'py>(
    py: Python<'py>,
    base: &PyAssembly,
    camera: &PyCamera,
    width: u32,
    height: u32,
    instances: Vec<(Bound<'py, PyComponent>, Bound<'py, PyAny>)>,
    time_limit_s: f64,
) -> PyResult<Vec<(Option<(u8, (i32, i32, i32))>, f64, bool)>> {
    if time_limit_s.is_nan() || time_limit_s <= 0.0 {
        return Err(PyValueError::new_err(format!(
            "time limit must be positive, got {time_limit_s}"
        )));
    }
    let mut list = Vec::new();
    for (k, (c, m)) in instances.iter().enumerate() {
        list.push((
            c.get().inner.clone(),
            mask_vec(m, width, height, &format!("instance {k}"))?,
        ));
    }
    let asm = &base.inner;
    let cam = camera.inner;
    let res = detach_core(py, || {
        abys_step(asm, &cam, width, height, &list, time_limit_s)
    })?;
    Ok(res
        .into_iter()
        .map(|(p, iou, t)| (p.map(|p| (p.yaw, (p.t[0], p.t[1], p.t[2]))), iou, t))
        .collect())
}

/// The `k` valid placements of `component` on `base` whose visible silhouettes best match
/// `mask` (H, W) bool by IoU, best first: `([(yaw, t, iou), ...], timed_out)`.
#[pyfunction(name = "abys_ranked")]
#[pyo3(signature = (base, camera, width, height, component, mask, k=8, time_limit_s=60.0))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn abys_ranked_py<'py>(
    py: Python<'py>,
    base: &PyAssembly,
    camera: &PyCamera,
    width: u32,
    height: u32,
    component: Bound<'py, PyComponent>,
    mask: Bound<'py, PyAny>,
    k: usize,
    time_limit_s: f64,
) -> PyResult<(Vec<(u8, (i32, i32, i32), f64)>, bool)> {
    if time_limit_s.is_nan() || time_limit_s <= 0.0 {
        return Err(PyValueError::new_err(format!(
            "time limit must be positive, got {time_limit_s}"
        )));
    }
    let m = mask_vec(&mask, width, height, "mask")?;
    let comp = component.get().inner.clone();
    let asm = &base.inner;
    let cam = camera.inner;
    let (ranked, timed_out) = detach_core(py, || {
        abys_ranked(asm, &comp, &cam, width, height, &m, k, time_limit_s)
    })?;
    Ok((
        ranked
            .into_iter()
            .map(|(p, iou)| (p.yaw, (p.t[0], p.t[1], p.t[2]), iou))
            .collect(),
        timed_out,
    ))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(infer_step_py, m)?)?;
    m.add_function(wrap_pyfunction!(abys_step_py, m)?)?;
    m.add_function(wrap_pyfunction!(abys_ranked_py, m)?)?;
    m.add_function(wrap_pyfunction!(rotation_class_py, m)?)?;
    Ok(())
}
