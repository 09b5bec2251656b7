//! The contract between the engine and the model families: the two capabilities a resident
//! model is served with ([`SteppingModel`], [`SamplingModel`] with its [`Sampler`]), what a
//! stepping family's pass takes and gives ([`SceneStep`], [`Stepped`]), and what the engine
//! lends a sampling family ([`SamplingHost`]). It names no family and no engine type, so the
//! engine and every family depend on it and never on each other.

use std::any::Any;
use std::sync::Arc;
use std::time::{Duration, Instant};

use dynaserve_api::limits::{Caps, GenerateCaps, Limits};
use dynaserve_api::spec::sampling::{GenerateEvent, GenerateSpec};
use dynaserve_api::spec::{ModelInfo, Scene};
use dynaserve_model::{Carry, OutOfRange, PathCost, PathGradient, Pose, PoseSpread, SceneState};
use tokio::sync::{Semaphore, watch};

use crate::config::ServeConfig;
use crate::engine::request::RequestCtx;
use crate::error::ApiError;
use crate::metrics::Metrics;
use crate::scheduler::SchedulerConfig;

/// A stepping family's prepared scene: whatever it computes once per request scene and
/// shares between every step, fork and variant of it.
pub trait SteppedScene: Send + Sync + 'static {
    /// Number of objects.
    fn len(&self) -> usize;
    /// True for a scene without objects.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Approximate heap bytes, counted against the sessions' memory caps.
    fn bytes(&self) -> usize;
    /// The scene as its family's own type.
    fn as_any(&self) -> &dyn Any;
}

/// A request scene prepared by its family.
pub struct Prepared {
    /// What stays fixed over the scene's steps.
    pub scene: Arc<dyn SteppedScene>,
    /// Its initial state: the poses now and one step (`dt_steps` frames) earlier.
    pub state: SceneState,
    /// Parameters outside the model's trained ranges (empty for a model without ranges).
    pub outside: Vec<OutOfRange>,
}

/// The poses a scene's kinematic objects have after a step, known before it (sessions that
/// drive objects along given paths).
#[derive(Clone, Debug)]
pub struct KinematicNext {
    /// Which objects are kinematic, `[objects]`.
    pub kinematic: Arc<[bool]>,
    /// Every object's pose after the step, `[objects]`; only the kinematic entries are read
    /// (a kinematic object without a given pose holds its current one).
    pub next: Vec<Pose>,
}

/// One scene to advance by one step: the scheduler's unit of work for a stepping model.
#[derive(Clone)]
pub struct SceneStep {
    /// The prepared scene (shared by every step of a stream).
    pub scene: Arc<dyn SteppedScene>,
    /// Its state before the step.
    pub state: SceneState,
    /// Step size in frames.
    pub dt_steps: u32,
    /// The kinematic objects' poses after the step, when the scene is driven.
    pub drive: Option<KinematicNext>,
}

/// What one step produced for one scene.
#[derive(Clone, Debug)]
pub struct Stepped {
    /// Every object's pose after the step, `[objects]`.
    pub poses: Vec<Pose>,
    /// The family's continuation for the new state ([`SceneState::carry`]).
    pub carry: Carry,
    /// Every object's spread, `[objects]`, when the model estimates one (an ensemble's
    /// members' disagreement on this step, [`dynaserve_model::WorldModel::step_with_spread`]);
    /// `None` otherwise.
    pub spread: Option<Vec<PoseSpread>>,
}

/// One Gradient call's work: candidate paths of a scene's kinematic objects, each rolled out
/// from `state` exactly as a driven Predict rolls it out and scored by `cost` (what
/// [`dynaserve_model::GradientItem`] borrows, owned for the queue). The gradient scheduler's
/// unit of work.
pub struct GradientJob {
    /// The prepared scene (a session's).
    pub scene: Arc<dyn SteppedScene>,
    /// The start state.
    pub state: SceneState,
    /// Which objects follow the paths, `[objects]`.
    pub kinematic: Arc<[bool]>,
    /// Candidate paths `[candidates][steps][kinematic objects]`: every kinematic object's pose
    /// (in object order) after each step.
    pub paths: Vec<Vec<Vec<Pose>>>,
    /// Frames per step.
    pub dt_steps: u32,
    /// The cost every candidate is scored by (steps `1..=steps`).
    pub cost: PathCost,
    /// The work is abandoned once this passes.
    pub deadline: Option<Instant>,
}

