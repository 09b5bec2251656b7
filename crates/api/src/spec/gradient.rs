//! The neutral vocabulary of a session Gradient call (`dynaserve.v1.Sessions.Gradient`,
//! `POST /v1/sessions/{id}/gradient`): the request in from either wire form, each candidate's
//! cost, gradients and rollout out. Only structure is checked here; the actions, the cost's
//! objects and steps and the limits are checked against the session by the server.

use super::session::Action;
use super::{Frame, Timing};
use crate::error::FieldError;
use crate::json;
use crate::v1;
use crate::wire::{vec3_from, vec3_to};

/// One term of a [`GradientCost`]: how far object `object` is after step `step` from a
/// target pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CostTarget {
    /// Object index in scene order.
    pub object: u32,
    /// The step after which the distance is measured, `1..=steps`; 0 means the last step.
    pub step: u32,
    /// Target centre of mass, metres, world frame.
    pub position: [f32; 3],
    /// Weight of the distance to `position`, per metre.
    pub position_weight: f32,
    /// Target orientation `[x, y, z, w]` (not yet normalised); `None` ignores it.
    pub rotation: Option<[f32; 4]>,
    /// Weight of `1 - cos(angle)` to `rotation`.
    pub rotation_weight: f32,
}

/// The cost every candidate of a call is scored by: its targets' terms plus the weighted
/// smoothness of the kinematic translations.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GradientCost {
    /// Distance terms.
    pub targets: Vec<CostTarget>,
    /// Weight of the squared second differences of the kinematic translations, per m^2.
    pub smoothness: f32,
}

/// `Gradient` from a session: candidate paths of its kinematic objects, scored and
/// differentiated from its current state.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionGradientSpec {
    /// The session.
    pub session_id: String,
    /// Candidate paths `[candidates][steps]`: one action per step.
    pub candidates: Vec<Vec<Action>>,
    /// Steps of every candidate.
    pub steps: u32,
    /// The cost.
    pub cost: GradientCost,
    /// Keep every k-th step's poses plus the final one; 0 keeps the final step only.
    pub every: u32,
    /// Deadline in milliseconds from arrival; 0 means none.
    pub timeout_ms: u32,
}

/// The answer for one candidate.
#[derive(Clone, Debug, PartialEq)]
pub struct CandidateGradient {
    /// The candidate's cost.
    pub cost: f64,
    /// d cost / d translation of every kinematic pose `[steps][kinematic][3]`, per metre.
    pub translation: Vec<Vec<[f32; 3]>>,
    /// d cost / d rotation of every kinematic pose `[steps][kinematic][3]`, per radian of a
    /// small world-axis rotation applied on the left.
    pub rotation: Vec<Vec<[f32; 3]>>,
    /// The kept frames of the rollout the cost was measured on.
    pub frames: Vec<Frame>,
}

/// The result of a Gradient call.
#[derive(Clone, Debug, PartialEq)]
pub struct Gradients {
    /// Model that served it.
    pub model: String,
    /// One answer per candidate, in request order.
    pub candidates: Vec<CandidateGradient>,
    /// Queue wait and duration of the pass that computed it, and the call's wall time.
    pub timing: Timing,
}

impl CostTarget {
    fn from_v1(t: &v1::CostTarget) -> CostTarget {
        CostTarget {
            object: t.object,
            step: t.step,
            position: vec3_from(t.position.as_ref()),
            position_weight: t.position_weight,
            rotation: t.rotation.as_ref().map(|q| [q.x, q.y, q.z, q.w]),
            rotation_weight: t.rotation_weight,
        }
    }

    fn from_json(t: &json::CostTarget) -> CostTarget {
        CostTarget {
            object: t.object,
            step: t.step,
            position: t.position,
            position_weight: t.position_weight,
            rotation: t.rotation,
            rotation_weight: t.rotation_weight,
        }
    }
}

impl SessionGradientSpec {
    /// Reads a gRPC session `Gradient` request (an absent cost is the zero cost).
    pub fn from_v1(r: &v1::SessionGradientRequest) -> Result<Self, FieldError> {
        let candidates = r
            .candidates
            .iter()
            .enumerate()
            .map(|(i, c)| {
                c.actions
                    .iter()
                    .enumerate()
                    .map(|(s, a)| Action::from_v1(a, &format!("candidates[{i}].actions[{s}]")))
                    .collect::<Result<Vec<_>, _>>()
            })
            .collect::<Result<_, _>>()?;
        let cost = r
            .cost
            .as_ref()
            .map_or_else(GradientCost::default, |c| GradientCost {
                targets: c.targets.iter().map(CostTarget::from_v1).collect(),
                smoothness: c.smoothness,
            });
        Ok(SessionGradientSpec {
            session_id: r.session_id.clone(),
            candidates,
            steps: r.steps,
            cost,
            every: r.every,
            timeout_ms: r.timeout_ms,
        })
    }

    /// Reads a `POST /v1/sessions/{id}/gradient` body.
    pub fn from_json(session_id: &str, r: &json::SessionGradientRequest) -> Self {
        SessionGradientSpec {
            session_id: session_id.to_string(),
            candidates: r
                .candidates
                .iter()
                .map(|c| c.actions.iter().map(Action::from_json).collect())
                .collect(),
            steps: r.steps,
            cost: GradientCost {
                targets: r.cost.targets.iter().map(CostTarget::from_json).collect(),
                smoothness: r.cost.smoothness,
            },
            every: r.every,
            timeout_ms: r.timeout_ms,
        }
    }
}

