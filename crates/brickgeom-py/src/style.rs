//! `RenderStyle`: how a picture is drawn (the core's `RenderStyle` plus the drawing options a
//! style sets: line width, page colour, anti-aliasing, stud and crease lines).

use brickgeom::raster::RenderOptions;
use brickgeom::render_style::{LineColour, LineMode, RenderStyle, Shading};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use crate::errors::{IntoPyResult, InvalidArgumentError};

type Rgb = (u8, u8, u8);

/// An (r, g, b) colour from any sequence of three integers 0..=255.
fn rgb_from(name: &str, v: &Bound<'_, PyAny>) -> PyResult<Rgb> {
    let bad = || {
        PyValueError::new_err(format!(
            "style {name} must be an (r, g, b) colour of 0..255"
        ))
    };
    let c: Vec<i64> = v.extract().map_err(|_| bad())?;
    match c[..] {
        [r, g, b] if [r, g, b].iter().all(|x| (0..=255).contains(x)) => {
            Ok((r as u8, g as u8, b as u8))
        }
        _ => Err(bad()),
    }
}

/// An f32 setting as the number it was written as (0.62, not 0.6200000047683716).
fn short(x: f32) -> f64 {
    x.to_string().parse().unwrap_or(x as f64)
}

fn rgb_list(c: [u8; 3]) -> Vec<u32> {
    c.iter().map(|&x| x as u32).collect()
}

/// Every setting, in the order of the constructor.
const SETTINGS: &[&str] = &[
    "light",
    "ambient",
    "diffuse",
    "shading",
    "specular",
    "shininess",
    "lines",
    "line_colour",
    "line_darken",
    "front_lines",
    "line_px",
    "saturation",
    "lighten",
    "highlight",
    "highlight_px",
    "fade",
    "background",
    "supersample",
    "plane_edge",
    "crease_cos",
];

/// A render style (frozen); every setting is keyword-only and optional, and the default is the
/// renderer's own look. `RenderStyle.from_dict(d)` and `to_dict()` convert from and to the
/// JSON form that `manual.json` records. Bad values raise `InvalidArgumentError` (out of range)
/// or `ValueError` (unknown names).
#[pyclass(name = "RenderStyle", module = "mepnet._brickgeom", frozen)]
#[derive(Clone)]
pub struct PyRenderStyle {
    pub style: RenderStyle,
    line_darken: f32,
    line_px: Option<f32>,
    background: Rgb,
    supersample: Option<u32>,
    plane_edge: f32,
    crease_cos: f32,
}

impl Default for PyRenderStyle {
    fn default() -> Self {
        let opts = RenderOptions::new(1, 1);
        PyRenderStyle {
            style: RenderStyle::default(),
            line_darken: 0.55,
            line_px: None,
            background: (opts.background[0], opts.background[1], opts.background[2]),
            supersample: None,
            plane_edge: opts.plane_edge,
            crease_cos: opts.crease_cos,
        }
    }
}

impl PyRenderStyle {
    /// Set the drawing options this style fixes (those it leaves open keep the caller's).
    pub fn apply(&self, opts: &mut RenderOptions) {
        opts.style = self.style;
        if let Some(l) = self.line_px {
            opts.line_px = l;
        }
        if let Some(s) = self.supersample {
            opts.supersample = s;
        }
        opts.background = [self.background.0, self.background.1, self.background.2];
        opts.plane_edge = self.plane_edge;
        opts.crease_cos = self.crease_cos;
    }

    /// A style from an optional `RenderStyle` or dict argument (None: the default).
    pub fn from_arg(arg: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        match arg {
            None => Ok(Self::default()),
            Some(a) if a.is_none() => Ok(Self::default()),
            Some(a) => {
                if let Ok(s) = a.cast::<PyRenderStyle>() {
                    return Ok(s.get().clone());
                }
                if let Ok(d) = a.cast::<PyDict>() {
                    return Self::from_mapping(d);
                }
                Err(PyValueError::new_err(format!(
                    "style must be a RenderStyle, a dict or None, got {}",
                    a.get_type().name()?
                )))
            }
        }
    }

