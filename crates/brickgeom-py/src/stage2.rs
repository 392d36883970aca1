//! Stage 2 (pose inference, `brickgeom::stage2`) and the analysis-by-synthesis baseline.

use brickgeom::stage2::{
    abys_ranking, abys_step, infer_step, rotation_class, Detection, InferOptions,
    InstancePrediction, TypeDetections,
};
use numpy::{PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

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

/// The detections of one component type of a step, as stage 2 takes them (a frozen wrapper over
/// the core's `TypeDetections`): the component, how many instances the step adds, and per
/// detection (N of them) `keypoints` (N, 2) float64 pixels, `scores` (N,) float32,
/// `rotations` (N, 7) float32 class probabilities or None, `masks` (N, H, W) bool or None.
#[pyclass(name = "StepDetections", module = "mepnet._brickgeom", frozen)]
pub struct PyStepDetections {
    inner: TypeDetections,
    /// (H, W) of the masks, when there are masks.
    mask_shape: Option<(usize, usize)>,
}

#[pymethods]
impl PyStepDetections {
    #[new]
    #[pyo3(signature = (component, count, keypoints, scores, rotations=None, masks=None))]
    fn new(
        component: &PyComponent,
        count: usize,
        keypoints: PyReadonlyArray2<'_, f64>,
        scores: PyReadonlyArray1<'_, f32>,
        rotations: Option<PyReadonlyArray2<'_, f32>>,
        masks: Option<PyReadonlyArray3<'_, bool>>,
    ) -> PyResult<Self> {
        if count > 1000 {
            return Err(PyValueError::new_err(format!("count {count} is absurd")));
        }
        let kp = keypoints.as_array();
        let n = kp.nrows();
        if kp.ncols() != 2 {
            return Err(PyValueError::new_err(format!(
                "keypoints must have shape (N, 2), got {:?}",
                kp.shape()
            )));
        }
        let sc = scores.as_array();
        if sc.len() != n {
            return Err(PyValueError::new_err(format!(
                "scores must have shape ({n},), got {:?}",
                sc.shape()
            )));
        }
        let rot = rotations.as_ref().map(|r| r.as_array());
        if let Some(r) = &rot {
            if r.shape() != [n, 7] {
                return Err(PyValueError::new_err(format!(
                    "rotations must have shape ({n}, 7), got {:?}",
                    r.shape()
                )));
            }
        }
        let m = masks.as_ref().map(|m| m.as_array());
        let mask_shape = match &m {
            Some(m) if m.shape()[0] != n => {
                return Err(PyValueError::new_err(format!(
                    "masks must have shape ({n}, H, W), got {:?}",
                    m.shape()
                )))
            }
            Some(m) => Some((m.shape()[1], m.shape()[2])),
            None => None,
        };
        let detections = (0..n)
            .map(|i| Detection {
                keypoint: [kp[[i, 0]], kp[[i, 1]]],
                score: sc[i],
                rotation: rot.as_ref().map(|r| std::array::from_fn(|k| r[[i, k]])),
                mask: m.as_ref().map(|m| {
                    m.index_axis(numpy::ndarray::Axis(0), i)
                        .iter()
                        .copied()
                        .collect()
                }),
            })
            .collect();
        Ok(PyStepDetections {
            inner: TypeDetections {
                component: component.inner.clone(),
                count,
                detections,
            },
            mask_shape,
        })
    }

    /// How many instances of the type the step adds.
    #[getter]
    fn count(&self) -> usize {
        self.inner.count
    }

    fn __len__(&self) -> usize {
        self.inner.detections.len()
    }
}

/// One instance as stage 2 placed it (a frozen wrapper over the core's `InstancePrediction`):
/// `type` (index into the types given), `detection` (the detection used, or None), `yaw` and
/// `t` (None on failure), `attach`, `error_px` (keypoint reprojection error), `iou` (mask IoU
/// when a mask was used), `failure` (why there is no pose).
#[pyclass(name = "PlacedInstance", module = "mepnet._brickgeom", frozen)]
pub struct PyPlacedInstance {
    inner: InstancePrediction,
}

#[pymethods]
impl PyPlacedInstance {
    #[getter(r#type)]
    fn type_index(&self) -> usize {
        self.inner.type_index
    }
    #[getter]
    fn detection(&self) -> Option<usize> {
        self.inner.detection
    }
    #[getter]
    fn yaw(&self) -> Option<u8> {
        self.inner.pose.map(|p| p.yaw)
    }
    #[getter]
    fn t(&self) -> Option<(i32, i32, i32)> {
        self.inner.pose.map(|p| (p.t[0], p.t[1], p.t[2]))
    }
    #[getter]
    fn attach(&self) -> Option<&'static str> {
        self.inner.attach.map(|a| a.name())
    }
    #[getter]
    fn error_px(&self) -> f64 {
        self.inner.error_px
    }
    #[getter]
    fn iou(&self) -> Option<f64> {
        self.inner.iou
    }
    #[getter]
    fn failure(&self) -> Option<&str> {
        self.inner.failure.as_deref()
    }
    fn __repr__(&self) -> String {
        format!(
            "PlacedInstance(type={}, yaw={:?}, t={:?}, attach={:?}, failure={:?})",
            self.inner.type_index,
            self.yaw(),
            self.t(),
            self.attach(),
            self.inner.failure
        )
    }
}

