//! What the generator produces: placed instances, steps, builds (a shape with its manual),
//! submodules and whole manuals, and the check that a build's manual is valid.

use std::collections::BTreeSet;
use std::sync::Arc;

use crate::assembly::{Assembly, AttachKind};
use crate::camera::Camera;
use crate::component::Component;
use crate::error::{BrickGeomError, Result};
use crate::lattice::Pose;

use super::config::SynthConfig;

/// What an instance places.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ComponentRef {
    Part(&'static str),
    /// Index into `SynthManual::submodules`.
    Submodule(usize),
}

/// A placed component instance.
#[derive(Debug, Clone)]
pub struct PlacedInstance {
    pub cref: ComponentRef,
    pub component: Arc<Component>,
    pub pose: Pose,
    pub colour: i32,
}

/// One step: the instances it adds (indices into the build's instances), the attach kind of
/// each, and the camera of its image.
#[derive(Debug, Clone)]
pub struct SynthStep {
    pub instances: Vec<usize>,
    pub attach: Vec<AttachKind>,
    pub camera: Camera,
}

/// A shape with its manual: instances (ids = indices, in build order) and steps.
#[derive(Debug, Clone, Default)]
pub struct Build {
    pub instances: Vec<PlacedInstance>,
    pub steps: Vec<SynthStep>,
}

impl Build {
    /// The components and poses a step adds.
    pub fn step_items(&self, step: usize) -> Vec<(Arc<Component>, Pose)> {
        self.steps[step]
            .instances
            .iter()
            .map(|&i| (self.instances[i].component.clone(), self.instances[i].pose))
            .collect()
    }

    /// Every step checked against the shape of the steps before it (`Assembly::check_step`):
    /// per step, per instance, its attach kind or why it is invalid. Instances that cannot be
    /// added (overlapping real parts) stay out of later base shapes.
    pub fn step_checks(&self) -> Vec<Vec<Result<AttachKind>>> {
        let mut asm = Assembly::new();
        (0..self.steps.len())
            .map(|s| {
                let items = self.step_items(s);
                let res = asm.check_step(&items);
                for (c, p) in items {
                    let _ = asm.add(c, p);
                }
                res
            })
            .collect()
    }

    /// The finished shape.
    pub fn assembly(&self) -> Result<Assembly> {
        let mut asm = Assembly::new();
        for inst in &self.instances {
            let id = asm.add(inst.component.clone(), inst.pose)?;
            asm.set_colour(id, inst.colour)?;
        }
        Ok(asm)
    }
}

/// A submodule: its component (in its own frame) and its own manual.
#[derive(Debug, Clone)]
pub struct SynthSubmodule {
    pub name: String,
    pub component: Arc<Component>,
    pub build: Build,
}

/// A generated manual: the main build and its submodules.
#[derive(Debug, Clone)]
pub struct SynthManual {
    pub seed: u64,
    pub main: Build,
    pub submodules: Vec<SynthSubmodule>,
}

/// Check a build's manual: every step valid against the shape before it (connected, no
/// collision), within the instance and type limits; the steps add every instance exactly once.
pub fn validate_build(build: &Build, cfg: &SynthConfig) -> Result<()> {
    let mut seen = vec![false; build.instances.len()];
    for (s, (step, checks)) in build.steps.iter().zip(build.step_checks()).enumerate() {
        let types: BTreeSet<ComponentRef> = step
            .instances
            .iter()
            .map(|&i| build.instances[i].cref)
            .collect();
        if step.instances.len() > cfg.max_step_instances || types.len() > cfg.max_step_types {
            return Err(BrickGeomError::InvalidArgument(format!(
                "step {}: {} instances of {} types exceed the limits",
                s + 1,
                step.instances.len(),
                types.len()
            )));
        }
        for (k, r) in checks.into_iter().enumerate() {
            if let Err(e) = r {
                return Err(BrickGeomError::InvalidArgument(format!(
                    "step {}: instance {} is invalid: {e}",
                    s + 1,
                    step.instances[k]
                )));
            }
        }
        for &i in &step.instances {
            if std::mem::replace(&mut seen[i], true) {
                return Err(BrickGeomError::InvalidArgument(format!(
                    "instance {i} is added twice"
                )));
            }
        }
    }
    if let Some(i) = seen.iter().position(|s| !s) {
        return Err(BrickGeomError::InvalidArgument(format!(
            "instance {i} is never added"
        )));
    }
    Ok(())
}
