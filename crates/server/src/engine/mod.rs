//! The protocol-independent core shared by both front ends: it takes and emits the neutral
//! vocabulary of `dynaserve_api::spec`, and `grpc.rs` and `http.rs` map their wire forms to and
//! from it. By concern:
//!
//! - this module: the engine's lifecycle (ready, drain, close, shutdown), admission checks and
//!   model lookup;
//! - [`registry`]: resident models with their schedulers and limits, scene preparation;
//! - [`admission`]: a stepping request's steps, step size and cost against its limits;
//! - [`request`]: request context, ids, and the call every entry point runs in (its span and
//!   the metrics record of its outcome);
//! - `stepper`: one scene stepping through the scheduler (the only code that submits steps);
//! - `rollout`, `predict`, `warmup`: the three users of steppers;
//! - Generate: resolved here, run by the sampling model's family (`crate::families`);
//! - [`sessions`]: scenes kept with their state between calls (planners), stepped through
//!   steppers whose kinematic objects follow given poses;
//! - `gradient`: the checks, scheduling and answer of Gradient calls (a session's candidate
//!   paths scored and differentiated in a gradient pass of its model).

pub mod admission;
mod gradient;
mod predict;
pub mod registry;
pub mod request;
mod rollout;
pub mod sessions;
pub(crate) mod stepper;
mod warmup;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use dynaserve_api::spec::sampling::GenerateSpec;
use dynaserve_api::spec::{ModelInfo, Scene};
use dynaserve_model::SceneState;
use tokio::sync::{Semaphore, watch};

pub use crate::families::contract::{GenerateHandle, Models};
pub use registry::ModelEntry;
use registry::{PreparedScenes, prepare_scenes};
pub use request::{Protocol, RequestCtx, new_request_id};
pub use rollout::RolloutHandle;
pub use sessions::{InteractHandle, StepHandle};

use crate::config::ServeConfig;
use crate::error::ApiError;
use crate::families::contract::{Sampler, SamplingCaps, SamplingHost, SteppedScene};
use crate::metrics::Metrics;
use crate::scheduler::{PassGate, SchedulerConfig};
use request::Call;

/// The server core shared by both front ends.
pub struct Engine {
    pub(crate) config: ServeConfig,
    models: BTreeMap<String, Arc<ModelEntry>>,
    samplers: BTreeMap<String, Arc<dyn Sampler>>,
    pub(crate) generate_slots: Arc<Semaphore>,
    pub(crate) metrics: Metrics,
    rollout_slots: Arc<Semaphore>,
    predict_slots: Arc<Semaphore>,
    ready: AtomicBool,
    draining: AtomicBool,
    pub(crate) close_tx: watch::Sender<bool>,
    pub(crate) next_stream: AtomicU64,
    sessions: Arc<sessions::SessionStore>,
}

impl Engine {
    /// Starts one scheduler per model. Model names must be unique across families.
    pub fn new(config: ServeConfig, models: impl Into<Models>) -> anyhow::Result<Engine> {
        config.validate().map_err(anyhow::Error::msg)?;
        let models: Models = models.into();
        let names = models.names();
        let metrics = Metrics::new(&names);
        let scheduling = SchedulerConfig {
            max_batch_scenes: config.max_batch_scenes,
            max_batch_objects: config.max_batch_objects,
            max_queue_delay: config.max_queue_delay(),
            bulk_share: config.scheduling.bulk_share,
            // One device for every model: passes of all schedulers take turns by class.
            gate: Some(Arc::new(PassGate::new(
                config.scheduling.bulk_share,
                config.max_queue_delay() + Duration::from_millis(1),
            ))),
        };
        let caps = config.caps();
        let mut entries = BTreeMap::new();
        for model in models.stepping {
            let entry = ModelEntry::start(model, &caps, scheduling.clone(), &metrics)?;
            let name = entry.name.clone();
            if entries.insert(name.clone(), Arc::new(entry)).is_some() {
                anyhow::bail!("two models are named {name:?}; model names must be unique");
            }
        }
        let mut samplers: BTreeMap<String, Arc<dyn Sampler>> = BTreeMap::new();
        let sampling_caps = SamplingCaps {
            generate: config.generate_caps(),
            max_objects: caps.max_objects,
        };
        for model in models.sampling {
            let sampler = model.start(sampling_caps, scheduling.clone(), &metrics)?;
            let name = sampler.name().to_string();
            if entries.contains_key(&name) || samplers.insert(name.clone(), sampler).is_some() {
                anyhow::bail!("two models are named {name:?}; model names must be unique");
            }
        }
        if entries.is_empty() && samplers.is_empty() {
            anyhow::bail!("no models to serve");
        }
        let (close_tx, _) = watch::channel(false);
        let sessions = Arc::new(sessions::SessionStore::new(
            config.sessions.clone(),
            metrics.clone(),
        ));
        Ok(Engine {
            sessions,
            rollout_slots: Arc::new(Semaphore::new(config.max_active_rollouts)),
            predict_slots: Arc::new(Semaphore::new(config.max_predict_variants)),
            generate_slots: Arc::new(Semaphore::new(config.max_generate_samples)),
            config,
            models: entries,
            samplers,
            metrics,
            ready: AtomicBool::new(false),
            draining: AtomicBool::new(false),
            close_tx,
            next_stream: AtomicU64::new(1),
        })
    }

