//! The PhysiFormer family: mesh scenes sampled whole with flow matching, served through
//! Generate. [`mesh_scene`] checks a request into the model's scene and sampling parameters;
//! each sample is its own scheduler stream submitting one network evaluation at a time
//! ([`denoise`]), so requests at different denoising steps share passes; [`serve`] admits a
//! call, runs its samples and reports progress; [`sample_frames`] splits each sample into
//! per-object frames with the Kabsch-fitted pose of every rigid object.

pub mod denoise;
pub mod mesh_scene;
pub mod sample_frames;
pub mod serve;

use std::path::Path;
use std::sync::Arc;

use dynaserve_model::PhysiFormer;
use dynaserve_model::physiformer::config::PHYSIFORMER;

use super::contract::{Resident, Sampler, SamplingCaps, SamplingModel};
use super::{LoadOptions, ModelFamily};
use crate::metrics::Metrics;
use crate::scheduler::SchedulerConfig;

pub use serve::GeneratorEntry;

/// Loads `physiformer` checkpoints.
pub struct PhysiFormerFamily;

impl ModelFamily for PhysiFormerFamily {
    fn recognises(&self, architecture: &str) -> bool {
        architecture == PHYSIFORMER
    }

    fn load(&self, dir: &Path, opts: &LoadOptions) -> anyhow::Result<Resident> {
        let model = PhysiFormer::load(dir, &opts.device, false)?;
        Ok(Resident::Sampling(Arc::new(model)))
    }
}

impl SamplingModel for PhysiFormer {
    fn name(&self) -> &str {
        PhysiFormer::name(self)
    }

    fn start(
        self: Arc<Self>,
        caps: SamplingCaps,
        scheduling: SchedulerConfig,
        metrics: &Metrics,
    ) -> std::io::Result<Arc<dyn Sampler>> {
        Ok(Arc::new(GeneratorEntry::start(
            self,
            &caps.generate,
            caps.max_objects,
            scheduling,
            metrics,
        )?))
    }
}