/// Stage 2 for one step: `types` is a list of `StepDetections`; returns one `PlacedInstance`
/// per instance the step adds. `rotation_by_mask`: primitives with a mask choose the yaw by mask
/// IoU plus class probability.
#[pyfunction(name = "infer_step")]
#[pyo3(signature = (base, camera, width, height, types, max_error_px=6.0, tie_px=2.5, rotation_by_mask=true))]
#[allow(clippy::too_many_arguments)]
fn infer_step_py(
    py: Python<'_>,
    base: &PyAssembly,
    camera: &PyCamera,
    width: u32,
    height: u32,
    types: Vec<PyRef<'_, PyStepDetections>>,
    max_error_px: f64,
    tie_px: f64,
    rotation_by_mask: bool,
) -> PyResult<Vec<PyPlacedInstance>> {
    for (ti, t) in types.iter().enumerate() {
        if let Some((h, w)) = t.mask_shape {
            if (h, w) != (height as usize, width as usize) {
                return Err(PyValueError::new_err(format!(
                    "type {ti}: masks are ({h}, {w}), the image is ({height}, {width})"
                )));
            }
        }
    }
    let tds: Vec<TypeDetections> = types.iter().map(|t| t.inner.clone()).collect();
    let opts = InferOptions {
        max_error_px,
        tie_px,
        rotation_by_mask,
    };
    let asm = &base.inner;
    let cam = camera.inner;
    let preds = detach_core(py, || infer_step(asm, &cam, width, height, &tds, &opts))?;
    Ok(preds
        .into_iter()
        .map(|inner| PyPlacedInstance { inner })
        .collect())
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
/// `mask` (H, W) bool by IoU, best first: `([(yaw, t, iou), ...], timed_out)`. The ground is
/// searched beside the base; with `wide_ground` also wherever the part may be seen in `mask`
/// (a placement standing away from the base scores its IoU less `DETACHED_PENALTY`). Placements
/// that cannot enter the ranking are skipped (the share of the mask inside their drawn box
/// bounds their IoU); `exhaustive` scores every one, the reference (tests, benchmarks).
#[pyfunction(name = "abys_ranked")]
#[pyo3(signature = (base, camera, width, height, component, mask, k=8, time_limit_s=60.0, wide_ground=false, exhaustive=false))]
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
    wide_ground: bool,
    exhaustive: bool,
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
        abys_ranking(
            asm,
            &comp,
            &cam,
            width,
            height,
            &m,
            k,
            time_limit_s,
            wide_ground,
            exhaustive,
        )
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
    m.add_class::<PyStepDetections>()?;
    m.add_class::<PyPlacedInstance>()?;
    m.add_function(wrap_pyfunction!(infer_step_py, m)?)?;
    m.add_function(wrap_pyfunction!(abys_step_py, m)?)?;
    m.add_function(wrap_pyfunction!(abys_ranked_py, m)?)?;
    m.add_function(wrap_pyfunction!(rotation_class_py, m)?)?;
    Ok(())
}
