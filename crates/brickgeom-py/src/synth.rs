//! The synthetic manual generator, as plain dicts and numpy images for `mepnet.synth`.

use std::path::PathBuf;

use brickgeom::camera::Camera;
use brickgeom::colours::ColourTable;
use brickgeom::raster::RenderOptions;
use brickgeom::scene::MeshSource;
use brickgeom::synth::{generate, render_build_with, Build, ComponentRef, StepImage, SynthConfig};
use brickgeom::{library, BrickGeomError};
use ndarray::{Array2, Array3};
use numpy::IntoPyArray;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::errors::{detach_core, IntoPyResult};
use crate::style::PyRenderStyle;

/// The options of the id images and annotations (the generator's size and anti-aliasing) and
/// of the step pictures (those, then what the style fixes).
fn step_options(cfg: &SynthConfig, style: &PyRenderStyle) -> (RenderOptions, RenderOptions) {
    let opts = RenderOptions {
        supersample: cfg.supersample,
        ..RenderOptions::new(cfg.image_size, cfg.image_size)
    };
    let mut look = opts;
    style.apply(&mut look);
    (opts, look)
}

/// Camera parameters as a dict (the `manual.json` form).
pub fn camera_dict<'py>(py: Python<'py>, c: &Camera) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("elevation", c.elevation)?;
    d.set_item("azimuth", c.azimuth)?;
    d.set_item("roll", c.roll)?;
    d.set_item("scale", c.scale)?;
    d.set_item("translation", c.translation)?;
    Ok(d)
}

fn config_from(d: Option<&Bound<'_, PyDict>>) -> PyResult<SynthConfig> {
    let mut c = SynthConfig::default();
    let Some(d) = d else {
        return Ok(c);
    };
    for (k, v) in d.iter() {
        let key: String = k.extract()?;
        // a value of the wrong type names its setting (the extraction error alone does not)
        let named = |e: PyErr| PyValueError::new_err(format!("setting '{key}': {e}"));
        match key.as_str() {
            "footprint" => c.footprint = v.extract().map_err(named)?,
            "height" => c.height = v.extract().map_err(named)?,
            "components" => c.components = v.extract().map_err(named)?,
            "rounds" => c.rounds = v.extract().map_err(named)?,
            "p_submodule" => c.p_submodule = v.extract().map_err(named)?,
            "p_stack" => c.p_stack = v.extract().map_err(named)?,
            "p_mirror_view" => c.p_mirror_view = v.extract().map_err(named)?,
            "submodule_bricks" => c.submodule_bricks = v.extract().map_err(named)?,
            "max_step_instances" => c.max_step_instances = v.extract().map_err(named)?,
            "max_step_types" => c.max_step_types = v.extract().map_err(named)?,
            "visibility" => c.visibility = v.extract().map_err(named)?,
            "elevation" => c.elevation = v.extract().map_err(named)?,
            "azimuth" => c.azimuth = v.extract().map_err(named)?,
            "fill" => c.fill = v.extract().map_err(named)?,
            "image_size" => c.image_size = v.extract().map_err(named)?,
            "supersample" => c.supersample = v.extract().map_err(named)?,
            "palette" => c.palette = v.extract().map_err(named)?,
            "parts" => {
                let ids: Vec<String> = v.extract().map_err(named)?;
                c.parts = ids
                    .iter()
                    .map(|p| library().get(p).map(|d| d.id))
                    .collect::<Result<_, BrickGeomError>>()
                    .py()?;
            }
            other => {
                return Err(PyValueError::new_err(format!(
                    "unknown generator setting '{other}'"
                )));
            }
        }
    }
    Ok(c)
}

/// The default generator settings as a dict.
#[pyfunction]
fn synth_default_config(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let c = SynthConfig::default();
    let d = PyDict::new(py);
    d.set_item("footprint", c.footprint)?;
    d.set_item("height", c.height)?;
    d.set_item("components", c.components)?;
    d.set_item("rounds", c.rounds)?;
    d.set_item("p_submodule", c.p_submodule)?;
    d.set_item("p_stack", c.p_stack)?;
    d.set_item("p_mirror_view", c.p_mirror_view)?;
    d.set_item("submodule_bricks", c.submodule_bricks)?;
    d.set_item("max_step_instances", c.max_step_instances)?;
    d.set_item("max_step_types", c.max_step_types)?;
    d.set_item("visibility", c.visibility)?;
    d.set_item("elevation", c.elevation)?;
    d.set_item("azimuth", c.azimuth)?;
    d.set_item("fill", c.fill)?;
    d.set_item("image_size", c.image_size)?;
    d.set_item("supersample", c.supersample)?;
    d.set_item("palette", c.palette)?;
    d.set_item("parts", c.parts)?;
    Ok(d)
}

