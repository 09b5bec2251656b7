//! JSON form of the `dynaserve.v1.Sessions` messages (`/v1/sessions` routes). The session id
//! travels in the path, so the request documents do not repeat it. Same units and conventions
//! as the rest of [`crate::json`].

use serde::{Deserialize, Serialize};

use super::{Pose, RequestTiming, Scene, StepFrame, Velocity, is_zero_u32};

/// The pose of one object, by index into the session's scene.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct ObjectPose {
    /// Object index, 0-based, in scene order.
    pub object: u32,
    /// Its pose.
    pub pose: Pose,
}

/// What the caller decides for one step: poses of kinematic objects at the end of the step.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct Action {
    /// At most one entry per object; every object named must be kinematic.
    #[serde(default)]
    pub kinematic: Vec<ObjectPose>,
}

/// The state of one object, by index: its pose and motion (neither `previous_pose` nor
/// `velocity`: at rest).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct ObjectState {
    /// Object index, 0-based, in scene order.
    pub object: u32,
    /// Current pose.
    pub pose: Pose,
    /// Pose one step (the session's `dt_steps` frames) before `pose`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub previous_pose: Option<Pose>,
    /// Velocities at `pose`, world frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity: Option<Velocity>,
}

/// Creates a session (`POST /v1/sessions`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct CreateSessionRequest {
    /// Model name; may be empty when exactly one model is resident.
    #[serde(default)]
    pub model: String,
    /// The scene and its initial state.
    pub scene: Scene,
    /// Frames per step for every step of the session; 0 or absent means 1.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub dt_steps: u32,
    /// Indices of the kinematic objects.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub kinematic: Vec<u32>,
    /// False (the default): the session belongs to its creator (its bearer token, or without
    /// authentication its IP address) and answers 404 to anyone else. True: every caller may
    /// use it; only its creator may delete it.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub shared: bool,
}

/// A session's description (answer of create and fork).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct SessionInfo {
    /// Opaque id (32 hex digits).
    pub session_id: String,
    /// Model that serves it.
    pub model: String,
    /// When it expires unless used again, milliseconds since the Unix epoch.
    pub expires_at_unix_ms: u64,
    /// Objects in its scene.
    pub objects: u32,
    /// Frames per step.
    pub dt_steps: u32,
    /// Indices of its kinematic objects.
    #[serde(default)]
    pub kinematic: Vec<u32>,
    /// Usable by every caller (created with `shared`).
    #[serde(default)]
    pub shared: bool,
}

/// Advances a session (`POST /v1/sessions/{id}/step`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct StepRequest {
    /// Steps to take.
    pub steps: u32,
    /// Either empty (kinematic objects hold still) or exactly `steps` actions.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub actions: Vec<Action>,
    /// Deadline, milliseconds from arrival; 0 or absent means none.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub timeout_ms: u32,
}

/// The frames of a session step call.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct StepResponse {
    /// The session.
    pub session_id: String,
    /// One frame per step; step indices and times count from the session's start.
    pub frames: Vec<StepFrame>,
    /// Timings.
    pub timing: RequestTiming,
}

/// Overwrites object states (`PUT /v1/sessions/{id}/state`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct SetStateRequest {
    /// New states of some objects (each at most once); the others keep theirs.
    pub objects: Vec<ObjectState>,
}

/// A session's state (`GET /v1/sessions/{id}`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct SessionState {
    /// The session.
    pub session_id: String,
    /// Steps taken since creation (of the session it was forked from, for a fork).
    pub step: u32,
    /// Physical time of the state, seconds.
    pub time: f64,
    /// Current pose of every object.
    pub poses: Vec<Pose>,
    /// Pose of every object one step before `poses`.
    pub previous_poses: Vec<Pose>,
    /// When it expires unless used again, milliseconds since the Unix epoch.
    pub expires_at_unix_ms: u64,
}

/// One variant of a session Predict call: differences from the session's state.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct SessionVariant {
    /// State overrides applied to the session's current state.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub state: Vec<ObjectState>,
    /// Either empty or exactly `steps` actions.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub actions: Vec<Action>,
}

/// Rolls variants of a session's state forward (`POST /v1/sessions/{id}/predict`); answered
/// by a [`super::PredictResponse`]. The session itself does not move.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct SessionPredictRequest {
    /// Variants.
    pub variants: Vec<SessionVariant>,
    /// Steps.
    pub steps: u32,
    /// Return every k-th step plus the final one; 0 or absent returns the final step only.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub every: u32,
    /// Deadline, milliseconds from arrival; 0 or absent means none.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub timeout_ms: u32,
}
