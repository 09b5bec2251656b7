//! JSON form of the `dynaserve.v1` messages: the HTTP API bodies and the scene file format
//! (a scene file is a [`RolloutRequest`] document, so `curl -d @scene.json` works). Types only:
//! the conversions to and from the gRPC form are in [`crate::wire`], those to and from the
//! protocol-neutral vocabulary in `crate::spec`.
//!
//! The JSON form mirrors the `.proto` field for field with the same snake_case names, except
//! that vectors are arrays: points and velocities `[x, y, z]`, quaternions `[x, y, z, w]`
//! (scalar last), clouds `[[x, y, z], ...]`, mesh faces `[[a, b, c], ...]`. Units: metres,
//! seconds, kilograms, radians; z up; ground plane z = 0. Field paths in error messages
//! (`scene.objects[2].mass`) are the same for both forms.

use serde::{Deserialize, Serialize};

mod gradient;
mod sampling;
mod session;
pub use gradient::{
    CandidateGradient, CostTarget, GradientCandidate, GradientCost, GradientResponse, PoseGradient,
    SessionGradientRequest, StepGradient,
};
pub use sampling::{
    GenerateDone, GenerateProgress, GenerateRequest, GenerateResponse, GeneratedSample, Material,
    MeshFrame, MeshObject, MeshScene, ObjectFrame, Sampler,
};
pub use session::{
    Action, CreateSessionRequest, ObjectPose, ObjectState, SessionInfo, SessionPredictRequest,
    SessionState, SessionVariant, SetStateRequest, StepRequest, StepResponse,
};

/// Identity quaternion `[x, y, z, w]`.
pub const IDENTITY_ROTATION: [f32; 4] = [0.0, 0.0, 0.0, 1.0];

fn identity_rotation() -> [f32; 4] {
    IDENTITY_ROTATION
}

fn is_zero_u32(v: &u32) -> bool {
    *v == 0
}

fn is_zero_u64(v: &u64) -> bool {
    *v == 0
}

/// Rigid pose: centre of mass in the world frame (metres) and body-to-world rotation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct Pose {
    /// Centre of mass `[x, y, z]`, metres, world frame (z up).
    pub translation: [f32; 3],
    /// Unit quaternion `[x, y, z, w]` (scalar last), body to world. Defaults to identity.
    /// Norms within 1e-3 of 1 are renormalised; others are rejected.
    #[serde(default = "identity_rotation")]
    pub rotation: [f32; 4],
}

/// A closed triangle mesh in the body frame (origin at the centre of mass), metres. The server
/// samples `samples` surface points from it (area-weighted, seeded).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct TriangleMesh {
    /// Vertex positions `[[x, y, z], ...]`, metres, body frame.
    pub vertices: Vec<[f32; 3]>,
    /// Vertex index triples `[[a, b, c], ...]`, counter-clockwise seen from outside.
    pub faces: Vec<[u32; 3]>,
    /// Points to sample; 0 (or absent) means the model's default point count.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub samples: u32,
    /// Seed of the surface sampler.
    #[serde(default, skip_serializing_if = "is_zero_u64")]
    pub seed: u64,
}

/// Linear (m/s) and angular (rad/s, axis times rate) velocity, world frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct Velocity {
    /// Centre-of-mass velocity `[vx, vy, vz]`, m/s. Defaults to zero.
    #[serde(default)]
    pub linear: [f32; 3],
    /// Angular velocity `[wx, wy, wz]`, rad/s. Defaults to zero.
    #[serde(default)]
    pub angular: [f32; 3],
}

/// One rigid object. Exactly one of `points` and `mesh`; at most one of `previous_pose` and
/// `velocity` (neither: the object starts at rest).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct ObjectSpec {
    /// Reference surface points `[[x, y, z], ...]` in the body frame (origin at the centre of
    /// mass), metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub points: Option<Vec<[f32; 3]>>,
    /// A mesh the server samples instead of `points`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<TriangleMesh>,
    /// Current pose.
    pub pose: Pose,
    /// Pose one step (`dt_steps` frames) before `pose`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub previous_pose: Option<Pose>,
    /// Velocities at `pose`; the server derives the previous pose from them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity: Option<Velocity>,
    /// Mass, kilograms, in (0, 1e4].
    pub mass: f32,
    /// Coulomb friction coefficient in [0, 10]. Defaults to 0. A learned model forecasts
    /// well only within the range its card says it was trained on.
    #[serde(default)]
    pub friction: f32,
    /// Coefficient of restitution in [0, 1]. Defaults to 0. As for `friction`, see the
    /// model's card for the range it was trained on.
    #[serde(default)]
    pub restitution: f32,
}

