//! The protocol-independent core: resident models with their schedulers, admission, rollout
//! sessions and Predict calls. The gRPC and HTTP front ends only translate to and from it.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use dynaserve_model::{PreparedScene, SceneState, WorldModel};
use dynaserve_proto::json;
use futures::future::try_join_all;
use tokio::sync::{OwnedSemaphorePermit, Semaphore, mpsc, oneshot, watch};
use tracing::Instrument;

use crate::config::ServeConfig;
use crate::error::ApiError;
use crate::metrics::Metrics;
use crate::scene::{BuiltScene, Limits, build_scene, check_steps};
use crate::scheduler::{Priority, Scheduler, SchedulerConfig, StepError, StepOutput, StepRequest};

/// Which front end a request came through (the `protocol` metric label).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Protocol {
    /// tonic.
    Grpc,
    /// axum.
    Http,
}

impl Protocol {
    /// Label value.
    pub fn as_str(self) -> &'static str {
        match self {
            Protocol::Grpc => "grpc",
            Protocol::Http => "http",
        }
    }
}

/// Per-request context set by the front end.
#[derive(Clone, Debug)]
pub struct RequestCtx {
    /// Front end.
    pub protocol: Protocol,
    /// Request id (from `x-request-id` or generated).
    pub request_id: Arc<str>,
    /// Arrival time.
    pub arrival: Instant,
    /// Deadline from the transport (`grpc-timeout`), if any.
    pub deadline: Option<Instant>,
}

impl RequestCtx {
    /// A context arriving now.
    pub fn new(protocol: Protocol, request_id: Option<&str>, timeout: Option<Duration>) -> Self {
        let arrival = Instant::now();
        RequestCtx {
            protocol,
            request_id: request_id
                .filter(|s| valid_request_id(s))
                .map_or_else(new_request_id, str::to_string)
                .into(),
            arrival,
            deadline: timeout.map(|t| arrival + t),
        }
    }

    fn deadline_with(&self, timeout_ms: u32) -> Option<Instant> {
        let field =
            (timeout_ms > 0).then(|| self.arrival + Duration::from_millis(timeout_ms.into()));
        match (self.deadline, field) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
}

fn valid_request_id(s: &str) -> bool {
    !s.is_empty() && s.len() <= 128 && s.bytes().all(|b| b.is_ascii_graphic())
}

/// A new unique request id (16 hex digits).
pub fn new_request_id() -> String {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    static BASE: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    let base = *BASE.get_or_init(|| {
        let t = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        // splitmix64 of the start time and pid, so restarts do not repeat ids.
        let mut z = t ^ (u64::from(std::process::id()) << 32);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    });
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    format!(
        "{:016x}",
        base.wrapping_add(n.wrapping_mul(0x9e37_79b9_7f4a_7c15))
    )
}

/// A resident model: its scheduler, limits and description.
pub struct ModelEntry {
    /// Name used in requests.
    pub name: String,
    /// The scheduler that owns all forward passes of the model.
    pub scheduler: Scheduler,
    /// Request limits.
    pub limits: Limits,
    /// Description returned by ListModels.
    pub info: json::ModelInfo,
    /// Interval of one frame, seconds.
    pub dt_frame: f64,
}

impl ModelEntry {
    fn model(&self) -> &Arc<dyn WorldModel> {
        self.scheduler.model()
    }
}

/// Records a request's outcome in the metrics exactly once; a request dropped without an
/// outcome (client went away) counts as cancelled.
struct RequestRecord {
    metrics: Metrics,
    protocol: &'static str,
    method: &'static str,
    arrival: Instant,
    done: bool,
}

impl RequestRecord {
    fn new(metrics: &Metrics, ctx: &RequestCtx, method: &'static str) -> RequestRecord {
        metrics
            .requests
            .with_label_values(&[ctx.protocol.as_str(), method])
            .inc();
        RequestRecord {
            metrics: metrics.clone(),
            protocol: ctx.protocol.as_str(),
            method,
            arrival: ctx.arrival,
            done: false,
        }
    }

    fn finish(&mut self, error: Option<&ApiError>) {
        if !self.done {
            self.done = true;
            self.metrics.finish_request(
                self.protocol,
                self.method,
                self.arrival.elapsed(),
                error.map(ApiError::reason),
            );
        }
    }

