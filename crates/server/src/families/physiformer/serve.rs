//! Generate (PhysiFormer): a mesh scene sampled whole, `samples` times. Each sample is its own
//! stream in its model's scheduler and submits one denoising evaluation at a time, so requests
//! at different denoising steps share forward passes. Progress is reported once every sample
//! has completed a step; the samples follow, in order, once all are done.

use std::sync::Arc;
use std::time::Instant;

use dynaserve_api::limits::{GenerateCaps, GenerateLimits};
use dynaserve_api::spec::sampling::{
    GenerateEvent, GenerateProgress, GenerateSpec, GeneratedSample,
};
use dynaserve_api::spec::{About, ModelInfo, ModelKind, StepTiming};
use dynaserve_model::PhysiFormer;
use dynaserve_model::physiformer::scene::{Material, MeshScene};
use futures::future::try_join_all;
use tokio::sync::{OwnedSemaphorePermit, mpsc};

use super::denoise::{DenoiseSteps, GenerateError, GenerateJob, StepProgress, generate};
use super::mesh_scene::{GenerateParams, build_mesh_scene, check_generate, check_generate_cost};
use super::sample_frames::mesh_frames;
use crate::engine::request::RequestCtx;
use crate::engine::request::{Call, GaugeGuard, sleep_until};
use crate::engine::stepper::step_error;
use crate::error::ApiError;
use crate::families::contract::{GenerateHandle, Sampler, SamplingHost};
use crate::metrics::Metrics;
use crate::scheduler::{Priority, Scheduler, SchedulerConfig};

/// A resident PhysiFormer model: its scheduler, Generate limits and description.
pub struct GeneratorEntry {
    /// Name used in requests.
    pub name: String,
    /// The scheduler that owns all forward passes of the model.
    pub scheduler: Scheduler<DenoiseSteps>,
    /// Generate limits.
    pub limits: GenerateLimits,
    /// Description returned by ListModels.
    pub info: ModelInfo,
}

impl GeneratorEntry {
    /// Starts the scheduler of `model` and derives its limits under the server's caps
    /// (`max_objects`: the server's per-scene object cap).
    pub fn start(
        model: Arc<PhysiFormer>,
        caps: &GenerateCaps,
        max_objects: usize,
        scheduling: SchedulerConfig,
        metrics: &Metrics,
    ) -> std::io::Result<GeneratorEntry> {
        let name = model.name().to_string();
        let config = model.config().clone();
        let limits = GenerateLimits::new(caps, max_objects, &config);
        let scheduler = Scheduler::start(
            Arc::new(DenoiseSteps::new(model)),
            scheduling,
            metrics.clone(),
        )?;
        Ok(GeneratorEntry {
            info: ModelInfo {
                name: name.clone(),
                kind: ModelKind::Sampling {
                    about: About {
                        architecture: config.architecture.clone(),
                        dt_frame: f64::from(config.dt_frame),
                        gravity: config.gravity,
                        config: serde_json::to_value(&config).unwrap_or_default(),
                    },
                    limits,
                },
                members: Vec::new(),
                gradients: false,
            },
            name,
            scheduler,
            limits,
        })
    }
}

const CLOSE_MSG: &str =
    "server shutting down: the drain deadline passed before the generation finished";

fn generate_error(e: GenerateError) -> ApiError {
    match e {
        GenerateError::Invalid(m) => ApiError::invalid("scene", m),
        GenerateError::Step(s) => step_error(s),
    }
}

/// The progress of every sample; emits a step once all samples have completed it.
struct Progress {
    /// Per sample, the timing of each completed step.
    done: Vec<Vec<StepProgress>>,
    /// Steps already reported.
    reported: usize,
    steps: usize,
}

impl Progress {
    fn record(&mut self, sample: usize, p: StepProgress) -> Vec<GenerateProgress> {
        self.done[sample].push(p);
        let all = self.done.iter().map(Vec::len).min().unwrap_or(0);
        let mut out = Vec::new();
        while self.reported < all {
            let s = self.reported;
            let slowest = self
                .done
                .iter()
                .map(|d| d[s])
                .max_by_key(|p| p.queue + p.forward);
            let widest = self.done.iter().map(|d| d[s].batch_scenes).max();
            if let (Some(p), Some(widest)) = (slowest, widest) {
                out.push(GenerateProgress {
                    step: (s + 1) as u32,
                    steps: self.steps as u32,
                    t: (s + 1) as f32 / self.steps as f32,
                    timing: StepTiming {
                        queue: p.queue,
                        forward: p.forward,
                        batch_scenes: widest,
                    },
                });
            }
            self.reported += 1;
        }
        out
    }
}