    fn from_mapping(d: &Bound<'_, PyDict>) -> PyResult<Self> {
        for k in d.keys() {
            let key: String = k
                .extract()
                .map_err(|_| PyValueError::new_err("style setting names must be strings"))?;
            if !SETTINGS.contains(&key.as_str()) {
                return Err(PyValueError::new_err(format!(
                    "unknown style setting '{key}' (known: {})",
                    SETTINGS.join(", ")
                )));
            }
        }
        let py = d.py();
        let ty = py.get_type::<PyRenderStyle>();
        let made = match ty.call(PyTuple::empty(py), Some(d)) {
            Ok(m) => m,
            Err(e) if e.is_instance_of::<PyTypeError>(py) => {
                // a value of the wrong type: name its setting (the extraction error does not)
                for (k, v) in d.iter() {
                    let one = PyDict::new(py);
                    one.set_item(&k, &v)?;
                    if let Err(e1) = ty.call(PyTuple::empty(py), Some(&one)) {
                        if e1.is_instance_of::<PyTypeError>(py) {
                            return Err(PyValueError::new_err(format!(
                                "style setting '{}': {}",
                                k.str()?,
                                e1.value(py).str()?
                            )));
                        }
                    }
                }
                return Err(e);
            }
            Err(e) => return Err(e),
        };
        Ok(made.cast::<PyRenderStyle>()?.get().clone())
    }
}

fn line_colour_from(v: &Bound<'_, PyAny>, darken: f32) -> PyResult<LineColour> {
    if let Ok(name) = v.extract::<String>() {
        return match name.as_str() {
            "auto" => Ok(LineColour::Auto),
            "part" => Ok(LineColour::Part { darken }),
            other => Err(PyValueError::new_err(format!(
                "style line_colour must be 'auto', 'part' or an (r, g, b) colour, got '{other}'"
            ))),
        };
    }
    let c = rgb_from("line_colour", v).map_err(|_| {
        PyValueError::new_err(
            "style line_colour must be 'auto', 'part' or an (r, g, b) colour of 0..255",
        )
    })?;
    Ok(LineColour::Fixed([c.0, c.1, c.2]))
}