    fn fail(&mut self, e: ApiError) -> ApiError {
        tracing::info!(code = e.code_name(), error = %e.message, "request failed");
        self.finish(Some(&e));
        e
    }
}

impl Drop for RequestRecord {
    fn drop(&mut self) {
        if !self.done {
            self.finish(Some(&ApiError::cancelled("client went away")));
        }
    }
}

/// Tells the scheduler not to wait for this stream any more once it ends (normally or not).
struct StreamGuard {
    entry: Arc<ModelEntry>,
    id: u64,
}

impl Drop for StreamGuard {
    fn drop(&mut self) {
        self.entry.scheduler.idle(self.id);
    }
}

/// Decrements an active-work gauge when dropped.
struct GaugeGuard(prometheus::IntGauge, i64);

impl Drop for GaugeGuard {
    fn drop(&mut self) {
        self.0.sub(self.1);
    }
}

/// A started rollout: frames (or one final error) arrive on `frames`.
pub struct RolloutHandle {
    /// Model serving the rollout.
    pub model: String,
    /// Request id.
    pub request_id: Arc<str>,
    /// Frames in step order; an `Err` ends the stream.
    pub frames: mpsc::Receiver<Result<json::StepFrame, ApiError>>,
}

/// Result of [`Engine::predict`].
pub struct PredictOutcome {
    /// The response document.
    pub response: json::PredictResponse,
}

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
}

