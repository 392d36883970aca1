//! Camera estimation kernels (`brickgeom::camfit`): foreground masks, coarse orientation search
//! and the photometric camera fit. The orchestration is `mepnet.cameras`.

use std::sync::OnceLock;

use brickgeom::camfit::{
    box_silhouette, edge_directions, fit_camera, foreground, search_orientations,
    search_placements, CameraFit, FitOptions, FitPicture,
};
use brickgeom::colours::ColourTable;
use brickgeom::scene::MeshSource;
use ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::errors::detach_core;
use crate::geom::{PyAssembly, PyComponent};
use crate::render::PyCamera;

/// The built-in meshes and colours (what synthetic manuals are drawn with).
fn builtin() -> &'static (MeshSource, ColourTable) {
    static BUILTIN: OnceLock<(MeshSource, ColourTable)> = OnceLock::new();
    BUILTIN.get_or_init(|| (MeshSource::builtin(), ColourTable::builtin()))
}

fn rgb_of(rgb: &PyReadonlyArray3<'_, u8>, what: &str) -> PyResult<(Vec<u8>, u32, u32)> {
    let a = rgb.as_array();
    let s = a.shape();
    if s[2] != 3 {
        return Err(PyValueError::new_err(format!(
            "{what}: expected an (H, W, 3) uint8 image, got shape {s:?}"
        )));
    }
    Ok((a.iter().copied().collect(), s[1] as u32, s[0] as u32))
}

fn mask_of(mask: &PyReadonlyArray2<'_, bool>, w: u32, h: u32, what: &str) -> PyResult<Vec<bool>> {
    let a = mask.as_array();
    if a.shape() != [h as usize, w as usize] {
        return Err(PyValueError::new_err(format!(
            "{what}: foreground mask has shape {:?}, the picture is ({h}, {w})",
            a.shape()
        )));
    }
    Ok(a.iter().copied().collect())
}

fn to_array(py: Python<'_>, v: Vec<bool>, w: u32, h: u32) -> PyResult<Bound<'_, PyArray2<bool>>> {
    Array2::from_shape_vec((h as usize, w as usize), v)
        .map(|a| a.into_pyarray(py))
        .map_err(|e| PyValueError::new_err(e.to_string()))
}

/// The drawing's pixels of an (H, W, 3) uint8 picture, (H, W) bool, and the page colour:
/// pixels whose largest channel difference from the border's median colour exceeds
/// `threshold`, page-coloured regions the border cannot reach, specks under `min_area` pixels
/// dropped.
#[pyfunction(name = "foreground_mask")]
#[pyo3(signature = (rgb, threshold=30.0, min_area=16))]
fn foreground_py<'py>(
    py: Python<'py>,
    rgb: PyReadonlyArray3<'py, u8>,
    threshold: f32,
    min_area: usize,
) -> PyResult<(Bound<'py, PyArray2<bool>>, (u8, u8, u8))> {
    let (data, w, h) = rgb_of(&rgb, "foreground_mask")?;
    let fg = detach_core(py, || foreground(&data, w, h, threshold, min_area))?;
    let bg = fg.background;
    Ok((to_array(py, fg.mask, w, h)?, (bg[0], bg[1], bg[2])))
}

/// Histogram (`bins` over [0, 180) degrees, y up, sums to 1) of the directions of an (H, W, 3)
/// uint8 picture's edges: structure-tensor direction per pixel (Gaussian derivatives of scale
/// `sigma`, averaged over `rho`), weighted by strength times coherence.
#[pyfunction(name = "edge_directions")]
#[pyo3(signature = (rgb, bins=360, sigma=1.5, rho=2.5))]
fn edge_directions_py<'py>(
    py: Python<'py>,
    rgb: PyReadonlyArray3<'py, u8>,
    bins: usize,
    sigma: f32,
    rho: f32,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let (data, w, h) = rgb_of(&rgb, "edge_directions")?;
    let hist = detach_core(py, || edge_directions(&data, w, h, bins, sigma, rho))?;
    Ok(hist.into_pyarray(py))
}

