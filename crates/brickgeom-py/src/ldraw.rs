//! LDraw files <-> plain Python dicts (the typed wrappers live in `mepnet/ldraw.py`).

use std::path::PathBuf;

use brickgeom::ldraw::{
    lattice_pose, ldraw_placement, load_part_geometry, parse_ldraw, read_ldraw, write_ldraw,
    write_ldraw_string, EmbeddedPart, LdrawFile, LdrawModel, LdrawRef,
};
use brickgeom::realmodel::{check_model_steps, ItemKind, LatticeFile};
use brickgeom::Pose;
use ndarray::Array2;
use numpy::IntoPyArray;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::errors::{detach_core, IntoPyResult, InvalidArgumentError};

type Mat = [[f64; 3]; 3];

fn file_to_dict<'py>(py: Python<'py>, f: &LdrawFile) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("name", &f.name)?;
    let models = PyList::empty(py);
    for m in &f.models {
        let md = PyDict::new(py);
        md.set_item("name", &m.name)?;
        md.set_item("title", &m.title)?;
        let steps = PyList::empty(py);
        for s in &m.steps {
            let refs = PyList::empty(py);
            for r in s {
                let rd = PyDict::new(py);
                rd.set_item("line", r.line)?;
                rd.set_item("colour", r.colour)?;
                rd.set_item("position", r.position)?;
                rd.set_item("matrix", r.matrix)?;
                rd.set_item("name", &r.name)?;
                rd.set_item("is_submodel", r.is_submodel)?;
                refs.append(rd)?;
            }
            steps.append(refs)?;
        }
        md.set_item("steps", steps)?;
        models.append(md)?;
    }
    d.set_item("models", models)?;
    let emb: Vec<(String, String)> = f
        .embedded_parts
        .iter()
        .map(|e| (e.name.clone(), e.text.clone()))
        .collect();
    d.set_item("embedded_parts", emb)?;
    Ok(d)
}

fn dict_to_file(d: &Bound<'_, PyDict>) -> PyResult<LdrawFile> {
    let get = |k: &str| -> PyResult<Bound<'_, PyAny>> {
        d.get_item(k)?
            .ok_or_else(|| PyValueError::new_err(format!("LDraw dict is missing '{k}'")))
    };
    let name: String = get("name")?.extract()?;
    let mut models = Vec::new();
    for m in get("models")?.try_iter()? {
        let m = m?;
        let m = m.cast::<PyDict>()?;
        let mget = |k: &str| -> PyResult<Bound<'_, PyAny>> {
            m.get_item(k)?
                .ok_or_else(|| PyValueError::new_err(format!("LDraw model dict is missing '{k}'")))
        };
        let mut steps = Vec::new();
        for s in mget("steps")?.try_iter()? {
            let mut refs = Vec::new();
            for r in s?.try_iter()? {
                let r = r?;
                let r = r.cast::<PyDict>()?;
                let rget = |k: &str| -> PyResult<Bound<'_, PyAny>> {
                    r.get_item(k)?.ok_or_else(|| {
                        PyValueError::new_err(format!("LDraw reference dict is missing '{k}'"))
                    })
                };
                refs.push(LdrawRef {
                    line: r
                        .get_item("line")?
                        .map(|v| v.extract())
                        .transpose()?
                        .unwrap_or(0),
                    colour: rget("colour")?.extract()?,
                    position: rget("position")?.extract()?,
                    matrix: rget("matrix")?.extract::<Mat>()?,
                    name: rget("name")?.extract()?,
                    is_submodel: rget("is_submodel")?.extract()?,
                });
            }
            steps.push(refs);
        }
        models.push(LdrawModel {
            name: mget("name")?.extract()?,
            title: m
                .get_item("title")?
                .map(|v| v.extract())
                .transpose()?
                .unwrap_or_default(),
            steps,
        });
    }
    let embedded_parts = match d.get_item("embedded_parts")? {
        None => Vec::new(),
        Some(v) => v
            .extract::<Vec<(String, String)>>()?
            .into_iter()
            .map(|(name, text)| EmbeddedPart { name, text })
            .collect(),
    };
    Ok(LdrawFile {
        name,
        models,
        embedded_parts,
    })
}

/// Read an .ldr/.mpd file into a dict tree: name, models[{name, title, steps[[ref]]}],
/// embedded_parts; each ref {line, colour, position, matrix, name, is_submodel} (LDraw frame).
#[pyfunction]
fn read_ldraw_dict<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let f = detach_core(py, || read_ldraw(&path))?;
    file_to_dict(py, &f)
}

/// Parse LDraw text (bytes) named `file_name` into a dict tree.
#[pyfunction]
fn parse_ldraw_dict<'py>(
    py: Python<'py>,
    data: &[u8],
    file_name: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let f = detach_core(py, || parse_ldraw(data, file_name))?;
    file_to_dict(py, &f)
}

