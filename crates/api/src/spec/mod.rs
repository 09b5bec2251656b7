//! The protocol-neutral vocabulary: what the engine takes (a [`RolloutSpec`] or a
//! [`PredictSpec`] holding [`Scene`]s) and what it emits ([`Frame`]s, a [`Prediction`],
//! [`ModelInfo`]). Each wire form maps to it on its own: [`json`] for the HTTP documents, [`v1`]
//! for the gRPC messages. Nothing here is validated beyond the wire form's own structure
//! (exactly one shape, at most one motion); limits and ranges are the server's to check, as it
//! builds a scene into its model's inputs.
//!
//! Units: metres, seconds, kilograms, radians; z up; quaternions `[x, y, z, w]`.

pub mod gradient;
pub mod json;
pub mod sampling;
pub mod session;
pub mod v1;

use std::time::Duration;

pub use dynaserve_model::{Pose, PoseSpread};

use crate::limits::{GenerateLimits, Limits};

/// A triangle mesh in the body frame (origin at the centre of mass), metres, to be sampled.
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    /// Vertex positions `[n, 3]`, metres.
    pub vertices: Vec<[f32; 3]>,
    /// Vertex index triples, counter-clockwise seen from outside.
    pub faces: Vec<[u32; 3]>,
    /// Points to sample; 0 means the model's default point count.
    pub samples: u32,
    /// Seed of the surface sampler.
    pub seed: u64,
}

/// The surface of an object.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// Reference surface points `[n, 3]` in the body frame, metres.
    Points(Vec<[f32; 3]>),
    /// A mesh the server samples.
    Mesh(Mesh),
}

/// How an object moves at the start.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Motion {
    /// At rest: the previous pose equals the current one.
    Rest,
    /// The pose one step (`dt_steps` frames) before the current one.
    PreviousPose(Pose),
    /// Velocities at the current pose, world frame: linear m/s, angular rad/s.
    Velocity {
        /// `[vx, vy, vz]`, m/s.
        linear: [f32; 3],
        /// `[wx, wy, wz]`, rad/s (axis times rate).
        angular: [f32; 3],
    },
}

/// One rigid object of a request.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectSpec {
    /// Its surface.
    pub shape: Shape,
    /// Current pose (centre of mass, body-to-world rotation), not yet normalised.
    pub pose: Pose,
    /// Initial motion.
    pub motion: Motion,
    /// Kilograms.
    pub mass: f32,
    /// Coulomb friction coefficient.
    pub friction: f32,
    /// Coefficient of restitution.
    pub restitution: f32,
}

/// A rigid multi-object scene above the ground plane z = 0.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// The objects, in request order.
    pub objects: Vec<ObjectSpec>,
}

/// A rollout request: one scene, streamed frame by frame.
#[derive(Clone, Debug, PartialEq)]
pub struct RolloutSpec {
    /// Model name; empty when exactly one model is resident.
    pub model: String,
    /// The scene.
    pub scene: Scene,
    /// Steps to produce.
    pub steps: u32,
    /// Frames per step; 0 means 1.
    pub dt_steps: u32,
    /// Deadline in milliseconds from arrival; 0 means none.
    pub timeout_ms: u32,
}

/// A planner call: many scene variants rolled forward together.
#[derive(Clone, Debug, PartialEq)]
pub struct PredictSpec {
    /// Model name; empty when exactly one model is resident.
    pub model: String,
    /// Scene variants, each rolled forward independently.
    pub variants: Vec<Scene>,
    /// Steps.
    pub steps: u32,
    /// Frames per step; 0 means 1.
    pub dt_steps: u32,
    /// Keep every k-th step plus the final one; 0 keeps the final step only.
    pub every: u32,
    /// Deadline in milliseconds from arrival; 0 means none.
    pub timeout_ms: u32,
}

/// Server-side timing of one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepTiming {
    /// Time the step waited in the scheduler queue.
    pub queue: Duration,
    /// Duration of the forward pass that computed it.
    pub forward: Duration,
    /// Scenes in that pass.
    pub batch_scenes: u32,
}

/// The state after one step.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Step index, from 1.
    pub step: u32,
    /// Physical time since the initial state, `step * dt_steps * dt_frame` seconds.
    pub time: f64,
    /// New pose of every object, in request order.
    pub poses: Vec<Pose>,
    /// Server-side timing (streamed frames carry it; planner frames do not).
    pub timing: Option<StepTiming>,
    /// Every object's spread, in request order, when the model estimates one (an ensemble's
    /// members' disagreement on this step); empty otherwise.
    pub spread: Vec<PoseSpread>,
}

/// Whole-request timings.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Timing {
    /// Time spent queued, summed over steps (a planner call: its slowest variant's).
    pub queue: Duration,
    /// Forward passes, summed over steps (a planner call: its slowest variant's).
    pub forward: Duration,
    /// Wall time from arrival to the last frame.
    pub total: Duration,
}

impl Timing {
    /// Adds one step's queue and forward time.
    pub fn add_step(&mut self, step: &StepTiming) {
        self.queue += step.queue;
        self.forward += step.forward;
    }
}

/// The result of a planner call.
#[derive(Clone, Debug, PartialEq)]
pub struct Prediction {
    /// Model that served it.
    pub model: String,
    /// Kept frames of every variant, in request order (`[variants][frames]`).
    pub trajectories: Vec<Vec<Frame>>,
    /// Timings.
    pub timing: Timing,
    /// One line per object parameter of the variants outside the range the model was trained
    /// on (sent as `x-dynaserve-warning` headers / metadata); empty when all are inside.
    pub warnings: Vec<String>,
}

/// A resident model and the limits requests to it must respect.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelInfo {
    /// Name used in requests.
    pub name: String,
    /// Its family, configuration and limits.
    pub kind: ModelKind,
    /// Names of an ensemble's member networks, whose predicted poses each step averages (the
    /// configuration is the first member's); empty for a single network.
    pub members: Vec<String>,
    /// True when the model computes gradients of a driven rollout's cost (session Gradient).
    pub gradients: bool,
}

/// How a resident model is served, with what every family reports about itself
/// (architecture, frame interval, gravity, its configuration) and its request limits.
#[derive(Clone, Debug, PartialEq)]
pub enum ModelKind {
    /// Advanced step by step: Rollout, Predict and sessions (RigidFormer, the simulator).
    Stepping {
        /// What the model is.
        about: About,
        /// Request limits.
        limits: Limits,
    },
    /// Sampled whole: Generate (PhysiFormer).
    Sampling {
        /// What the model is.
        about: About,
        /// Generate limits.
        limits: GenerateLimits,
    },
}

/// What every family reports about a model.
#[derive(Clone, Debug, PartialEq)]
pub struct About {
    /// Architecture name (config.json's `architecture`).
    pub architecture: String,
    /// Interval of one frame, seconds.
    pub dt_frame: f64,
    /// Gravity the model assumes, m/s^2 (world frame).
    pub gravity: [f32; 3],
    /// The model's configuration as JSON.
    pub config: serde_json::Value,
}

/// Milliseconds of a duration, as the wire forms carry them.
pub fn millis(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}
