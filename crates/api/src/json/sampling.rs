//! JSON form of the Generate messages (`POST /v1/generate`): a mesh scene of rigid and elastic
//! objects in a closed box, sampled whole by a PhysiFormer model. Same units and conventions
//! as the rest of [`crate::json`]; vertices are world coordinates at frame 0.

use serde::{Deserialize, Serialize};

use super::{Pose, RequestTiming, StepTiming, Velocity, is_zero_u32, is_zero_u64};

/// How an object deforms (`"rigid"` or `"elastic"`). The model knows one elastic material,
/// the fixed stiffness of its training data.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum Material {
    /// Keeps its shape.
    Rigid,
    /// Deforms elastically.
    Elastic,
}

/// Integrator of the flow from noise to trajectory (`"heun"`, the default, or `"euler"`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum Sampler {
    /// Second order: two network evaluations per denoising step, one in the last.
    #[default]
    Heun,
    /// First order: one network evaluation per denoising step.
    Euler,
}

/// One object of a mesh scene at frame 0, world frame of the model's box.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct MeshObject {
    /// Vertex positions `[[x, y, z], ...]` at frame 0, metres, world frame; every coordinate
    /// within `[-2e, 2e]` for the model's box half extent `e`.
    pub vertices: Vec<[f32; 3]>,
    /// Triangles `[[a, b, c], ...]` indexing this object's vertices. Optional; checked, not
    /// used by the model.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub faces: Vec<[u32; 3]>,
    /// `"rigid"` or `"elastic"`.
    pub material: Material,
    /// Initial velocity: `linear` (m/s) of the vertex centroid, `angular` (rad/s) about it.
    /// Absent: at rest.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity: Option<Velocity>,
    /// Per-vertex initial velocities `[[vx, vy, vz], ...]`, m/s, one per vertex, instead of
    /// `velocity` (the official PhysiFormer data's form). Give one or the other.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vertex_velocities: Option<Vec<[f32; 3]>>,
}

/// Objects in the model's closed box `[-e, e]^3`, gravity along -z.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct MeshScene {
    /// The objects, at least one.
    pub objects: Vec<MeshObject>,
}

/// Samples whole trajectories of a mesh scene (`POST /v1/generate`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct GenerateRequest {
    /// A PhysiFormer model (`GET /v1/models`); may be empty when exactly one is resident.
    #[serde(default)]
    pub model: String,
    /// The scene.
    pub scene: MeshScene,
    /// Frames to sample, frame 0 included; 0 or absent means the model's `max_frames`.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub frames: u32,
    /// Denoising steps; 0 or absent means the model's `default_denoise_steps`.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub denoise_steps: u32,
    /// Integrator; absent means `"heun"`.
    #[serde(default)]
    pub sampler: Sampler,
    /// Independent samples; 0 or absent means 1.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub samples: u32,
    /// Seed of the starting noise; sample `i` uses `seed + i`.
    #[serde(default, skip_serializing_if = "is_zero_u64")]
    pub seed: u64,
    /// Deadline, milliseconds from arrival; 0 or absent means none.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub timeout_ms: u32,
    /// Return rigid objects' vertices as sampled; by default (false) they are the frame-0
    /// vertices moved by the fitted rigid motion, so rigid objects stay exactly rigid.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub raw_vertices: bool,
    /// Starting noise instead of `seed`, to reproduce another implementation's sampling run:
    /// one list per sample of standard-normal draws, flattened `[frames][V][3]` (V the
    /// scene's vertices in request order), scaled by the model's noise scale in its network
    /// coordinates.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise: Option<Vec<Vec<f32>>>,
    /// Stream `progress` and `sample` events as Server-Sent Events (same as
    /// `Accept: text/event-stream`).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub stream: bool,
}

/// One denoising step completed by every sample of the request (SSE `progress` event).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct GenerateProgress {
    /// Steps completed, 1 to `steps`.
    pub step: u32,
    /// Denoising steps of the request.
    pub steps: u32,
    /// Flow time reached, `step / steps`.
    pub t: f32,
    /// Queue and forward time of this step's network evaluations (slowest sample), and the
    /// most scenes in one of their passes.
    pub timing: StepTiming,
}

/// One object at one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ObjectFrame {
    /// Vertex positions `[[x, y, z], ...]`, metres, world frame, in request order. For a rigid
    /// object, its frame-0 vertices moved by `pose` unless the request set `raw_vertices`.
    pub vertices: Vec<[f32; 3]>,
    /// Rigid objects: the rigid motion best fitting the sampled vertices (Kabsch) as a pose
    /// whose body frame is the frame-0 vertices about their centroid.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose: Option<Pose>,
    /// Rigid objects: RMS distance of the sampled vertices from that rigid motion, metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit_rms: Option<f32>,
}

/// The scene at one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct MeshFrame {
    /// Frame index, 0 for the given state.
    pub frame: u32,
    /// `frame * dt_frame`, seconds.
    pub time: f64,
    /// Every object, in request order.
    pub objects: Vec<ObjectFrame>,
}

/// One sampled trajectory (SSE `sample` event).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct GeneratedSample {
    /// Sample index.
    pub sample: u32,
    /// Seed of its starting noise (not used when the request gives `noise`).
    pub seed: u64,
    /// Frames 0 to `frames - 1`.
    pub frames: Vec<MeshFrame>,
}

/// Result of `POST /v1/generate` without streaming.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct GenerateResponse {
    /// Model that served the request.
    pub model: String,
    /// Request id (also in the `x-request-id` header).
    pub request_id: String,
    /// Denoising steps run.
    pub denoise_steps: u32,
    /// One trajectory per sample, in sample order.
    pub samples: Vec<GeneratedSample>,
    /// Queue and forward time summed over the denoising steps, and the wall time.
    pub timing: RequestTiming,
}

/// Payload of the final `done` event of a streamed (SSE) generation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct GenerateDone {
    /// Request id.
    pub request_id: String,
    /// Samples sent.
    pub samples: u32,
    /// Totals over the request.
    pub timing: RequestTiming,
}
