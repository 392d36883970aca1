//! LDraw files as typed values: frozen pyclasses over the core's [`LdrawFile`], [`LdrawModel`]
//! and [`LdrawRef`] (read by the core or built in Python, checked by the reader's rules), the
//! world-placed parts of a flattened file ([`FlatPart`]) and per-model / per-step / per-item
//! validity ([`PyModelCheck`], [`StepCheck`], [`StepItem`]).
//!
//! A file's models and a model's steps are tuples of Python objects made on first access (or
//! kept from the constructor), so `f.models[1] is f.model("sub.ldr")` and each access after the
//! first costs nothing.

use std::hash::{Hash, Hasher};
use std::path::PathBuf;

use brickgeom::ldraw::{
    self as core, lattice_pose, ldraw_placement, load_part_geometry, normalise_name, EmbeddedPart,
    FlatPart, LdrawFile, LdrawModel, LdrawRef,
};
use brickgeom::realmodel::{check_model_steps, ItemKind, LatticeFile, StepCheck, StepItem};
use brickgeom::Pose;
use ndarray::Array2;
use numpy::IntoPyArray;
use pyo3::exceptions::PyIndexError;
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyTuple;

use crate::errors::{detach_core, IntoPyResult, InvalidArgumentError};

type Mat = [[f64; 3]; 3];
type Vec3 = (f64, f64, f64);

const IDENTITY: Mat = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

fn vec3(v: [f64; 3]) -> Vec3 {
    (v[0], v[1], v[2])
}

fn mat3(m: Mat) -> (Vec3, Vec3, Vec3) {
    (vec3(m[0]), vec3(m[1]), vec3(m[2]))
}

/// A type-1 line: a part or submodel placed with a colour and a transform (LDraw frame, y down).
/// Equality and hash ignore `line` (where it was read, not what it is).
#[pyclass(name = "LDrawRef", module = "mepnet._brickgeom", frozen, eq, hash)]
#[derive(Clone)]
pub struct PyLdrawRef {
    inner: LdrawRef,
}

impl PartialEq for PyLdrawRef {
    fn eq(&self, other: &Self) -> bool {
        self.inner == other.inner
    }
}

impl Hash for PyLdrawRef {
    // Consistent with equality: the fields compared exactly, floats left out (0.0 == -0.0).
    fn hash<H: Hasher>(&self, state: &mut H) {
        (&self.inner.name, self.inner.colour, self.inner.is_submodel).hash(state);
    }
}

#[pymethods]
impl PyLdrawRef {
    /// Raises `LDrawError` for what the reader would not read back: a blank name, a non-finite
    /// or huge number, a singular matrix.
    #[new]
    #[pyo3(signature = (name, colour=16, position=[0.0; 3], matrix=IDENTITY, is_submodel=false, line=0))]
    fn new(
        name: String,
        colour: i32,
        position: [f64; 3],
        matrix: Mat,
        is_submodel: bool,
        line: usize,
    ) -> PyResult<Self> {
        let inner = LdrawRef {
            line,
            colour,
            position,
            matrix,
            name,
            is_submodel,
        };
        inner.validate().py()?;
        Ok(Self { inner })
    }
    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }
    #[getter]
    fn colour(&self) -> i32 {
        self.inner.colour
    }
    #[getter]
    fn position(&self) -> Vec3 {
        vec3(self.inner.position)
    }
    #[getter]
    fn matrix(&self) -> (Vec3, Vec3, Vec3) {
        mat3(self.inner.matrix)
    }
    #[getter]
    fn is_submodel(&self) -> bool {
        self.inner.is_submodel
    }
    #[getter]
    fn line(&self) -> usize {
        self.inner.line
    }
    fn __repr__(&self) -> String {
        let r = &self.inner;
        format!(
            "LDrawRef({:?}, colour={}, position={:?}, matrix={:?}, is_submodel={}, line={})",
            r.name,
            r.colour,
            vec3(r.position),
            mat3(r.matrix),
            if r.is_submodel { "True" } else { "False" },
            r.line
        )
    }
}

