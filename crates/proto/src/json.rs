//! JSON form of the `dynaserve.v1` messages: the HTTP API bodies and the scene file format
//! (a scene file is a [`RolloutRequest`] document, so `curl -d @scene.json` works).
//!
//! The JSON form mirrors the `.proto` field for field with the same snake_case names, except
//! that vectors are arrays: points and velocities `[x, y, z]`, quaternions `[x, y, z, w]`
//! (scalar last), clouds `[[x, y, z], ...]`, mesh faces `[[a, b, c], ...]`. Units: metres,
//! seconds, kilograms, radians; z up; ground plane z = 0. Field paths in error messages
//! (`scene.objects[2].mass`) are the same for both forms.

use serde::{Deserialize, Serialize};

use crate::v1;

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
    /// Coulomb friction coefficient in [0, 10]. Defaults to 0.
    #[serde(default)]
    pub friction: f32,
    /// Coefficient of restitution in [0, 1]. Defaults to 0.
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
    /// Gravity the model was trained with, m/s^2, world frame.
    pub gravity: [f32; 3],
    /// The checkpoint's `config.json`.
    #[cfg_attr(feature = "openapi", schema(value_type = Object))]
    pub config: serde_json::Value,
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

/// A malformed field found while converting a gRPC message to its JSON form.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct FieldError {
    /// Field path, e.g. `scene.objects[0].points.xyz`.
    pub field: String,
    /// What is wrong.
    pub message: String,
}