/// Write a dict tree to `path` (atomically: temporary file, then rename).
#[pyfunction]
fn write_ldraw_dict(py: Python<'_>, path: PathBuf, file: &Bound<'_, PyDict>) -> PyResult<()> {
    let f = dict_to_file(file)?;
    detach_core(py, || write_ldraw(&path, &f))
}

/// The text a dict tree is written as.
#[pyfunction]
fn format_ldraw_dict(file: &Bound<'_, PyDict>) -> PyResult<String> {
    Ok(write_ldraw_string(&dict_to_file(file)?))
}

/// Every part of the main model with world placement: list of dicts {name, colour, position,
/// matrix, path, step, line}.
#[pyfunction]
fn flatten_ldraw<'py>(py: Python<'py>, file: &Bound<'py, PyDict>) -> PyResult<Bound<'py, PyList>> {
    let f = dict_to_file(file)?;
    let parts = py.detach(|| f.flatten());
    let out = PyList::empty(py);
    for p in parts {
        let d = PyDict::new(py);
        d.set_item("name", p.name)?;
        d.set_item("colour", p.colour)?;
        d.set_item("position", p.position)?;
        d.set_item("matrix", p.matrix)?;
        d.set_item("path", p.path)?;
        d.set_item("step", p.step)?;
        d.set_item("line", p.line)?;
        out.append(d)?;
    }
    Ok(out)
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

/// Resolve every model against the library and check each step's physical validity.
/// Returns per model a dict {name, placeable, steps: [{step, items, placeable, results}],
/// items: [[{name, kind, part, submodel, colour, yaw, t, off_lattice, non_yaw, line}]]} where
/// `results` is None when some item is not placeable, else per item `(ok, kind_or_error)`.
#[pyfunction]
fn check_ldraw<'py>(py: Python<'py>, file: &Bound<'py, PyDict>) -> PyResult<Bound<'py, PyList>> {
    let f = dict_to_file(file)?;
    let (lf, checks) = py.detach(|| {
        let lf = LatticeFile::new(&f);
        let checks: Vec<_> = (0..lf.models.len())
            .map(|m| check_model_steps(&lf, m))
            .collect();
        (lf, checks)
    });
    let out = PyList::empty(py);
    for (m, (model, check)) in lf.models.iter().zip(checks).enumerate() {
        let d = PyDict::new(py);
        d.set_item("name", &model.name)?;
        d.set_item("placeable", lf.placeable[m])?;
        d.set_item("offset", model.offset)?;
        let steps = PyList::empty(py);
        for s in check.py()? {
            let sd = PyDict::new(py);
            sd.set_item("step", s.step)?;
            sd.set_item("items", s.items)?;
            sd.set_item("placeable", s.placeable)?;
            let res: Option<Vec<(bool, String)>> = s.results.map(|r| {
                r.into_iter()
                    .map(|x| match x {
                        Ok(k) => (true, k.name().to_string()),
                        Err(e) => (false, e.to_string()),
                    })
                    .collect()
            });
            sd.set_item("results", res)?;
            sd.set_item("complete_base", s.complete_base)?;
            steps.append(sd)?;
        }
        d.set_item("steps", steps)?;
        let items = PyList::empty(py);
        for step in &model.steps {
            let row = PyList::empty(py);
            for it in step {
                let id = PyDict::new(py);
                id.set_item("name", &it.name)?;
                let (kind, part, sub) = match it.kind {
                    ItemKind::Part(p) => ("part", Some(p), None),
                    ItemKind::Submodel(s) => ("submodel", None, Some(s)),
                    ItemKind::Unknown => ("unknown", None, None),
                };
                id.set_item("kind", kind)?;
                id.set_item("part", part)?;
                id.set_item("submodel", sub)?;
                id.set_item("colour", it.colour)?;
                id.set_item("yaw", it.pose.yaw)?;
                id.set_item("t", (it.pose.t[0], it.pose.t[1], it.pose.t[2]))?;
                id.set_item("off_lattice", it.off_lattice)?;
                id.set_item("non_yaw", it.non_yaw)?;
                id.set_item("line", it.line)?;
                id.set_item("blocker", lf.blocker(it))?;
                row.append(id)?;
            }
            items.append(row)?;
        }
        d.set_item("items", items)?;
        out.append(d)?;
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
    m.add_function(wrap_pyfunction!(read_ldraw_dict, m)?)?;
    m.add_function(wrap_pyfunction!(parse_ldraw_dict, m)?)?;
    m.add_function(wrap_pyfunction!(write_ldraw_dict, m)?)?;
    m.add_function(wrap_pyfunction!(format_ldraw_dict, m)?)?;
    m.add_function(wrap_pyfunction!(flatten_ldraw, m)?)?;
    m.add_function(wrap_pyfunction!(lattice_pose_of, m)?)?;
    m.add_function(wrap_pyfunction!(ldraw_placement_of, m)?)?;
    m.add_function(wrap_pyfunction!(check_ldraw, m)?)?;
    m.add_function(wrap_pyfunction!(load_part_mesh, m)?)?;
    Ok(())
}
