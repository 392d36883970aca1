//! Cameras and rendering.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, OnceLock};

use brickgeom::camera::Camera;
use brickgeom::colours::ColourTable;
use brickgeom::raster::{RenderOptions, Rendered};
use brickgeom::render_style::Mark;
use brickgeom::scene::{render_assembly_marked, MeshSource};
use ndarray::{Array1, Array2, Array3};
use numpy::{
    IntoPyArray, PyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::errors::{detach_core, IntoPyResult};
use crate::geom::PyAssembly;
use crate::style::PyRenderStyle;

/// A weak-perspective camera (angles in degrees, scale in NDC per LDU, translation in NDC).
#[pyclass(name = "Camera", module = "mepnet._brickgeom", frozen)]
#[derive(Clone)]
pub struct PyCamera {
    pub inner: Camera,
}

#[pymethods]
impl PyCamera {
    #[new]
    #[pyo3(signature = (elevation=30.0, azimuth=225.0, roll=0.0, scale=0.01, translation=(0.0, 0.0)))]
    fn new(
        elevation: f64,
        azimuth: f64,
        roll: f64,
        scale: f64,
        translation: (f64, f64),
    ) -> PyResult<Self> {
        Ok(PyCamera {
            inner: Camera::new(
                elevation,
                azimuth,
                roll,
                scale,
                [translation.0, translation.1],
            )
            .py()?,
        })
    }

    #[getter]
    fn elevation(&self) -> f64 {
        self.inner.elevation
    }
    #[getter]
    fn azimuth(&self) -> f64 {
        self.inner.azimuth
    }
    #[getter]
    fn roll(&self) -> f64 {
        self.inner.roll
    }
    #[getter]
    fn scale(&self) -> f64 {
        self.inner.scale
    }
    #[getter]
    fn translation(&self) -> (f64, f64) {
        (self.inner.translation[0], self.inner.translation[1])
    }

    /// Rows u (right), v (up), w (view direction) of the world-to-camera rotation, (3, 3).
    fn rotation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let r = self.inner.rotation();
        Array2::from_shape_fn((3, 3), |(i, j)| r[(i, j)]).into_pyarray(py)
    }

    /// The (2, 4) projection from homogeneous world points (LDU) to pixels.
    fn pixel_matrix<'py>(
        &self,
        py: Python<'py>,
        width: u32,
        height: u32,
    ) -> Bound<'py, PyArray2<f64>> {
        let m = self.inner.pixel_matrix(width, height);
        Array2::from_shape_fn((2, 4), |(i, j)| m[(i, j)]).into_pyarray(py)
    }

    /// Project (N, 3) world points (LDU) to `(pixels (N, 2), depth (N,))`.
    fn project<'py>(
        &self,
        py: Python<'py>,
        points: PyReadonlyArray2<'py, f64>,
        width: u32,
        height: u32,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>)> {
        let p = points.as_array();
        if p.ncols() != 3 {
            return Err(PyValueError::new_err(format!(
                "points must have shape (N, 3), got {:?}",
                p.shape()
            )));
        }
        let mut px = Array2::zeros((p.nrows(), 2));
        let mut d = Array1::zeros(p.nrows());
        for (i, row) in p.rows().into_iter().enumerate() {
            let (q, z) = self.inner.project([row[0], row[1], row[2]], width, height);
            px[(i, 0)] = q[0];
            px[(i, 1)] = q[1];
            d[i] = z;
        }
        Ok((px.into_pyarray(py), d.into_pyarray(py)))
    }

    /// A copy with scale and translation making (N, 3) points fill `fill` of the frame.
    fn fitted(&self, points: PyReadonlyArray2<'_, f64>, fill: f64) -> PyResult<Self> {
        let p = points.as_array();
        if p.ncols() != 3 {
            return Err(PyValueError::new_err(format!(
                "points must have shape (N, 3), got {:?}",
                p.shape()
            )));
        }
        let pts: Vec<[f64; 3]> = p.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect();
        Ok(PyCamera {
            inner: self.inner.fitted(&pts, fill).py()?,
        })
    }

    fn __repr__(&self) -> String {
        let c = &self.inner;
        format!(
            "Camera(elevation={}, azimuth={}, roll={}, scale={}, translation=({}, {}))",
            c.elevation, c.azimuth, c.roll, c.scale, c.translation[0], c.translation[1]
        )
    }
}

