//! The neutral vocabulary of sessions (`dynaserve.v1.Sessions`, `/v1/sessions`): requests in
//! from either wire form, descriptions and states out. Only structure is checked here (one
//! motion per object state, required poses); indices, kinematic sets and values are checked
//! against the session by the server.

use dynaserve_model::SceneState;

use super::json::{motion as json_motion, pose as json_pose};
use super::v1::{pose_to_v1, required_pose};
use super::{Motion, Pose, Scene};
use crate::error::FieldError;
use crate::json;
use crate::v1;
use crate::wire::vec3_from;

/// The state of one object of a session, by index.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObjectState {
    /// Object index in scene order.
    pub object: u32,
    /// Current pose (not yet normalised).
    pub pose: Pose,
    /// Motion at `pose`.
    pub motion: Motion,
}

/// One step's decision: poses of kinematic objects at the end of the step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Action {
    /// `(object index, pose)` pairs (not yet normalised).
    pub kinematic: Vec<(u32, Pose)>,
}

/// `CreateSession`: a scene prepared once and kept with its state.
#[derive(Clone, Debug, PartialEq)]
pub struct CreateSessionSpec {
    /// Model name; empty when exactly one model is resident.
    pub model: String,
    /// Scene and initial state.
    pub scene: Scene,
    /// Frames per step of every step of the session; 0 means 1.
    pub dt_steps: u32,
    /// Indices of the kinematic objects.
    pub kinematic: Vec<u32>,
    /// Usable by every caller, not only its creator.
    pub shared: bool,
}

/// `Step`: advance a session.
#[derive(Clone, Debug, PartialEq)]
pub struct StepSpec {
    /// The session.
    pub session_id: String,
    /// Steps to take.
    pub steps: u32,
    /// Empty or one action per step.
    pub actions: Vec<Action>,
    /// Deadline in milliseconds from arrival; 0 means none.
    pub timeout_ms: u32,
}

/// `SetState`: overwrite some objects' states.
#[derive(Clone, Debug, PartialEq)]
pub struct SetStateSpec {
    /// The session.
    pub session_id: String,
    /// New object states.
    pub objects: Vec<ObjectState>,
}

/// One variant of a session Predict call.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SessionVariant {
    /// Overrides of the session's state.
    pub state: Vec<ObjectState>,
    /// Empty or one action per step.
    pub actions: Vec<Action>,
}

/// `Predict` from a session: many variants of its state rolled forward together.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionPredictSpec {
    /// The session.
    pub session_id: String,
    /// Variants.
    pub variants: Vec<SessionVariant>,
    /// Steps.
    pub steps: u32,
    /// Keep every k-th step plus the final one; 0 keeps the final step only.
    pub every: u32,
    /// Deadline in milliseconds from arrival; 0 means none.
    pub timeout_ms: u32,
}

/// One step of an Interact stream: corrections applied first, then one step under `action`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct InteractStep {
    /// The step's action.
    pub action: Action,
    /// State corrections applied before the step.
    pub correct: Vec<ObjectState>,
}

/// How an Interact stream starts.
#[derive(Clone, Debug, PartialEq)]
pub enum InteractOpen {
    /// Drive an existing session.
    Session(String),
    /// Create a session for this stream only.
    Create(CreateSessionSpec),
}

/// A session's description.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionInfo {
    /// Opaque id.
    pub session_id: String,
    /// Model serving it.
    pub model: String,
    /// Expiry unless used again, milliseconds since the Unix epoch.
    pub expires_at_unix_ms: u64,
    /// Objects in its scene.
    pub objects: u32,
    /// Frames per step.
    pub dt_steps: u32,
    /// Kinematic object indices, ascending.
    pub kinematic: Vec<u32>,
    /// Usable by every caller, not only its creator.
    pub shared: bool,
}

/// A session's state.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionStateView {
    /// The session.
    pub session_id: String,
    /// Steps taken since creation.
    pub step: u32,
    /// Physical time of the state, seconds.
    pub time: f64,
    /// Previous and current poses (`dt_steps` frames apart).
    pub state: SceneState,
    /// Expiry unless used again, milliseconds since the Unix epoch.
    pub expires_at_unix_ms: u64,
}

// ---- gRPC in ----

impl ObjectState {
    /// Reads a gRPC object state at path `field`.
    pub fn from_v1(o: &v1::ObjectState, field: &str) -> Result<ObjectState, FieldError> {
        let motion = match &o.motion {
            Some(v1::object_state::Motion::PreviousPose(p)) => {
                Motion::PreviousPose(required_pose(Some(p), &format!("{field}.previous_pose"))?)
            }
            Some(v1::object_state::Motion::Velocity(v)) => Motion::Velocity {
                linear: vec3_from(v.linear.as_ref()),
                angular: vec3_from(v.angular.as_ref()),
            },
            None => Motion::Rest,
        };
        Ok(ObjectState {
            object: o.object,
            pose: required_pose(o.pose.as_ref(), &format!("{field}.pose"))?,
            motion,
        })
    }