/// One model (the main model or a submodel): its name, description and non-empty build steps.
#[pyclass(name = "LDrawModel", module = "mepnet._brickgeom", frozen, eq)]
pub struct PyLdrawModel {
    inner: LdrawModel,
    /// `steps` as a tuple of tuples of `LDrawRef`, made once.
    steps: PyOnceLock<Py<PyTuple>>,
}

impl PartialEq for PyLdrawModel {
    fn eq(&self, other: &Self) -> bool {
        self.inner == other.inner
    }
}

impl PyLdrawModel {
    fn wrap(inner: LdrawModel) -> Self {
        Self {
            inner,
            steps: PyOnceLock::new(),
        }
    }
}

#[pymethods]
impl PyLdrawModel {
    /// Raises `LDrawError` for a blank name or an empty step.
    #[new]
    #[pyo3(signature = (name, steps=Vec::new(), title=String::new()))]
    fn new(
        py: Python<'_>,
        name: String,
        steps: Vec<Vec<Bound<'_, PyLdrawRef>>>,
        title: String,
    ) -> PyResult<Self> {
        let inner = LdrawModel {
            name,
            title,
            steps: steps
                .iter()
                .map(|s| s.iter().map(|r| r.get().inner.clone()).collect())
                .collect(),
        };
        inner.validate().py()?;
        let rows = steps
            .into_iter()
            .map(|s| PyTuple::new(py, s))
            .collect::<PyResult<Vec<_>>>()?;
        let model = Self::wrap(inner);
        // A fresh lock: setting cannot fail.
        let _ = model.steps.set(py, PyTuple::new(py, rows)?.unbind());
        Ok(model)
    }
    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }
    #[getter]
    fn title(&self) -> &str {
        &self.inner.title
    }
    /// The build steps, each a tuple of the references added in it.
    #[getter]
    fn steps<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let steps = self.steps.get_or_try_init(py, || {
            let rows = self
                .inner
                .steps
                .iter()
                .map(|s| PyTuple::new(py, s.iter().map(|r| PyLdrawRef { inner: r.clone() })))
                .collect::<PyResult<Vec<_>>>()?;
            PyResult::Ok(PyTuple::new(py, rows)?.unbind())
        })?;
        Ok(steps.bind(py).clone())
    }
    fn __repr__(&self) -> String {
        let m = &self.inner;
        format!(
            "LDrawModel({:?}, title={:?}, steps=<{} steps, {} references>)",
            m.name,
            m.title,
            m.steps.len(),
            m.steps.iter().map(Vec::len).sum::<usize>()
        )
    }
}

/// A parsed (or built) .ldr/.mpd file: `models[0]` is the main model.
#[pyclass(name = "LDrawFile", module = "mepnet._brickgeom", frozen, eq)]
pub struct PyLdrawFile {
    inner: LdrawFile,
    /// `models` as a tuple of `LDrawModel`, made once.
    models: PyOnceLock<Py<PyTuple>>,
}

impl PartialEq for PyLdrawFile {
    fn eq(&self, other: &Self) -> bool {
        self.inner == other.inner
    }
}

impl PyLdrawFile {
    fn wrap(inner: LdrawFile) -> Self {
        Self {
            inner,
            models: PyOnceLock::new(),
        }
    }

    fn models_tuple<'py>(&self, py: Python<'py>) -> PyResult<&Bound<'py, PyTuple>> {
        let models = self.models.get_or_try_init(py, || {
            let models = self
                .inner
                .models
                .iter()
                .map(|m| PyLdrawModel::wrap(m.clone()));
            PyResult::Ok(PyTuple::new(py, models)?.unbind())
        })?;
        Ok(models.bind(py))
    }
}

