//! A stepping request's scene validated and built into model inputs ([`BuiltScene`]: the
//! objects' point clouds and parameters, the previous and current poses), or a [`FieldError`]
//! naming the offending field (the server answers INVALID_ARGUMENT / HTTP 422). Every stepping
//! family prepares its scenes from here, and the sessions check the poses and motions they are
//! given with the same rules ([`check_pose`], [`previous_pose`], [`check_implied_speed`]). The
//! load tester's in-process mode and the end-to-end tests' reference rollouts build their
//! scenes here too, so they agree with the server by construction.
//!
//! Rules (the numbers are in [`dynaserve_api::limits`]; every limit is also reported by
//! `ListModels`):
//! - every number finite;
//! - a scene holds 1..=`max_objects` objects and at most `max_scene_points` points in all;
//! - `points`: [`MIN_POINTS`]..=`max_points_per_object` points, each coordinate within ±[`MAX_BODY_EXTENT`]
//!   of the centre of mass; `mesh`: vertices within the same bound, faces indexing existing
//!   vertices, positive area, `samples` 0 (the model's default) or [`MIN_POINTS`] up to
//!   `max_points_per_object`, sampled into a point cloud;
//! - pose translations within ±[`MAX_WORLD_EXTENT`]; quaternions must have norm
//!   1 ± [`QUATERNION_TOLERANCE`] and are then renormalised (anything else, including the zero
//!   quaternion, is rejected rather than guessed at);
//! - speeds up to [`MAX_SPEED`] and [`MAX_ANGULAR_SPEED`] per component, given or implied by a
//!   previous pose;
//! - mass in [[`MIN_MASS`], [`MAX_MASS`]] kg, friction in [0, [`MAX_FRICTION`]], restitution in [0, 1].
//!
//! Steps, step size and a request's cost are the engine's admission
//! ([`crate::engine::admission`]).

use dynaserve_api::FieldError;
use dynaserve_api::limits::{
    Limits, MAX_ANGULAR_SPEED, MAX_BODY_EXTENT, MAX_FRICTION, MAX_MASS, MAX_SPEED,
    MAX_WORLD_EXTENT, MIN_MASS, MIN_POINTS, QUATERNION_TOLERANCE,
};
use dynaserve_api::spec::{Motion, Scene, Shape};
use dynaserve_geometry::{TriMesh, sample_surface};
use dynaserve_model::{ObjectInput, Pose, SceneState};

/// Model inputs built from a validated scene.
#[derive(Clone, Debug, PartialEq)]
pub struct BuiltScene {
    /// Objects in request order.
    pub objects: Vec<ObjectInput>,
    /// Previous and current poses (`dt_steps` frames apart).
    pub state: SceneState,
}

fn finite(v: &[f32], field: &str) -> Result<(), FieldError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(FieldError::new(
            field,
            "must be finite (NaN or infinity given)",
        ))
    }
}

fn within(v: &[f32], bound: f32, field: &str, unit: &str) -> Result<(), FieldError> {
    finite(v, field)?;
    if v.iter().all(|x| x.abs() <= bound) {
        Ok(())
    } else {
        Err(FieldError::new(
            field,
            format!("components must lie within ±{bound} {unit}"),
        ))
    }
}

/// Checks and renormalises a quaternion `[x, y, z, w]`.
pub fn unit_quaternion(q: [f32; 4], field: &str) -> Result<[f32; 4], FieldError> {
    finite(&q, field)?;
    let n = q.iter().map(|c| c * c).sum::<f32>().sqrt();
    if (n - 1.0).abs() > QUATERNION_TOLERANCE {
        return Err(FieldError::new(
            field,
            format!(
                "must be a unit quaternion [x, y, z, w]; its norm is {n:.6} (norms within \
                 {QUATERNION_TOLERANCE} of 1 are renormalised, others rejected)"
            ),
        ));
    }
    Ok(q.map(|c| c / n))
}

