//! Library, components and assemblies.

use std::sync::Arc;

use brickgeom::component::{Brick, MAIN_COLOUR};
use brickgeom::{library, Assembly, AttachKind, Component, GroundSearch, Lattice, Pose};
use ndarray::{Array1, Array2};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::{detach_core, IntoPyResult, InvalidArgumentError};

type Int3 = (i32, i32, i32);

fn lat(t: Int3) -> Lattice {
    [t.0, t.1, t.2]
}

fn tup(p: Lattice) -> Int3 {
    (p[0], p[1], p[2])
}

fn pose(yaw: i64, t: Int3) -> PyResult<Pose> {
    if !(0..=3).contains(&yaw) {
        return Err(InvalidArgumentError::new_err(format!(
            "yaw must be 0..=3 quarter turns, got {yaw}"
        )));
    }
    Ok(Pose::new(yaw as u8, lat(t)))
}

/// (N, 3) int32 array from lattice points.
/// Lattice points as an (N, 3) array: built without the GIL where the list is long
/// ([`points_array`] hands it to numpy without a copy).
fn points_rows(points: impl ExactSizeIterator<Item = Lattice>) -> Array2<i32> {
    let n = points.len();
    let flat: Vec<i32> = points.flat_map(|p| p.into_iter()).collect();
    Array2::from_shape_vec((n, 3), flat).expect("length is 3 * points")
}

fn points_array<'py>(py: Python<'py>, points: &[Lattice]) -> Bound<'py, PyArray2<i32>> {
    points_rows(points.iter().copied()).into_pyarray(py)
}

fn mesh_arrays<'py>(
    py: Python<'py>,
    mesh: &brickgeom::Mesh,
) -> (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<u32>>) {
    let v: Vec<f32> = mesh
        .vertices
        .iter()
        .flat_map(|p| p.iter().copied())
        .collect();
    let t: Vec<u32> = mesh
        .triangles
        .iter()
        .flat_map(|p| p.iter().copied())
        .collect();
    (
        Array2::from_shape_vec((mesh.vertices.len(), 3), v)
            .expect("3 per vertex")
            .into_pyarray(py),
        Array2::from_shape_vec((mesh.triangles.len(), 3), t)
            .expect("3 per triangle")
            .into_pyarray(py),
    )
}

/// Canonical ids of the library parts, in table order.
#[pyfunction]
fn part_ids() -> Vec<&'static str> {
    library().ids()
}

/// The canonical library id of a part reference or alias ("3070B.dat" -> "3070b"), or None.
#[pyfunction]
fn resolve_part(id: &str) -> Option<&'static str> {
    library().resolve(id)
}

/// A dict describing a library part: id, name, category, symmetry, keypoint, voxels, studs,
/// anti_studs ((N, 3) int32 lattice arrays).
#[pyfunction]
fn part_info<'py>(py: Python<'py>, id: &str) -> PyResult<Bound<'py, PyDict>> {
    let p = library().get(id).py()?;
    let d = PyDict::new(py);
    d.set_item("id", p.id)?;
    d.set_item("name", p.name)?;
    d.set_item("category", p.category.name())?;
    d.set_item("symmetry", p.symmetry)?;
    d.set_item("keypoint", (p.keypoint[0], p.keypoint[1], p.keypoint[2]))?;
    d.set_item("voxels", points_array(py, &p.voxels))?;
    d.set_item("studs", points_array(py, &p.studs))?;
    d.set_item("anti_studs", points_array(py, &p.anti_studs))?;
    Ok(d)
}

/// `(vertices (V, 3) float32 LDU y-up, triangles (T, 3) uint32)` of a library part's mesh.
#[pyfunction]
fn part_mesh<'py>(
    py: Python<'py>,
    id: &str,
) -> PyResult<(Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<u32>>)> {
    let p = library().get(id).py()?;
    Ok(mesh_arrays(py, &p.mesh))
}

/// A placeable component: a primitive part, or a submodule made of placed bricks.
#[pyclass(name = "Component", module = "mepnet._brickgeom", frozen)]
#[derive(Clone)]
pub struct PyComponent {
    pub inner: Arc<Component>,
}

#[pymethods]
impl PyComponent {
    /// The component of one library part (id or alias).
    #[staticmethod]
    fn primitive(id: &str) -> PyResult<Self> {
        Ok(PyComponent {
            inner: Arc::new(Component::primitive(id).py()?),
        })
    }