#[pymethods]
impl PyLdrawFile {
    /// `embedded_parts`: `(name, text)` of parts defined inside an .mpd, written back verbatim.
    /// Raises `LDrawError` for an embedded part with a blank name.
    #[new]
    #[pyo3(signature = (name, models=Vec::new(), embedded_parts=Vec::new()))]
    fn new(
        py: Python<'_>,
        name: String,
        models: Vec<Bound<'_, PyLdrawModel>>,
        embedded_parts: Vec<(String, String)>,
    ) -> PyResult<Self> {
        let inner = LdrawFile {
            name,
            models: models.iter().map(|m| m.get().inner.clone()).collect(),
            embedded_parts: embedded_parts
                .into_iter()
                .map(|(name, text)| EmbeddedPart { name, text })
                .collect(),
        };
        inner.validate().py()?;
        let file = Self::wrap(inner);
        // A fresh lock: setting cannot fail.
        let _ = file.models.set(py, PyTuple::new(py, models)?.unbind());
        Ok(file)
    }
    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }
    #[getter]
    fn models<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        self.models_tuple(py).cloned()
    }
    #[getter]
    fn embedded_parts<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        PyTuple::new(
            py,
            self.inner
                .embedded_parts
                .iter()
                .map(|e| (e.name.as_str(), e.text.as_str())),
        )
    }
    /// The main model (`models[0]`); `IndexError` when the file has none.
    #[getter]
    fn main<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let models = self.models_tuple(py)?;
        if models.is_empty() {
            return Err(PyIndexError::new_err(format!(
                "LDraw file {:?} has no models",
                self.inner.name
            )));
        }
        models.get_item(0)
    }
    /// A model by name (case-insensitive, `\` and `/` alike), or None.
    fn model<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Option<Bound<'py, PyAny>>> {
        let key = normalise_name(name);
        let Some(i) = self
            .inner
            .models
            .iter()
            .position(|m| normalise_name(&m.name) == key)
        else {
            return Ok(None);
        };
        self.models_tuple(py)?.get_item(i).map(Some)
    }
    /// Every part of the main model with its world placement (LDraw frame), in file order.
    fn flatten(&self, py: Python<'_>) -> Vec<PyFlatPart> {
        flatten(py, &self.inner)
    }
    /// The file as LDraw text.
    fn to_text(&self, py: Python<'_>) -> String {
        let f = &self.inner;
        py.detach(|| core::write_ldraw_string(f))
    }
    fn __repr__(&self) -> String {
        let f = &self.inner;
        format!(
            "LDrawFile({:?}, models=<{} models>, embedded_parts=<{} parts>)",
            f.name,
            f.models.len(),
            f.embedded_parts.len()
        )
    }
}

/// A part of a flattened file: its world placement after composing every submodel transform
/// above it. Equality ignores `line`.
#[pyclass(name = "FlatPart", module = "mepnet._brickgeom", frozen, eq)]
#[derive(PartialEq)]
pub struct PyFlatPart {
    inner: FlatPart,
}

#[pymethods]
impl PyFlatPart {
    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }
    /// Colour after LDraw's inheritance through every submodel above it (`resolve_colour`):
    /// 16 and 24 stay as written only where nothing above sets a colour.
    #[getter]
    fn colour(&self) -> i32 {
        self.inner.colour
    }
    #[getter]
    fn position(&self) -> Vec3 {
        vec3(self.inner.position)
    }
    #[getter]
    fn matrix(&self) -> (Vec3, Vec3, Vec3) {
        mat3(self.inner.matrix)
    }
    /// Submodels from just below the main model down to the one holding the part.
    #[getter]
    fn path<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        PyTuple::new(py, &self.inner.path)
    }
    /// Index into `models[0].steps` of the main-model step holding the top-level reference.
    #[getter]
    fn step(&self) -> usize {
        self.inner.step
    }
    #[getter]
    fn line(&self) -> usize {
        self.inner.line
    }
    fn __repr__(&self) -> String {
        let p = &self.inner;
        format!(
            "FlatPart({:?}, colour={}, position={:?}, path={:?}, step={}, line={})",
            p.name,
            p.colour,
            vec3(p.position),
            p.path,
            p.step,
            p.line
        )
    }
}

fn flatten(py: Python<'_>, file: &LdrawFile) -> Vec<PyFlatPart> {
    py.detach(|| file.flatten())
        .into_iter()
        .map(|inner| PyFlatPart { inner })
        .collect()
}