impl GradientJob {
    /// Work in scene-steps, candidates x steps (the unit of `--max-gradient-work`).
    pub fn work(&self) -> usize {
        self.paths.len() * self.paths.first().map_or(0, Vec::len)
    }
}

/// A model served step by step (Rollout, Predict, Sessions, Interact).
pub trait SteppingModel: Send + Sync + 'static {
    /// Name used in requests.
    fn name(&self) -> &str;
    /// Interval of one frame, seconds.
    fn dt_frame(&self) -> f64;
    /// The model's request limits under the server's `caps`.
    fn limits(&self, caps: &Caps) -> Limits;
    /// The ListModels entry with `limits`.
    fn info(&self, limits: Limits) -> ModelInfo;
    /// Validates and prepares one request scene (`path` names it in errors: `scene` or
    /// `variants[i]`) for steps of `dt_steps` frames; `kinematic` flags the objects the
    /// caller moves (`[objects]`, empty for none). CPU work: the engine calls it on a
    /// blocking thread.
    fn prepare(
        &self,
        scene: &Scene,
        path: &str,
        limits: &Limits,
        dt_steps: u32,
        kinematic: &[bool],
    ) -> Result<Prepared, ApiError>;
    /// Objects the model computes in one forward, when it splits a scheduler pass into
    /// forwards of that size (the scheduler then makes its passes whole numbers of them);
    /// `None` when every scene is its own computation.
    fn forward_objects(&self) -> Option<usize>;
    /// One scheduler pass: advances every item one step, one result per item in order.
    /// `Err` fails the whole pass; an item's own `Err` fails only that item.
    #[allow(clippy::type_complexity)]
    fn step(&self, items: &[&SceneStep]) -> Result<Vec<Result<Stepped, String>>, String>;
    /// Why the model computes no gradients of a driven rollout's cost (the message of the
    /// FAILED_PRECONDITION a Gradient call is answered with), or `None` when it does. By
    /// default it does not.
    fn gradients_unsupported(&self) -> Option<String> {
        Some(format!("model {} does not compute gradients", self.name()))
    }
    /// Checks a Gradient job against its scene before it is queued (INVALID_ARGUMENT naming
    /// the field); the engine has checked the request's shapes and limits.
    fn check_gradient(&self, job: &GradientJob) -> Result<(), ApiError> {
        let _ = job;
        Ok(())
    }
    /// One gradient pass: every candidate's cost, gradients and rollout for all `jobs` at
    /// once, `output[i][c]` answering candidate `c` of `jobs[i]`. CPU work, run on the
    /// gradient scheduler's thread. By default FAILED_PRECONDITION with
    /// [`SteppingModel::gradients_unsupported`].
    fn gradients(&self, jobs: &[&GradientJob]) -> Result<Vec<Vec<PathGradient>>, ApiError> {
        let _ = jobs;
        Err(ApiError::failed_precondition(
            self.gradients_unsupported().unwrap_or_default(),
        ))
    }
}

/// A model served by sampling whole trajectories (Generate), as loaded.
pub trait SamplingModel: Send + Sync + 'static {
    /// Name used in requests.
    fn name(&self) -> &str;
    /// Starts serving it: its scheduler, limits and description.
    fn start(
        self: Arc<Self>,
        caps: SamplingCaps,
        scheduling: SchedulerConfig,
        metrics: &Metrics,
    ) -> std::io::Result<Arc<dyn Sampler>>;
}

