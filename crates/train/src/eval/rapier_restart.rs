//! The simulator itself as a predictor: rapier restarted from the two observed frames.
//!
//! Every object is rebuilt from what a scene record stores (its shape kind and scale, or the
//! convex hull of its reference cloud for a random hull; its mass, friction and restitution) on
//! the data's floor, posed at the observed frame `s` with the velocity the two observed frames
//! imply, and simulated at the data's physics rate. It knows everything a learned model is
//! told and the exact shapes and contact laws besides; what it lacks is the same as the model:
//! the velocity at `s` (the finite difference is an average over the step, through any impact
//! inside it) and the solver's contact state. Its error is therefore a reference for how
//! predictable a dataset is from two frames, not a bound a model cannot pass: a model may learn
//! to read a better velocity from the poses than the finite difference.
//!
//! The velocity is the free-flight one (the finite difference plus the gravity the step's
//! last substeps add), for every object: two frames cannot tell a supported object from a
//! falling one. For an object at rest it is a downward 0.2 m/s at 24 fps that the first
//! contact step absorbs; without the term, free flight would be 8.5 mm off one frame ahead
//! while the one-step errors at contacts on MOVi-B move by at most 0.0007 m (see the model
//! card).
//!
//! With [`RapierRestart::cloud_points`] every object is instead the convex hull of the first
//! `n` points of its reference cloud, the points a model evaluated with `n` points per object
//! is given: rapier then knows the shape only as well as such a model can (less, for a
//! non-convex shape, whose hollows the hull fills), which separates what the sampled geometry
//! allows from what the exact shapes allow.

use dynaserve_model::{Pose, SceneState};
use dynaserve_sim::materials::MOVI_FLOOR;
use dynaserve_sim::scene::{FloorSpec, simulate};
use dynaserve_sim::shapes::{Part, Polytope};
use dynaserve_sim::{KinematicPath, Manifest, ObjectSpec, SceneRecord, SceneSpec, Shape};
use dynaserve_sim::{ShapeKind, SimConfig};
use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use serde::Deserialize;

use super::baselines::{check_state, unit};
use super::{EvalError, Predictor};

/// Rapier restarted from the observed frames (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct RapierRestart {
    /// The shape of each `shape_id`, in the manifest's order.
    pub shapes: Vec<ShapeKind>,
    /// The floor (top face at z = 0).
    pub floor: FloorSpec,
    /// Gravity, m/s^2.
    pub gravity: [f32; 3],
    /// Physics steps per second.
    pub physics_hz: u32,
    /// Physics steps per recorded frame.
    pub substeps_per_frame: u32,
    /// rapier solver iterations per physics step.
    pub solver_iterations: usize,
    /// `Some(n)`: every object is rebuilt as the convex hull of the first `n` points of its
    /// reference cloud (all of them if it has fewer) instead of its exact shape, and the
    /// predictor is labelled `rapier-hull-{n}`; `None`: the exact shapes (`rapier-restart`).
    pub cloud_points: Option<usize>,
}

impl RapierRestart {
    /// The conditions every generator of this project records: the MOVi-B shape list, the
    /// MOVi floor, 240 Hz physics, 10 steps per frame, 4 solver iterations, under `gravity`.
    pub fn movi(gravity: [f32; 3]) -> RapierRestart {
        RapierRestart {
            shapes: ShapeKind::MOVI_B.to_vec(),
            floor: MOVI_FLOOR,
            gravity,
            physics_hz: 240,
            substeps_per_frame: 10,
            solver_iterations: 4,
            cloud_points: None,
        }
    }