/// One reference of a step resolved against the library: a library part, a submodel of the
/// file, or a part outside the library; its lattice pose in the model's own frame.
#[pyclass(name = "StepItem", module = "mepnet._brickgeom", frozen)]
pub struct PyStepItem {
    inner: StepItem,
    blocker: Option<String>,
}

#[pymethods]
impl PyStepItem {
    /// The name as referenced (normalised).
    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }
    /// `"part"`, `"submodel"` or `"unknown"` (a part outside the library).
    #[getter]
    fn kind(&self) -> &'static str {
        match self.inner.kind {
            ItemKind::Part(_) => "part",
            ItemKind::Submodel(_) => "submodel",
            ItemKind::Unknown => "unknown",
        }
    }
    /// The library part id, for a part.
    #[getter]
    fn part(&self) -> Option<&'static str> {
        match self.inner.kind {
            ItemKind::Part(p) => Some(p),
            _ => None,
        }
    }
    /// The index into the file's models, for a submodel.
    #[getter]
    fn submodel(&self) -> Option<usize> {
        match self.inner.kind {
            ItemKind::Submodel(m) => Some(m),
            _ => None,
        }
    }
    #[getter]
    fn colour(&self) -> i32 {
        self.inner.colour
    }
    #[getter]
    fn yaw(&self) -> u8 {
        self.inner.pose.yaw
    }
    #[getter]
    fn t(&self) -> (i32, i32, i32) {
        let t = self.inner.pose.t;
        (t[0], t[1], t[2])
    }
    #[getter]
    fn off_lattice(&self) -> bool {
        self.inner.off_lattice
    }
    #[getter]
    fn non_yaw(&self) -> bool {
        self.inner.non_yaw
    }
    #[getter]
    fn line(&self) -> usize {
        self.inner.line
    }
    /// Why the item cannot be placed as a component, or None when it can.
    #[getter]
    fn blocker(&self) -> Option<&str> {
        self.blocker.as_deref()
    }
    fn __repr__(&self) -> String {
        format!(
            "StepItem({:?}, kind={:?}, yaw={}, t={:?}, colour={}, line={}, blocker={:?})",
            self.inner.name,
            self.kind(),
            self.inner.pose.yaw,
            self.t(),
            self.inner.colour,
            self.inner.line,
            self.blocker
        )
    }
}

/// The physical validity of one step.
#[pyclass(name = "StepCheck", module = "mepnet._brickgeom", frozen)]
pub struct PyStepCheck {
    inner: StepCheck,
}

#[pymethods]
impl PyStepCheck {
    /// 1-based step number within its model.
    #[getter]
    fn step(&self) -> usize {
        self.inner.step
    }
    /// How many items the step has.
    #[getter]
    fn items(&self) -> usize {
        self.inner.items
    }
    /// How many of them are placeable components.
    #[getter]
    fn placeable(&self) -> usize {
        self.inner.placeable
    }
    /// Per item `(ok, attach kind or why it fails)` when every item is placeable, else None.
    #[getter]
    fn results<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyTuple>>> {
        let Some(results) = &self.inner.results else {
            return Ok(None);
        };
        let pairs = results.iter().map(|r| match r {
            Ok(kind) => (true, kind.name().to_string()),
            Err(e) => (false, e.to_string()),
        });
        PyTuple::new(py, pairs).map(Some)
    }
    /// Every item of this and all earlier steps is placeable, so "not connected" is a real
    /// finding (otherwise the part may rest on something outside the library).
    #[getter]
    fn complete_base(&self) -> bool {
        self.inner.complete_base
    }
    fn __repr__(&self) -> String {
        let s = &self.inner;
        let failed = s.results.as_ref().map_or("None".to_string(), |r| {
            r.iter().filter(|x| x.is_err()).count().to_string()
        });
        format!(
            "StepCheck(step={}, items={}, placeable={}, failed={}, complete_base={})",
            s.step,
            s.items,
            s.placeable,
            failed,
            if s.complete_base { "True" } else { "False" }
        )
    }
}

