//! Rendering assemblies: meshes from the built-in library or from an LDraw library root.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use crate::assembly::Assembly;
use crate::camera::Camera;
use crate::colours::ColourTable;
use crate::error::Result;
use crate::library::part;
use crate::mesh::Mesh;
use crate::raster::{render_marked, RenderItem, RenderOptions, Rendered};
use crate::render_style::Mark;

/// Where part meshes come from: the package's own meshes, or real LDraw geometry.
#[derive(Debug, Default)]
pub struct MeshSource {
    ldraw_root: Option<PathBuf>,
    cache: Mutex<HashMap<&'static str, Arc<Mesh>>>,
}

impl MeshSource {
    /// The built-in meshes.
    pub fn builtin() -> Self {
        MeshSource::default()
    }

    /// Real part geometry from an LDraw library root (`parts/`, `p/`).
    pub fn ldraw(root: impl Into<PathBuf>) -> Self {
        MeshSource {
            ldraw_root: Some(root.into()),
            cache: Mutex::default(),
        }
    }

    /// The LDraw root, if any.
    pub fn ldraw_root(&self) -> Option<&PathBuf> {
        self.ldraw_root.as_ref()
    }

    /// The mesh (LDU, y up, part frame) of a library part.
    pub fn mesh(&self, id: &str) -> Result<Arc<Mesh>> {
        let def = part(id)?;
        // A poisoned lock only means another thread panicked mid-insert; the map is still valid.
        if let Some(m) = self
            .cache
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(def.id)
        {
            return Ok(m.clone());
        }
        let mesh = match &self.ldraw_root {
            None => Arc::new(def.mesh.clone()),
            Some(root) => Arc::new(crate::ldraw::load_part_geometry(root, def.id)?.mesh),
        };
        self.cache
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(def.id, mesh.clone());
        Ok(mesh)
    }
}

/// Render every instance of an assembly; the id image holds instance ids.
pub fn render_assembly(
    asm: &Assembly,
    camera: &Camera,
    opts: &RenderOptions,
    colours: &ColourTable,
    source: &MeshSource,
) -> Result<Rendered> {
    render_assembly_marked(asm, camera, opts, colours, source, &[])
}

/// [`render_assembly`] with each instance emphasised by its mark (`marks[instance id]`, see
/// [`render_marked`]).
pub fn render_assembly_marked(
    asm: &Assembly,
    camera: &Camera,
    opts: &RenderOptions,
    colours: &ColourTable,
    source: &MeshSource,
    marks: &[Mark],
) -> Result<Rendered> {
    let mut meshes = Vec::new();
    let mut placed = Vec::new();
    for (id, inst) in asm.instances() {
        for b in &inst.component.bricks {
            let colour = if b.colour == crate::component::MAIN_COLOUR {
                inst.colour
            } else {
                b.colour
            };
            meshes.push(source.mesh(b.part)?);
            placed.push((inst.pose.compose(&b.pose), colours.rgb(colour), id));
        }
    }
    let items: Vec<RenderItem> = meshes
        .iter()
        .zip(&placed)
        .map(|(m, &(pose, colour, id))| RenderItem {
            mesh: m,
            pose,
            colour,
            id,
        })
        .collect();
    render_marked(&items, camera, opts, marks)
}
