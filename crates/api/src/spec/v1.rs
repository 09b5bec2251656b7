//! The generated gRPC messages ([`crate::v1`]) to and from the neutral vocabulary: requests in
//! (flattened arrays must hold whole triples, required fields must be present), frames and
//! model descriptions out. No detour through the JSON form.

use super::{
    Frame, Mesh, ModelInfo, ModelKind, Motion, ObjectSpec, Pose, PredictSpec, Prediction,
    RolloutSpec, Scene, Shape, millis,
};
use crate::error::FieldError;
use crate::json::IDENTITY_ROTATION;
use crate::v1;
use crate::wire::{vec3_from, vec3_to};

pub(super) fn triples<T: Copy>(flat: &[T], field: &str) -> Result<Vec<[T; 3]>, FieldError> {
    if !flat.len().is_multiple_of(3) {
        return Err(FieldError::new(
            field,
            format!("length {} is not a multiple of 3", flat.len()),
        ));
    }
    Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// A pose whose translation is required (a missing rotation is the identity).
pub(super) fn required_pose(p: Option<&v1::Pose>, field: &str) -> Result<Pose, FieldError> {
    let p = p.ok_or_else(|| FieldError::new(field, "required"))?;
    let t = p
        .translation
        .as_ref()
        .ok_or_else(|| FieldError::new(format!("{field}.translation"), "required"))?;
    Ok(Pose {
        translation: [t.x, t.y, t.z],
        rotation: p
            .rotation
            .as_ref()
            .map_or(IDENTITY_ROTATION, |q| [q.x, q.y, q.z, q.w]),
    })
}

/// The gRPC form of a pose.
pub(super) fn pose_to_v1(p: &Pose) -> v1::Pose {
    let [x, y, z, w] = p.rotation;
    v1::Pose {
        translation: Some(vec3_to(p.translation)),
        rotation: Some(v1::Quaternion { x, y, z, w }),
    }
}

impl ObjectSpec {
    /// Reads a gRPC object at path `field` (e.g. `scene.objects[3]`).
    pub fn from_v1(o: &v1::ObjectSpec, field: &str) -> Result<ObjectSpec, FieldError> {
        let shape = match &o.shape {
            Some(v1::object_spec::Shape::Points(c)) => {
                Shape::Points(triples(&c.xyz, &format!("{field}.points.xyz"))?)
            }
            Some(v1::object_spec::Shape::Mesh(m)) => Shape::Mesh(Mesh {
                vertices: triples(&m.vertices, &format!("{field}.mesh.vertices"))?,
                faces: triples(&m.faces, &format!("{field}.mesh.faces"))?,
                samples: m.samples,
                seed: m.seed,
            }),
            None => {
                return Err(FieldError::new(
                    field,
                    "exactly one of `points` and `mesh` is required",
                ));
            }
        };
        let motion = match &o.motion {
            Some(v1::object_spec::Motion::PreviousPose(p)) => {
                Motion::PreviousPose(required_pose(Some(p), &format!("{field}.previous_pose"))?)
            }
            Some(v1::object_spec::Motion::Velocity(v)) => Motion::Velocity {
                linear: vec3_from(v.linear.as_ref()),
                angular: vec3_from(v.angular.as_ref()),
            },
            None => Motion::Rest,
        };
        Ok(ObjectSpec {
            shape,
            pose: required_pose(o.pose.as_ref(), &format!("{field}.pose"))?,
            motion,
            mass: o.mass,
            friction: o.friction,
            restitution: o.restitution,
        })
    }
}

impl Scene {
    /// Reads a gRPC scene at path `field` (`scene` or `variants[4]`); absent is an error.
    pub fn from_v1(s: Option<&v1::Scene>, field: &str) -> Result<Scene, FieldError> {
        let s = s.ok_or_else(|| FieldError::new(field, "required"))?;
        let objects = s
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| ObjectSpec::from_v1(o, &format!("{field}.objects[{i}]")))
            .collect::<Result<_, _>>()?;
        Ok(Scene { objects })
    }
}