/// One model of a checked file: its lattice offset, whether every item is placeable, the items
/// of each step and the validity of each step.
#[pyclass(name = "ModelCheck", module = "mepnet._brickgeom", frozen)]
pub struct PyModelCheck {
    name: String,
    placeable: bool,
    offset: [f64; 3],
    /// Tuple of `StepCheck`, one per step.
    steps: Py<PyTuple>,
    /// Tuple (per step) of tuples of `StepItem`.
    items: Py<PyTuple>,
}

#[pymethods]
impl PyModelCheck {
    #[getter]
    fn name(&self) -> &str {
        &self.name
    }
    /// Every item, submodels included recursively, is a library part on the lattice.
    #[getter]
    fn placeable(&self) -> bool {
        self.placeable
    }
    /// Where the model's lattice sits in its LDraw frame (LDU, y down).
    #[getter]
    fn offset(&self) -> Vec3 {
        vec3(self.offset)
    }
    #[getter]
    fn steps<'py>(&self, py: Python<'py>) -> Bound<'py, PyTuple> {
        self.steps.bind(py).clone()
    }
    #[getter]
    fn items<'py>(&self, py: Python<'py>) -> Bound<'py, PyTuple> {
        self.items.bind(py).clone()
    }
    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "ModelCheck({:?}, placeable={}, steps=<{} steps>)",
            self.name,
            if self.placeable { "True" } else { "False" },
            self.steps.bind(py).len()
        )
    }
}

/// Read an .ldr/.mpd file (references in LDraw's y-down frame).
#[pyfunction(name = "read_ldraw")]
fn read_ldraw_py(py: Python<'_>, path: PathBuf) -> PyResult<PyLdrawFile> {
    detach_core(py, || core::read_ldraw(&path)).map(PyLdrawFile::wrap)
}

/// Parse LDraw text (bytes) named `file_name`.
#[pyfunction(name = "parse_ldraw")]
fn parse_ldraw_py(py: Python<'_>, data: &[u8], file_name: &str) -> PyResult<PyLdrawFile> {
    detach_core(py, || core::parse_ldraw(data, file_name)).map(PyLdrawFile::wrap)
}

/// Write a file to `path` (atomically: temporary file, then rename).
#[pyfunction(name = "write_ldraw")]
fn write_ldraw_py(py: Python<'_>, path: PathBuf, file: &PyLdrawFile) -> PyResult<()> {
    let f = &file.inner;
    detach_core(py, || core::write_ldraw(&path, f))
}

/// The text a file is written as.
#[pyfunction(name = "format_ldraw")]
fn format_ldraw_py(py: Python<'_>, file: &PyLdrawFile) -> String {
    file.to_text(py)
}

/// Every part of the main model with its world placement.
#[pyfunction]
fn flatten_ldraw(py: Python<'_>, file: &PyLdrawFile) -> Vec<PyFlatPart> {
    flatten(py, &file.inner)
}

/// LDraw's colour inheritance: the colour of a line written in `code` inside a file referenced
/// in colour `inherited` (16 -> `inherited`; 24 -> its edge colour as a direct colour
/// `0x2RRGGBB`, 24 while `inherited` is 16; any other code is the line's own).
#[pyfunction]
fn resolve_colour(code: i32, inherited: i32) -> i32 {
    brickgeom::colours::resolve_colour(code, inherited)
}

/// `(yaw, (x, y, z), off_lattice, non_yaw)` of an LDraw placement (y-down LDU, 3x3 matrix).
#[pyfunction]
fn lattice_pose_of(position: [f64; 3], matrix: Mat) -> (u8, (i32, i32, i32), bool, bool) {
    let lp = lattice_pose(position, matrix);
    let t = lp.pose.t;
    (lp.pose.yaw, (t[0], t[1], t[2]), lp.off_lattice, lp.non_yaw)
}