    /// A submodule from parts and their poses: `poses` is an (N, 4) int array of
    /// `[yaw, x, y, z]` rows in the submodule's frame; `colours` LDraw codes (default 16, the
    /// colour the submodule is placed with).
    #[staticmethod]
    #[pyo3(signature = (name, parts, poses, colours=None))]
    fn from_bricks(
        name: &str,
        parts: Vec<String>,
        poses: PyReadonlyArray2<'_, i64>,
        colours: Option<Vec<i32>>,
    ) -> PyResult<Self> {
        if let Some(c) = &colours {
            if c.len() != parts.len() {
                return Err(PyValueError::new_err(format!(
                    "colours has {} entries for {} parts",
                    c.len(),
                    parts.len()
                )));
            }
        }
        let a = poses.as_array();
        if a.ncols() != 4 || a.nrows() != parts.len() {
            return Err(PyValueError::new_err(format!(
                "poses must have shape ({}, 4) = [yaw, x, y, z] per part, got {:?}",
                parts.len(),
                a.shape()
            )));
        }
        let mut bricks = Vec::with_capacity(parts.len());
        for (i, id) in parts.iter().enumerate() {
            let part = library().get(id).py()?.id;
            let row = a.row(i);
            let coords: Vec<i32> = (1..4)
                .map(|j| i32::try_from(row[j]))
                .collect::<Result<_, _>>()
                .map_err(|_| {
                    PyValueError::new_err(format!("pose {i} has a coordinate beyond int32"))
                })?;
            bricks.push(Brick {
                part,
                pose: pose(row[0], (coords[0], coords[1], coords[2]))?,
                colour: colours.as_ref().map_or(MAIN_COLOUR, |c| c[i]),
            });
        }
        Ok(PyComponent {
            inner: Arc::new(Component::from_bricks(name.to_string(), bricks).py()?),
        })
    }

    /// A submodule from placed components `(component, yaw, (x, y, z), colour)` in its own
    /// frame: every brick of every component placed with it; a brick in LDraw's main colour 16
    /// takes the colour its component is placed with (the one colour rule, in the core).
    #[staticmethod]
    fn from_placed(
        name: &str,
        placed: Vec<(PyRef<'_, PyComponent>, i64, Int3, i32)>,
    ) -> PyResult<Self> {
        let mut items = Vec::with_capacity(placed.len());
        for (c, yaw, t, colour) in &placed {
            items.push((c.inner.as_ref(), pose(*yaw, *t)?, *colour));
        }
        Ok(PyComponent {
            inner: Arc::new(Component::from_placed(name.to_string(), items).py()?),
        })
    }

    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }

    #[getter]
    fn is_submodule(&self) -> bool {
        self.inner.is_submodule
    }

    #[getter]
    fn symmetry(&self) -> u8 {
        self.inner.symmetry
    }

    /// Occupied voxels, (N, 3) int32.
    #[getter]
    fn voxels<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i32>> {
        points_array(py, &self.inner.voxels)
    }

    /// Exposed stud points, (N, 3) int32.
    #[getter]
    fn studs<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i32>> {
        points_array(py, &self.inner.studs)
    }

    /// Exposed anti-stud points, (N, 3) int32.
    #[getter]
    fn anti_studs<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i32>> {
        points_array(py, &self.inner.anti_studs)
    }

    /// Indices of the topmost bricks in `bricks`.
    #[getter]
    fn topmost(&self) -> Vec<usize> {
        self.inner.topmost.clone()
    }

    /// `[(part_id, yaw, (x, y, z), colour), ...]` in the component frame.
    #[getter]
    fn bricks(&self) -> Vec<(&'static str, u8, Int3, i32)> {
        self.inner
            .bricks
            .iter()
            .map(|b| (b.part, b.pose.yaw, tup(b.pose.t), b.colour))
            .collect()
    }

    /// Keypoints of the topmost bricks, (K, 3) float32 LDU y-up.
    #[getter]
    fn keypoints<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f32>> {
        let k = self.inner.keypoints();
        let flat: Vec<f32> = k.iter().flat_map(|p| p.iter().copied()).collect();
        Array2::from_shape_vec((k.len(), 3), flat)
            .expect("3 per keypoint")
            .into_pyarray(py)
    }