/// Checks a pose at path `field` (translation finite and within ±[`MAX_WORLD_EXTENT`] m, unit
/// quaternion) and renormalises its rotation.
pub fn check_pose(p: &Pose, field: &str) -> Result<Pose, FieldError> {
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

/// The checked pose one step (`dt_seconds`) before `now` of the object at path `field`, from
/// its motion: the given previous pose, the pose its velocities (m/s, rad/s, within the
/// limits) reach back from `now`, or `now` at rest.
pub fn previous_pose(
    now: Pose,
    motion: &Motion,
    dt_seconds: f32,
    field: &str,
) -> Result<Pose, FieldError> {
    match motion {
        Motion::PreviousPose(p) => {
            let f = format!("{field}.previous_pose");
            let before = check_pose(p, &f)?;
            check_implied_speed(&before, &now, dt_seconds, &f, "pose one step later")?;
            Ok(before)
        }
        Motion::Velocity { linear, angular } => {
            within(
                linear,
                MAX_SPEED,
                &format!("{field}.velocity.linear"),
                "m/s",
            )?;
            within(
                angular,
                MAX_ANGULAR_SPEED,
                &format!("{field}.velocity.angular"),
                "rad/s",
            )?;
            Ok(
                SceneState::from_velocities(vec![now], &[*linear], &[*angular], dt_seconds)
                    .map_err(|e| FieldError::new(format!("{field}.velocity"), e.to_string()))?
                    .previous[0],
            )
        }
        Motion::Rest => Ok(now),
    }
}

/// Checks that going from `from` to `to` in `dt_seconds` stays within [`MAX_SPEED`] m/s per
/// component, the bound on velocities: a pose pair may not imply a speed a velocity could not
/// have. The error names `field` (the pose checked, `against` naming the other one).
pub fn check_implied_speed(
    from: &Pose,
    to: &Pose,
    dt_seconds: f32,
    field: &str,
    against: &str,
) -> Result<(), FieldError> {
    // A step of no length (or not a number) implies no speed; the step size is checked
    // elsewhere.
    if dt_seconds.is_nan() || dt_seconds <= 0.0 {
        return Ok(());
    }
    let fastest = (0..3)
        .map(|k| (f64::from(to.translation[k]) - f64::from(from.translation[k])).abs())
        .fold(0.0f64, f64::max)
        / f64::from(dt_seconds);
    if fastest > f64::from(MAX_SPEED) {
        return Err(FieldError::new(
            field,
            format!(
                "implies a speed of {fastest:.4e} m/s from the {against} over one step of \
                 {dt_seconds} s; velocities are at most {MAX_SPEED} m/s per component"
            ),
        ));
    }
    Ok(())
}

fn shape(shape: &Shape, field: &str, limits: &Limits) -> Result<Vec<[f32; 3]>, FieldError> {
    match shape {
        Shape::Points(points) => {
            let f = format!("{field}.points");
            if points.len() < MIN_POINTS {
                return Err(FieldError::new(
                    f,
                    format!(
                        "{} points given; an object needs at least {MIN_POINTS}",
                        points.len()
                    ),
                ));
            }
            if points.len() > limits.caps.max_points_per_object {
                return Err(FieldError::new(
                    f,
                    format!(
                        "{} points exceed the limit of {} per object",
                        points.len(),
                        limits.caps.max_points_per_object
                    ),
                ));
            }
            for (k, p) in points.iter().enumerate() {
                within(p, MAX_BODY_EXTENT, &format!("{f}[{k}]"), "m")?;
            }
            Ok(points.clone())
        }
        Shape::Mesh(mesh) => {
            let f = format!("{field}.mesh");
            if mesh.vertices.is_empty() {
                return Err(FieldError::new(
                    format!("{f}.vertices"),
                    "must hold at least three vertices",
                ));
            }
            for (k, v) in mesh.vertices.iter().enumerate() {
                within(v, MAX_BODY_EXTENT, &format!("{f}.vertices[{k}]"), "m")?;
            }
            if mesh.faces.is_empty() {
                return Err(FieldError::new(
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
                return Err(FieldError::new(
                    format!("{f}.faces[{k}]"),
                    format!("refers to a vertex outside 0..{nv}"),
                ));
            }
            let samples = if mesh.samples == 0 {
                limits.default_points
            } else {
                mesh.samples as usize
            };
            if samples < MIN_POINTS {
                return Err(FieldError::new(
                    format!("{f}.samples"),
                    format!("{samples} samples; at least {MIN_POINTS} (or 0 for the default)"),
                ));
            }
            if samples > limits.caps.max_points_per_object {
                return Err(FieldError::new(
                    format!("{f}.samples"),
                    format!(
                        "{samples} exceeds the limit of {} points per object",
                        limits.caps.max_points_per_object
                    ),
                ));
            }
            let tri = TriMesh::new(mesh.vertices.clone(), mesh.faces.clone())
                .map_err(|e| FieldError::new(&f, e.to_string()))?;
            let area = tri.area();
            if !(area.is_finite() && area > 0.0) {
                return Err(FieldError::new(f, "has no surface area"));
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
) -> Result<f32, FieldError> {
    finite(&[v], field)?;
    let ok = if lo_open { v > lo } else { v >= lo } && v <= hi;
    if ok {
        Ok(v)
    } else {
        let open = if lo_open { "(" } else { "[" };
        Err(FieldError::new(
            field,
            format!("{v} is outside {open}{lo}, {hi}]{unit}"),
        ))
    }
}

/// Checks that `scene` (at path `field`) holds 1..=`max_objects` objects; [`build_scene`]
/// checks this first, and the engine before it weighs a request's cost
/// ([`check_request_cost`](crate::engine::admission::check_request_cost)), so that a scene with too many objects is refused naming them.
pub fn check_object_count(scene: &Scene, field: &str, limits: &Limits) -> Result<(), FieldError> {
    let of = || format!("{field}.objects");
    if scene.objects.is_empty() {
        return Err(FieldError::new(of(), "must hold at least one object"));
    }
    if scene.objects.len() > limits.caps.max_objects {
        return Err(FieldError::new(
            of(),
            format!(
                "{} objects exceed the limit of {}",
                scene.objects.len(),
                limits.caps.max_objects
            ),
        ));
    }
    Ok(())
}

/// Validates `scene` (at path `field`, e.g. `scene` or `variants[3]`) and builds model inputs.
/// `dt_seconds` is the step duration (`dt_steps * dt_frame`), used to turn velocities into a
/// previous pose.
pub fn build_scene(
    scene: &Scene,
    field: &str,
    limits: &Limits,
    dt_seconds: f32,
) -> Result<BuiltScene, FieldError> {
    check_object_count(scene, field, limits)?;
    let of = format!("{field}.objects");
    // Count points before sampling meshes, so an oversized scene costs nothing.
    let total_points: usize = scene
        .objects
        .iter()
        .map(|o| match &o.shape {
            Shape::Points(p) => p.len(),
            Shape::Mesh(m) if m.samples > 0 => m.samples as usize,
            Shape::Mesh(_) => limits.default_points,
        })
        .sum();
    if total_points > limits.caps.max_scene_points {
        return Err(FieldError::new(
            of,
            format!(
                "{total_points} points in all exceed the limit of {} per scene",
                limits.caps.max_scene_points
            ),
        ));
    }
    let mut objects = Vec::with_capacity(scene.objects.len());
    let mut previous = Vec::with_capacity(scene.objects.len());
    let mut current = Vec::with_capacity(scene.objects.len());
    for (i, o) in scene.objects.iter().enumerate() {
        let f = format!("{of}[{i}]");
        let reference = shape(&o.shape, &f, limits)?;
        let now = check_pose(&o.pose, &format!("{f}.pose"))?;
        let before = previous_pose(now, &o.motion, dt_seconds, &f)?;
        let mass = parameter(
            o.mass,
            MIN_MASS,
            MAX_MASS,
            false,
            &format!("{f}.mass"),
            " kg",
        )?;
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
            kinematic: false,
        });
        previous.push(before);
        current.push(now);
    }
    Ok(BuiltScene {
        objects,
        state: SceneState::new(previous, current),
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use dynaserve_api::json;
    use dynaserve_api::limits::Caps;

    /// Small limits the request-rule tests share: 4 objects of up to 64 points, 100 steps,
    /// step sizes up to 4, a cost ceiling of 1000 object-steps.
    pub(crate) fn limits() -> Limits {
        Limits {
            caps: Caps {
                max_objects: 4,
                max_points_per_object: 64,
                max_scene_points: 128,
                max_steps: 100,
                max_dt_steps: 4,
                max_variants: 8,
                max_request_cost: 1000,
                max_gradient_work: 200,
            },
            default_points: 32,
        }
    }

    fn object() -> json::ObjectSpec {
        json::ObjectSpec {
            points: Some(vec![
                [0.1, 0.0, 0.0],
                [-0.1, 0.0, 0.0],
                [0.0, 0.1, 0.0],
                [0.0, 0.0, 0.1],
            ]),
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

    fn build(s: &json::Scene) -> Result<BuiltScene, FieldError> {
        build_scene(&Scene::from_json(s, "scene")?, "scene", &limits(), 0.1)
    }

    fn err(s: json::Scene) -> FieldError {
        build(&s).unwrap_err()
    }

    #[test]
    fn builds_velocity_state_and_renormalises() {
        let b = build(&json::Scene {
            objects: vec![object()],
        })
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
        };
        assert_eq!(one(&|o| o.mass = 0.0), "scene.objects[1].mass");
        assert_eq!(one(&|o| o.mass = 1e-45), "scene.objects[1].mass");
        assert_eq!(
            one(&|o| o.points = Some(vec![[0.0; 3]])),
            "scene.objects[1].points"
        );
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
        assert_eq!(err(json::Scene { objects: vec![] }).field, "scene.objects");
        assert_eq!(
            err(json::Scene {
                objects: vec![object(); 5]
            })
            .field,
            "scene.objects"
        );
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
        let b = build(&json::Scene {
            objects: vec![o.clone()],
        })
        .unwrap();
        assert_eq!(b.objects[0].reference.len(), 32);
        o.mesh.as_mut().unwrap().faces[1] = [0, 1, 9];
        assert_eq!(
            err(json::Scene { objects: vec![o] }).field,
            "scene.objects[0].mesh.faces[1]"
        );
    }
}