/// `(position, matrix)` in LDraw's frame of a lattice pose.
#[pyfunction]
fn ldraw_placement_of(yaw: i64, t: (i32, i32, i32)) -> PyResult<([f64; 3], Mat)> {
    if !(0..=3).contains(&yaw) {
        return Err(InvalidArgumentError::new_err(format!(
            "yaw must be 0..=3, got {yaw}"
        )));
    }
    Ok(ldraw_placement(Pose::new(yaw as u8, [t.0, t.1, t.2])))
}

/// Resolve every model against the library and check each step's physical validity: one
/// `ModelCheck` per model of the file.
#[pyfunction]
fn check_ldraw(py: Python<'_>, file: &PyLdrawFile) -> PyResult<Vec<PyModelCheck>> {
    let f = &file.inner;
    let (lf, checks) = py.detach(|| {
        let lf = LatticeFile::new(f);
        let checks: Vec<_> = (0..lf.models.len())
            .map(|m| check_model_steps(&lf, m))
            .collect();
        (lf, checks)
    });
    let mut out = Vec::with_capacity(lf.models.len());
    for (m, (model, check)) in lf.models.iter().zip(checks).enumerate() {
        let steps = check.py()?.into_iter().map(|inner| PyStepCheck { inner });
        let items = model
            .steps
            .iter()
            .map(|step| {
                let row = step.iter().map(|it| PyStepItem {
                    inner: it.clone(),
                    blocker: lf.blocker(it),
                });
                PyTuple::new(py, row)
            })
            .collect::<PyResult<Vec<_>>>()?;
        out.push(PyModelCheck {
            name: model.name.clone(),
            placeable: lf.placeable[m],
            offset: model.offset,
            steps: PyTuple::new(py, steps)?.unbind(),
            items: PyTuple::new(py, items)?.unbind(),
        });
    }
    Ok(out)
}

/// Real part geometry from an LDraw library root: `(vertices (V, 3) float32 LDU y-up,
/// triangles (T, 3) uint32, stud_count)`.
#[pyfunction]
#[allow(clippy::type_complexity)]
fn load_part_mesh<'py>(
    py: Python<'py>,
    root: PathBuf,
    id: &str,
) -> PyResult<(
    Bound<'py, numpy::PyArray2<f32>>,
    Bound<'py, numpy::PyArray2<u32>>,
    usize,
)> {
    let g = detach_core(py, || load_part_geometry(&root, id))?;
    let v: Vec<f32> = g
        .mesh
        .vertices
        .iter()
        .flat_map(|p| p.iter().copied())
        .collect();
    let t: Vec<u32> = g
        .mesh
        .triangles
        .iter()
        .flat_map(|p| p.iter().copied())
        .collect();
    Ok((
        Array2::from_shape_vec((g.mesh.vertices.len(), 3), v)
            .expect("3 per vertex")
            .into_pyarray(py),
        Array2::from_shape_vec((g.mesh.triangles.len(), 3), t)
            .expect("3 per triangle")
            .into_pyarray(py),
        g.stud_count,
    ))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyLdrawRef>()?;
    m.add_class::<PyLdrawModel>()?;
    m.add_class::<PyLdrawFile>()?;
    m.add_class::<PyFlatPart>()?;
    m.add_class::<PyStepItem>()?;
    m.add_class::<PyStepCheck>()?;
    m.add_class::<PyModelCheck>()?;
    m.add_function(wrap_pyfunction!(read_ldraw_py, m)?)?;
    m.add_function(wrap_pyfunction!(parse_ldraw_py, m)?)?;
    m.add_function(wrap_pyfunction!(write_ldraw_py, m)?)?;
    m.add_function(wrap_pyfunction!(format_ldraw_py, m)?)?;
    m.add_function(wrap_pyfunction!(flatten_ldraw, m)?)?;
    m.add_function(wrap_pyfunction!(resolve_colour, m)?)?;
    m.add_function(wrap_pyfunction!(lattice_pose_of, m)?)?;
    m.add_function(wrap_pyfunction!(ldraw_placement_of, m)?)?;
    m.add_function(wrap_pyfunction!(check_ldraw, m)?)?;
    m.add_function(wrap_pyfunction!(load_part_mesh, m)?)?;
    Ok(())
}
