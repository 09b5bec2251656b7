//! The protocol-independent core shared by both front ends: it takes and emits the neutral
//! vocabulary of `dynaserve_api::spec`, and `grpc.rs` and `http.rs` map their wire forms to and
//! from it. By concern:
//!
//! - this module: the engine's lifecycle (ready, drain, close, shutdown), admission checks and
//!   model lookup;
//! - [`registry`]: resident models with their schedulers and limits, scene preparation;
//! - [`request`]: request context, ids and the metrics record of each request;
//! - `stepper`: one scene stepping through the scheduler (the only code that submits steps);
//! - `rollout`, `predict`, `warmup`: the three users of steppers;
//! - [`generate`]: PhysiFormer models and Generate calls, one scheduler stream per sample;
//! - [`sessions`]: scenes kept with their state between calls (planners), stepped through
//!   steppers whose kinematic objects follow given poses.

pub mod generate;
mod predict;
pub mod registry;
pub mod request;
mod rollout;
pub mod sessions;
mod stepper;
mod warmup;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use dynaserve_api::spec::{ModelInfo, Scene};
use dynaserve_model::{PhysiFormer, PreparedScene, SceneState, WorldModel};
use tokio::sync::{Semaphore, watch};

pub use generate::{GenerateHandle, GeneratorEntry};
pub use registry::ModelEntry;
use registry::{PreparedScenes, prepare_scenes};
pub use request::{Protocol, RequestCtx, new_request_id};
pub use rollout::RolloutHandle;
pub use sessions::{InteractHandle, StepHandle};

use crate::config::ServeConfig;
use crate::error::ApiError;
use crate::metrics::Metrics;
use crate::scheduler::{PassGate, SchedulerConfig};
use request::RequestRecord;

/// The models an engine serves, by family.
#[derive(Clone, Default)]
pub struct Models {
    /// RigidFormer models (Rollout, Predict, sessions).
    pub rigid: Vec<Arc<dyn WorldModel>>,
    /// PhysiFormer models (Generate).
    pub physi: Vec<Arc<PhysiFormer>>,
}

impl Models {
    /// Names of every model, rigid first.
    pub fn names(&self) -> Vec<String> {
        self.rigid
            .iter()
            .map(|m| m.name().to_string())
            .chain(self.physi.iter().map(|m| m.name().to_string()))
            .collect()
    }
}

impl From<Vec<Arc<dyn WorldModel>>> for Models {
    fn from(rigid: Vec<Arc<dyn WorldModel>>) -> Models {
        Models {
            rigid,
            physi: Vec::new(),
        }
    }
}

/// The server core shared by both front ends.
pub struct Engine {
    config: ServeConfig,
    models: BTreeMap<String, Arc<ModelEntry>>,
    generators: BTreeMap<String, Arc<GeneratorEntry>>,
    generate_slots: Arc<Semaphore>,
    metrics: Metrics,
    rollout_slots: Arc<Semaphore>,
    predict_slots: Arc<Semaphore>,
    ready: AtomicBool,
    draining: AtomicBool,
    close_tx: watch::Sender<bool>,
    next_stream: AtomicU64,
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
        for model in models.rigid {
            let entry = ModelEntry::start(model, &caps, scheduling.clone(), &metrics)?;
            let name = entry.name.clone();
            if entries.insert(name.clone(), Arc::new(entry)).is_some() {
                anyhow::bail!("two models are named {name:?}; model names must be unique");
            }
        }
        let mut generators = BTreeMap::new();
        for model in models.physi {
            let entry = GeneratorEntry::start(
                model,
                &config.generate_caps(),
                caps.max_objects,
                scheduling.clone(),
                &metrics,
            )?;
            let name = entry.name.clone();
            if entries.contains_key(&name)
                || generators.insert(name.clone(), Arc::new(entry)).is_some()
            {
                anyhow::bail!("two models are named {name:?}; model names must be unique");
            }
        }
        if entries.is_empty() && generators.is_empty() {
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
            generators,
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
            .chain(self.generators.keys())
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
        }
        for e in self.generators.values() {
            e.scheduler.shutdown();
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
    ) -> Result<(Arc<PreparedScene>, SceneState, Vec<String>), ApiError> {
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
        let mut rec = RequestRecord::new(&self.metrics, ctx, method);
        let span = tracing::info_span!("request", request_id = %ctx.request_id, method);
        span.in_scope(|| rec.fail(e))
    }

    /// Resident models (both families) and their limits, sorted by name, for ListModels.
    pub fn list_models(&self, ctx: &RequestCtx) -> Vec<ModelInfo> {
        let mut rec = RequestRecord::new(&self.metrics, ctx, "list_models");
        rec.finish(None);
        let mut out: Vec<ModelInfo> = self
            .models
            .values()
            .map(|e| e.info.clone())
            .chain(self.generators.values().map(|e| e.info.clone()))
            .collect();
        out.sort_by(|a, b| a.name.cmp(&b.name));
        out
    }

    fn resolve(&self, name: &str) -> Result<Arc<ModelEntry>, ApiError> {
        let rigid = || self.models.keys().cloned().collect::<Vec<_>>().join(", ");
        if name.is_empty() {
            if self.models.len() == 1
                && let Some(e) = self.models.values().next()
            {
                return Ok(e.clone());
            }
            if self.models.is_empty() {
                return Err(ApiError::invalid(
                    "model",
                    "no RigidFormer model is resident; this call needs one",
                ));
            }
            return Err(ApiError::invalid(
                "model",
                format!(
                    "required when several models are resident (one of: {})",
                    rigid()
                ),
            ));
        }
        self.models.get(name).cloned().ok_or_else(|| {
            let why = if self.generators.contains_key(name) {
                "is a PhysiFormer model, which serves Generate only"
            } else {
                "is not resident"
            };
            ApiError::invalid(
                "model",
                format!("{name:?} {why} (RigidFormer models: {})", rigid()),
            )
        })
    }

    fn admit_check(&self) -> Result<(), ApiError> {
        if self.is_draining() {
            return Err(ApiError::unavailable("server is shutting down"));
        }
        if !self.ready.load(Ordering::SeqCst) {
            return Err(ApiError::unavailable("server is warming up; retry shortly"));
        }
        Ok(())
    }

    fn retry_after(&self) -> Duration {
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