fn build_dict<'py>(
    py: Python<'py>,
    b: &Build,
    images: Vec<StepImage>,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let insts = PyList::empty(py);
    for inst in &b.instances {
        let id = PyDict::new(py);
        match inst.cref {
            ComponentRef::Part(p) => id.set_item("part", p)?,
            ComponentRef::Submodule(k) => id.set_item("submodule", k)?,
        }
        id.set_item("yaw", inst.pose.yaw)?;
        id.set_item("t", inst.pose.t)?;
        id.set_item("colour", inst.colour)?;
        insts.append(id)?;
    }
    d.set_item("instances", insts)?;
    let steps = PyList::empty(py);
    for (step, img) in b.steps.iter().zip(images) {
        let sd = PyDict::new(py);
        sd.set_item("instances", &step.instances)?;
        let attach: Vec<&str> = step.attach.iter().map(|a| a.name()).collect();
        sd.set_item("attach", attach)?;
        sd.set_item("camera", camera_dict(py, &step.camera)?)?;
        let (h, w) = (img.height as usize, img.width as usize);
        sd.set_item(
            "rgb",
            Array3::from_shape_vec((h, w, 3), img.rgb)
                .expect("h*w*3")
                .into_pyarray(py),
        )?;
        sd.set_item(
            "ids",
            Array2::from_shape_vec((h, w), img.ids)
                .expect("h*w")
                .into_pyarray(py),
        )?;
        let views = PyList::empty(py);
        for v in img.instances {
            let vd = PyDict::new(py);
            vd.set_item("keypoints", v.keypoints)?;
            vd.set_item("box", v.bbox)?;
            vd.set_item("visible_fraction", v.visible_fraction)?;
            views.append(vd)?;
        }
        sd.set_item("views", views)?;
        steps.append(sd)?;
    }
    d.set_item("steps", steps)?;
    Ok(d)
}

/// Generate and render one manual: a dict {seed, config, main, submodules}. `main` and each
/// submodule's `build` hold `instances` (component, yaw, t, colour) and `steps` (instance
/// indices, attach kinds, camera, `rgb`/`ids` images, per-instance keypoints, box, visibility).
/// `style` (a `RenderStyle` or its dict) changes how the step images are drawn, never what the
/// manual holds nor its id images; each step's new instances are marked new, earlier ones old.
#[pyfunction]
#[pyo3(signature = (seed, config=None, ldraw_dir=None, style=None))]
fn synth_manual<'py>(
    py: Python<'py>,
    seed: u64,
    config: Option<&Bound<'py, PyDict>>,
    ldraw_dir: Option<PathBuf>,
    style: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let cfg = config_from(config)?;
    let (opts, look) = step_options(&cfg, &PyRenderStyle::from_arg(style)?);
    let (manual, main_imgs, sub_imgs) = detach_core(py, || {
        let src = match &ldraw_dir {
            None => MeshSource::builtin(),
            Some(r) => MeshSource::ldraw(r),
        };
        let colours = ColourTable::builtin();
        let m = generate(&cfg, seed)?;
        let main = render_build_with(&m.main, &opts, &look, &src, &colours)?;
        let subs = m
            .submodules
            .iter()
            .map(|s| render_build_with(&s.build, &opts, &look, &src, &colours))
            .collect::<Result<Vec<_>, _>>()?;
        Ok((m, main, subs))
    })?;
    let d = PyDict::new(py);
    d.set_item("seed", seed)?;
    d.set_item("image_size", cfg.image_size)?;
    d.set_item("visibility", cfg.visibility)?;
    d.set_item("main", build_dict(py, &manual.main, main_imgs)?)?;
    let subs = PyList::empty(py);
    for (s, imgs) in manual.submodules.iter().zip(sub_imgs) {
        let sd = PyDict::new(py);
        sd.set_item("name", &s.name)?;
        sd.set_item("symmetry", s.component.symmetry)?;
        let bricks = PyList::empty(py);
        for b in &s.component.bricks {
            let bd = PyDict::new(py);
            bd.set_item("part", b.part)?;
            bd.set_item("yaw", b.pose.yaw)?;
            bd.set_item("t", b.pose.t)?;
            bd.set_item("colour", b.colour)?;
            bricks.append(bd)?;
        }
        sd.set_item("bricks", bricks)?;
        sd.set_item("topmost", &s.component.topmost)?;
        sd.set_item("build", build_dict(py, &s.build, imgs)?)?;
        subs.append(sd)?;
    }
    d.set_item("submodules", subs)?;
    Ok(d)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(synth_manual, m)?)?;
    m.add_function(wrap_pyfunction!(synth_default_config, m)?)?;
    m.add_function(wrap_pyfunction!(render_plan, m)?)?;
    Ok(())
}