    /// The conditions a dataset was recorded with: its shape list (by name), floor (its
    /// generator's `floor`, else the MOVi floor), gravity and physics timing. Errors name a
    /// shape this simulator cannot build.
    pub fn from_manifest(m: &Manifest) -> Result<RapierRestart, EvalError> {
        let shapes = m
            .shapes
            .iter()
            .map(|s| {
                ShapeKind::MOVI_B
                    .into_iter()
                    .find(|k| k.name() == s.name)
                    .ok_or_else(|| {
                        EvalError::Invalid(format!(
                            "rapier restart: the dataset's shape {:?} is not one it can build",
                            s.name
                        ))
                    })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let floor = m
            .generator_parameters
            .get("floor")
            .and_then(|f| FloorSpec::deserialize(f).ok())
            .unwrap_or(MOVI_FLOOR);
        Ok(RapierRestart {
            shapes,
            floor,
            gravity: m.gravity,
            physics_hz: m.physics_hz,
            substeps_per_frame: m.substeps_per_frame,
            solver_iterations: m.solver_iterations,
            cloud_points: None,
        })
    }

    /// This restart with every object rebuilt from the first `n` points of its reference cloud
    /// ([`RapierRestart::cloud_points`]), or from its exact shape with `None`.
    pub fn with_cloud_points(self, cloud_points: Option<usize>) -> RapierRestart {
        RapierRestart {
            cloud_points,
            ..self
        }
    }

    /// The rapier object for `scene.objects[j]` at `pose` with velocities `(linear m/s,
    /// angular rad/s)`.
    fn object(
        &self,
        scene: &SceneRecord,
        j: usize,
        pose: &Pose,
        velocity: ([f32; 3], [f32; 3]),
    ) -> Result<ObjectSpec, EvalError> {
        let o = &scene.objects[j];
        let bad = |m: String| EvalError::Invalid(format!("rapier restart: object {j}: {m}"));
        if o.material != 0 {
            return Err(bad("only rigid objects can be simulated".into()));
        }
        let kind = usize::try_from(o.shape_id)
            .ok()
            .and_then(|i| self.shapes.get(i).copied())
            .ok_or_else(|| bad(format!("shape_id {} is not in the shape list", o.shape_id)))?;
        let [sx, sy, sz] = o.scale;
        if (sx - sy).abs() > 1e-5 * sx.abs() || (sx - sz).abs() > 1e-5 * sx.abs() {
            return Err(bad(format!("scale {:?} is not uniform", o.scale)));
        }
        // A hull shape is a different solid per object, spanned by its whole reference cloud;
        // with `cloud_points` every shape is the hull of what a model given that many sees.
        let hull_points = self
            .cloud_points
            .or((kind == ShapeKind::Hull).then_some(usize::MAX));
        let (shape, scale) = if let Some(n) = hull_points {
            // Reference points are already scaled.
            let cloud = &o.reference_points[..n.clamp(1, o.reference_points.len().max(1))];
            let parts = vec![Part::Polytope(Polytope::hull(cloud)?)];
            (Shape { kind, parts }, 1.0)
        } else {
            // Only the hull draws from the generator; the others are fixed.
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
            (Shape::unit(kind, &mut rng)?, sx)
        };
        let rigid =
            ObjectSpec::rigid_of_mass(shape, o.shape_id, scale, o.mass, o.friction, o.restitution)
                .map_err(|e| bad(e.to_string()))?;
        Ok(ObjectSpec {
            position: pose.translation,
            rotation: pose.rotation,
            linvel: velocity.0,
            angvel: velocity.1,
            ..rigid
        })
    }
}

/// The velocity of object `j` at the end of the `n` integration substeps of `h` seconds
/// ([`SimConfig::dt_substep`]) that took it from `before` to `now`, under gravity `g`, as
/// rapier's symplectic Euler integrates free flight: (linear m/s, angular rad/s in the world
/// frame). At a contact this is the step's average motion, which is all two frames tell.
fn velocity_from_frames(
    j: usize,
    (before, now): (&Pose, &Pose),
    n: u32,
    h: f32,
    g: [f32; 3],
) -> Result<([f32; 3], [f32; 3]), EvalError> {
    let dt = (n as f64) * h as f64;
    let turn = unit(now.rotation, "current", j)? * unit(before.rotation, "previous", j)?.inverse();
    let w: Vector3<f64> = turn.scaled_axis() / dt;
    // x_n - x_0 = h sum_i v_i with v_i = v_0 + i g h, so v_n = dx / dt + g h (n - 1) / 2.
    let lift = h as f64 * (n as f64 - 1.0) / 2.0;
    let v = std::array::from_fn(|d| {
        ((now.translation[d] - before.translation[d]) as f64 / dt + g[d] as f64 * lift) as f32
    });
    Ok((v, [w.x as f32, w.y as f32, w.z as f32]))
}

/// The path of a kinematic object moving on at the velocity `(linear, angular)` from `pose`:
/// its poses at the next `frames` frames of `dt` seconds.
fn constant_motion(
    object: usize,
    pose: &Pose,
    (v, w): ([f32; 3], [f32; 3]),
    dt: f64,
    frames: usize,
) -> Result<KinematicPath, EvalError> {
    let q = unit(pose.rotation, "current", object)?;
    let spin = Vector3::new(w[0] as f64, w[1] as f64, w[2] as f64);
    let poses = (1..=frames)
        .map(|i| {
            let t = i as f64 * dt;
            let r = UnitQuaternion::from_scaled_axis(spin * t) * q;
            let p = std::array::from_fn(|d| (pose.translation[d] as f64 + v[d] as f64 * t) as f32);
            (p, [r.i as f32, r.j as f32, r.k as f32, r.w as f32])
        })
        .collect();
    Ok(KinematicPath { object, poses })
}

impl Predictor for RapierRestart {
    fn name(&self) -> String {
        match self.cloud_points {
            Some(n) => format!("rapier-hull-{n}"),
            None => "rapier-restart".into(),
        }
    }

    fn rollout(
        &self,
        scene: &SceneRecord,
        observed: &SceneState,
        dt_steps: u32,
        steps: usize,
    ) -> Result<Vec<Vec<Pose>>, EvalError> {
        check_state(scene, observed)?;
        let m = scene.objects.len();
        if steps == 0 {
            return Ok(Vec::new());
        }
        let k = dt_steps.max(1) as usize;
        let cfg = SimConfig {
            physics_hz: self.physics_hz,
            substeps: self.substeps_per_frame,
            frames: steps * k + 1,
            solver_iterations: self.solver_iterations,
        };
        let (h, n) = (cfg.dt_substep(), cfg.integration_substeps() * k as u32);
        let frame_s = cfg.dt_frame() as f64;
        let mut objects = Vec::with_capacity(m);
        let mut kinematic = Vec::new();
        for j in 0..m {
            let (before, now) = (&observed.previous[j], &observed.current[j]);
            if scene.objects[j].kinematic {
                // A pusher's path ahead is not observed: it moves on as it moved over the step.
                let v = velocity_from_frames(j, (before, now), n, h, [0.0; 3])?;
                kinematic.push(constant_motion(j, now, v, frame_s, cfg.frames - 1)?);
                objects.push(self.object(scene, j, now, ([0.0; 3], [0.0; 3]))?);
            } else {
                let v = velocity_from_frames(j, (before, now), n, h, self.gravity)?;
                objects.push(self.object(scene, j, now, v)?);
            }
        }
        let spec = SceneSpec {
            objects,
            floor: self.floor,
            gravity: self.gravity,
            settle_steps: 0,
            kinematic,
        };
        let traj = simulate(&spec, &cfg)?;
        Ok((1..=steps)
            .map(|i| {
                (0..m)
                    .map(|j| Pose {
                        translation: traj.positions[j][i * k],
                        rotation: traj.rotations[j][i * k],
                    })
                    .collect()
            })
            .collect())
    }
}