    /// `(vertices, triangles)` of the union mesh in the component frame.
    fn mesh<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<u32>>) {
        let m = py.detach(|| self.inner.mesh());
        mesh_arrays(py, &m)
    }

    /// True when two poses place this component identically (pose equality modulo symmetry).
    fn same_placement(&self, yaw_a: i64, t_a: Int3, yaw_b: i64, t_b: Int3) -> PyResult<bool> {
        Ok(self
            .inner
            .same_placement(&pose(yaw_a, t_a)?, &pose(yaw_b, t_b)?))
    }

    /// `same_placement` blind to faces drawn unlike their opposite (2877's grille): the same
    /// shape in the same place, whichever way such a face looks. What the evaluation scores.
    fn same_shape(&self, yaw_a: i64, t_a: Int3, yaw_b: i64, t_b: Int3) -> PyResult<bool> {
        Ok(self
            .inner
            .same_shape(&pose(yaw_a, t_a)?, &pose(yaw_b, t_b)?))
    }

    fn __repr__(&self) -> String {
        format!(
            "Component({:?}, submodule={}, bricks={}, symmetry={})",
            self.inner.name,
            self.inner.is_submodule,
            self.inner.bricks.len(),
            self.inner.symmetry
        )
    }
}

fn ground_search(ground: Option<&Bound<'_, PyAny>>) -> PyResult<GroundSearch> {
    let Some(g) = ground else {
        return Ok(GroundSearch::Off);
    };
    if let Ok(s) = g.extract::<String>() {
        return match s.as_str() {
            "auto" => Ok(GroundSearch::Auto),
            "off" => Ok(GroundSearch::Off),
            _ => Err(PyValueError::new_err(format!(
                "ground must be 'auto', 'off', None or (x0, x1, z0, z1), got {s:?}"
            ))),
        };
    }
    let (x0, x1, z0, z1): (i32, i32, i32, i32) = g.extract().map_err(|_| {
        PyValueError::new_err("ground must be 'auto', 'off', None or (x0, x1, z0, z1)")
    })?;
    if x1 < x0 || z1 < z0 || (x1 - x0) as i64 * (z1 - z0) as i64 > 4_000_000 {
        return Err(PyValueError::new_err(format!(
            "ground region ({x0}, {x1}, {z0}, {z1}) is empty or larger than 4e6 positions"
        )));
    }
    Ok(GroundSearch::Region { x0, x1, z0, z1 })
}

/// Placed components on the lattice with exact collision and connection rules.
#[pyclass(name = "Assembly", module = "mepnet._brickgeom")]
#[derive(Clone, Default)]
pub struct PyAssembly {
    pub inner: Assembly,
}

#[pymethods]
impl PyAssembly {
    #[new]
    fn new() -> Self {
        PyAssembly::default()
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn copy(&self) -> Self {
        self.clone()
    }

    /// Place a component (collision and ground checked, connection not required) with an
    /// LDraw colour code; returns its id.
    #[pyo3(signature = (component, yaw, t, colour=16))]
    fn add(&mut self, component: &PyComponent, yaw: i64, t: Int3, colour: i32) -> PyResult<u32> {
        let id = self
            .inner
            .add(component.inner.clone(), pose(yaw, t)?)
            .py()?;
        self.inner.set_colour(id, colour).py()?;
        Ok(id)
    }

    /// The LDraw colour code of an instance.
    fn colour(&self, id: u32) -> PyResult<i32> {
        Ok(self.inner.instance(id).py()?.colour)
    }

    /// Place a component only if it is valid; returns `(id, attach_kind)`.
    fn add_checked(
        &mut self,
        component: &PyComponent,
        yaw: i64,
        t: Int3,
    ) -> PyResult<(u32, &'static str)> {
        let (id, kind) = self
            .inner
            .add_checked(component.inner.clone(), pose(yaw, t)?)
            .py()?;
        Ok((id, kind.name()))
    }

    /// Remove an instance by id; returns `(component, yaw, t)`.
    fn remove(&mut self, id: u32) -> PyResult<(PyComponent, u8, Int3)> {
        let inst = self.inner.remove(id).py()?;
        Ok((
            PyComponent {
                inner: inst.component,
            },
            inst.pose.yaw,
            tup(inst.pose.t),
        ))
    }

    /// `[(id, component, yaw, t), ...]` of every placed instance.
    fn instances(&self) -> Vec<(u32, PyComponent, u8, Int3)> {
        self.inner
            .instances()
            .map(|(id, i)| {
                (
                    id,
                    PyComponent {
                        inner: i.component.clone(),
                    },
                    i.pose.yaw,
                    tup(i.pose.t),
                )
            })
            .collect()
    }

    /// The attach kind of a valid placement; raises a `PlacementError` subclass otherwise.
    fn check(&self, component: &PyComponent, yaw: i64, t: Int3) -> PyResult<&'static str> {
        Ok(self
            .inner
            .check(&component.inner, &pose(yaw, t)?)
            .py()?
            .name())
    }