/// A rigid multi-object scene above the ground plane z = 0.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// The objects, at least one.
    pub objects: Vec<ObjectSpec>,
}

/// Rolls one scene forward (`POST /v1/rollout`). Also the scene file format.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct RolloutRequest {
    /// Model name (`GET /v1/models`); may be empty when exactly one model is resident.
    #[serde(default)]
    pub model: String,
    /// The scene.
    pub scene: Scene,
    /// Steps to produce.
    pub steps: u32,
    /// Frames per step; 0 or absent means 1.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub dt_steps: u32,
    /// Deadline for the whole rollout, milliseconds from arrival; 0 or absent means none.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub timeout_ms: u32,
    /// HTTP only: stream frames as Server-Sent Events (same as `Accept: text/event-stream`).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub stream: bool,
}

/// Server-side timing of one step, milliseconds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct StepTiming {
    /// Time the step waited in the scheduler queue.
    pub queue_ms: f32,
    /// Duration of the batched forward pass that computed it.
    pub forward_ms: f32,
    /// Scenes in that batch.
    pub batch_scenes: u32,
}

/// The state after one step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct StepFrame {
    /// Step index, from 1.
    pub step: u32,
    /// Physical time since the initial state, `step * dt_steps * dt_frame` seconds.
    pub time: f64,
    /// New pose of every object, in request order.
    pub poses: Vec<Pose>,
    /// Server-side timing of this step.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timing: Option<StepTiming>,
    /// How far the model's own predictions of this step disagree, per object: entry `j`
    /// belongs to object `j` (as `poses[j]`). Absent (empty) when the model estimates none;
    /// an ensemble reports its members' disagreement.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub spread: Vec<ObjectSpread>,
}

/// The spread of one object's predicted pose in one step (an ensemble: the weighted root mean
/// square over its members' predictions, around the mean the frame's pose is).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ObjectSpread {
    /// Root mean square distance of the predicted positions from the frame's position, metres.
    pub position_m: f32,
    /// Root mean square rotation angle of the predicted orientations from the frame's
    /// orientation, degrees.
    pub orientation_deg: f32,
}

/// Whole-request timings, milliseconds. For a planner call the variants step concurrently, so
/// `queue_ms` and `forward_ms` are those of its slowest variant.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct RequestTiming {
    /// Sum over steps of the time spent waiting in the scheduler queue.
    pub queue_ms: f64,
    /// Sum over steps of the forward passes that computed them.
    pub forward_ms: f64,
    /// Wall time from arrival to the last frame.
    pub total_ms: f64,
}

/// A whole rollout trajectory (`POST /v1/rollout` without streaming).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct RolloutResponse {
    /// Model that served the request.
    pub model: String,
    /// Request id (also in the `x-request-id` header).
    pub request_id: String,
    /// One frame per step.
    pub frames: Vec<StepFrame>,
    /// Timings.
    pub timing: RequestTiming,
}

/// Payload of the final `done` event of a streamed (SSE) rollout.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct SseDone {
    /// Request id.
    pub request_id: String,
    /// Steps streamed.
    pub steps: u32,
    /// Totals over the rollout.
    pub timing: RequestTiming,
}

/// Rolls many scene variants forward (`POST /v1/predict`), for planners.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct PredictRequest {
    /// Model name; may be empty when exactly one model is resident.
    #[serde(default)]
    pub model: String,
    /// Scene variants, each rolled forward independently.
    pub variants: Vec<Scene>,
    /// Steps.
    pub steps: u32,
    /// Frames per step; 0 or absent means 1.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub dt_steps: u32,
    /// Return every k-th step plus the final one; 0 or absent returns the final step only.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub every: u32,
    /// Deadline, milliseconds from arrival; 0 or absent means none.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub timeout_ms: u32,
}

