//! Synthetic manuals: the generator of the paper's supplementary ("Synthetic Dataset
//! Generation"), deterministic for a seed.
//!
//! The files follow the pipeline: `forward` samples a shape (bounding box, partitions, fill and
//! grown edges, components placed by rejection sampling, submodules with their own manual),
//! `backward` takes it apart into steps (chunks of removable and visible components, in
//! reverse), `views` gives each step its camera and renders the step images with their
//! annotations. `config` holds the settings, `rng` the random source, `build` the produced
//! types ([`SynthManual`], [`Build`], ...) and [`validate_build`]. This module runs the stages
//! ([`generate`]) and re-exports the public items.

mod backward;
mod build;
mod config;
mod forward;
mod rng;
mod views;

pub use build::{
    validate_build, Build, ComponentRef, PlacedInstance, SynthManual, SynthStep, SynthSubmodule,
};
pub use config::SynthConfig;
pub use rng::Rng;
pub use views::{project_keypoints, render_build, render_build_with, InstanceView, StepImage};

use crate::error::{BrickGeomError, Result};

use backward::backward;
use forward::forward;
use views::ViewSampler;

/// Generate one manual from a seed. Deterministic: the same seed and settings give the same
/// manual on any machine and with any number of threads.
pub fn generate(cfg: &SynthConfig, seed: u64) -> Result<SynthManual> {
    cfg.validate()?;
    // Rejection at the manual level: a shape that ends up too small is regenerated from the
    // next sub-seed (deterministically).
    const ATTEMPTS: u64 = 8;
    for attempt in 0..ATTEMPTS {
        let mut rng = Rng::new(seed, 1 + attempt);
        let w = rng.range(cfg.footprint.0 as i64, cfg.footprint.1 as i64) as i32;
        let d = rng.range(cfg.footprint.0 as i64, cfg.footprint.1 as i64) as i32;
        let height = rng.range(cfg.height.0 as i64, cfg.height.1 as i64) as i32;
        let target = rng.range(cfg.components.0 as i64, cfg.components.1 as i64) as usize;
        let shape = forward(cfg, rng, (w, d), height, target);
        if shape.instances.len() < cfg.components.0.min(8) {
            continue;
        }
        let mut rng = Rng::new(seed, 100 + attempt);
        let view = ViewSampler::new(cfg, &mut rng);
        let submodules = shape.submodules;
        // Every component must be visible in its step image; a shape where the backward stage
        // cannot manage that is regenerated (the last attempt accepts the least hidden one).
        let Ok(mut main) = backward(
            cfg,
            &mut rng,
            &view,
            shape.instances,
            shape.units,
            attempt + 1 < ATTEMPTS,
        ) else {
            continue;
        };
        // Submodules dropped with hidden units are not part of the manual.
        let mut used: Vec<Option<usize>> = vec![None; submodules.len()];
        let mut kept = Vec::new();
        for inst in &mut main.instances {
            if let ComponentRef::Submodule(k) = inst.cref {
                let new = *used[k].get_or_insert_with(|| {
                    kept.push(submodules[k].clone());
                    kept.len() - 1
                });
                inst.cref = ComponentRef::Submodule(new);
            }
        }
        for (k, sub) in kept.iter_mut().enumerate() {
            sub.name = format!("submodule_{k}");
        }
        return Ok(SynthManual {
            seed,
            main,
            submodules: kept,
        });
    }
    Err(BrickGeomError::InvalidArgument(format!(
        "seed {seed}: could not build a shape with these settings"
    )))
}
