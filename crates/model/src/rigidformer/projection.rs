//! From anchor accelerations to rigid poses at inference: Verlet at the anchors
//! (`A_{t+k} = base + b + a`, metres, the base `2 A_t - A_{t-k}` or the rigid constant-velocity
//! extrapolation, `DynamicsConfig::rigid_extrapolation`), then the Kabsch fit per object (f64)
//! and, with `ModelConfig::floor_projection`, the floor's non-penetration constraint.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

use super::batch::BatchInputs;
use crate::api::Pose;
use crate::{ModelConfig, ModelError, team};

/// Objects from which the Kabsch fits run over rayon's pool (one is a few microseconds).
const PARALLEL_OBJECTS: usize = 64;

/// Displacement of free fall over one step of `dt_steps` frames that the Verlet base adds
/// (`g (k dt_frame)^2`, metres), zero unless `dynamics.gravity_residual`.
pub(crate) fn free_fall(c: &ModelConfig, dt_steps: u32) -> [f64; 3] {
    if !c.dynamics.gravity_residual {
        return [0.0; 3];
    }
    let h = dt_steps as f64 * c.dt_frame as f64;
    c.gravity.map(|g| g as f64 * h * h)
}

/// What the Verlet base adds to every anchor of object `obj` of a pass after the
/// constant-velocity extrapolation, metres: the [`free_fall`] of its step size and the
/// object's floor lift (`dynamics.floor_base`, zero otherwise).
pub(crate) fn base_shift(c: &ModelConfig, inp: &BatchInputs, obj: usize) -> [f64; 3] {
    let mut shift = free_fall(c, inp.object_dt[obj]);
    shift[2] += inp.floor_lift.get(obj).copied().unwrap_or(0.0);
    shift
}

/// New poses of every object of a pass, `[scenes][objects]`, from accelerations
/// `acc` (`[O * K * 3]`, metres per step^2), objects in parallel when there are many.
pub(crate) fn project_poses(
    c: &ModelConfig,
    inp: &BatchInputs,
    acc: &[f32],
) -> Result<Vec<Vec<Pose>>, ModelError> {
    let k = c.anchors;
    let poses: Result<Vec<Pose>, ModelError> = team::map_indices(inp.o, PARALLEL_OBJECTS, |obj| {
        let fall = base_shift(c, inp, obj);
        // An object in free flight moves on the base alone (`dynamics.free_flight_gate`).
        let free = inp.free_flight.get(obj).copied().unwrap_or(false);
        let target: Vec<[f64; 3]> = (0..k)
            .map(|i| {
                let base = inp.anchors_base[obj][i];
                let a = &acc[(obj * k + i) * 3..(obj * k + i + 1) * 3];
                [0, 1, 2].map(|d| base[d] + fall[d] + if free { 0.0 } else { a[d] as f64 })
            })
            .collect();
        let sol = dynaserve_geometry::kabsch(&inp.anchors_ref[obj], &target, None)
            .map_err(|e| ModelError::Internal(format!("kabsch failed: {e}")))?;
        let mut translation = sol.translation;
        if let (Some(Some(cloud)), Some(ground), Some(depth)) =
            (inp.floor_clouds.get(obj), c.ground_z, c.floor_projection)
        {
            let floor = f64::from(ground) - f64::from(depth);
            translation.z += floor_rise(cloud, &sol.rotation, translation.z, floor);
        }
        Ok(pose_from(&sol.rotation, &translation, inp.current_rot[obj]))
    })
    .into_iter()
    .collect();
    let poses = poses?;
    Ok((0..inp.b)
        .map(|s| poses[inp.scene_offsets[s]..inp.scene_offsets[s + 1]].to_vec())
        .collect())
}

/// The lowest height (metres) of body-frame points `cloud` (metres) turned by `r`, relative
/// to the body origin; infinite for an empty cloud.
pub(crate) fn lowest_offset(cloud: &[[f32; 3]], r: &Matrix3<f64>) -> f64 {
    let row = r.row(2);
    cloud
        .iter()
        .map(|x| row[0] * f64::from(x[0]) + row[1] * f64::from(x[1]) + row[2] * f64::from(x[2]))
        .fold(f64::INFINITY, f64::min)
}

/// How far (metres, >= 0) an object with body-frame points `cloud` (metres), rotation `r`
/// and centre height `z` (metres) must rise so that none of its points is below `ground`
/// (metres): the floor projection ([`ModelConfig::floor_projection`]) and the floor base.
pub(crate) fn floor_rise(cloud: &[[f32; 3]], r: &Matrix3<f64>, z: f64, ground: f64) -> f64 {
    let lowest = lowest_offset(cloud, r);
    if lowest.is_finite() {
        (ground - z - lowest).max(0.0)
    } else {
        0.0
    }
}

/// Rotation matrix and translation (metres) of a pose, in f64.
pub(crate) fn pose_f64(p: &Pose) -> (Matrix3<f64>, Vector3<f64>) {
    let [x, y, z, w] = p.rotation.map(|v| v as f64);
    let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
    let t = p.translation.map(|v| v as f64);
    (
        q.to_rotation_matrix().into_inner(),
        Vector3::new(t[0], t[1], t[2]),
    )
}

/// Pose from a rotation matrix and translation, with the quaternion sign nearest `near`.
fn pose_from(r: &Matrix3<f64>, p: &Vector3<f64>, near: [f32; 4]) -> Pose {
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*r));
    let c = q.coords;
    let mut rotation = [c.x as f32, c.y as f32, c.z as f32, c.w as f32];
    let dot: f32 = rotation.iter().zip(near).map(|(a, b)| a * b).sum();
    if dot < 0.0 {
        rotation = rotation.map(|v| -v);
    }
    Pose {
        translation: [p.x as f32, p.y as f32, p.z as f32],
        rotation,
    }
}
