//! Model families as plug-ins. A family owns, in its own module, everything that differs
//! between kinds of model: recognising its model directory, loading it, its ListModels
//! description and limits, building a request's scene and initial state, and what one
//! scheduler pass of its work is. The engine and the server know only the two capabilities
//! below and the [`registry`]:
//!
//! - [`SteppingModel`]: advances scenes one step at a time, served through Rollout, Predict,
//!   Sessions and Interact (RigidFormer, the rapier simulator);
//! - [`SamplingModel`]: samples whole trajectories, served through Generate (PhysiFormer).
//!
//! [`built_scene`] validates a stepping request's scene into model inputs, the same for every
//! stepping family (and for the poses sessions are given).
//!
//! Adding a family is one module here and one line in [`registry`] (docs/architecture.md,
//! "Adding a family").

pub mod built_scene;
pub mod contract;
pub mod physiformer;
pub mod rapier;
pub mod rigidformer;

use std::path::Path;

use anyhow::Context;

pub use contract::*;

/// Where and how models load.
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// The device networks run on.
    pub device: candle_core::Device,
}

/// One family as the registry sees it.
pub trait ModelFamily: Sync {
    /// The `architecture` names of config.json this family loads.
    fn recognises(&self, architecture: &str) -> bool;
    /// Loads the model directory `dir`.
    fn load(&self, dir: &Path, opts: &LoadOptions) -> anyhow::Result<Resident>;
}

/// Every family the server can load, tried in order: the one place that lists them.
pub fn registry() -> [&'static dyn ModelFamily; 3] {
    [
        &physiformer::PhysiFormerFamily,
        &rapier::RapierFamily,
        // Last: RigidFormer checkpoints name several architectures (and older ones none).
        &rigidformer::RigidFormerFamily,
    ]
}

/// Loads `dir` in the family that recognises its config.json's `architecture`.
pub fn load_dir(dir: &Path, opts: &LoadOptions) -> anyhow::Result<Resident> {
    let architecture = dynaserve_model::read_architecture(dir)
        .with_context(|| format!("reading {}", dir.display()))?;
    let start = std::time::Instant::now();
    let family = registry()
        .into_iter()
        .find(|f| f.recognises(&architecture))
        .with_context(|| format!("no family serves architecture {architecture:?}"))?;
    let resident = family
        .load(dir, opts)
        .with_context(|| format!("loading model {}", dir.display()))?;
    let name = match &resident {
        Resident::Stepping(m) => m.name().to_string(),
        Resident::Sampling(m) => m.name().to_string(),
    };
    tracing::info!(
        model = %name,
        architecture = %architecture,
        dir = %dir.display(),
        device = %dynaserve_model::device_name(&opts.device),
        ms = start.elapsed().as_secs_f64() * 1e3,
        "model loaded"
    );
    Ok(resident)
}