/// Mesh sources are cached per LDraw root so real part geometry is loaded once per process.
fn source(ldraw_dir: Option<PathBuf>) -> Arc<MeshSource> {
    static SOURCES: OnceLock<Mutex<HashMap<Option<PathBuf>, Arc<MeshSource>>>> = OnceLock::new();
    let map = SOURCES.get_or_init(Mutex::default);
    let mut map = map.lock().unwrap_or_else(|e| e.into_inner());
    map.entry(ldraw_dir.clone())
        .or_insert_with(|| {
            Arc::new(match ldraw_dir {
                None => MeshSource::builtin(),
                Some(root) => MeshSource::ldraw(root),
            })
        })
        .clone()
}

fn colour_table(ldraw_dir: Option<&PathBuf>) -> PyResult<Arc<ColourTable>> {
    static TABLES: OnceLock<Mutex<HashMap<Option<PathBuf>, Arc<ColourTable>>>> = OnceLock::new();
    let map = TABLES.get_or_init(Mutex::default);
    let mut map = map.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(t) = map.get(&ldraw_dir.cloned()) {
        return Ok(t.clone());
    }
    let t = Arc::new(match ldraw_dir {
        None => ColourTable::builtin(),
        Some(root) => ColourTable::load(root).py()?,
    });
    map.insert(ldraw_dir.cloned(), t.clone());
    Ok(t)
}

/// RGB of an LDraw colour code (built-in table, or the LDConfig.ldr of `ldraw_dir`).
#[pyfunction]
#[pyo3(signature = (code, ldraw_dir=None))]
fn colour_rgb(code: i32, ldraw_dir: Option<PathBuf>) -> PyResult<(u8, u8, u8)> {
    let c = colour_table(ldraw_dir.as_ref())?.rgb(code);
    Ok((c[0], c[1], c[2]))
}

/// The result of `render` (a frozen wrapper over the core's `Rendered`): `rgb` (H, W, 3) uint8,
/// `rgb_unlined` the same without outlines (None unless `render(..., unlined=True)`),
/// `depth` (H, W) float32 (inf on the background), `ids` (H, W) int32 instance ids (-1
/// background), and per instance id (0 to the largest id drawn) `visible_fraction` float32,
/// `visible_pixels` and `total_pixels` uint64 (supersampled counts). The arrays are made once, when the rendering is,
/// and are read-only: every access returns the same array, so a caller that wants to draw on one
/// copies it first.
#[pyclass(name = "Rendering", module = "mepnet._brickgeom", frozen)]
pub struct PyRendering {
    width: u32,
    height: u32,
    rgb: Py<PyArray3<u8>>,
    rgb_unlined: Option<Py<PyArray3<u8>>>,
    depth: Py<PyArray2<f32>>,
    ids: Py<PyArray2<i32>>,
    visible_fraction: Py<PyArray1<f32>>,
    visible_pixels: Py<PyArray1<u64>>,
    total_pixels: Py<PyArray1<u64>>,
}

/// A numpy array that Python code cannot write to (the owner is frozen).
fn read_only<'py, T, D>(array: Bound<'py, PyArray<T, D>>) -> PyResult<Py<PyArray<T, D>>> {
    array.call_method1("setflags", (false,))?;
    Ok(array.unbind())
}

impl PyRendering {
    fn new(py: Python<'_>, r: Rendered) -> PyResult<Self> {
        let (h, w) = (r.height as usize, r.width as usize);
        let visible_fraction = Array1::from(r.visible_fraction());
        // The core returns `height * width` pixels (times 3 for rgb), so the shapes fit.
        let shape_error = |e: ndarray::ShapeError| PyValueError::new_err(e.to_string());
        let rgb_unlined = if r.rgb_unlined.is_empty() {
            None
        } else {
            Some(read_only(
                Array3::from_shape_vec((h, w, 3), r.rgb_unlined)
                    .map_err(shape_error)?
                    .into_pyarray(py),
            )?)
        };
        Ok(PyRendering {
            width: r.width,
            height: r.height,
            rgb_unlined,
            rgb: read_only(
                Array3::from_shape_vec((h, w, 3), r.rgb)
                    .map_err(shape_error)?
                    .into_pyarray(py),
            )?,
            depth: read_only(
                Array2::from_shape_vec((h, w), r.depth)
                    .map_err(shape_error)?
                    .into_pyarray(py),
            )?,
            ids: read_only(
                Array2::from_shape_vec((h, w), r.ids)
                    .map_err(shape_error)?
                    .into_pyarray(py),
            )?,
            visible_fraction: read_only(visible_fraction.into_pyarray(py))?,
            visible_pixels: read_only(Array1::from(r.visible_samples).into_pyarray(py))?,
            total_pixels: read_only(Array1::from(r.total_samples).into_pyarray(py))?,
        })
    }
}

