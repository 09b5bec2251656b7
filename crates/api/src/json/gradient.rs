//! JSON form of a session Gradient call (`POST /v1/sessions/{id}/gradient`, the
//! `dynaserve.v1.Sessions.Gradient` messages): candidate paths of the session's kinematic
//! objects and a cost in, each candidate's cost, its gradient with respect to every kinematic
//! pose and its rollout out. Same units and conventions as the rest of [`crate::json`].

use serde::{Deserialize, Serialize};

use super::session::Action;
use super::{RequestTiming, StepFrame, is_zero_u32};

/// One candidate path: the pose of every kinematic object at the end of every step.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct GradientCandidate {
    /// Exactly `steps` actions, one per step; each names every kinematic object of the session
    /// exactly once.
    pub actions: Vec<Action>,
}

/// One term of a [`GradientCost`]: `position_weight * |p - position|` (metres) plus
/// `rotation_weight * (1 - cos(angle to rotation))`, for object `object` after step `step`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct CostTarget {
    /// Object index, 0-based, in scene order (kinematic or not).
    pub object: u32,
    /// The step after which the distance is measured, 1 to `steps`; 0 or absent means the
    /// last step.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub step: u32,
    /// Target centre of mass `[x, y, z]`, metres, world frame. Defaults to the origin.
    #[serde(default)]
    pub position: [f32; 3],
    /// Weight of the distance to `position`, per metre; 0 or absent ignores the position.
    #[serde(default)]
    pub position_weight: f32,
    /// Target orientation `[x, y, z, w]`; absent ignores the orientation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation: Option<[f32; 4]>,
    /// Weight of `1 - cos(angle)` to `rotation`; 0 or absent ignores the orientation.
    #[serde(default)]
    pub rotation_weight: f32,
}

/// The cost every candidate is scored by: the sum of the targets' terms plus `smoothness`
/// times the squared second differences of the kinematic translations, summed over kinematic
/// objects and steps (metres squared; the session's previous and current poses open the path).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct GradientCost {
    /// Distance terms (none: smoothness only).
    #[serde(default)]
    pub targets: Vec<CostTarget>,
    /// Weight of the smoothness term, per square metre; 0 or absent ignores it.
    #[serde(default)]
    pub smoothness: f32,
}

/// Scores and differentiates candidate paths from a session's state
/// (`POST /v1/sessions/{id}/gradient`); the session itself does not move.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct SessionGradientRequest {
    /// Candidate paths, 1 to the model's `max_variants`; candidates x steps at most its
    /// `max_gradient_work`.
    pub candidates: Vec<GradientCandidate>,
    /// Steps of every candidate.
    pub steps: u32,
    /// The cost.
    pub cost: GradientCost,
    /// Return the rollout's poses every k-th step plus the final one; 0 or absent returns the
    /// final step only.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub every: u32,
    /// Deadline, milliseconds from arrival; 0 or absent means none.
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub timeout_ms: u32,
}

/// The gradient of a candidate's cost with respect to one kinematic object's pose at one step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct PoseGradient {
    /// d cost / d translation `[x, y, z]`, per metre, world frame.
    pub translation: [f32; 3],
    /// d cost / d rotation `[x, y, z]`, per radian of a small rotation about each world axis
    /// applied to the pose on the left.
    pub rotation: [f32; 3],
}

/// The gradients of one step of a candidate's path.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct StepGradient {
    /// One entry per kinematic object, in object order.
    pub kinematic: Vec<PoseGradient>,
}

/// The answer for one candidate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct CandidateGradient {
    /// The candidate's cost.
    pub cost: f64,
    /// One entry per step of the path, in step order.
    pub steps: Vec<StepGradient>,
    /// The rollout the cost was measured on: every `every`-th step plus the final one (step
    /// indices and times count from the session's start).
    pub frames: Vec<StepFrame>,
}

/// Result of `POST /v1/sessions/{id}/gradient`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct GradientResponse {
    /// Model that served the request.
    pub model: String,
    /// One answer per candidate, in request order.
    pub candidates: Vec<CandidateGradient>,
    /// Timings: the time the call waited for its pass, that pass's duration, the wall time.
    #[serde(default)]
    pub timing: RequestTiming,
}
