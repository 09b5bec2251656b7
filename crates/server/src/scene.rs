//! Request validation and scene building: JSON-form scenes (gRPC requests are converted to
//! that form first) become model inputs, or an INVALID_ARGUMENT naming the offending field.
//!
//! Rules (every limit is also reported by `ListModels`):
//! - every number finite;
//! - a scene holds 1..=`max_objects` objects and at most `max_scene_points` points in all;
//! - each object has exactly one shape: `points` (1..=`max_points_per_object` points, each
//!   coordinate within ±1000 m of the centre of mass) or `mesh` (vertices within ±1000 m, faces
//!   indexing existing vertices, positive area, `samples` up to `max_points_per_object`);
//! - pose translations within ±1e5 m; quaternions must have norm 1 ± 1e-3 and are then
//!   renormalised (anything else, including the zero quaternion, is rejected rather than
//!   guessed at);
//! - at most one of `previous_pose` and `velocity`; speeds up to 1000 m/s and 1000 rad/s;
//! - mass in (0, 1e4] kg, friction in [0, 10], restitution in [0, 1];
//! - steps in 1..=`max_steps`, dt_steps in 1..=`max_dt_steps` (0 means 1).

use dynaserve_geometry::{TriMesh, sample_surface};
use dynaserve_model::{ModelConfig, ObjectInput, Pose, SceneState};
use dynaserve_proto::json;

use crate::config::ServeConfig;
use crate::error::ApiError;

/// Largest accepted absolute body-frame coordinate (points, mesh vertices), metres.
pub const MAX_BODY_EXTENT: f32 = 1.0e3;
/// Largest accepted absolute world coordinate of a pose translation, metres.
pub const MAX_WORLD_EXTENT: f32 = 1.0e5;
/// Largest accepted linear speed component, m/s.
pub const MAX_SPEED: f32 = 1.0e3;
/// Largest accepted angular speed component, rad/s.
pub const MAX_ANGULAR_SPEED: f32 = 1.0e3;
/// Quaternions whose norm is within this of 1 are renormalised; others are rejected.
pub const QUATERNION_TOLERANCE: f32 = 1.0e-3;
/// Largest accepted mass, kilograms.
pub const MAX_MASS: f32 = 1.0e4;
/// Largest accepted friction coefficient.
pub const MAX_FRICTION: f32 = 10.0;

/// Request limits for one model: the server flags capped by the model's own limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Objects per scene.
    pub max_objects: usize,
    /// Points (or mesh samples) per object.
    pub max_points_per_object: usize,
    /// Points per scene.
    pub max_scene_points: usize,
    /// Steps per request.
    pub max_steps: u32,
    /// Frames per step.
    pub max_dt_steps: u32,
    /// Variants per Predict call.
    pub max_variants: usize,
    /// Points sampled from a mesh when `samples` is 0.
    pub default_points: usize,
}

impl Limits {
    /// Limits for a model with configuration `model` under the server flags `config`.
    pub fn new(config: &ServeConfig, model: &ModelConfig) -> Limits {
        let max_points_per_object = config
            .max_points_per_object
            .min(model.max_points_per_object);
        Limits {
            max_objects: config.max_objects.min(model.max_objects),
            max_points_per_object,
            max_scene_points: config.max_scene_points,
            max_steps: config.max_steps,
            max_dt_steps: config.max_dt_steps.min(dynaserve_model::MAX_DT_STEPS),
            max_variants: config.max_variants,
            default_points: model.points_per_object.min(max_points_per_object),
        }
    }
}

/// Model inputs built from a validated scene.
#[derive(Clone, Debug, PartialEq)]
pub struct BuiltScene {
    /// Objects in request order.
    pub objects: Vec<ObjectInput>,
    /// Previous and current poses (`dt_steps` frames apart).
    pub state: SceneState,
}

fn finite(v: &[f32], field: &str) -> Result<(), ApiError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(ApiError::invalid(
            field,
            "must be finite (NaN or infinity given)",
        ))
    }
}