/// The coarse silhouette (bricks as voxel boxes, studs as slabs) of an assembly, (H, W) bool.
#[pyfunction(name = "box_silhouette")]
fn box_silhouette_py<'py>(
    py: Python<'py>,
    assembly: &PyAssembly,
    camera: &PyCamera,
    width: u32,
    height: u32,
) -> PyResult<Bound<'py, PyArray2<bool>>> {
    let asm = &assembly.inner;
    let cam = camera.inner;
    let mask = detach_core(py, || box_silhouette(asm, &cam, width, height))?;
    to_array(py, mask, width, height)
}

/// Orientation hypotheses `(elevation, azimuth, roll)` scored for a picture showing exactly the
/// assembly: per hypothesis `(iou, camera)`, the coarse silhouette framed to the foreground's
/// bounding box, at most `work` pixels a side.
#[pyfunction(name = "search_orientations")]
#[pyo3(signature = (assembly, foreground, candidates, work=64))]
fn search_orientations_py(
    py: Python<'_>,
    assembly: &PyAssembly,
    foreground: PyReadonlyArray2<'_, bool>,
    candidates: Vec<(f64, f64, f64)>,
    work: u32,
) -> PyResult<Vec<(f64, PyCamera)>> {
    let s = foreground.as_array().shape().to_vec();
    let (w, h) = (s[1] as u32, s[0] as u32);
    let fg = mask_of(&foreground, w, h, "search_orientations")?;
    let cands: Vec<[f64; 3]> = candidates.iter().map(|&(a, b, c)| [a, b, c]).collect();
    let asm = &assembly.inner;
    let out = detach_core(py, || search_orientations(asm, &fg, w, h, &cands, work))?;
    Ok(out
        .into_iter()
        .map(|(iou, c)| (iou, PyCamera { inner: c }))
        .collect())
}

/// The `k` best valid placements `(iou, yaw, t, camera)` of `component` on `assembly` for a
/// picture showing exactly the assembly with it added, from one of `orientations`: coarse
/// silhouettes framed to the foreground's box, at most `work` pixels a side.
#[pyfunction(name = "search_placements")]
#[pyo3(signature = (assembly, component, foreground, orientations, work=64, k=8))]
fn search_placements_py(
    py: Python<'_>,
    assembly: &PyAssembly,
    component: &PyComponent,
    foreground: PyReadonlyArray2<'_, bool>,
    orientations: Vec<(f64, f64, f64)>,
    work: u32,
    k: usize,
) -> PyResult<Vec<(f64, u8, (i32, i32, i32), PyCamera)>> {
    let s = foreground.as_array().shape().to_vec();
    let (w, h) = (s[1] as u32, s[0] as u32);
    let fg = mask_of(&foreground, w, h, "search_placements")?;
    let ors: Vec<[f64; 3]> = orientations.iter().map(|&(a, b, c)| [a, b, c]).collect();
    let (asm, comp) = (&assembly.inner, &component.inner);
    let out = detach_core(py, || {
        search_placements(asm, comp, &fg, w, h, &ors, work, k)
    })?;
    Ok(out
        .into_iter()
        .map(|(iou, yaw, t, c)| (iou, yaw, (t[0], t[1], t[2]), PyCamera { inner: c }))
        .collect())
}

/// A step picture prepared for `fit_camera` (frozen): built from an (H, W, 3) uint8 array; the
/// blurred copies and gradients a fit needs are made once and kept.
#[pyclass(name = "FitPicture", module = "mepnet._brickgeom", frozen)]
pub struct PyFitPicture {
    inner: FitPicture,
}

#[pymethods]
impl PyFitPicture {
    #[new]
    fn new(rgb: PyReadonlyArray3<'_, u8>) -> PyResult<Self> {
        let (data, w, h) = rgb_of(&rgb, "FitPicture")?;
        Ok(PyFitPicture {
            inner: FitPicture::new(&data, w, h).map_err(crate::errors::to_py)?,
        })
    }
    /// (width, height) in pixels.
    #[getter]
    fn size(&self) -> (u32, u32) {
        self.inner.size()
    }
}

/// The result of `fit_camera` (frozen): the camera and how well it explains the picture.
#[pyclass(name = "CameraFit", module = "mepnet._brickgeom", frozen)]
pub struct PyCameraFit {
    inner: CameraFit,
}

