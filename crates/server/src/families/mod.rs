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
//! Adding a family is one module here and one line in [`registry`] (docs/architecture.md,
//! "Adding a family").

pub mod physiformer;
pub mod rapier;
pub mod rigidformer;

use std::any::Any;
use std::path::Path;
use std::sync::Arc;

use anyhow::Context;
use dynaserve_api::limits::{Caps, GenerateCaps, Limits};
use dynaserve_api::spec::generate::{GenerateEvent, GenerateSpec};
use dynaserve_api::spec::{ModelInfo, Scene};
use dynaserve_model::{Carry, OutOfRange, Pose, PoseSpread, SceneState};

use crate::engine::{Engine, RequestCtx};
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
        engine: &Arc<Engine>,
        req: GenerateSpec,
        ctx: RequestCtx,
    ) -> Result<GenerateHandle, ApiError>;
    /// One small sample through the scheduler, so the first request does not pay for lazy
    /// initialisation.
    fn warm_up<'a>(
        &'a self,
        engine: &'a Engine,
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

/// A model as loaded, by the capability it is served with.
pub enum Resident {
    /// Served step by step.
    Stepping(Arc<dyn SteppingModel>),
    /// Served by sampling whole trajectories.
    Sampling(Arc<dyn SamplingModel>),
}

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
