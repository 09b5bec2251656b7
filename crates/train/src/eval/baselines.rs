//! Naive baselines every learned model must beat.
//!
//! - [`Static`]: every object stays at its last observed pose.
//! - [`Ballistic`]: constant angular velocity and free flight under gravity from the two
//!   observed frames, with an inelastic, frictionless floor.

use dynaserve_geometry::quat;
use dynaserve_model::{Pose, SceneState};
use dynaserve_sim::{Manifest, SceneRecord};
use nalgebra::{UnitQuaternion, Vector3};

use super::{EvalError, Predictor};

/// Every object stays at its last observed pose (`observed.current`) for the whole rollout.
#[derive(Clone, Copy, Debug, Default)]
pub struct Static;

impl Predictor for Static {
    fn name(&self) -> String {
        "static".into()
    }

    fn rollout(
        &self,
        scene: &SceneRecord,
        observed: &SceneState,
        _dt_steps: u32,
        steps: usize,
    ) -> Result<Vec<Vec<Pose>>, EvalError> {
        check_state(scene, observed)?;
        Ok(vec![observed.current.clone(); steps])
    }
}

/// Ballistic extrapolation from the two observed poses, `dt = dt_steps * dt_frame` apart.
///
/// Per object, in `f64`:
/// - translation by position Verlet under gravity `g`:
///   `p_{n+1} = 2 p_n - p_{n-1} + g dt^2`, which is exact for free flight (a parabola through
///   the two observed centres of mass);
/// - orientation with the constant world-frame rotation increment of the observed pair,
///   `q_{n+1} = (q_s q_{s-k}^-1) q_n` (constant angular velocity; torque-free precession is
///   ignored);
/// - with a floor at `floor_z`, the centre of mass is raised after each step just enough that
///   the lowest point of the object's reference cloud, rotated to the new orientation, is not
///   below the floor, and the vertical velocity carried into the next step is then zero: an
///   object that lands stays down (a perfectly inelastic floor; a slightly sunken observed pose
///   is lifted without being launched) but keeps sliding horizontally (no friction).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ballistic {
    /// Gravity, m/s^2 (MOVi-like data: `(0, 0, -10)`, read from the manifest).
    pub gravity: [f32; 3],
    /// Height of the floor's top in metres (`Some(0.0)` in all generated data), or `None`.
    pub floor_z: Option<f32>,
}

impl Ballistic {
    /// The baseline for a dataset: its recorded gravity, the floor at z = 0.
    pub fn from_manifest(manifest: &Manifest) -> Ballistic {
        Ballistic {
            gravity: manifest.gravity,
            floor_z: Some(0.0),
        }
    }
}

/// Refuses an observed state whose pose counts are not the scene's object count.
pub(super) fn check_state(scene: &SceneRecord, observed: &SceneState) -> Result<(), EvalError> {
    let n = scene.objects.len();
    if observed.previous.len() != n || observed.current.len() != n {
        return Err(EvalError::Invalid(format!(
            "observed state has {} and {} poses for a scene of {n} objects",
            observed.previous.len(),
            observed.current.len()
        )));
    }
    Ok(())
}

/// Object `j`'s `what` rotation as a unit quaternion, or an error naming it.
pub(super) fn unit(q: [f32; 4], what: &str, j: usize) -> Result<UnitQuaternion<f64>, EvalError> {
    quat::to_unit_quaternion(quat::to_f64(q))
        .map_err(|e| EvalError::Invalid(format!("object {j} {what} rotation: {e}")))
}

fn vec3(p: [f32; 3]) -> Vector3<f64> {
    Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

impl Predictor for Ballistic {
    fn name(&self) -> String {
        "ballistic".into()
    }

    fn rollout(
        &self,
        scene: &SceneRecord,
        observed: &SceneState,
        dt_steps: u32,
        steps: usize,
    ) -> Result<Vec<Vec<Pose>>, EvalError> {
        check_state(scene, observed)?;
        let dt = f64::from(dt_steps) * f64::from(scene.dt_frame);
        let g_dt2 = vec3(self.gravity) * dt * dt;
        let n = scene.objects.len();
        let mut out = vec![Vec::with_capacity(n); steps];
        for (j, object) in scene.objects.iter().enumerate() {
            let mut p_prev = vec3(observed.previous[j].translation);
            let mut p = vec3(observed.current[j].translation);
            let q_prev = unit(observed.previous[j].rotation, "previous", j)?;
            let mut q = unit(observed.current[j].rotation, "current", j)?;
            let delta = q * q_prev.inverse();
            let reference: Vec<Vector3<f64>> =
                object.reference_points.iter().map(|x| vec3(*x)).collect();
            for poses in out.iter_mut() {
                let mut p_next = 2.0 * p - p_prev + g_dt2;
                let q_next = delta * q;
                let mut landed = false;
                if let Some(floor) = self.floor_z {
                    let lowest = reference
                        .iter()
                        .map(|x| (q_next * x).z)
                        .fold(f64::INFINITY, f64::min);
                    let support = f64::from(floor) - lowest;
                    if lowest.is_finite() && p_next.z < support {
                        p_next.z = support;
                        landed = true;
                    }
                }
                p_prev = p;
                if landed {
                    // Inelastic contact: no vertical velocity carried into the next step.
                    p_prev.z = p_next.z;
                }
                p = p_next;
                q = q_next;
                let c = q.coords;
                poses.push(Pose {
                    translation: [p.x as f32, p.y as f32, p.z as f32],
                    rotation: [c.x as f32, c.y as f32, c.z as f32, c.w as f32],
                });
            }
        }
        Ok(out)
    }
}