impl Engine {
    /// Starts one scheduler per model. Model names must be unique.
    pub fn new(config: ServeConfig, models: Vec<Arc<dyn WorldModel>>) -> anyhow::Result<Engine> {
        config.validate().map_err(anyhow::Error::msg)?;
        let names: Vec<String> = models.iter().map(|m| m.name().to_string()).collect();
        let metrics = Metrics::new(&names);
        let sched = SchedulerConfig {
            max_batch_scenes: config.max_batch_scenes,
            max_batch_objects: config.max_batch_objects,
            max_queue_delay: config.max_queue_delay(),
        };
        let mut entries = BTreeMap::new();
        for model in models {
            let name = model.name().to_string();
            let cfg = model.config().clone();
            let limits = Limits::new(&config, &cfg);
            let info = json::ModelInfo {
                name: name.clone(),
                architecture: cfg.architecture.clone(),
                dt_frame: f64::from(cfg.dt_frame),
                default_points: limits.default_points as u32,
                max_objects: limits.max_objects as u32,
                max_points_per_object: limits.max_points_per_object as u32,
                max_steps: limits.max_steps,
                max_dt_steps: limits.max_dt_steps,
                max_variants: limits.max_variants as u32,
                gravity: cfg.gravity,
                config: serde_json::to_value(&cfg).unwrap_or(serde_json::Value::Null),
            };
            let scheduler = Scheduler::start(model, sched, metrics.clone())?;
            let entry = ModelEntry {
                name: name.clone(),
                scheduler,
                limits,
                info,
                dt_frame: f64::from(cfg.dt_frame),
            };
            if entries.insert(name.clone(), Arc::new(entry)).is_some() {
                anyhow::bail!("two models are named {name:?}; model names must be unique");
            }
        }
        if entries.is_empty() {
            anyhow::bail!("no models to serve");
        }
        let (close_tx, _) = watch::channel(false);
        Ok(Engine {
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

    /// Runs two steps of a small synthetic scene through every model's scheduler, so that the
    /// first request does not pay for lazy initialisation.
    pub async fn warm_up(&self) -> Result<(), ApiError> {
        for entry in self.models.values() {
            let start = Instant::now();
            let limits = entry.limits;
            let points = limits.default_points.clamp(1, 256) as u32;
            let cube = |x: f32, z: f32| json::ObjectSpec {
                points: None,
                mesh: Some(json::TriangleMesh {
                    vertices: dynaserve_geometry::mesh::cube().vertices,
                    faces: dynaserve_geometry::mesh::cube().faces,
                    samples: points,
                    seed: 1,
                }),
                pose: json::Pose {
                    translation: [x, 0.0, z],
                    rotation: json::IDENTITY_ROTATION,
                },
                previous_pose: None,
                velocity: None,
                mass: 1.0,
                friction: 0.5,
                restitution: 0.3,
            };
            let scene = json::Scene {
                objects: vec![cube(0.0, 0.5), cube(0.3, 1.6)],
            };
            let model = entry.model().clone();
            let dt = entry.dt_frame as f32;
            let prepared = tokio::task::spawn_blocking(move || {
                let built = build_scene(&scene, "scene", &limits, dt)?;
                let prepared = model
                    .prepare(built.objects)
                    .map_err(|e| ApiError::internal(format!("warm-up: {e}")))?;
                Ok::<_, ApiError>((Arc::new(prepared), built.state))
            })
            .await
            .map_err(|e| ApiError::internal(format!("warm-up task: {e}")))??;
            let (scene, mut state) = prepared;
            let rid: Arc<str> = "warm-up".into();
            for step in 0..2 {
                let id = self.next_stream.fetch_add(1, Ordering::Relaxed);
                let out = submit_step(
                    entry,
                    StepRequestParts {
                        scene: scene.clone(),
                        state: state.clone(),
                        dt_steps: 1,
                        priority: Priority::Interactive,
                        deadline: None,
                        stream_id: id,
                        more_steps: step == 0,
                        request_id: rid.clone(),
                    },
                )
                .await
                .map_err(|e| ApiError::internal(format!("warm-up step: {e}")))?;
                state.previous = std::mem::replace(&mut state.current, out.poses);
            }
            tracing::info!(
                model = %entry.name,
                ms = start.elapsed().as_secs_f64() * 1e3,
                "warmed up"
            );
        }
        Ok(())
    }

    /// Counts a request that a front end rejected before it reached the engine (malformed or
    /// oversized payload) and returns the error.
    pub fn reject(&self, ctx: &RequestCtx, method: &'static str, e: ApiError) -> ApiError {
        let mut rec = RequestRecord::new(&self.metrics, ctx, method);
        let span = tracing::info_span!("request", request_id = %ctx.request_id, method);
        span.in_scope(|| rec.fail(e))
    }

    /// Models for ListModels.
    pub fn list_models(&self, ctx: &RequestCtx) -> json::ListModelsResponse {
        let mut rec = RequestRecord::new(&self.metrics, ctx, "list_models");
        rec.finish(None);
        json::ListModelsResponse {
            models: self.models.values().map(|e| e.info.clone()).collect(),
        }
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

    /// Validates and admits a rollout, then runs it in a session task. Frames arrive on the
    /// returned channel (bounded: a slow reader pauses the rollout).
    pub async fn start_rollout(
        self: &Arc<Self>,
        req: json::RolloutRequest,
        ctx: RequestCtx,
    ) -> Result<RolloutHandle, ApiError> {
        let mut rec = RequestRecord::new(&self.metrics, &ctx, "rollout");
        let span = tracing::info_span!(
            "rollout",
            request_id = %ctx.request_id,
            protocol = ctx.protocol.as_str(),
            model = tracing::field::Empty
        );
        let prepared = async {
            self.admit_check()?;
            let entry = self.resolve(&req.model)?;
            tracing::Span::current().record("model", entry.name.as_str());
            let dt_steps = check_steps(req.steps, req.dt_steps, &entry.limits)?;
            let deadline = ctx.deadline_with(req.timeout_ms);
            let permit = self
                .rollout_slots
                .clone()
                .try_acquire_owned()
                .map_err(|_| {
                    ApiError::exhausted(
                        format!(
                            "{} rollouts are active, the server's limit; retry later",
                            self.config.max_active_rollouts
                        ),
                        self.retry_after(),
                    )
                })?;
            let (scene, state) = prepare_scenes(&entry, vec![req.scene], dt_steps, "scene")
                .await?
                .pop()
                .ok_or_else(|| ApiError::internal("no scene prepared"))?;
            Ok::<_, ApiError>((entry, dt_steps, deadline, permit, scene, state))
        }
        .instrument(span.clone())
        .await;
        let (entry, dt_steps, deadline, permit, scene, state) = match prepared {
            Ok(p) => p,
            Err(e) => return Err(span.in_scope(|| rec.fail(e))),
        };
        let (tx, rx) = mpsc::channel(self.config.stream_buffer);
        let session = Session {
            stream_id: self.next_stream.fetch_add(1, Ordering::Relaxed),
            entry: entry.clone(),
            scene,
            state,
            dt_steps,
            steps: req.steps,
            deadline,
            request_id: ctx.request_id.clone(),
            close: self.close_tx.subscribe(),
        };
        let gauge = self
            .metrics
            .active_rollouts
            .with_label_values(&[entry.name.as_str()]);
        gauge.inc();
        tokio::spawn(
            async move {
                let _permit: OwnedSemaphorePermit = permit;
                let _gauge = GaugeGuard(gauge, 1);
                let start = Instant::now();
                let outcome = session.run(tx).await;
                match &outcome {
                    Ok(()) => {
                        tracing::info!(
                            steps = req.steps,
                            ms = start.elapsed().as_secs_f64() * 1e3,
                            "rollout finished"
                        );
                        rec.finish(None);
                    }
                    Err(e) => {
                        rec.fail(e.clone());
                    }
                }
            }
            .instrument(span),
        );
        Ok(RolloutHandle {
            model: entry.name.clone(),
            request_id: ctx.request_id,
            frames: rx,
        })
    }

    /// Validates, admits and runs a Predict call: every variant is rolled forward as its own
    /// stream of bulk-priority step requests, all joining the same batches.
    pub async fn predict(
        self: &Arc<Self>,
        req: json::PredictRequest,
        ctx: RequestCtx,
    ) -> Result<PredictOutcome, ApiError> {
        let mut rec = RequestRecord::new(&self.metrics, &ctx, "predict");
        let span = tracing::info_span!(
            "predict",
            request_id = %ctx.request_id,
            protocol = ctx.protocol.as_str(),
            model = tracing::field::Empty,
            variants = req.variants.len()
        );
        let result = self.predict_inner(req, &ctx).instrument(span.clone()).await;
        span.in_scope(|| match result {
            Ok(r) => {
                rec.finish(None);
                Ok(r)
            }
            Err(e) => Err(rec.fail(e)),
        })
    }

    async fn predict_inner(
        self: &Arc<Self>,
        req: json::PredictRequest,
        ctx: &RequestCtx,
    ) -> Result<PredictOutcome, ApiError> {
        self.admit_check()?;
        let entry = self.resolve(&req.model)?;
        tracing::Span::current().record("model", entry.name.as_str());
        let dt_steps = check_steps(req.steps, req.dt_steps, &entry.limits)?;
        let n = req.variants.len();
        if n == 0 || n > entry.limits.max_variants {
            return Err(ApiError::invalid(
                "variants",
                format!(
                    "{n} variants given; 1..={} accepted",
                    entry.limits.max_variants
                ),
            ));
        }
        let deadline = ctx.deadline_with(req.timeout_ms);
        let permit = u32::try_from(n)
            .ok()
            .and_then(|k| self.predict_slots.clone().try_acquire_many_owned(k).ok())
            .ok_or_else(|| {
                ApiError::exhausted(
                    format!(
                        "{n} variants would exceed the server's limit of {} in flight; retry later",
                        self.config.max_predict_variants
                    ),
                    self.retry_after(),
                )
            })?;
        let gauge = self
            .metrics
            .active_predict
            .with_label_values(&[entry.name.as_str()]);
        gauge.add(n as i64);
        let _gauge = GaugeGuard(gauge, n as i64);
        let _permit = permit;
        let variants = with_deadline(
            deadline,
            prepare_scenes(&entry, req.variants, dt_steps, "variants"),
        )
        .await?;
        let every = req.every;
        let steps = req.steps;
        let runs = variants.into_iter().map(|(scene, state)| {
            let entry = entry.clone();
            let id = self.next_stream.fetch_add(1, Ordering::Relaxed);
            let rid = ctx.request_id.clone();
            async move {
                let _guard = StreamGuard {
                    entry: entry.clone(),
                    id,
                };
                let mut state = state;
                let mut frames = Vec::new();
                let mut timing = json::RequestTiming::default();
                for step in 1..=steps {
                    let out = submit_step(
                        &entry,
                        StepRequestParts {
                            scene: scene.clone(),
                            state: state.clone(),
                            dt_steps,
                            priority: Priority::Bulk,
                            deadline,
                            stream_id: id,
                            more_steps: step < steps,
                            request_id: rid.clone(),
                        },
                    )
                    .await?;
                    timing.queue_ms += out.queue_wait.as_secs_f64() * 1e3;
                    timing.forward_ms += out.forward.as_secs_f64() * 1e3;
                    let keep = step == steps || (every > 0 && step % every == 0);
                    if keep {
                        frames.push(json::StepFrame {
                            step,
                            time: f64::from(step) * f64::from(dt_steps) * entry.dt_frame,
                            poses: out.poses.iter().map(to_json_pose).collect(),
                            timing: None,
                        });
                    }
                    state.previous = std::mem::replace(&mut state.current, out.poses);
                }
                Ok::<_, ApiError>((json::Trajectory { frames }, timing))
            }
        });
        let mut close = self.close_tx.subscribe();
        let all = tokio::select! {
            r = with_deadline(deadline, try_join_all(runs)) => r?,
            _ = close.wait_for(|c| *c) => {
                return Err(ApiError::unavailable(
                    "server shutting down: the drain deadline passed before the call finished",
                ));
            }
        };
        let mut timing = json::RequestTiming::default();
        let mut trajectories = Vec::with_capacity(all.len());
        // The variants step concurrently (mostly in the same passes): the request's timing is
        // that of its slowest variant, not the sum over variants.
        for (t, tm) in all {
            timing.queue_ms = timing.queue_ms.max(tm.queue_ms);
            timing.forward_ms = timing.forward_ms.max(tm.forward_ms);
            trajectories.push(t);
        }
        timing.total_ms = ctx.arrival.elapsed().as_secs_f64() * 1e3;
        Ok(PredictOutcome {
            response: json::PredictResponse {
                model: entry.name.clone(),
                trajectories,
                timing,
            },
        })
    }
}

async fn with_deadline<T>(
    deadline: Option<Instant>,
    fut: impl std::future::Future<Output = Result<T, ApiError>>,
) -> Result<T, ApiError> {
    match deadline {
        Some(d) => tokio::time::timeout_at(d.into(), fut)
            .await
            .map_err(|_| ApiError::deadline("deadline exceeded"))?,
        None => fut.await,
    }
}

fn to_json_pose(p: &dynaserve_model::Pose) -> json::Pose {
    json::Pose {
        translation: p.translation,
        rotation: p.rotation,
    }
}

/// Validates, builds and prepares scenes on a blocking thread (mesh sampling and the model's
/// per-object caches are CPU work that must not run on the async runtime).
async fn prepare_scenes(
    entry: &Arc<ModelEntry>,
    scenes: Vec<json::Scene>,
    dt_steps: u32,
    field: &'static str,
) -> Result<Vec<(Arc<PreparedScene>, SceneState)>, ApiError> {
    let entry = entry.clone();
    let single = field == "scene";
    tokio::task::spawn_blocking(move || {
        let dt_seconds = (f64::from(dt_steps) * entry.dt_frame) as f32;
        scenes
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let path = if single {
                    field.to_string()
                } else {
                    format!("{field}[{i}]")
                };
                let BuiltScene { objects, state } =
                    build_scene(s, &path, &entry.limits, dt_seconds)?;
                let prepared = entry.model().prepare(objects).map_err(|e| match e {
                    dynaserve_model::ModelError::InvalidInput(m) => {
                        ApiError::invalid(path.clone(), m)
                    }
                    other => ApiError::internal(other.to_string()),
                })?;
                Ok((Arc::new(prepared), state))
            })
            .collect()
    })
    .await
    .map_err(|e| ApiError::internal(format!("scene preparation failed: {e}")))?
}

struct StepRequestParts {
    scene: Arc<PreparedScene>,
    state: SceneState,
    dt_steps: u32,
    priority: Priority,
    deadline: Option<Instant>,
    stream_id: u64,
    more_steps: bool,
    request_id: Arc<str>,
}

fn send_step(
    entry: &ModelEntry,
    p: StepRequestParts,
) -> oneshot::Receiver<Result<StepOutput, StepError>> {
    let (reply, rx) = oneshot::channel();
    entry.scheduler.submit(StepRequest {
        scene: p.scene,
        state: p.state,
        dt_steps: p.dt_steps,
        priority: p.priority,
        deadline: p.deadline,
        stream_id: p.stream_id,
        more_steps: p.more_steps,
        request_id: p.request_id,
        reply,
    });
    rx
}

fn step_error(e: StepError) -> ApiError {
    match e {
        StepError::DeadlineExceeded => ApiError::deadline("deadline exceeded while queued"),
        StepError::Model(m) => ApiError::internal(m),
        StepError::Stopped => ApiError::unavailable("server shutting down"),
    }
}

async fn submit_step(entry: &ModelEntry, p: StepRequestParts) -> Result<StepOutput, ApiError> {
    let rx = send_step(entry, p);
    match rx.await {
        Ok(r) => r.map_err(step_error),
        Err(_) => Err(ApiError::unavailable("server shutting down")),
    }
}

/// One streamed rollout: owns the scene state and submits one step at a time.
struct Session {
    stream_id: u64,
    entry: Arc<ModelEntry>,
    scene: Arc<PreparedScene>,
    state: SceneState,
    dt_steps: u32,
    steps: u32,
    deadline: Option<Instant>,
    request_id: Arc<str>,
    close: watch::Receiver<bool>,
}

async fn sleep_until(deadline: Option<Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d.into()).await,
        None => std::future::pending().await,
    }
}