/// Render a given build (e.g. a real model converted to the lattice) the way generated manuals
/// are rendered. `instances`: `(component, ref, yaw, (x, y, z), colour)` with `ref` a part id
/// or a submodule index; `steps`: instance indices per step; `cameras`: one per step. Returns
/// the build dict of `synth_manual`, with `attach` computed against each step's base shape
/// ("unsupported" where a part is not connected or collides). `style` draws the pictures as
/// in `synth_manual`.
#[pyfunction]
#[pyo3(signature = (instances, steps, cameras, image_size, supersample=1, ldraw_dir=None, style=None))]
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
fn render_plan<'py>(
    py: Python<'py>,
    instances: Vec<(
        Bound<'py, crate::geom::PyComponent>,
        Bound<'py, PyAny>,
        i64,
        (i32, i32, i32),
        i32,
    )>,
    steps: Vec<Vec<usize>>,
    cameras: Vec<Bound<'py, crate::render::PyCamera>>,
    image_size: u32,
    supersample: u32,
    ldraw_dir: Option<PathBuf>,
    style: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    use brickgeom::synth::{PlacedInstance, SynthStep};
    use brickgeom::{AttachKind, Pose};
    if cameras.len() != steps.len() {
        return Err(PyValueError::new_err(format!(
            "{} cameras for {} steps",
            cameras.len(),
            steps.len()
        )));
    }
    let mut placed = Vec::with_capacity(instances.len());
    for (k, (comp, r, yaw, t, colour)) in instances.iter().enumerate() {
        let cref = if let Ok(i) = r.extract::<usize>() {
            ComponentRef::Submodule(i)
        } else {
            let id: String = r.extract()?;
            ComponentRef::Part(library().get(&id).py()?.id)
        };
        if !(0..=3).contains(yaw) {
            return Err(PyValueError::new_err(format!(
                "instance {k}: yaw {yaw} is not 0..=3"
            )));
        }
        placed.push(PlacedInstance {
            cref,
            component: comp.get().inner.clone(),
            pose: Pose::new(*yaw as u8, [t.0, t.1, t.2]),
            colour: *colour,
        });
    }
    for (s, step) in steps.iter().enumerate() {
        if let Some(&bad) = step.iter().find(|&&i| i >= placed.len()) {
            return Err(PyValueError::new_err(format!(
                "step {}: no instance {bad}",
                s + 1
            )));
        }
    }
    let build = Build {
        instances: placed,
        steps: steps
            .iter()
            .zip(&cameras)
            .map(|(ids, cam)| SynthStep {
                instances: ids.clone(),
                attach: vec![AttachKind::Ground; ids.len()],
                camera: cam.get().inner,
            })
            .collect(),
    };
    let cfg = SynthConfig {
        image_size,
        supersample,
        ..SynthConfig::default()
    };
    let (opts, look) = step_options(&cfg, &PyRenderStyle::from_arg(style)?);
    let (images, attach) = detach_core(py, || {
        let src = match &ldraw_dir {
            None => MeshSource::builtin(),
            Some(r) => MeshSource::ldraw(r),
        };
        let images = render_build_with(&build, &opts, &look, &src, &ColourTable::builtin())?;
        let attach: Vec<Vec<&str>> = build
            .step_checks()
            .into_iter()
            .map(|step| {
                step.into_iter()
                    .map(|r| r.map_or("unsupported", |k| k.name()))
                    .collect()
            })
            .collect();
        Ok((images, attach))
    })?;
    let d = build_dict(py, &build, images)?;
    let steps_list = d.get_item("steps")?.expect("build_dict sets steps");
    for (s, a) in steps_list.try_iter()?.zip(attach) {
        s?.set_item("attach", a)?;
    }
    Ok(d)
}