    /// The metrics.
    pub fn metrics(&self) -> &Metrics {
        &self.metrics
    }

    /// The configuration.
    pub fn config(&self) -> &ServeConfig {
        &self.config
    }

    /// Names of the resident models, sorted.
    pub fn model_names(&self) -> Vec<String> {
        let mut names: Vec<String> = self
            .models
            .keys()
            .chain(self.samplers.keys())
            .cloned()
            .collect();
        names.sort();
        names
    }

    /// True once warmed up and not draining.
    pub fn is_ready(&self) -> bool {
        self.ready.load(Ordering::SeqCst) && !self.draining.load(Ordering::SeqCst)
    }

    /// True after [`Engine::start_drain`].
    pub fn is_draining(&self) -> bool {
        self.draining.load(Ordering::SeqCst)
    }

    fn set_ready_gauge(&self) {
        self.metrics.ready.set(i64::from(self.is_ready()));
    }

    /// Marks the server ready.
    pub fn mark_ready(&self) {
        self.ready.store(true, Ordering::SeqCst);
        self.set_ready_gauge();
    }

    /// Stops admitting work (new requests get UNAVAILABLE); running work continues.
    pub fn start_drain(&self) {
        self.draining.store(true, Ordering::SeqCst);
        self.set_ready_gauge();
    }

    /// Ends all running work with UNAVAILABLE (the drain deadline passed).
    pub fn close_running(&self) {
        self.close_tx.send_replace(true);
    }

    /// Number of rollouts, Predict variants and Generate samples still running.
    pub fn running(&self) -> usize {
        (self.config.max_active_rollouts - self.rollout_slots.available_permits())
            + (self.config.max_predict_variants - self.predict_slots.available_permits())
            + (self.config.max_generate_samples - self.generate_slots.available_permits())
    }

    /// Stops every scheduler thread (blocking until they exit).
    pub fn shutdown_schedulers(&self) {
        for e in self.models.values() {
            e.scheduler.shutdown();
            if let Some(g) = &e.gradients {
                g.shutdown();
            }
        }
        for s in self.samplers.values() {
            s.shutdown();
        }
    }

    /// The warnings of `prepared` (see [`PreparedScenes::warnings`]), each parameter outside
    /// the trained ranges counted once per scene in `dynaserve_out_of_range_scenes_total` and
    /// logged.
    pub(crate) fn range_warnings(
        &self,
        entry: &ModelEntry,
        prepared: &PreparedScenes,
    ) -> Vec<String> {
        for (_, o) in &prepared.outside {
            self.metrics
                .out_of_range_scenes
                .with_label_values(&[entry.name.as_str(), o.field])
                .inc();
        }
        let warnings = prepared.warnings();
        for w in &warnings {
            tracing::info!(warning = %w, "parameter outside the trained range");
        }
        warnings
    }

    /// Validates and prepares the one scene of a request (field `scene`), with its warnings
    /// (see [`Engine::range_warnings`]); `kinematic` flags the objects the caller moves
    /// (`[objects]`, empty for none).
    pub(crate) async fn prepare_one(
        &self,
        entry: &Arc<ModelEntry>,
        scene: Scene,
        dt_steps: u32,
        kinematic: Arc<[bool]>,
    ) -> Result<(Arc<dyn SteppedScene>, SceneState, Vec<String>), ApiError> {
        let mut prepared = prepare_scenes(entry, vec![scene], dt_steps, "scene", kinematic).await?;
        let warnings = self.range_warnings(entry, &prepared);
        let (scene, state) = prepared
            .scenes
            .pop()
            .ok_or_else(|| ApiError::internal("no scene prepared"))?;
        Ok((scene, state, warnings))
    }

    /// Counts a request that a front end rejected before it reached the engine (malformed or
    /// oversized payload) and returns the error.
    pub fn reject(&self, ctx: &RequestCtx, method: &'static str, e: ApiError) -> ApiError {
        let span = tracing::info_span!("request", request_id = %ctx.request_id, method);
        Call::new(&self.metrics, ctx, method, span).fail(e)
    }