impl GeneratorEntry {
    /// Validates and admits a Generate call, then runs its samples in a task. Events arrive
    /// on the returned channel, which holds everything the call produces (at most one event
    /// per step plus one per sample), so a slow reader never holds up the passes.
    fn generate_call(
        self: Arc<Self>,
        engine: Arc<dyn SamplingHost>,
        req: GenerateSpec,
        ctx: RequestCtx,
    ) -> Result<GenerateHandle, ApiError> {
        let span = tracing::info_span!(
            "generate",
            request_id = %ctx.request_id,
            protocol = ctx.protocol.as_str(),
            model = tracing::field::Empty
        );
        let mut call = Call::new(engine.metrics(), &ctx, "generate", span);
        let (params, scene, permit, priority) =
            call.admit_now(|| self.admit_generate(engine.as_ref(), &req, &ctx))?;
        let deadline = ctx.deadline_with(req.timeout_ms, engine.config().default_timeout());
        let (tx, rx) = mpsc::channel(params.steps + params.samples as usize + 1);
        let entry = self;
        let run = GenerateRun {
            engine: engine.clone(),
            entry: entry.clone(),
            params,
            scene,
            sampler: req.sampler,
            seed: req.seed,
            noise: req.noise.iter().map(|n| Arc::new(n.clone())).collect(),
            deadline,
            request_id: ctx.request_id.clone(),
            priority,
            caller: ctx.caller(),
        };
        let gauge = engine
            .metrics()
            .active_generate_samples
            .with_label_values(&[entry.name.as_str()]);
        gauge.add(i64::from(params.samples));
        call.spawn(move |call| async move {
            let _permit: OwnedSemaphorePermit = permit;
            let _gauge = GaugeGuard(gauge, i64::from(params.samples));
            let start = Instant::now();
            let r = run.run(&tx).await;
            match &r {
                Ok(()) => tracing::info!(
                    steps = params.steps,
                    samples = params.samples,
                    ms = start.elapsed().as_secs_f64() * 1e3,
                    "generation finished"
                ),
                Err(e) => {
                    let _ = tx.try_send(Err(e.clone()));
                }
            }
            call.end(r);
        });
        Ok(GenerateHandle {
            model: entry.name.clone(),
            request_id: ctx.request_id,
            steps: params.steps as u32,
            events: rx,
        })
    }

    /// Admission: readiness, the model, the request's numbers and scene, its cost (which
    /// also sets its class: bulk above `--bulk-generate-cost`), then the sample slots.
    #[allow(clippy::type_complexity)]
    fn admit_generate(
        &self,
        engine: &dyn SamplingHost,
        req: &GenerateSpec,
        ctx: &RequestCtx,
    ) -> Result<
        (
            GenerateParams,
            Arc<MeshScene>,
            OwnedSemaphorePermit,
            Priority,
        ),
        ApiError,
    > {
        engine.admit_check()?;
        let entry = self;
        tracing::Span::current().record("model", entry.name.as_str());
        let params = check_generate(req, &entry.limits)?;
        let scene = build_mesh_scene(&req.objects, &entry.limits)?;
        let config = entry.scheduler.family().model().config();
        scene
            .validate(config)
            .map_err(|e| ApiError::invalid("scene", e))?;
        // The call's cost, now that the scene's vertices are counted; before any slot is taken.
        let cost = check_generate_cost(&params, req.sampler, scene.vertices(), &entry.limits)?;
        let priority = if engine.config().scheduling.generate_is_bulk(cost) {
            Priority::Bulk
        } else {
            Priority::Interactive
        };
        let permit = engine
            .generate_slots()
            .clone()
            .try_acquire_many_owned(params.samples)
            .map_err(|_| {
                ApiError::exhausted(
                    format!(
                        "{} Generate samples are in flight, the server's limit; retry later",
                        engine.config().max_generate_samples
                    ),
                    engine.retry_after(),
                )
            })?;
        tracing::debug!(request_id = %ctx.request_id, samples = params.samples, "admitted");
        Ok((params, Arc::new(scene), permit, priority))
    }
}

/// One admitted Generate call.
struct GenerateRun {
    engine: Arc<dyn SamplingHost>,
    entry: Arc<GeneratorEntry>,
    params: GenerateParams,
    scene: Arc<MeshScene>,
    sampler: dynaserve_api::spec::sampling::SamplerKind,
    seed: u64,
    /// Starting noise per sample, when the request gave it.
    noise: Vec<Arc<Vec<f32>>>,
    deadline: Option<Instant>,
    request_id: Arc<str>,
    /// Class of every evaluation of the call.
    priority: Priority,
    /// Who asked.
    caller: u64,
}