fn within(v: &[f32], bound: f32, field: &str, unit: &str) -> Result<(), ApiError> {
    finite(v, field)?;
    if v.iter().all(|x| x.abs() <= bound) {
        Ok(())
    } else {
        Err(ApiError::invalid(
            field,
            format!("components must lie within ±{bound} {unit}"),
        ))
    }
}

/// Checks and renormalises a quaternion `[x, y, z, w]`.
pub fn unit_quaternion(q: [f32; 4], field: &str) -> Result<[f32; 4], ApiError> {
    finite(&q, field)?;
    let n = q.iter().map(|c| c * c).sum::<f32>().sqrt();
    if (n - 1.0).abs() > QUATERNION_TOLERANCE {
        return Err(ApiError::invalid(
            field,
            format!(
                "must be a unit quaternion [x, y, z, w]; its norm is {n:.6} (norms within \
                 {QUATERNION_TOLERANCE} of 1 are renormalised, others rejected)"
            ),
        ));
    }
    Ok(q.map(|c| c / n))
}

fn pose(p: &json::Pose, field: &str) -> Result<Pose, ApiError> {
    within(
        &p.translation,
        MAX_WORLD_EXTENT,
        &format!("{field}.translation"),
        "m",
    )?;
    Ok(Pose {
        translation: p.translation,
        rotation: unit_quaternion(p.rotation, &format!("{field}.rotation"))?,
    })
}

fn shape(o: &json::ObjectSpec, field: &str, limits: &Limits) -> Result<Vec<[f32; 3]>, ApiError> {
    match (&o.points, &o.mesh) {
        (Some(_), Some(_)) | (None, None) => Err(ApiError::invalid(
            field,
            "exactly one of `points` and `mesh` is required",
        )),
        (Some(points), None) => {
            let f = format!("{field}.points");
            if points.is_empty() {
                return Err(ApiError::invalid(f, "must hold at least one point"));
            }
            if points.len() > limits.max_points_per_object {
                return Err(ApiError::invalid(
                    f,
                    format!(
                        "{} points exceed the limit of {} per object",
                        points.len(),
                        limits.max_points_per_object
                    ),
                ));
            }
            for (k, p) in points.iter().enumerate() {
                within(p, MAX_BODY_EXTENT, &format!("{f}[{k}]"), "m")?;
            }
            Ok(points.clone())
        }
        (None, Some(mesh)) => {
            let f = format!("{field}.mesh");
            if mesh.vertices.is_empty() {
                return Err(ApiError::invalid(
                    format!("{f}.vertices"),
                    "must hold at least three vertices",
                ));
            }
            for (k, v) in mesh.vertices.iter().enumerate() {
                within(v, MAX_BODY_EXTENT, &format!("{f}.vertices[{k}]"), "m")?;
            }
            if mesh.faces.is_empty() {
                return Err(ApiError::invalid(
                    format!("{f}.faces"),
                    "must hold at least one face",
                ));
            }
            let nv = mesh.vertices.len();
            if let Some(k) = mesh
                .faces
                .iter()
                .position(|t| t.iter().any(|&i| i as usize >= nv))
            {
                return Err(ApiError::invalid(
                    format!("{f}.faces[{k}]"),
                    format!("refers to a vertex outside 0..{nv}"),
                ));
            }
            let samples = if mesh.samples == 0 {
                limits.default_points
            } else {
                mesh.samples as usize
            };
            if samples > limits.max_points_per_object {
                return Err(ApiError::invalid(
                    format!("{f}.samples"),
                    format!(
                        "{samples} exceeds the limit of {} points per object",
                        limits.max_points_per_object
                    ),
                ));
            }
            let tri = TriMesh::new(mesh.vertices.clone(), mesh.faces.clone())
                .map_err(|e| ApiError::invalid(&f, e))?;
            let area = tri.area();
            if !(area.is_finite() && area > 0.0) {
                return Err(ApiError::invalid(f, "has no surface area"));
            }
            Ok(sample_surface(&tri, samples, mesh.seed))
        }
    }
}

