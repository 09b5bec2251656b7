//! The JSON documents ([`crate::json`]) to and from the neutral vocabulary: requests in,
//! frames, predictions and model descriptions out.

use super::{
    Frame, Mesh, ModelInfo, Motion, ObjectSpec, Pose, PredictSpec, Prediction, RolloutSpec, Scene,
    Shape, Timing, millis,
};
use crate::error::FieldError;
use crate::json;

/// The neutral form of a JSON pose.
pub(super) fn pose(p: &json::Pose) -> Pose {
    Pose {
        translation: p.translation,
        rotation: p.rotation,
    }
}

/// The motion of an object at path `field`: at most one of `previous_pose` and `velocity`
/// (neither: at rest).
pub(super) fn motion(
    previous_pose: Option<&json::Pose>,
    velocity: Option<&json::Velocity>,
    field: &str,
) -> Result<Motion, FieldError> {
    match (previous_pose, velocity) {
        (None, None) => Ok(Motion::Rest),
        (Some(p), None) => Ok(Motion::PreviousPose(pose(p))),
        (None, Some(v)) => Ok(Motion::Velocity {
            linear: v.linear,
            angular: v.angular,
        }),
        (Some(_), Some(_)) => Err(FieldError::new(
            field,
            "at most one of `previous_pose` and `velocity` may be given",
        )),
    }
}

impl ObjectSpec {
    /// Reads a JSON object at path `field` (e.g. `scene.objects[3]`): exactly one of `points`
    /// and `mesh`, at most one of `previous_pose` and `velocity`.
    pub fn from_json(o: &json::ObjectSpec, field: &str) -> Result<ObjectSpec, FieldError> {
        let shape = match (&o.points, &o.mesh) {
            (Some(points), None) => Shape::Points(points.clone()),
            (None, Some(m)) => Shape::Mesh(Mesh {
                vertices: m.vertices.clone(),
                faces: m.faces.clone(),
                samples: m.samples,
                seed: m.seed,
            }),
            _ => {
                return Err(FieldError::new(
                    field,
                    "exactly one of `points` and `mesh` is required",
                ));
            }
        };
        Ok(ObjectSpec {
            shape,
            pose: pose(&o.pose),
            motion: motion(o.previous_pose.as_ref(), o.velocity.as_ref(), field)?,
            mass: o.mass,
            friction: o.friction,
            restitution: o.restitution,
        })
    }
}

impl Scene {
    /// Reads a JSON scene at path `field` (`scene` or `variants[4]`).
    pub fn from_json(s: &json::Scene, field: &str) -> Result<Scene, FieldError> {
        let objects = s
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| ObjectSpec::from_json(o, &format!("{field}.objects[{i}]")))
            .collect::<Result<_, _>>()?;
        Ok(Scene { objects })
    }
}

impl RolloutSpec {
    /// Reads a `POST /v1/rollout` body (its `stream` flag is the front end's business).
    pub fn from_json(r: &json::RolloutRequest) -> Result<RolloutSpec, FieldError> {
        Ok(RolloutSpec {
            model: r.model.clone(),
            scene: Scene::from_json(&r.scene, "scene")?,
            steps: r.steps,
            dt_steps: r.dt_steps,
            timeout_ms: r.timeout_ms,
        })
    }
}

impl PredictSpec {
    /// Reads a `POST /v1/predict` body.
    pub fn from_json(r: &json::PredictRequest) -> Result<PredictSpec, FieldError> {
        let variants = r
            .variants
            .iter()
            .enumerate()
            .map(|(i, s)| Scene::from_json(s, &format!("variants[{i}]")))
            .collect::<Result<_, _>>()?;
        Ok(PredictSpec {
            model: r.model.clone(),
            variants,
            steps: r.steps,
            dt_steps: r.dt_steps,
            every: r.every,
            timeout_ms: r.timeout_ms,
        })
    }
}

impl Frame {
    /// The JSON frame (an SSE `frame` event, an element of a trajectory).
    pub fn to_json(&self) -> json::StepFrame {
        json::StepFrame {
            step: self.step,
            time: self.time,
            poses: self
                .poses
                .iter()
                .map(|p| json::Pose {
                    translation: p.translation,
                    rotation: p.rotation,
                })
                .collect(),
            timing: self.timing.map(|t| json::StepTiming {
                queue_ms: millis(t.queue) as f32,
                forward_ms: millis(t.forward) as f32,
                batch_scenes: t.batch_scenes,
            }),
            spread: self
                .spread
                .iter()
                .map(|s| json::ObjectSpread {
                    position_m: s.position_m,
                    orientation_deg: s.orientation_deg,
                })
                .collect(),
        }
    }
}

impl Timing {
    /// The JSON timing document, milliseconds.
    pub fn to_json(&self) -> json::RequestTiming {
        json::RequestTiming {
            queue_ms: millis(self.queue),
            forward_ms: millis(self.forward),
            total_ms: millis(self.total),
        }
    }
}

impl Prediction {
    /// The `POST /v1/predict` response.
    pub fn to_json(&self) -> json::PredictResponse {
        json::PredictResponse {
            model: self.model.clone(),
            trajectories: self
                .trajectories
                .iter()
                .map(|t| json::Trajectory {
                    frames: t.iter().map(Frame::to_json).collect(),
                })
                .collect(),
            timing: self.timing.to_json(),
        }
    }
}

impl ModelInfo {
    /// The `GET /v1/models` entry.
    pub fn to_json(&self) -> json::ModelInfo {
        let v = self.to_v1();
        json::ModelInfo {
            name: v.name,
            architecture: v.architecture,
            dt_frame: v.dt_frame,
            default_points: v.default_points,
            max_objects: v.max_objects,
            max_points_per_object: v.max_points_per_object,
            max_steps: v.max_steps,
            max_dt_steps: v.max_dt_steps,
            max_variants: v.max_variants,
            max_request_cost: v.max_request_cost,
            gravity: crate::wire::vec3_from(v.gravity.as_ref()),
            config: self.config_json(),
            max_vertices: v.max_vertices,
            max_frames: v.max_frames,
            max_denoise_steps: v.max_denoise_steps,
            default_denoise_steps: v.default_denoise_steps,
            max_samples: v.max_samples,
            box_half_extent: v.box_half_extent,
            members: v.members,
            gradients: v.gradients,
            max_gradient_work: v.max_gradient_work,
        }
    }
}