impl FieldError {
    /// Builds an error for `field`.
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        FieldError {
            field: field.into(),
            message: message.into(),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// gRPC -> JSON (fallible: flattened arrays must have whole triples, required fields present)

fn vec3_from(v: Option<&v1::Vec3>) -> [f32; 3] {
    v.map_or([0.0; 3], |v| [v.x, v.y, v.z])
}

fn pose_from(p: Option<&v1::Pose>, field: &str) -> Result<Pose, FieldError> {
    let p = p.ok_or_else(|| FieldError::new(field, "required"))?;
    let translation = p
        .translation
        .as_ref()
        .ok_or_else(|| FieldError::new(format!("{field}.translation"), "required"))?;
    Ok(Pose {
        translation: [translation.x, translation.y, translation.z],
        rotation: p
            .rotation
            .as_ref()
            .map_or(IDENTITY_ROTATION, |q| [q.x, q.y, q.z, q.w]),
    })
}

fn triples<T: Copy>(flat: &[T], field: &str) -> Result<Vec<[T; 3]>, FieldError> {
    if !flat.len().is_multiple_of(3) {
        return Err(FieldError::new(
            field,
            format!("length {} is not a multiple of 3", flat.len()),
        ));
    }
    Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

impl ObjectSpec {
    /// Converts a gRPC object; `field` is its path (e.g. `scene.objects[3]`).
    pub fn from_proto(o: &v1::ObjectSpec, field: &str) -> Result<ObjectSpec, FieldError> {
        let (points, mesh) = match &o.shape {
            Some(v1::object_spec::Shape::Points(c)) => {
                (Some(triples(&c.xyz, &format!("{field}.points.xyz"))?), None)
            }
            Some(v1::object_spec::Shape::Mesh(m)) => (
                None,
                Some(TriangleMesh {
                    vertices: triples(&m.vertices, &format!("{field}.mesh.vertices"))?,
                    faces: triples(&m.faces, &format!("{field}.mesh.faces"))?,
                    samples: m.samples,
                    seed: m.seed,
                }),
            ),
            None => (None, None),
        };
        let (previous_pose, velocity) = match &o.motion {
            Some(v1::object_spec::Motion::PreviousPose(p)) => (
                Some(pose_from(Some(p), &format!("{field}.previous_pose"))?),
                None,
            ),
            Some(v1::object_spec::Motion::Velocity(v)) => (
                None,
                Some(Velocity {
                    linear: vec3_from(v.linear.as_ref()),
                    angular: vec3_from(v.angular.as_ref()),
                }),
            ),
            None => (None, None),
        };
        Ok(ObjectSpec {
            points,
            mesh,
            pose: pose_from(o.pose.as_ref(), &format!("{field}.pose"))?,
            previous_pose,
            velocity,
            mass: o.mass,
            friction: o.friction,
            restitution: o.restitution,
        })
    }

    /// Converts to the gRPC form. If both `points` and `mesh` are set, `points` wins; if both
    /// `previous_pose` and `velocity` are set, `previous_pose` wins (the server rejects such a
    /// JSON object before converting).
    pub fn to_proto(&self) -> v1::ObjectSpec {
        let shape = match (&self.points, &self.mesh) {
            (Some(p), _) => Some(v1::object_spec::Shape::Points(v1::PointCloud {
                xyz: p.iter().flatten().copied().collect(),
            })),
            (None, Some(m)) => Some(v1::object_spec::Shape::Mesh(v1::TriangleMesh {
                vertices: m.vertices.iter().flatten().copied().collect(),
                faces: m.faces.iter().flatten().copied().collect(),
                samples: m.samples,
                seed: m.seed,
            })),
            (None, None) => None,
        };
        let motion = match (&self.previous_pose, &self.velocity) {
            (Some(p), _) => Some(v1::object_spec::Motion::PreviousPose(p.to_proto())),
            (None, Some(v)) => Some(v1::object_spec::Motion::Velocity(v1::Velocity {
                linear: Some(vec3_to(v.linear)),
                angular: Some(vec3_to(v.angular)),
            })),
            (None, None) => None,
        };
        v1::ObjectSpec {
            shape,
            pose: Some(self.pose.to_proto()),
            motion,
            mass: self.mass,
            friction: self.friction,
            restitution: self.restitution,
        }
    }
}

fn vec3_to(v: [f32; 3]) -> v1::Vec3 {
    v1::Vec3 {
        x: v[0],
        y: v[1],
        z: v[2],
    }
}

impl Pose {
    /// Converts to the gRPC form.
    pub fn to_proto(&self) -> v1::Pose {
        let [x, y, z, w] = self.rotation;
        v1::Pose {
            translation: Some(vec3_to(self.translation)),
            rotation: Some(v1::Quaternion { x, y, z, w }),
        }
    }

    /// Converts from the gRPC form (missing translation: origin; missing rotation: identity).
    pub fn from_proto(p: &v1::Pose) -> Pose {
        Pose {
            translation: vec3_from(p.translation.as_ref()),
            rotation: p
                .rotation
                .as_ref()
                .map_or(IDENTITY_ROTATION, |q| [q.x, q.y, q.z, q.w]),
        }
    }
}

impl Scene {
    /// Converts a gRPC scene; `field` is its path (e.g. `scene` or `variants[4]`).
    pub fn from_proto(s: Option<&v1::Scene>, field: &str) -> Result<Scene, FieldError> {
        let s = s.ok_or_else(|| FieldError::new(field, "required"))?;
        let objects = s
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| ObjectSpec::from_proto(o, &format!("{field}.objects[{i}]")))
            .collect::<Result<_, _>>()?;
        Ok(Scene { objects })
    }

    /// Converts to the gRPC form.
    pub fn to_proto(&self) -> v1::Scene {
        v1::Scene {
            objects: self.objects.iter().map(ObjectSpec::to_proto).collect(),
        }
    }
}

impl RolloutRequest {
    /// Converts a gRPC request.
    pub fn from_proto(r: &v1::RolloutRequest) -> Result<RolloutRequest, FieldError> {
        Ok(RolloutRequest {
            model: r.model.clone(),
            scene: Scene::from_proto(r.scene.as_ref(), "scene")?,
            steps: r.steps,
            dt_steps: r.dt_steps,
            timeout_ms: r.timeout_ms,
            stream: false,
        })
    }

    /// Converts to the gRPC form (`stream` has no gRPC counterpart: gRPC always streams).
    pub fn to_proto(&self) -> v1::RolloutRequest {
        v1::RolloutRequest {
            model: self.model.clone(),
            scene: Some(self.scene.to_proto()),
            steps: self.steps,
            dt_steps: self.dt_steps,
            timeout_ms: self.timeout_ms,
        }
    }
}

impl PredictRequest {
    /// Converts a gRPC request.
    pub fn from_proto(r: &v1::PredictRequest) -> Result<PredictRequest, FieldError> {
        let variants = r
            .variants
            .iter()
            .enumerate()
            .map(|(i, s)| Scene::from_proto(Some(s), &format!("variants[{i}]")))
            .collect::<Result<_, _>>()?;
        Ok(PredictRequest {
            model: r.model.clone(),
            variants,
            steps: r.steps,
            dt_steps: r.dt_steps,
            every: r.every,
            timeout_ms: r.timeout_ms,
        })
    }

    /// Converts to the gRPC form.
    pub fn to_proto(&self) -> v1::PredictRequest {
        v1::PredictRequest {
            model: self.model.clone(),
            variants: self.variants.iter().map(Scene::to_proto).collect(),
            steps: self.steps,
            dt_steps: self.dt_steps,
            every: self.every,
            timeout_ms: self.timeout_ms,
        }
    }
}

impl StepFrame {
    /// Converts to the gRPC form.
    pub fn to_proto(&self) -> v1::StepFrame {
        v1::StepFrame {
            step: self.step,
            time: self.time,
            poses: self.poses.iter().map(Pose::to_proto).collect(),
            timing: self.timing.map(|t| v1::StepTiming {
                queue_ms: t.queue_ms,
                forward_ms: t.forward_ms,
                batch_scenes: t.batch_scenes,
            }),
        }
    }

    /// Converts from the gRPC form.
    pub fn from_proto(f: &v1::StepFrame) -> StepFrame {
        StepFrame {
            step: f.step,
            time: f.time,
            poses: f.poses.iter().map(Pose::from_proto).collect(),
            timing: f.timing.map(|t| StepTiming {
                queue_ms: t.queue_ms,
                forward_ms: t.forward_ms,
                batch_scenes: t.batch_scenes,
            }),
        }
    }
}

impl ModelInfo {
    /// Converts to the gRPC form (`config` becomes `config_json`).
    pub fn to_proto(&self) -> v1::ModelInfo {
        v1::ModelInfo {
            name: self.name.clone(),
            architecture: self.architecture.clone(),
            dt_frame: self.dt_frame,
            default_points: self.default_points,
            max_objects: self.max_objects,
            max_points_per_object: self.max_points_per_object,
            max_steps: self.max_steps,
            max_dt_steps: self.max_dt_steps,
            max_variants: self.max_variants,
            gravity: Some(vec3_to(self.gravity)),
            config_json: self.config.to_string(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn object() -> ObjectSpec {
        ObjectSpec {
            points: Some(vec![[0.1, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, -0.3]]),
            mesh: None,
            pose: Pose {
                translation: [1.0, 2.0, 0.5],
                rotation: [0.0, 0.0, 0.38268343, 0.9238795],
            },
            previous_pose: None,
            velocity: Some(Velocity {
                linear: [1.0, 0.0, 0.0],
                angular: [0.0, 0.0, 2.0],
            }),
            mass: 2.5,
            friction: 0.4,
            restitution: 0.3,
        }
    }

    #[test]
    fn rollout_request_round_trips_through_proto() {
        let req = RolloutRequest {
            model: "m".into(),
            scene: Scene {
                objects: vec![
                    object(),
                    ObjectSpec {
                        points: None,
                        mesh: Some(TriangleMesh {
                            vertices: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                            faces: vec![[0, 1, 2]],
                            samples: 64,
                            seed: 7,
                        }),
                        previous_pose: Some(Pose {
                            translation: [0.0, 0.0, 1.0],
                            rotation: IDENTITY_ROTATION,
                        }),
                        velocity: None,
                        ..object()
                    },
                ],
            },
            steps: 10,
            dt_steps: 2,
            timeout_ms: 500,
            stream: false,
        };
        let back = RolloutRequest::from_proto(&req.to_proto()).unwrap();
        assert_eq!(back, req);
    }

    #[test]
    fn malformed_flat_cloud_names_the_field() {
        let mut p = RolloutRequest {
            model: String::new(),
            scene: Scene {
                objects: vec![object(), object()],
            },
            steps: 1,
            dt_steps: 0,
            timeout_ms: 0,
            stream: false,
        }
        .to_proto();
        if let Some(v1::object_spec::Shape::Points(c)) =
            &mut p.scene.as_mut().unwrap().objects[1].shape
        {
            c.xyz.pop();
        }
        let err = RolloutRequest::from_proto(&p).unwrap_err();
        assert_eq!(err.field, "scene.objects[1].points.xyz");
    }

    #[test]
    fn json_defaults_and_unknown_fields() {
        let doc = r#"{"scene":{"objects":[{"points":[[0,0,0]],"pose":{"translation":[0,0,1]},"mass":1}]},"steps":3}"#;
        let r: RolloutRequest = serde_json::from_str(doc).unwrap();
        assert_eq!(r.scene.objects[0].pose.rotation, IDENTITY_ROTATION);
        assert_eq!(r.dt_steps, 0);
        let bad = r#"{"scene":{"objects":[]},"steps":3,"stepz":4}"#;
        assert!(serde_json::from_str::<RolloutRequest>(bad).is_err());
    }
}