impl GenerateRun {
    /// Runs every sample to its end, a deadline, a drain close or the client's disappearance,
    /// sending progress as it comes and the samples at the end.
    async fn run(
        &self,
        tx: &mpsc::Sender<Result<GenerateEvent, ApiError>>,
    ) -> Result<(), ApiError> {
        let name = self.entry.name.as_str();
        let steps_metric = self
            .engine
            .metrics()
            .denoise_steps
            .with_label_values(&[name]);
        let sample_seconds = self
            .engine
            .metrics()
            .generate_sample_seconds
            .with_label_values(&[name]);
        let progress = std::sync::Mutex::new(Progress {
            done: vec![Vec::new(); self.params.samples as usize],
            reported: 0,
            steps: self.params.steps,
        });
        let start = Instant::now();
        let samples = (0..self.params.samples).map(|i| {
            let job = GenerateJob {
                scene: self.scene.clone(),
                frames: self.params.frames,
                steps: self.params.steps,
                sampler: self.sampler,
                seed: self.seed.wrapping_add(u64::from(i)),
                noise: self.noise.get(i as usize).cloned(),
                priority: self.priority,
                deadline: self.deadline,
                stream_id: self.engine.next_stream_id(),
                caller: self.caller,
                request_id: self.request_id.clone(),
            };
            let (progress, steps_metric, sample_seconds) =
                (&progress, steps_metric.clone(), sample_seconds.clone());
            async move {
                let out = generate(&self.entry.scheduler, job, |p| {
                    steps_metric.inc();
                    let events = match progress.lock() {
                        Ok(mut g) => g.record(i as usize, p),
                        Err(_) => Vec::new(),
                    };
                    for e in events {
                        let _ = tx.try_send(Ok(GenerateEvent::Progress(e)));
                    }
                })
                .await
                .map_err(generate_error)?;
                sample_seconds.observe(start.elapsed().as_secs_f64());
                Ok::<_, ApiError>(out)
            }
        });
        let mut close = self.engine.closing();
        let trajectories = tokio::select! {
            r = try_join_all(samples) => r?,
            _ = tx.closed() => return Err(ApiError::cancelled("client went away")),
            _ = sleep_until(self.deadline) => return Err(ApiError::deadline("deadline exceeded")),
            _ = close.wait_for(|c| *c) => return Err(ApiError::unavailable(CLOSE_MSG)),
        };
        let dt_frame = self.entry.limits.dt_frame;
        for (i, traj) in trajectories.into_iter().enumerate() {
            if let Some(k) = traj.iter().position(|v| !v.is_finite()) {
                let nv = self.scene.vertices();
                return Err(ApiError::internal(format!(
                    "sample {i}: the model produced a non-finite position (frame {}, vertex {})",
                    k / 3 / nv.max(1),
                    k / 3 % nv.max(1)
                )));
            }
            let sample = GeneratedSample {
                sample: i as u32,
                seed: self.seed.wrapping_add(i as u64),
                frames: mesh_frames(
                    &self.scene,
                    &traj,
                    self.params.frames,
                    dt_frame,
                    self.params.raw_vertices,
                ),
            };
            if tx.send(Ok(GenerateEvent::Sample(sample))).await.is_err() {
                return Err(ApiError::cancelled("client went away"));
            }
        }
        Ok(())
    }
}

impl Sampler for GeneratorEntry {
    fn name(&self) -> &str {
        &self.name
    }

    fn info(&self) -> &ModelInfo {
        &self.info
    }

    fn start_generate(
        self: Arc<Self>,
        engine: Arc<dyn SamplingHost>,
        req: GenerateSpec,
        ctx: RequestCtx,
    ) -> Result<GenerateHandle, ApiError> {
        self.generate_call(engine, req, ctx)
    }

    /// One denoising step of a two-frame sample of one tetrahedron.
    fn warm_up<'a>(
        &'a self,
        engine: &'a dyn SamplingHost,
    ) -> futures::future::BoxFuture<'a, Result<(), ApiError>> {
        Box::pin(async move {
            let positions = vec![
                [0.0, 0.0, -0.9],
                [0.1, 0.0, -0.9],
                [0.0, 0.1, -0.9],
                [0.0, 0.0, -0.8],
            ];
            let scene = MeshScene {
                velocities: vec![[0.0; 3]; positions.len()],
                positions,
                vertex_offsets: vec![0, 4],
                materials: vec![Material::Elastic],
            };
            let job = GenerateJob {
                scene: Arc::new(scene),
                frames: 2,
                steps: 1,
                sampler: dynaserve_model::physiformer::flow::SamplerKind::Heun,
                seed: 0,
                noise: None,
                priority: Priority::Interactive,
                deadline: None,
                stream_id: engine.next_stream_id(),
                caller: 0,
                request_id: crate::scheduler::WARMUP_REQUEST_ID.into(),
            };
            generate(&self.scheduler, job, |_| {})
                .await
                .map(|_| ())
                .map_err(|e| ApiError::internal(format!("warm-up sample: {e}")))
        })
    }

    fn shutdown(&self) {
        self.scheduler.shutdown();
    }
}