impl Session {
    /// Runs the rollout to its end, a deadline, a drain close or the client's disappearance.
    /// The final error, if any, is also sent to the client.
    async fn run(
        mut self,
        tx: mpsc::Sender<Result<json::StepFrame, ApiError>>,
    ) -> Result<(), ApiError> {
        let _guard = StreamGuard {
            entry: self.entry.clone(),
            id: self.stream_id,
        };
        let deadline_msg = "deadline exceeded";
        let close_msg =
            "server shutting down: the drain deadline passed before the rollout finished";
        let mut close = self.close.clone();
        for step in 1..=self.steps {
            // Reserve room for the frame before asking for the step: a client that reads slowly
            // pauses only this rollout, and the scheduler is told not to wait for it meanwhile.
            let permit = match tx.try_reserve() {
                Ok(p) => p,
                Err(mpsc::error::TrySendError::Closed(())) => {
                    return Err(ApiError::cancelled("client went away"));
                }
                Err(mpsc::error::TrySendError::Full(())) => {
                    self.entry.scheduler.idle(self.stream_id);
                    tokio::select! {
                        p = tx.reserve() => match p {
                            Ok(p) => p,
                            Err(_) => return Err(ApiError::cancelled("client went away")),
                        },
                        _ = sleep_until(self.deadline) => {
                            // The client is not reading; the error cannot be delivered either.
                            return Err(ApiError::deadline(deadline_msg));
                        }
                        _ = close.wait_for(|c| *c) => {
                            return Err(ApiError::unavailable(close_msg));
                        }
                    }
                }
            };
            let rx = send_step(
                &self.entry,
                StepRequestParts {
                    scene: self.scene.clone(),
                    state: self.state.clone(),
                    dt_steps: self.dt_steps,
                    priority: Priority::Interactive,
                    deadline: self.deadline,
                    stream_id: self.stream_id,
                    more_steps: step < self.steps,
                    request_id: self.request_id.clone(),
                },
            );
            let out = tokio::select! {
                r = rx => match r {
                    Ok(Ok(out)) => out,
                    Ok(Err(e)) => {
                        let e = step_error(e);
                        permit.send(Err(e.clone()));
                        return Err(e);
                    }
                    Err(_) => {
                        let e = ApiError::unavailable("server shutting down");
                        permit.send(Err(e.clone()));
                        return Err(e);
                    }
                },
                // Dropping `rx` here lets the scheduler discard the queued step.
                _ = tx.closed() => return Err(ApiError::cancelled("client went away")),
                _ = sleep_until(self.deadline) => {
                    let e = ApiError::deadline(deadline_msg);
                    permit.send(Err(e.clone()));
                    return Err(e);
                }
                _ = close.wait_for(|c| *c) => {
                    let e = ApiError::unavailable(close_msg);
                    permit.send(Err(e.clone()));
                    return Err(e);
                }
            };
            tracing::trace!(step, batch = out.batch_id, "step");
            let frame = json::StepFrame {
                step,
                time: f64::from(step) * f64::from(self.dt_steps) * self.entry.dt_frame,
                poses: out.poses.iter().map(to_json_pose).collect(),
                timing: Some(json::StepTiming {
                    queue_ms: (out.queue_wait.as_secs_f64() * 1e3) as f32,
                    forward_ms: (out.forward.as_secs_f64() * 1e3) as f32,
                    batch_scenes: out.batch_scenes,
                }),
            };
            self.state.previous = std::mem::replace(&mut self.state.current, out.poses);
            permit.send(Ok(frame));
        }
        Ok(())
    }
}