fn parameter(
    v: f32,
    lo: f32,
    hi: f32,
    lo_open: bool,
    field: &str,
    unit: &str,
) -> Result<f32, ApiError> {
    finite(&[v], field)?;
    let ok = if lo_open { v > lo } else { v >= lo } && v <= hi;
    if ok {
        Ok(v)
    } else {
        let open = if lo_open { "(" } else { "[" };
        Err(ApiError::invalid(
            field,
            format!("{v} is outside {open}{lo}, {hi}]{unit}"),
        ))
    }
}

/// Validates `scene` (at path `field`, e.g. `scene` or `variants[3]`) and builds model inputs.
/// `dt_seconds` is the step duration (`dt_steps * dt_frame`), used to turn velocities into a
/// previous pose.
pub fn build_scene(
    scene: &json::Scene,
    field: &str,
    limits: &Limits,
    dt_seconds: f32,
) -> Result<BuiltScene, ApiError> {
    let of = format!("{field}.objects");
    if scene.objects.is_empty() {
        return Err(ApiError::invalid(of, "must hold at least one object"));
    }
    if scene.objects.len() > limits.max_objects {
        return Err(ApiError::invalid(
            of,
            format!(
                "{} objects exceed the limit of {}",
                scene.objects.len(),
                limits.max_objects
            ),
        ));
    }
    // Count points before sampling meshes, so an oversized scene costs nothing.
    let total_points: usize = scene
        .objects
        .iter()
        .map(|o| match (&o.points, &o.mesh) {
            (Some(p), _) => p.len(),
            (None, Some(m)) if m.samples > 0 => m.samples as usize,
            (None, Some(_)) => limits.default_points,
            (None, None) => 0,
        })
        .sum();
    if total_points > limits.max_scene_points {
        return Err(ApiError::invalid(
            of,
            format!(
                "{total_points} points in all exceed the limit of {} per scene",
                limits.max_scene_points
            ),
        ));
    }
    let mut objects = Vec::with_capacity(scene.objects.len());
    let mut previous = Vec::with_capacity(scene.objects.len());
    let mut current = Vec::with_capacity(scene.objects.len());
    for (i, o) in scene.objects.iter().enumerate() {
        let f = format!("{of}[{i}]");
        let reference = shape(o, &f, limits)?;
        let now = pose(&o.pose, &format!("{f}.pose"))?;
        let before = match (&o.previous_pose, &o.velocity) {
            (Some(_), Some(_)) => {
                return Err(ApiError::invalid(
                    f,
                    "at most one of `previous_pose` and `velocity` may be given",
                ));
            }
            (Some(p), None) => pose(p, &format!("{f}.previous_pose"))?,
            (None, Some(v)) => {
                within(&v.linear, MAX_SPEED, &format!("{f}.velocity.linear"), "m/s")?;
                within(
                    &v.angular,
                    MAX_ANGULAR_SPEED,
                    &format!("{f}.velocity.angular"),
                    "rad/s",
                )?;
                SceneState::from_velocities(vec![now], &[v.linear], &[v.angular], dt_seconds)
                    .map_err(|e| ApiError::invalid(format!("{f}.velocity"), e))?
                    .previous[0]
            }
            (None, None) => now,
        };
        let mass = parameter(o.mass, 0.0, MAX_MASS, true, &format!("{f}.mass"), " kg")?;
        let friction = parameter(
            o.friction,
            0.0,
            MAX_FRICTION,
            false,
            &format!("{f}.friction"),
            "",
        )?;
        let restitution = parameter(
            o.restitution,
            0.0,
            1.0,
            false,
            &format!("{f}.restitution"),
            "",
        )?;
        objects.push(ObjectInput {
            reference,
            mass,
            friction,
            restitution,
        });
        previous.push(before);
        current.push(now);
    }
    Ok(BuiltScene {
        objects,
        state: SceneState { previous, current },
    })
}