#[pymethods]
impl PyRenderStyle {
    #[new]
    #[pyo3(signature = (
        *,
        light=None,
        ambient=0.62,
        diffuse=0.38,
        shading="lambert",
        specular=0.0,
        shininess=16.0,
        lines="all",
        line_colour=None,
        line_darken=0.55,
        front_lines=false,
        line_px=None,
        saturation=1.0,
        lighten=0.0,
        highlight=None,
        highlight_px=2.0,
        fade=0.0,
        background=None,
        supersample=None,
        plane_edge=1.0,
        crease_cos=0.8,
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        light: Option<Vec<f64>>,
        ambient: f32,
        diffuse: f32,
        shading: &str,
        specular: f32,
        shininess: f32,
        lines: &str,
        line_colour: Option<&Bound<'_, PyAny>>,
        line_darken: f32,
        front_lines: bool,
        line_px: Option<f32>,
        saturation: f32,
        lighten: f32,
        highlight: Option<&Bound<'_, PyAny>>,
        highlight_px: f32,
        fade: f32,
        background: Option<&Bound<'_, PyAny>>,
        supersample: Option<u32>,
        plane_edge: f32,
        crease_cos: f32,
    ) -> PyResult<Self> {
        if !(0.0..=1.0).contains(&line_darken) {
            return Err(InvalidArgumentError::new_err(format!(
                "style line_darken must be within [0, 1], got {line_darken}"
            )));
        }
        let line_colour = match line_colour {
            None => LineColour::Auto,
            Some(v) => line_colour_from(v, line_darken)?,
        };
        let defaults = Self::default();
        let light = match light.as_deref() {
            None => defaults.style.light,
            Some(&[x, y, z]) => [x, y, z],
            Some(_) => {
                return Err(PyValueError::new_err(
                    "style light must be three numbers (x right, y up, z along the view)",
                ))
            }
        };
        let highlight = highlight.map(|c| rgb_from("highlight", c)).transpose()?;
        let background = match background {
            None => defaults.background,
            Some(c) => rgb_from("background", c)?,
        };
        let style = RenderStyle {
            light,
            ambient,
            diffuse,
            shading: Shading::from_name(shading).py()?,
            specular,
            shininess,
            lines: LineMode::from_name(lines).py()?,
            line_colour,
            front_lines,
            saturation,
            lighten,
            highlight: highlight.map(|c| [c.0, c.1, c.2]),
            highlight_px,
            fade,
        };
        let s = PyRenderStyle {
            style,
            line_darken,
            line_px,
            background,
            supersample,
            plane_edge,
            crease_cos,
        };
        // one check of everything, on a throwaway set of options
        let mut opts = RenderOptions::new(256, 256);
        s.apply(&mut opts);
        opts.validate().py()?;
        Ok(s)
    }

    /// The style from a dict of settings (the form `to_dict` gives).
    #[staticmethod]
    fn from_dict(settings: &Bound<'_, PyDict>) -> PyResult<Self> {
        Self::from_mapping(settings)
    }

    /// Every setting as a JSON-able dict (colours and vectors as lists).
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = &self.style;
        let d = PyDict::new(py);
        d.set_item("light", s.light.to_vec())?;
        d.set_item("ambient", short(s.ambient))?;
        d.set_item("diffuse", short(s.diffuse))?;
        d.set_item("shading", s.shading.name())?;
        d.set_item("specular", short(s.specular))?;
        d.set_item("shininess", short(s.shininess))?;
        d.set_item("lines", s.lines.name())?;
        match s.line_colour {
            LineColour::Auto => d.set_item("line_colour", "auto")?,
            LineColour::Part { .. } => d.set_item("line_colour", "part")?,
            LineColour::Fixed(c) => d.set_item("line_colour", rgb_list(c))?,
        }
        d.set_item("line_darken", short(self.line_darken))?;
        d.set_item("front_lines", s.front_lines)?;
        d.set_item("line_px", self.line_px.map(short))?;
        d.set_item("saturation", short(s.saturation))?;
        d.set_item("lighten", short(s.lighten))?;
        d.set_item("highlight", s.highlight.map(rgb_list))?;
        d.set_item("highlight_px", short(s.highlight_px))?;
        d.set_item("fade", short(s.fade))?;
        let b = self.background;
        d.set_item("background", rgb_list([b.0, b.1, b.2]))?;
        d.set_item("supersample", self.supersample)?;
        d.set_item("plane_edge", short(self.plane_edge))?;
        d.set_item("crease_cos", short(self.crease_cos))?;
        Ok(d)
    }

    /// Whether this is the renderer's own look (every setting at its default).
    #[getter]
    fn is_default(&self) -> bool {
        let d = Self::default();
        self.style == d.style
            && self.line_darken == d.line_darken
            && self.line_px.is_none()
            && self.background == d.background
            && self.supersample.is_none()
            && self.plane_edge == d.plane_edge
            && self.crease_cos == d.crease_cos
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        let mine = self.to_dict(py)?;
        let base = Self::default().to_dict(py)?;
        let mut parts = Vec::new();
        for (k, v) in mine.iter() {
            let same = match base.get_item(&k)? {
                Some(b) => b.eq(&v)?,
                None => false,
            };
            if !same {
                parts.push(format!("{}={}", k.str()?, v.repr()?));
            }
        }
        Ok(format!("RenderStyle({})", parts.join(", ")))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyRenderStyle>()?;
    Ok(())
}
