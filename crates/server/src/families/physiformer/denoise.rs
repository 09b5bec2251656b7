//! PhysiFormer work for the scheduler: one network evaluation of one scene at its own flow
//! time ([`DenoiseStep`]), so the evaluations of requests at different denoising steps share
//! a pass ([`DenoiseSteps`]), and [`generate`], which drives one sample through the scheduler
//! evaluation by evaluation with the Heun (or Euler) sampler.

use std::sync::Arc;
use std::time::{Duration, Instant};

use dynaserve_model::PhysiFormer;
use dynaserve_model::physiformer::flow::{Sampler, SamplerKind};
use dynaserve_model::physiformer::inputs::{PreparedItem, PreparedScene};
use dynaserve_model::physiformer::scene::MeshScene;
use tokio::sync::oneshot;

use crate::scheduler::{Family, Job, Priority, Scheduler, StepError};

/// One evaluation: the prepared scene, its current noisy trajectory and its flow time.
#[derive(Clone, Debug)]
pub struct DenoiseStep {
    /// The scene prepared once per sample ([`PhysiFormer::prepare`]: validated, its
    /// step-invariant inputs laid out and embedded), shared by every evaluation of the sample.
    pub scene: Arc<PreparedScene>,
    /// Noisy trajectory `[frames, V, 3]` flattened, metres (`frames` of the preparation).
    pub z: Vec<f32>,
    /// Flow time in `[0, 1]`.
    pub t: f32,
}

/// PhysiFormer models as a scheduler family: items are [`DenoiseStep`]s costing their vertex
/// count; a pass evaluates every item, each as its own [`PhysiFormer::denoise_prepared`]
/// forward, and yields each item's predicted clean trajectory `[frames, V, 3]`.
///
/// One forward per scene instead of one padded forward for the whole pass: on these CPUs a
/// padded pass of 8 example scenes costs more per scene than 8 forwards of one (its tensors
/// outgrow the caches; BENCHMARKS.md, "Generate"), and a scene's result is then bit for bit
/// the same whatever its pass-mates, since it runs the same kernels on the same shapes. A
/// scene whose forward fails fails alone.
pub struct DenoiseSteps {
    model: Arc<PhysiFormer>,
}

impl DenoiseSteps {
    /// The family of `model`.
    pub fn new(model: Arc<PhysiFormer>) -> DenoiseSteps {
        DenoiseSteps { model }
    }

    /// The model.
    pub fn model(&self) -> &Arc<PhysiFormer> {
        &self.model
    }
}

impl Family for DenoiseSteps {
    type Item = DenoiseStep;
    type Output = Vec<f32>;

    fn name(&self) -> &str {
        self.model.name()
    }

    fn cost(&self, item: &DenoiseStep) -> usize {
        item.scene.vertices()
    }

    fn separate_forwards(&self) -> bool {
        true
    }

    fn run(&self, items: &[&DenoiseStep]) -> Result<Vec<Result<Vec<f32>, String>>, String> {
        Ok(items
            .iter()
            .map(|s| {
                let item = PreparedItem {
                    scene: &s.scene,
                    z: &s.z,
                    t: s.t,
                };
                self.model
                    .denoise_prepared(&[item])
                    .map_err(|e| e.to_string())
                    .and_then(|mut out| out.pop().ok_or_else(|| "no prediction".to_string()))
            })
            .collect())
    }
}

/// A generation request as the scheduler needs it.
#[derive(Clone, Debug)]
pub struct GenerateJob {
    /// The scene (validated by [`Sampler::new`]).
    pub scene: Arc<MeshScene>,
    /// Frames to sample (frame 0 included).
    pub frames: usize,
    /// Denoising steps.
    pub steps: usize,
    /// Integrator.
    pub sampler: SamplerKind,
    /// Seed of the starting noise.
    pub seed: u64,
    /// Standard-normal draws of the starting noise `[frames, V, 3]` in place of the seed
    /// ([`Sampler::with_noise`]).
    pub noise: Option<Arc<Vec<f32>>>,
    /// Scheduling class.
    pub priority: Priority,
    /// Instant after which the result is no longer wanted.
    pub deadline: Option<Instant>,
    /// Identifies this request's evaluations across passes.
    pub stream_id: u64,
    /// Who asked (fair share within the class).
    pub caller: u64,
    /// Request id for logs.
    pub request_id: Arc<str>,
}