/// Checks `steps` and `dt_steps` (0 means 1); returns the effective `dt_steps`.
pub fn check_steps(steps: u32, dt_steps: u32, limits: &Limits) -> Result<u32, ApiError> {
    if steps == 0 || steps > limits.max_steps {
        return Err(ApiError::invalid(
            "steps",
            format!("{steps} is outside 1..={}", limits.max_steps),
        ));
    }
    let dt = dt_steps.max(1);
    if dt > limits.max_dt_steps {
        return Err(ApiError::invalid(
            "dt_steps",
            format!("{dt_steps} is outside 1..={} frames", limits.max_dt_steps),
        ));
    }
    Ok(dt)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> Limits {
        Limits {
            max_objects: 4,
            max_points_per_object: 64,
            max_scene_points: 128,
            max_steps: 100,
            max_dt_steps: 4,
            max_variants: 8,
            default_points: 32,
        }
    }

    fn object() -> json::ObjectSpec {
        json::ObjectSpec {
            points: Some(vec![[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0], [0.0, 0.1, 0.0]]),
            mesh: None,
            pose: json::Pose {
                translation: [0.0, 0.0, 1.0],
                rotation: [0.0, 0.0, 0.0, 1.0004],
            },
            previous_pose: None,
            velocity: Some(json::Velocity {
                linear: [1.0, 0.0, 0.0],
                angular: [0.0; 3],
            }),
            mass: 1.0,
            friction: 0.5,
            restitution: 0.2,
        }
    }

    fn err(s: json::Scene) -> ApiError {
        build_scene(&s, "scene", &limits(), 0.1).unwrap_err()
    }

    #[test]
    fn builds_velocity_state_and_renormalises() {
        let b = build_scene(
            &json::Scene {
                objects: vec![object()],
            },
            "scene",
            &limits(),
            0.1,
        )
        .unwrap();
        assert_eq!(b.state.current[0].rotation, [0.0, 0.0, 0.0, 1.0]);
        assert!((b.state.previous[0].translation[0] + 0.1).abs() < 1e-6);
    }

    #[test]
    fn errors_name_the_field() {
        let one = |f: &dyn Fn(&mut json::ObjectSpec)| {
            let mut o = object();
            f(&mut o);
            err(json::Scene {
                objects: vec![object(), o],
            })
            .field
            .unwrap()
        };
        assert_eq!(one(&|o| o.mass = 0.0), "scene.objects[1].mass");
        assert_eq!(one(&|o| o.friction = f32::NAN), "scene.objects[1].friction");
        assert_eq!(
            one(&|o| o.restitution = 1.5),
            "scene.objects[1].restitution"
        );
        assert_eq!(
            one(&|o| o.pose.rotation = [0.0, 0.0, 0.0, 2.0]),
            "scene.objects[1].pose.rotation"
        );
        assert_eq!(
            one(&|o| o.points.as_mut().unwrap()[2][1] = f32::INFINITY),
            "scene.objects[1].points[2]"
        );
        assert_eq!(one(&|o| o.points = Some(vec![])), "scene.objects[1].points");
        assert_eq!(one(&|o| o.points = None), "scene.objects[1]");
        assert_eq!(
            one(&|o| o.velocity.as_mut().unwrap().angular[0] = 1e9),
            "scene.objects[1].velocity.angular"
        );
        assert_eq!(
            err(json::Scene { objects: vec![] }).field.unwrap(),
            "scene.objects"
        );
        assert_eq!(
            err(json::Scene {
                objects: vec![object(); 5]
            })
            .field
            .unwrap(),
            "scene.objects"
        );
        assert_eq!(
            check_steps(0, 1, &limits()).unwrap_err().field.unwrap(),
            "steps"
        );
        assert_eq!(
            check_steps(5, 5, &limits()).unwrap_err().field.unwrap(),
            "dt_steps"
        );
        assert_eq!(check_steps(5, 0, &limits()).unwrap(), 1);
    }

    #[test]
    fn samples_meshes() {
        let mut o = object();
        o.points = None;
        o.mesh = Some(json::TriangleMesh {
            vertices: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            faces: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
            samples: 0,
            seed: 3,
        });
        let b = build_scene(
            &json::Scene {
                objects: vec![o.clone()],
            },
            "scene",
            &limits(),
            0.1,
        )
        .unwrap();
        assert_eq!(b.objects[0].reference.len(), 32);
        o.mesh.as_mut().unwrap().faces[1] = [0, 1, 9];
        assert_eq!(
            err(json::Scene { objects: vec![o] }).field.unwrap(),
            "scene.objects[0].mesh.faces[1]"
        );
    }
}