#[pymethods]
impl PyCameraFit {
    /// The fitted camera.
    #[getter]
    fn camera(&self) -> PyCamera {
        PyCamera {
            inner: self.inner.camera,
        }
    }
    /// Share of the shape's sampled pixels whose colour the picture shows where the camera
    /// puts them.
    #[getter]
    fn agree(&self) -> f64 {
        self.inner.agree
    }
    /// Share of the shape's silhouette on the picture's foreground.
    #[getter]
    fn inside(&self) -> f64 {
        self.inner.inside
    }
    /// IoU of the shape's silhouette with the foreground.
    #[getter]
    fn iou(&self) -> f64 {
        self.inner.iou
    }
    /// Mean robust cost per sample at the finest level.
    #[getter]
    fn cost(&self) -> f64 {
        self.inner.cost
    }
    /// Samples used.
    #[getter]
    fn samples(&self) -> usize {
        self.inner.samples
    }
    /// RMS motion of the shape's pixels from the initial camera (px).
    #[getter]
    fn moved_px(&self) -> f64 {
        self.inner.moved_px
    }
    fn __repr__(&self) -> String {
        let c = &self.inner;
        format!(
            "CameraFit(agree={:.3}, inside={:.3}, iou={:.3}, cost={:.5}, samples={}, moved_px={:.2})",
            c.agree, c.inside, c.iou, c.cost, c.samples, c.moved_px
        )
    }
}

/// Fit a camera to a picture (`FitPicture`) of `assembly` from `init` (photometric, coarse
/// to fine over box-blur radii `levels`, the shape rendered anew at a level when the camera moved
/// more than `rerender_px` since the last render, and at the last level; `free` says which of elevation, azimuth, roll, ln scale, tx,
/// ty move; `prior`: (centre, weight) per parameter; `lines`: the template's outline width as a
/// share of the renderer's, 0 for faces only). `foreground` (H, W) bool scores the result.
#[pyfunction(name = "fit_camera")]
#[pyo3(signature = (assembly, picture, foreground, init, free=(true, true, true, true, true, true),
    levels=vec![4, 2, 1, 0, 0], rerender_px=0.0, iterations=8, tukey=0.3, samples=6000, prior=None,
    lines=1.0))]
#[allow(clippy::too_many_arguments)]
fn fit_camera_py(
    py: Python<'_>,
    assembly: &PyAssembly,
    picture: &PyFitPicture,
    foreground: PyReadonlyArray2<'_, bool>,
    init: &PyCamera,
    free: (bool, bool, bool, bool, bool, bool),
    levels: Vec<u32>,
    rerender_px: f64,
    iterations: u32,
    tukey: f64,
    samples: usize,
    prior: Option<([f64; 6], [f64; 6])>,
    lines: f32,
) -> PyResult<PyCameraFit> {
    let (w, h) = picture.inner.size();
    let fg = mask_of(&foreground, w, h, "fit_camera")?;
    let opts = FitOptions {
        free: [free.0, free.1, free.2, free.3, free.4, free.5],
        levels,
        rerender_px,
        iterations,
        tukey,
        samples,
        prior,
        lines,
    };
    let asm = &assembly.inner;
    let cam = init.inner;
    let (source, colours) = builtin();
    let pic = &picture.inner;
    let fit = detach_core(py, || {
        fit_camera(asm, pic, &fg, &cam, &opts, source, colours)
    })?;
    Ok(PyCameraFit { inner: fit })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyCameraFit>()?;
    m.add_class::<PyFitPicture>()?;
    m.add_function(wrap_pyfunction!(foreground_py, m)?)?;
    m.add_function(wrap_pyfunction!(box_silhouette_py, m)?)?;
    m.add_function(wrap_pyfunction!(edge_directions_py, m)?)?;
    m.add_function(wrap_pyfunction!(search_orientations_py, m)?)?;
    m.add_function(wrap_pyfunction!(search_placements_py, m)?)?;
    m.add_function(wrap_pyfunction!(fit_camera_py, m)?)?;
    Ok(())
}