/// What one completed denoising step reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepProgress {
    /// Steps completed.
    pub step: usize,
    /// Steps in total.
    pub steps: usize,
    /// Flow time reached.
    pub t: f32,
    /// Largest number of scenes in the passes of this step's evaluations.
    pub batch_scenes: u32,
    /// Time this step's evaluations waited in the queue, summed.
    pub queue: Duration,
    /// Forward passes of this step's evaluations, summed.
    pub forward: Duration,
}

/// Tells the scheduler, when dropped (the sample finished, failed or was abandoned), not to
/// wait for the stream's next evaluation.
struct IdleOnDrop<'a> {
    scheduler: &'a Scheduler<DenoiseSteps>,
    stream_id: u64,
}

impl Drop for IdleOnDrop<'_> {
    fn drop(&mut self) {
        self.scheduler.idle(self.stream_id);
    }
}

/// Why a generation failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum GenerateError {
    /// The request is invalid; the message names the field.
    #[error("invalid request: {0}")]
    Invalid(String),
    /// An evaluation failed or was not run.
    #[error(transparent)]
    Step(#[from] StepError),
}

/// Samples one trajectory `[frames, V, 3]` by submitting one evaluation at a time to
/// `scheduler`, so it joins whatever passes other requests are running; `progress` is called
/// after every denoising step. The result depends only on the model, the scene, `frames`,
/// `steps`, the sampler and `seed`, never on the pass-mates. Dropping the future abandons the
/// sample: its queued evaluation is discarded and the scheduler stops waiting for it.
pub async fn generate(
    scheduler: &Scheduler<DenoiseSteps>,
    job: GenerateJob,
    mut progress: impl FnMut(StepProgress),
) -> Result<Vec<f32>, GenerateError> {
    let config = scheduler.family().model().config().clone();
    let mut sampler = match &job.noise {
        Some(eps) => {
            Sampler::with_noise(&config, &job.scene, job.frames, job.steps, job.sampler, eps)
        }
        None => Sampler::with_kind(
            &config,
            &job.scene,
            job.frames,
            job.steps,
            job.seed,
            job.sampler,
        ),
    }
    .map_err(|e| GenerateError::Invalid(e.to_string()))?;
    let prepared = Arc::new(
        scheduler
            .family()
            .model()
            .prepare(&job.scene, job.frames)
            .map_err(|e| GenerateError::Invalid(e.to_string()))?,
    );
    let _idle = IdleOnDrop {
        scheduler,
        stream_id: job.stream_id,
    };
    let mut widest = 0u32;
    let (mut queue, mut forward) = (Duration::ZERO, Duration::ZERO);
    async {
        while !sampler.done() {
            let (z, t) = sampler.query();
            let (tx, rx) = oneshot::channel();
            scheduler.submit(Job {
                item: DenoiseStep {
                    scene: prepared.clone(),
                    z: z.to_vec(),
                    t,
                },
                priority: job.priority,
                deadline: job.deadline,
                stream_id: job.stream_id,
                caller: job.caller,
                more_steps: true,
                request_id: job.request_id.clone(),
                reply: tx,
            });
            let done = rx.await.map_err(|_| StepError::Stopped)??;
            widest = widest.max(done.batch_scenes);
            queue += done.queue_wait;
            forward += done.forward;
            if sampler
                .advance(&done.output)
                .map_err(|e| StepError::Model(e.to_string()))?
            {
                progress(StepProgress {
                    step: sampler.step(),
                    steps: sampler.steps(),
                    t: sampler.step() as f32 / sampler.steps() as f32,
                    batch_scenes: widest,
                    queue,
                    forward,
                });
                widest = 0;
                (queue, forward) = (Duration::ZERO, Duration::ZERO);
            }
        }
        Ok::<(), GenerateError>(())
    }
    .await?;
    Ok(sampler.trajectory().to_vec())
}