    /// Reads a JSON object state at path `field` (at most one of `previous_pose` and
    /// `velocity`).
    pub fn from_json(o: &json::ObjectState, field: &str) -> Result<ObjectState, FieldError> {
        Ok(ObjectState {
            object: o.object,
            pose: json_pose(&o.pose),
            motion: json_motion(o.previous_pose.as_ref(), o.velocity.as_ref(), field)?,
        })
    }
}

fn states_v1(list: &[v1::ObjectState], field: &str) -> Result<Vec<ObjectState>, FieldError> {
    list.iter()
        .enumerate()
        .map(|(i, o)| ObjectState::from_v1(o, &format!("{field}[{i}]")))
        .collect()
}

fn states_json(list: &[json::ObjectState], field: &str) -> Result<Vec<ObjectState>, FieldError> {
    list.iter()
        .enumerate()
        .map(|(i, o)| ObjectState::from_json(o, &format!("{field}[{i}]")))
        .collect()
}

impl Action {
    /// Reads a gRPC action at path `field`.
    pub fn from_v1(a: &v1::Action, field: &str) -> Result<Action, FieldError> {
        let kinematic = a
            .kinematic
            .iter()
            .enumerate()
            .map(|(i, k)| {
                Ok((
                    k.object,
                    required_pose(k.pose.as_ref(), &format!("{field}.kinematic[{i}].pose"))?,
                ))
            })
            .collect::<Result<_, FieldError>>()?;
        Ok(Action { kinematic })
    }

    /// Reads a JSON action.
    pub fn from_json(a: &json::Action) -> Action {
        Action {
            kinematic: a
                .kinematic
                .iter()
                .map(|k| (k.object, json_pose(&k.pose)))
                .collect(),
        }
    }
}

fn actions_v1(list: &[v1::Action], field: &str) -> Result<Vec<Action>, FieldError> {
    list.iter()
        .enumerate()
        .map(|(i, a)| Action::from_v1(a, &format!("{field}[{i}]")))
        .collect()
}

impl CreateSessionSpec {
    /// Reads a gRPC `CreateSession` request; `field` prefixes the paths (empty at the top).
    pub fn from_v1(r: &v1::CreateSessionRequest, field: &str) -> Result<Self, FieldError> {
        Ok(CreateSessionSpec {
            model: r.model.clone(),
            scene: Scene::from_v1(r.scene.as_ref(), &format!("{field}scene"))?,
            dt_steps: r.dt_steps,
            kinematic: r.kinematic.clone(),
            shared: r.shared,
        })
    }

    /// Reads a `POST /v1/sessions` body.
    pub fn from_json(r: &json::CreateSessionRequest) -> Result<Self, FieldError> {
        Ok(CreateSessionSpec {
            model: r.model.clone(),
            scene: Scene::from_json(&r.scene, "scene")?,
            dt_steps: r.dt_steps,
            kinematic: r.kinematic.clone(),
            shared: r.shared,
        })
    }
}

impl StepSpec {
    /// Reads a gRPC `Step` request.
    pub fn from_v1(r: &v1::StepRequest) -> Result<Self, FieldError> {
        Ok(StepSpec {
            session_id: r.session_id.clone(),
            steps: r.steps,
            actions: actions_v1(&r.actions, "actions")?,
            timeout_ms: r.timeout_ms,
        })
    }

    /// Reads a `POST /v1/sessions/{id}/step` body.
    pub fn from_json(session_id: &str, r: &json::StepRequest) -> Self {
        StepSpec {
            session_id: session_id.to_string(),
            steps: r.steps,
            actions: r.actions.iter().map(Action::from_json).collect(),
            timeout_ms: r.timeout_ms,
        }
    }
}

impl SetStateSpec {
    /// Reads a gRPC `SetState` request.
    pub fn from_v1(r: &v1::SetStateRequest) -> Result<Self, FieldError> {
        Ok(SetStateSpec {
            session_id: r.session_id.clone(),
            objects: states_v1(&r.objects, "objects")?,
        })
    }

    /// Reads a `PUT /v1/sessions/{id}/state` body.
    pub fn from_json(session_id: &str, r: &json::SetStateRequest) -> Result<Self, FieldError> {
        Ok(SetStateSpec {
            session_id: session_id.to_string(),
            objects: states_json(&r.objects, "objects")?,
        })
    }
}