/// Frames returned for one variant.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Trajectory {
    /// Frames in step order.
    pub frames: Vec<StepFrame>,
}

/// Result of `POST /v1/predict`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct PredictResponse {
    /// Model that served the request.
    pub model: String,
    /// One trajectory per variant, in request order.
    pub trajectories: Vec<Trajectory>,
    /// Timings.
    #[serde(default)]
    pub timing: RequestTiming,
}

/// A resident model and the server's limits for it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ModelInfo {
    /// Name used in requests.
    pub name: String,
    /// Architecture, e.g. `rigidformer`.
    pub architecture: String,
    /// Interval of one frame, seconds.
    pub dt_frame: f64,
    /// Points sampled from a mesh when `samples` is 0.
    pub default_points: u32,
    /// Maximum objects per scene.
    pub max_objects: u32,
    /// Maximum reference points (or mesh samples) per object.
    pub max_points_per_object: u32,
    /// Maximum steps per request.
    pub max_steps: u32,
    /// Maximum frames per step.
    pub max_dt_steps: u32,
    /// Maximum variants per predict request.
    pub max_variants: u32,
    /// Largest cost of one request (`--max-request-cost` / `--max-generate-cost`), in the
    /// unit of the model's family: object-steps for RigidFormer models (objects x steps,
    /// summed over a Predict's variants), vertex-frame evaluations for PhysiFormer models
    /// (vertices x frames x network evaluations x samples, the evaluations `2 denoise_steps -
    /// 1` with Heun and `denoise_steps` with Euler). A request above it is refused naming
    /// `steps` / `denoise_steps`. 0 from a server that predates it.
    #[serde(default)]
    pub max_request_cost: u64,
    /// Gravity the model was trained with, m/s^2, world frame.
    pub gravity: [f32; 3],
    /// The checkpoint's `config.json`.
    #[cfg_attr(feature = "openapi", schema(value_type = Object))]
    pub config: serde_json::Value,
    /// PhysiFormer models: most vertices per Generate scene (absent for other models).
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub max_vertices: u32,
    /// PhysiFormer models: most frames of a sampled trajectory, also the default.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub max_frames: u32,
    /// PhysiFormer models: most denoising steps per request.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub max_denoise_steps: u32,
    /// PhysiFormer models: denoising steps of a request that names none.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub default_denoise_steps: u32,
    /// PhysiFormer models: most samples per request.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub max_samples: u32,
    /// PhysiFormer models: half extent `e` of the closed box `[-e, e]^3`, metres.
    #[serde(default, skip_serializing_if = "is_zero_f32")]
    pub box_half_extent: f32,
    /// RigidFormer ensembles: names of the member networks, whose predicted poses every step
    /// averages (`config` is the first member's; absent for a single network).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub members: Vec<String>,
    /// True when the model computes gradients of a driven rollout's cost
    /// (`POST /v1/sessions/{id}/gradient`); false for ensembles, the simulator and PhysiFormer
    /// models, and from a server that predates it.
    #[serde(default)]
    pub gradients: bool,
    /// Most work of one gradient call, candidates x steps (`--max-gradient-work`); absent when
    /// the model computes no gradients.
    #[serde(default, skip_serializing_if = "is_zero_u64")]
    pub max_gradient_work: u64,
}

fn is_zero_f32(v: &f32) -> bool {
    *v == 0.0
}

/// Result of `GET /v1/models`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ListModelsResponse {
    /// Resident models.
    pub models: Vec<ModelInfo>,
}

/// Error document of every failed HTTP request (and of an SSE `error` event).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ErrorResponse {
    /// The error.
    pub error: ErrorDetail,
}

/// What went wrong.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ErrorDetail {
    /// gRPC-style code name: `INVALID_ARGUMENT`, `RESOURCE_EXHAUSTED`, `DEADLINE_EXCEEDED`,
    /// `UNAVAILABLE`, `INTERNAL`, `CANCELLED`.
    pub code: String,
    /// Human-readable message; for invalid input it starts with the field path.
    pub message: String,
    /// Offending field path for invalid input, e.g. `scene.objects[2].mass`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field: Option<String>,
    /// Suggested wait before retrying, milliseconds (overload only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retry_after_ms: Option<u64>,
}