#[pymethods]
impl PyRendering {
    #[getter]
    fn width(&self) -> u32 {
        self.width
    }
    #[getter]
    fn height(&self) -> u32 {
        self.height
    }
    #[getter]
    fn rgb<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<u8>> {
        self.rgb.bind(py).clone()
    }
    #[getter]
    fn rgb_unlined<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray3<u8>>> {
        self.rgb_unlined.as_ref().map(|a| a.bind(py).clone())
    }
    #[getter]
    fn depth<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f32>> {
        self.depth.bind(py).clone()
    }
    #[getter]
    fn ids<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i32>> {
        self.ids.bind(py).clone()
    }
    #[getter]
    fn visible_fraction<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f32>> {
        self.visible_fraction.bind(py).clone()
    }
    #[getter]
    fn visible_pixels<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        self.visible_pixels.bind(py).clone()
    }
    #[getter]
    fn total_pixels<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        self.total_pixels.bind(py).clone()
    }
    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "Rendering(width={}, height={}, instance_ids={})",
            self.width,
            self.height,
            PyUntypedArrayMethods::len(self.visible_fraction.bind(py))
        )
    }
}

/// Per-instance marks from the ids drawn as new and as old (new wins where both list an id).
fn marks_of(new_ids: &[u32], old_ids: &[u32]) -> PyResult<Vec<Mark>> {
    // ids are instance ids of one assembly; far beyond any real one is a caller's mistake
    const MAX_ID: u32 = 1 << 24;
    let top = new_ids.iter().chain(old_ids).copied().max();
    let Some(top) = top else {
        return Ok(Vec::new());
    };
    if top >= MAX_ID {
        return Err(PyValueError::new_err(format!(
            "instance id {top} in new_ids/old_ids is beyond any assembly's"
        )));
    }
    let mut marks = vec![Mark::Plain; top as usize + 1];
    for &i in old_ids {
        marks[i as usize] = Mark::Old;
    }
    for &i in new_ids {
        marks[i as usize] = Mark::New;
    }
    Ok(marks)
}

/// Render an assembly (see `Rendering` for what comes back). `style`: a `RenderStyle` (or its
/// dict); the settings it fixes (line width, anti-aliasing) replace `line_px` and
/// `supersample`. `new_ids` are drawn as added in this step (the style's highlight), `old_ids`
/// as added before (the style's fade); ids and depth never depend on the style. `unlined`: the
/// colours without outlines too (`Rendering.rgb_unlined`, from the same pass).
#[pyfunction]
#[pyo3(signature = (assembly, camera, width, height, supersample=1, line_px=None, ldraw_dir=None, style=None, new_ids=None, old_ids=None, unlined=false))]
#[allow(clippy::too_many_arguments)]
fn render(
    py: Python<'_>,
    assembly: &PyAssembly,
    camera: &PyCamera,
    width: u32,
    height: u32,
    supersample: u32,
    line_px: Option<f32>,
    ldraw_dir: Option<PathBuf>,
    style: Option<&Bound<'_, PyAny>>,
    new_ids: Option<Vec<u32>>,
    old_ids: Option<Vec<u32>>,
    unlined: bool,
) -> PyResult<PyRendering> {
    let mut opts = RenderOptions::new(width, height);
    opts.supersample = supersample;
    opts.unlined = unlined;
    if let Some(l) = line_px {
        opts.line_px = l;
    }
    PyRenderStyle::from_arg(style)?.apply(&mut opts);
    let marks = marks_of(
        new_ids.as_deref().unwrap_or(&[]),
        old_ids.as_deref().unwrap_or(&[]),
    )?;
    let colours = colour_table(ldraw_dir.as_ref())?;
    let src = source(ldraw_dir);
    let asm = &assembly.inner;
    let cam = camera.inner;
    let r = detach_core(py, || {
        render_assembly_marked(asm, &cam, &opts, &colours, &src, &marks)
    })?;
    PyRendering::new(py, r)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyCamera>()?;
    m.add_class::<PyRendering>()?;
    m.add_function(wrap_pyfunction!(colour_rgb, m)?)?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    Ok(())
}