impl CandidateGradient {
    /// Pairs of translation and rotation gradients, `[steps][kinematic]`.
    fn steps(&self) -> impl Iterator<Item = impl Iterator<Item = ([f32; 3], [f32; 3])> + '_> {
        self.translation
            .iter()
            .zip(&self.rotation)
            .map(|(t, r)| t.iter().copied().zip(r.iter().copied()))
    }
}

impl Gradients {
    /// The gRPC `Gradient` response (timings travel as metadata).
    pub fn to_v1(&self) -> v1::GradientResponse {
        v1::GradientResponse {
            model: self.model.clone(),
            candidates: self
                .candidates
                .iter()
                .map(|c| v1::CandidateGradient {
                    cost: c.cost,
                    steps: c
                        .steps()
                        .map(|s| v1::StepGradient {
                            kinematic: s
                                .map(|(t, r)| v1::PoseGradient {
                                    translation: Some(vec3_to(t)),
                                    rotation: Some(vec3_to(r)),
                                })
                                .collect(),
                        })
                        .collect(),
                    frames: c.frames.iter().map(Frame::to_v1).collect(),
                })
                .collect(),
        }
    }

    /// The `POST /v1/sessions/{id}/gradient` response.
    pub fn to_json(&self) -> json::GradientResponse {
        json::GradientResponse {
            model: self.model.clone(),
            candidates: self
                .candidates
                .iter()
                .map(|c| json::CandidateGradient {
                    cost: c.cost,
                    steps: c
                        .steps()
                        .map(|s| json::StepGradient {
                            kinematic: s
                                .map(|(translation, rotation)| json::PoseGradient {
                                    translation,
                                    rotation,
                                })
                                .collect(),
                        })
                        .collect(),
                    frames: c.frames.iter().map(Frame::to_json).collect(),
                })
                .collect(),
            timing: self.timing.to_json(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spec::Pose;

    fn request() -> json::SessionGradientRequest {
        let pose = json::Pose {
            translation: [0.1, 0.0, 0.05],
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        let action = json::Action {
            kinematic: vec![json::ObjectPose { object: 1, pose }],
        };
        json::SessionGradientRequest {
            candidates: vec![json::GradientCandidate {
                actions: vec![action.clone(), action],
            }],
            steps: 2,
            cost: json::GradientCost {
                targets: vec![json::CostTarget {
                    object: 0,
                    step: 0,
                    position: [0.5, 0.0, 0.1],
                    position_weight: 1.0,
                    rotation: Some([0.0, 0.0, 0.0, 1.0]),
                    rotation_weight: 0.5,
                }],
                smoothness: 0.25,
            },
            every: 1,
            timeout_ms: 300,
        }
    }

    #[test]
    fn both_wire_forms_read_to_the_same_spec() {
        let r = request();
        let from_json = SessionGradientSpec::from_json("s", &r);
        let a = &r.candidates[0].actions[0].kinematic[0];
        let v = v1::SessionGradientRequest {
            session_id: "s".into(),
            candidates: vec![v1::GradientCandidate {
                actions: vec![
                    v1::Action {
                        kinematic: vec![v1::ObjectPose {
                            object: a.object,
                            pose: Some(a.pose.to_proto()),
                        }],
                    };
                    2
                ],
            }],
            steps: 2,
            cost: Some(v1::GradientCost {
                targets: vec![v1::CostTarget {
                    object: 0,
                    step: 0,
                    position: Some(vec3_to([0.5, 0.0, 0.1])),
                    position_weight: 1.0,
                    rotation: Some(v1::Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: 0.0,
                        w: 1.0,
                    }),
                    rotation_weight: 0.5,
                }],
                smoothness: 0.25,
            }),
            every: 1,
            timeout_ms: 300,
        };
        assert_eq!(SessionGradientSpec::from_v1(&v).unwrap(), from_json);
        // A pose without a translation names its field.
        let mut bad = v.clone();
        bad.candidates[0].actions[1].kinematic[0].pose = Some(v1::Pose::default());
        let e = SessionGradientSpec::from_v1(&bad).unwrap_err();
        assert_eq!(
            e.field,
            "candidates[0].actions[1].kinematic[0].pose.translation"
        );
        // Absent fields of a JSON target take their defaults.
        let t: json::CostTarget = serde_json::from_str(r#"{"object": 2}"#).unwrap();
        assert_eq!((t.step, t.position_weight, t.rotation), (0, 0.0, None));
    }

    #[test]
    fn answers_map_to_both_forms_alike() {
        let g = Gradients {
            model: "m".into(),
            candidates: vec![CandidateGradient {
                cost: 1.5,
                translation: vec![vec![[1.0, 2.0, 3.0]], vec![[4.0, 5.0, 6.0]]],
                rotation: vec![vec![[0.1, 0.2, 0.3]], vec![[0.4, 0.5, 0.6]]],
                frames: vec![Frame {
                    step: 2,
                    time: 0.1,
                    poses: vec![Pose::IDENTITY],
                    timing: None,
                    spread: Vec::new(),
                }],
            }],
            timing: Timing::default(),
        };
        let (p, j) = (g.to_v1(), g.to_json());
        let c = &p.candidates[0];
        assert_eq!(c.steps.len(), 2);
        let t = c.steps[1].kinematic[0].translation.unwrap();
        assert_eq!(
            [t.x, t.y, t.z],
            j.candidates[0].steps[1].kinematic[0].translation
        );
        let r = c.steps[0].kinematic[0].rotation.unwrap();
        assert_eq!([r.x, r.y, r.z], [0.1, 0.2, 0.3]);
        assert_eq!(j.candidates[0].cost, 1.5);
        assert_eq!(
            json::StepFrame::from_proto(&c.frames[0]),
            j.candidates[0].frames[0]
        );
    }
}