impl RolloutSpec {
    /// Reads a gRPC `Rollout` request.
    pub fn from_v1(r: &v1::RolloutRequest) -> Result<RolloutSpec, FieldError> {
        Ok(RolloutSpec {
            model: r.model.clone(),
            scene: Scene::from_v1(r.scene.as_ref(), "scene")?,
            steps: r.steps,
            dt_steps: r.dt_steps,
            timeout_ms: r.timeout_ms,
        })
    }
}

impl PredictSpec {
    /// Reads a gRPC `Predict` request.
    pub fn from_v1(r: &v1::PredictRequest) -> Result<PredictSpec, FieldError> {
        let variants = r
            .variants
            .iter()
            .enumerate()
            .map(|(i, s)| Scene::from_v1(Some(s), &format!("variants[{i}]")))
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
    /// The gRPC frame.
    pub fn to_v1(&self) -> v1::StepFrame {
        v1::StepFrame {
            step: self.step,
            time: self.time,
            poses: self.poses.iter().map(pose_to_v1).collect(),
            timing: self.timing.map(|t| v1::StepTiming {
                queue_ms: millis(t.queue) as f32,
                forward_ms: millis(t.forward) as f32,
                batch_scenes: t.batch_scenes,
            }),
            spread: self
                .spread
                .iter()
                .map(|s| v1::ObjectSpread {
                    position_m: s.position_m,
                    orientation_deg: s.orientation_deg,
                })
                .collect(),
        }
    }
}

impl Prediction {
    /// The gRPC `Predict` response (timings travel as metadata).
    pub fn to_v1(&self) -> v1::PredictResponse {
        v1::PredictResponse {
            trajectories: self
                .trajectories
                .iter()
                .map(|t| v1::Trajectory {
                    frames: t.iter().map(Frame::to_v1).collect(),
                })
                .collect(),
            model: self.model.clone(),
        }
    }
}

impl ModelInfo {
    /// The checkpoint's configuration as JSON.
    pub fn config_json(&self) -> serde_json::Value {
        match &self.kind {
            ModelKind::Stepping { about, .. } | ModelKind::Sampling { about, .. } => {
                about.config.clone()
            }
        }
    }

