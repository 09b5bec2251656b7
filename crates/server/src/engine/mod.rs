//! The protocol-independent core shared by both front ends: it takes and emits the neutral
//! vocabulary of `dynaserve_api::spec`, and `grpc.rs` and `http.rs` map their wire forms to and
//! from it. By concern:
//!
//! - this module: the engine's lifecycle (ready, drain, close, shutdown), admission checks and
//!   model lookup;
//! - [`registry`]: resident models with their schedulers and limits, scene preparation;
//! - [`request`]: request context, ids and the metrics record of each request;
//! - [`stepper`]: one scene stepping through the scheduler (the only code that submits steps);
//! - [`rollout`], [`predict`], [`warmup`]: the three users of steppers;
//! - [`sessions`]: scenes kept with their state between calls (planners), stepped through
//!   steppers whose kinematic objects follow given poses.

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

use dynaserve_api::spec::ModelInfo;
use dynaserve_model::WorldModel;
use tokio::sync::{Semaphore, watch};

pub use registry::ModelEntry;
pub use request::{Protocol, RequestCtx, new_request_id};
pub use rollout::RolloutHandle;
pub use sessions::{InteractHandle, SessionConfig, StepHandle};

use crate::config::ServeConfig;
use crate::error::ApiError;
use crate::metrics::Metrics;
use crate::scheduler::SchedulerConfig;
use request::RequestRecord;

/// The server core shared by both front ends.
pub struct Engine {
    config: ServeConfig,
    models: BTreeMap<String, Arc<ModelEntry>>,
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
    /// Starts one scheduler per model. Model names must be unique.
    pub fn new(config: ServeConfig, models: Vec<Arc<dyn WorldModel>>) -> anyhow::Result<Engine> {
        config.validate().map_err(anyhow::Error::msg)?;
        let names: Vec<String> = models.iter().map(|m| m.name().to_string()).collect();
        let metrics = Metrics::new(&names);
        let scheduling = SchedulerConfig {
            max_batch_scenes: config.max_batch_scenes,
            max_batch_objects: config.max_batch_objects,
            max_queue_delay: config.max_queue_delay(),
        };
        let caps = config.caps();
        let mut entries = BTreeMap::new();
        for model in models {
            let entry = ModelEntry::start(model, &caps, scheduling, &metrics)?;
            let name = entry.name.clone();
            if entries.insert(name.clone(), Arc::new(entry)).is_some() {
                anyhow::bail!("two models are named {name:?}; model names must be unique");
            }
        }
        if entries.is_empty() {
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
            config,
            models: entries,
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

    /// Names of the resident models.
    pub fn model_names(&self) -> Vec<String> {
        self.models.keys().cloned().collect()
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

    /// Number of rollouts and Predict variants still running.
    pub fn running(&self) -> usize {
        (self.config.max_active_rollouts - self.rollout_slots.available_permits())
            + (self.config.max_predict_variants - self.predict_slots.available_permits())
    }

    /// Stops every scheduler thread (blocking until they exit).
    pub fn shutdown_schedulers(&self) {
        for e in self.models.values() {
            e.scheduler.shutdown();
        }
    }

    /// Counts a request that a front end rejected before it reached the engine (malformed or
    /// oversized payload) and returns the error.
    pub fn reject(&self, ctx: &RequestCtx, method: &'static str, e: ApiError) -> ApiError {
        let mut rec = RequestRecord::new(&self.metrics, ctx, method);
        let span = tracing::info_span!("request", request_id = %ctx.request_id, method);
        span.in_scope(|| rec.fail(e))
    }

    /// Resident models and their limits, for ListModels.
    pub fn list_models(&self, ctx: &RequestCtx) -> Vec<ModelInfo> {
        let mut rec = RequestRecord::new(&self.metrics, ctx, "list_models");
        rec.finish(None);
        self.models.values().map(|e| e.info.clone()).collect()
    }

    fn resolve(&self, name: &str) -> Result<Arc<ModelEntry>, ApiError> {
        if name.is_empty() {
            if self.models.len() == 1
                && let Some(e) = self.models.values().next()
            {
                return Ok(e.clone());
            }
            return Err(ApiError::invalid(
                "model",
                format!(
                    "required when several models are resident (one of: {})",
                    self.model_names().join(", ")
                ),
            ));
        }
        self.models.get(name).cloned().ok_or_else(|| {
            ApiError::invalid(
                "model",
                format!(
                    "unknown model {name:?} (resident: {})",
                    self.model_names().join(", ")
                ),
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