/// A sampling model being served.
pub trait Sampler: Send + Sync + 'static {
    /// Name used in requests.
    fn name(&self) -> &str;
    /// The ListModels entry.
    fn info(&self) -> &ModelInfo;
    /// Validates and admits a Generate call, then runs it in a task: its events arrive on the
    /// returned handle. Counts the call in the request metrics either way.
    fn start_generate(
        self: Arc<Self>,
        host: Arc<dyn SamplingHost>,
        req: GenerateSpec,
        ctx: RequestCtx,
    ) -> Result<GenerateHandle, ApiError>;
    /// One small sample through the scheduler, so the first request does not pay for lazy
    /// initialisation.
    fn warm_up<'a>(
        &'a self,
        host: &'a dyn SamplingHost,
    ) -> futures::future::BoxFuture<'a, Result<(), ApiError>>;
    /// Stops the scheduler thread (blocking until it exits).
    fn shutdown(&self);
}

/// A started Generate call: events (or one final error) arrive on `events`.
pub struct GenerateHandle {
    /// Model serving the call.
    pub model: String,
    /// Request id.
    pub request_id: Arc<str>,
    /// Denoising steps the call runs.
    pub steps: u32,
    /// Progress events, then one sample event per sample; an `Err` ends the stream.
    pub events: tokio::sync::mpsc::Receiver<Result<GenerateEvent, ApiError>>,
}

/// What the engine lends a sampling family for its calls.
pub trait SamplingHost: Send + Sync + 'static {
    /// The server's metrics.
    fn metrics(&self) -> &Metrics;
    /// The server's flags.
    fn config(&self) -> &ServeConfig;
    /// UNAVAILABLE while warming up or draining.
    fn admit_check(&self) -> Result<(), ApiError>;
    /// The Retry-After of a refusal for load.
    fn retry_after(&self) -> Duration;
    /// The slots of Generate samples in flight over all sampling models.
    fn generate_slots(&self) -> &Arc<Semaphore>;
    /// A scheduler stream id, unique in the engine.
    fn next_stream_id(&self) -> u64;
    /// Turns true when running work must end (the drain deadline passed).
    fn closing(&self) -> watch::Receiver<bool>;
}

/// The models an engine serves, by how they are served.
#[derive(Clone, Default)]
pub struct Models {
    /// Models served step by step (Rollout, Predict, sessions).
    pub stepping: Vec<Arc<dyn SteppingModel>>,
    /// Models served by sampling (Generate).
    pub sampling: Vec<Arc<dyn SamplingModel>>,
}

impl Models {
    /// Names of every model, stepping ones first.
    pub fn names(&self) -> Vec<String> {
        self.stepping
            .iter()
            .map(|m| m.name().to_string())
            .chain(self.sampling.iter().map(|m| m.name().to_string()))
            .collect()
    }

    /// Adds a loaded model.
    pub fn push(&mut self, model: Resident) {
        match model {
            Resident::Stepping(m) => self.stepping.push(m),
            Resident::Sampling(m) => self.sampling.push(m),
        }
    }
}

/// A model as loaded, by the capability it is served with.
pub enum Resident {
    /// Served step by step.
    Stepping(Arc<dyn SteppingModel>),
    /// Served by sampling whole trajectories.
    Sampling(Arc<dyn SamplingModel>),
}

/// Generate caps and the server's per-scene object cap, as a sampling model is started with.
#[derive(Clone, Copy, Debug)]
pub struct SamplingCaps {
    /// The server's Generate caps.
    pub generate: GenerateCaps,
    /// The server's per-scene object cap.
    pub max_objects: usize,
}

/// True when `p` lies in the domain every stepping model serves (the learned models' own
/// check, [`dynaserve_model::normalise_pose`]): a finite translation within
/// [`dynaserve_model::MAX_WORLD_EXTENT`] metres of the origin on every axis and a usable
/// rotation.
pub fn pose_in_domain(p: &Pose) -> bool {
    dynaserve_model::normalise_pose(p).is_ok()
}