    /// The gRPC `ListModels` entry (`config_json` holds the configuration as JSON text; the
    /// fields of the other family are 0).
    pub fn to_v1(&self) -> v1::ModelInfo {
        let mut out = v1::ModelInfo {
            name: self.name.clone(),
            config_json: self.config_json().to_string(),
            members: self.members.clone(),
            ..v1::ModelInfo::default()
        };
        match &self.kind {
            ModelKind::Stepping { about, limits: l } => {
                out.architecture = about.architecture.clone();
                out.dt_frame = about.dt_frame;
                out.default_points = l.default_points as u32;
                out.max_objects = l.caps.max_objects as u32;
                out.max_points_per_object = l.caps.max_points_per_object as u32;
                out.max_steps = l.caps.max_steps;
                out.max_dt_steps = l.caps.max_dt_steps;
                out.max_variants = l.caps.max_variants as u32;
                out.max_request_cost = l.caps.max_request_cost;
                out.gravity = Some(vec3_to(about.gravity));
                out.gradients = self.gradients;
                if self.gradients {
                    out.max_gradient_work = l.caps.max_gradient_work;
                }
            }
            ModelKind::Sampling { about, limits: l } => {
                out.architecture = about.architecture.clone();
                out.dt_frame = about.dt_frame;
                out.max_objects = l.max_objects as u32;
                out.gravity = Some(vec3_to(about.gravity));
                [
                    out.max_vertices,
                    out.max_frames,
                    out.max_denoise_steps,
                    out.default_denoise_steps,
                    out.max_samples,
                ] = super::sampling::generate_fields(l);
                out.box_half_extent = l.box_half_extent;
                out.max_request_cost = l.max_cost;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::json;

    fn object() -> json::ObjectSpec {
        json::ObjectSpec {
            points: Some(vec![[0.1, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, -0.3]]),
            mesh: None,
            pose: json::Pose {
                translation: [1.0, 2.0, 0.5],
                rotation: [0.0, 0.0, 0.38268343, 0.9238795],
            },
            previous_pose: None,
            velocity: Some(json::Velocity {
                linear: [1.0, 0.0, 0.0],
                angular: [0.0, 0.0, 2.0],
            }),
            mass: 2.5,
            friction: 0.4,
            restitution: 0.3,
        }
    }

    fn request(objects: Vec<json::ObjectSpec>) -> json::RolloutRequest {
        json::RolloutRequest {
            model: "m".into(),
            scene: json::Scene { objects },
            steps: 10,
            dt_steps: 2,
            timeout_ms: 500,
            stream: false,
        }
    }

    #[test]
    fn both_wire_forms_read_to_the_same_spec() {
        let req = request(vec![
            object(),
            json::ObjectSpec {
                points: None,
                mesh: Some(json::TriangleMesh {
                    vertices: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                    faces: vec![[0, 1, 2]],
                    samples: 64,
                    seed: 7,
                }),
                previous_pose: Some(json::Pose {
                    translation: [0.0, 0.0, 1.0],
                    rotation: IDENTITY_ROTATION,
                }),
                velocity: None,
                ..object()
            },
            json::ObjectSpec {
                velocity: None,
                ..object()
            },
        ]);
        let from_json = RolloutSpec::from_json(&req).unwrap();
        let from_v1 = RolloutSpec::from_v1(&req.to_proto()).unwrap();
        assert_eq!(from_json, from_v1);
        assert_eq!(from_json.scene.objects[2].motion, Motion::Rest);
    }

    #[test]
    fn malformed_input_names_the_field() {
        let mut p = request(vec![object(), object()]).to_proto();
        if let Some(v1::object_spec::Shape::Points(c)) =
            &mut p.scene.as_mut().unwrap().objects[1].shape
        {
            c.xyz.pop();
        }
        let err = RolloutSpec::from_v1(&p).unwrap_err();
        assert_eq!(err.field, "scene.objects[1].points.xyz");
        let mut two = object();
        two.previous_pose = Some(two.pose);
        let err = RolloutSpec::from_json(&request(vec![object(), two])).unwrap_err();
        assert_eq!(err.field, "scene.objects[1]");
        let mut none = object();
        none.points = None;
        let err = RolloutSpec::from_json(&request(vec![none])).unwrap_err();
        assert_eq!(err.field, "scene.objects[0]");
    }

    #[test]
    fn frames_map_to_both_forms_alike() {
        let f = Frame {
            step: 2,
            time: 0.5,
            poses: vec![Pose::IDENTITY],
            timing: Some(super::super::StepTiming {
                queue: std::time::Duration::from_micros(1500),
                forward: std::time::Duration::from_millis(3),
                batch_scenes: 5,
            }),
            spread: Vec::new(),
        };
        assert_eq!(json::StepFrame::from_proto(&f.to_v1()), f.to_json());
        assert_eq!(f.to_json().timing.unwrap().queue_ms, 1.5);
        // Without a spread the JSON frame has no `spread` key, as before.
        let text = serde_json::to_string(&f.to_json()).unwrap();
        assert!(!text.contains("spread"), "{text}");
        let spread = vec![super::super::PoseSpread {
            position_m: 0.25,
            orientation_deg: 3.5,
        }];
        let f = Frame { spread, ..f };
        assert_eq!(json::StepFrame::from_proto(&f.to_v1()), f.to_json());
        let back: json::StepFrame =
            serde_json::from_str(&serde_json::to_string(&f.to_json()).unwrap()).unwrap();
        assert_eq!(back.spread[0].position_m, 0.25);
        assert_eq!(f.to_v1().spread[0].orientation_deg, 3.5);
    }
}