    /// Resident models (both families) and their limits, sorted by name, for ListModels.
    pub fn list_models(&self, ctx: &RequestCtx) -> Vec<ModelInfo> {
        Call::new(&self.metrics, ctx, "list_models", tracing::Span::none()).finish();
        let mut out: Vec<ModelInfo> = self
            .models
            .values()
            .map(|e| e.info.clone())
            .chain(self.samplers.values().map(|s| s.info().clone()))
            .collect();
        out.sort_by(|a, b| a.name.cmp(&b.name));
        out
    }

    fn resolve(&self, name: &str) -> Result<Arc<ModelEntry>, ApiError> {
        let stepping = || self.models.keys().cloned().collect::<Vec<_>>().join(", ");
        if name.is_empty() {
            if self.models.len() == 1
                && let Some(e) = self.models.values().next()
            {
                return Ok(e.clone());
            }
            if self.models.is_empty() {
                return Err(ApiError::invalid(
                    "model",
                    "no model served step by step is resident; this call needs one",
                ));
            }
            return Err(ApiError::invalid(
                "model",
                format!(
                    "required when several models are resident (one of: {})",
                    stepping()
                ),
            ));
        }
        self.models.get(name).cloned().ok_or_else(|| {
            let why = if self.samplers.contains_key(name) {
                "samples whole trajectories and serves Generate only"
            } else {
                "is not resident"
            };
            ApiError::invalid(
                "model",
                format!(
                    "{name:?} {why} (models served step by step: {})",
                    stepping()
                ),
            )
        })
    }

    /// The sampling model a Generate call names (or the only one).
    fn resolve_sampler(&self, name: &str) -> Result<Arc<dyn Sampler>, ApiError> {
        let names = || {
            let n: Vec<&str> = self.samplers.keys().map(String::as_str).collect();
            if n.is_empty() {
                "none".to_string()
            } else {
                n.join(", ")
            }
        };
        if name.is_empty() {
            if self.samplers.len() == 1
                && let Some(s) = self.samplers.values().next()
            {
                return Ok(s.clone());
            }
            return Err(ApiError::invalid(
                "model",
                format!(
                    "required unless exactly one sampling model is resident (resident: {})",
                    names()
                ),
            ));
        }
        self.samplers.get(name).cloned().ok_or_else(|| {
            let why = if self.models.contains_key(name) {
                "is not a sampling model; Generate needs one"
            } else {
                "is not resident"
            };
            ApiError::invalid(
                "model",
                format!("{name:?} {why} (sampling models: {})", names()),
            )
        })
    }

    /// Validates and admits a Generate call, then runs its samples in a task. Events arrive
    /// on the returned channel, which holds everything the call produces (at most one event
    /// per step plus one per sample), so a slow reader never holds up the passes.
    pub async fn start_generate(
        self: &Arc<Self>,
        req: GenerateSpec,
        ctx: RequestCtx,
    ) -> Result<GenerateHandle, ApiError> {
        let admitted = self
            .admit_check()
            .and_then(|()| self.resolve_sampler(&req.model));
        match admitted {
            Ok(sampler) => sampler.start_generate(self.clone(), req, ctx),
            Err(e) => Err(self.reject(&ctx, "generate", e)),
        }
    }

    pub(crate) fn admit_check(&self) -> Result<(), ApiError> {
        if self.is_draining() {
            return Err(ApiError::unavailable("server is shutting down"));
        }
        if !self.ready.load(Ordering::SeqCst) {
            return Err(ApiError::unavailable("server is warming up; retry shortly"));
        }
        Ok(())
    }

    pub(crate) fn retry_after(&self) -> Duration {
        Duration::from_millis(self.config.retry_after_ms)
    }

    /// Checks the payload size of a request.
    pub fn check_payload(&self, bytes: usize) -> Result<(), ApiError> {
        if bytes > self.config.max_request_bytes {
            return Err(ApiError::invalid(
                "request",
                format!(
                    "payload of {bytes} bytes exceeds the limit of {} bytes",
                    self.config.max_request_bytes
                ),
            ));
        }
        Ok(())
    }
}

impl SamplingHost for Engine {
    fn metrics(&self) -> &Metrics {
        &self.metrics
    }

    fn config(&self) -> &ServeConfig {
        &self.config
    }

    fn admit_check(&self) -> Result<(), ApiError> {
        Engine::admit_check(self)
    }

    fn retry_after(&self) -> Duration {
        Engine::retry_after(self)
    }

    fn generate_slots(&self) -> &Arc<Semaphore> {
        &self.generate_slots
    }

    fn next_stream_id(&self) -> u64 {
        self.next_stream.fetch_add(1, Ordering::Relaxed)
    }

    fn closing(&self) -> watch::Receiver<bool> {
        self.close_tx.subscribe()
    }
}