    /// Validity of many poses of one component: `poses` is (N, 4) int `[yaw, x, y, z]`; returns
    /// (N,) int8 codes: 0 on_studs, 1 from_below, 2 ground, -1 collision, -2 not connected,
    /// -3 below ground or out of range.
    fn check_many<'py>(
        &self,
        py: Python<'py>,
        component: &PyComponent,
        poses: PyReadonlyArray2<'py, i64>,
    ) -> PyResult<Bound<'py, PyArray1<i8>>> {
        let a = poses.as_array();
        if a.ncols() != 4 {
            return Err(PyValueError::new_err(format!(
                "poses must have shape (N, 4) = [yaw, x, y, z] per row, got {:?}",
                a.shape()
            )));
        }
        let mut list = Vec::with_capacity(a.nrows());
        for row in a.rows() {
            let c: Vec<i32> = (1..4)
                .map(|j| row[j].clamp(i32::MIN as i64, i32::MAX as i64) as i32)
                .collect();
            list.push(pose(row[0], (c[0], c[1], c[2]))?);
        }
        let comp = component.inner.clone();
        let res = py.detach(|| self.inner.check_many(&comp, &list));
        let codes: Array1<i8> = res
            .into_iter()
            .map(|r| match r {
                Ok(k) => k as i8,
                Err(brickgeom::BrickGeomError::Collision { .. }) => -1,
                Err(brickgeom::BrickGeomError::NotConnected) => -2,
                Err(_) => -3,
            })
            .collect();
        Ok(codes.into_pyarray(py))
    }

    /// Every way a placement connects (collision not checked).
    fn attach_kinds(
        &self,
        component: &PyComponent,
        yaw: i64,
        t: Int3,
    ) -> PyResult<Vec<&'static str>> {
        let p = pose(yaw, t)?;
        Ok(self
            .inner
            .attach_kinds(&component.inner, &p)
            .iter()
            .map(AttachKind::name)
            .collect())
    }

    /// Id of the first instance the placement overlaps, or None.
    fn collision(&self, component: &PyComponent, yaw: i64, t: Int3) -> PyResult<Option<u32>> {
        Ok(self.inner.collision(&component.inner, &pose(yaw, t)?))
    }

    /// Free studs, (N, 3) int32 lattice points.
    fn free_studs<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i32>> {
        let s = py.detach(|| self.inner.free_studs());
        points_array(py, &s)
    }

    /// Free anti-studs, (N, 3) int32 lattice points.
    fn free_anti_studs<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i32>> {
        let s = py.detach(|| self.inner.free_anti_studs());
        points_array(py, &s)
    }

    /// `((x0, y0, z0), (x1, y1, z1))` inclusive occupied cell bounds, or None when empty.
    fn bounds(&self) -> Option<(Int3, Int3)> {
        self.inner.bounds().map(|(lo, hi)| (tup(lo), tup(hi)))
    }

    /// `(grid, origin)`: uint8 occupancy over [lo, hi] (default: the occupied bounds), indexed
    /// `[x - origin.x, y - origin.y, z - origin.z]`.
    #[pyo3(signature = (lo=None, hi=None))]
    fn occupancy<'py>(
        &self,
        py: Python<'py>,
        lo: Option<Int3>,
        hi: Option<Int3>,
    ) -> PyResult<(Bound<'py, PyArray3<u8>>, Int3)> {
        let (lo, hi) = self.window(lo, hi)?;
        let g = py.detach(|| self.inner.occupancy(lo, hi));
        Ok((g.into_pyarray(py), tup(lo)))
    }

    /// `(grid, origin)`: int32 instance ids (-1 = empty), same indexing as `occupancy`.
    #[pyo3(signature = (lo=None, hi=None))]
    fn brick_ids<'py>(
        &self,
        py: Python<'py>,
        lo: Option<Int3>,
        hi: Option<Int3>,
    ) -> PyResult<(Bound<'py, PyArray3<i32>>, Int3)> {
        let (lo, hi) = self.window(lo, hi)?;
        let g = py.detach(|| self.inner.id_grid(lo, hi));
        Ok((g.into_pyarray(py), tup(lo)))
    }

    /// Every valid placement of `component` at `yaw`: `(translations (N, 3) int32, kinds)` with
    /// kinds as uint8 codes 0 on_studs, 1 from_below, 2 ground. `ground`: None/'off' (no ground
    /// placements), 'auto' (around the current footprint) or (x0, x1, z0, z1).
    #[pyo3(signature = (component, yaw, ground=None))]
    fn candidates<'py>(
        &self,
        py: Python<'py>,
        component: &PyComponent,
        yaw: i64,
        ground: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<(Bound<'py, PyArray2<i32>>, Bound<'py, PyArray1<u8>>)> {
        let g = ground_search(ground)?;
        let yaw = pose(yaw, (0, 0, 0))?.yaw;
        let comp = component.inner.clone();
        // The arrays are built without the GIL too: a huge region gives millions of rows, and
        // into_pyarray then hands the owned buffers to numpy without copying.
        let (ts, kinds) = detach_core(py, || {
            let found = self.inner.candidates(&comp, yaw, g)?;
            let ts = points_rows(found.iter().map(|p| p.pose.t));
            let kinds: Array1<u8> = found.iter().map(|p| p.kind as u8).collect();
            Ok((ts, kinds))
        })?;
        Ok((ts.into_pyarray(py), kinds.into_pyarray(py)))
    }

    /// Validity of a step `[(component, yaw, t), ...]`: per component its attach kind, or the
    /// error message when it cannot be placed. The assembly is unchanged.
    fn check_step<'py>(
        &self,
        py: Python<'py>,
        items: Vec<(Bound<'py, PyComponent>, i64, Int3)>,
    ) -> PyResult<Vec<(bool, String)>> {
        let mut list = Vec::with_capacity(items.len());
        for (c, yaw, t) in items {
            list.push((c.get().inner.clone(), pose(yaw, t)?));
        }
        let res = py.detach(|| self.inner.check_step(&list));
        Ok(res
            .into_iter()
            .map(|r| match r {
                Ok(k) => (true, k.name().to_string()),
                Err(e) => (false, e.to_string()),
            })
            .collect())
    }

    /// The whole assembly as a submodule component.
    fn to_component(&self, name: &str) -> PyResult<PyComponent> {
        Ok(PyComponent {
            inner: Arc::new(self.inner.to_component(name).py()?),
        })
    }

    /// True when both assemblies hold the same instances, cells and free connection points.
    fn same_state(&self, other: &PyAssembly) -> bool {
        self.inner.snapshot() == other.inner.snapshot()
    }
}

impl PyAssembly {
    fn window(&self, lo: Option<Int3>, hi: Option<Int3>) -> PyResult<(Lattice, Lattice)> {
        let (blo, bhi) = self.inner.bounds().unwrap_or(([0; 3], [-1, -1, -1]));
        let lo = lo.map(lat).unwrap_or(blo);
        let hi = hi.map(lat).unwrap_or(bhi);
        let cells: i64 = (0..3)
            .map(|a| (hi[a] as i64 - lo[a] as i64 + 1).max(0))
            .product();
        if cells > 512 * 512 * 512 {
            return Err(PyValueError::new_err(format!(
                "window {lo:?}..{hi:?} has {cells} cells (limit 512^3)"
            )));
        }
        Ok((lo, hi))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(part_ids, m)?)?;
    m.add_function(wrap_pyfunction!(resolve_part, m)?)?;
    m.add_function(wrap_pyfunction!(part_info, m)?)?;
    m.add_function(wrap_pyfunction!(part_mesh, m)?)?;
    m.add_class::<PyComponent>()?;
    m.add_class::<PyAssembly>()?;
    Ok(())
}