impl SessionPredictSpec {
    /// Reads a gRPC session `Predict` request.
    pub fn from_v1(r: &v1::SessionPredictRequest) -> Result<Self, FieldError> {
        let variants = r
            .variants
            .iter()
            .enumerate()
            .map(|(i, v)| {
                Ok(SessionVariant {
                    state: states_v1(&v.state, &format!("variants[{i}].state"))?,
                    actions: actions_v1(&v.actions, &format!("variants[{i}].actions"))?,
                })
            })
            .collect::<Result<_, FieldError>>()?;
        Ok(SessionPredictSpec {
            session_id: r.session_id.clone(),
            variants,
            steps: r.steps,
            every: r.every,
            timeout_ms: r.timeout_ms,
        })
    }

    /// Reads a `POST /v1/sessions/{id}/predict` body.
    pub fn from_json(
        session_id: &str,
        r: &json::SessionPredictRequest,
    ) -> Result<Self, FieldError> {
        let variants = r
            .variants
            .iter()
            .enumerate()
            .map(|(i, v)| {
                Ok(SessionVariant {
                    state: states_json(&v.state, &format!("variants[{i}].state"))?,
                    actions: v.actions.iter().map(Action::from_json).collect(),
                })
            })
            .collect::<Result<_, FieldError>>()?;
        Ok(SessionPredictSpec {
            session_id: session_id.to_string(),
            variants,
            steps: r.steps,
            every: r.every,
            timeout_ms: r.timeout_ms,
        })
    }
}

impl InteractOpen {
    /// Reads the first message of an Interact stream: exactly one of `session_id` and
    /// `create`, and no step yet.
    pub fn from_v1(r: &v1::InteractRequest) -> Result<Self, FieldError> {
        if r.action.is_some() || !r.correct.is_empty() {
            return Err(FieldError::new(
                "action",
                "the first message opens the stream (`session_id` or `create`); steps follow",
            ));
        }
        match (&r.create, r.session_id.is_empty()) {
            (Some(c), true) => Ok(InteractOpen::Create(CreateSessionSpec::from_v1(
                c, "create.",
            )?)),
            (None, false) => Ok(InteractOpen::Session(r.session_id.clone())),
            _ => Err(FieldError::new(
                "session_id",
                "the first message needs exactly one of `session_id` and `create`",
            )),
        }
    }
}

impl InteractStep {
    /// Reads a later message of an Interact stream (one step).
    pub fn from_v1(r: &v1::InteractRequest) -> Result<Self, FieldError> {
        if !r.session_id.is_empty() || r.create.is_some() {
            return Err(FieldError::new(
                "session_id",
                "only the first message of the stream names or creates a session",
            ));
        }
        Ok(InteractStep {
            action: match &r.action {
                Some(a) => Action::from_v1(a, "action")?,
                None => Action::default(),
            },
            correct: states_v1(&r.correct, "correct")?,
        })
    }
}

// ---- out ----

fn pose_json(p: &Pose) -> json::Pose {
    json::Pose {
        translation: p.translation,
        rotation: p.rotation,
    }
}

impl SessionInfo {
    /// The gRPC description.
    pub fn to_v1(&self) -> v1::SessionInfo {
        v1::SessionInfo {
            session_id: self.session_id.clone(),
            model: self.model.clone(),
            expires_at_unix_ms: self.expires_at_unix_ms,
            objects: self.objects,
            dt_steps: self.dt_steps,
            kinematic: self.kinematic.clone(),
            shared: self.shared,
        }
    }

    /// The JSON description.
    pub fn to_json(&self) -> json::SessionInfo {
        json::SessionInfo {
            session_id: self.session_id.clone(),
            model: self.model.clone(),
            expires_at_unix_ms: self.expires_at_unix_ms,
            objects: self.objects,
            dt_steps: self.dt_steps,
            kinematic: self.kinematic.clone(),
            shared: self.shared,
        }
    }
}

impl SessionStateView {
    /// The gRPC state.
    pub fn to_v1(&self) -> v1::SessionState {
        v1::SessionState {
            session_id: self.session_id.clone(),
            step: self.step,
            time: self.time,
            poses: self.state.current.iter().map(pose_to_v1).collect(),
            previous_poses: self.state.previous.iter().map(pose_to_v1).collect(),
            expires_at_unix_ms: self.expires_at_unix_ms,
        }
    }

    /// The JSON state.
    pub fn to_json(&self) -> json::SessionState {
        json::SessionState {
            session_id: self.session_id.clone(),
            step: self.step,
            time: self.time,
            poses: self.state.current.iter().map(pose_json).collect(),
            previous_poses: self.state.previous.iter().map(pose_json).collect(),
            expires_at_unix_ms: self.expires_at_unix_ms,
        }
    }
}
