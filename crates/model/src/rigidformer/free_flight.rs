//! Which objects of a step are certainly in free flight (`dynamics.free_flight_gate`): out of
//! reach of the floor and of every other object for the whole step, so that their exact
//! motion is the rigid Verlet base (constant velocity plus free fall; rapier's bodies have no
//! air drag) and the network's output for them can be left out.
//!
//! Each object is bounded by a sphere about its centre of mass (the pose's origin) holding its
//! reference cloud in any attitude, grown by [`MARGIN_M`] and a tenth of the radius for the
//! surface between sampled points. Between two free bodies gravity cancels, so their
//! separation moves on a straight line over the step; the other body may also be deflected by
//! a contact of its own within the step, taken as at most twice the scene's largest step
//! displacement, or held up against gravity (a body resting on another does not fall), which
//! adds the step's free fall. The floor is cleared when the cloud's lowest point at t, lowered
//! by the centre's drop over the step (a free centre's height is a parabola opening downwards,
//! lowest at an end), by the most the rotation over the step can move a point (the angle times
//! the radius: a chord is shorter than its arc) and by [`MARGIN_M`] plus a tenth of the radius,
//! stays above it. A flat object flying low clears it where its bounding sphere would not.

use nalgebra::Vector3;

use super::batch::SceneRequest;
use super::projection::free_fall;
use super::projection::lowest_offset;
use crate::ModelConfig;
use crate::api::Pose;

/// Clearance added to every bounding sphere, metres: contact skins and the surface between a
/// cloud's points.
pub(crate) const MARGIN_M: f64 = 0.02;

/// Per object of `r`'s scene, true when it can touch nothing during the step (module docs;
/// without a ground, `ground_z` unset, only other objects are checked). All false when the
/// scene has a kinematic object, or when the Verlet base is not a rigid body's ballistic
/// motion (`dynamics.gravity_residual` and `dynamics.rigid_extrapolation` both needed).
pub(crate) fn free_flight(cfg: &ModelConfig, r: &SceneRequest<'_>) -> Vec<bool> {
    let objects = &r.scene.objects;
    let m = objects.len();
    let exact_base = cfg.dynamics.gravity_residual && cfg.dynamics.rigid_extrapolation;
    if !exact_base || objects.iter().any(|o| o.kinematic) {
        return vec![false; m];
    }
    let fall = Vector3::from(free_fall(cfg, r.dt_steps));
    let centre = |p: &Pose| Vector3::from(p.translation).cast::<f64>();
    let now: Vec<Vector3<f64>> = r.current.iter().map(centre).collect();
    let step: Vec<Vector3<f64>> = r
        .previous
        .iter()
        .zip(&now)
        .map(|(prev, c)| c - centre(prev))
        .collect();
    let reach: Vec<f64> = objects
        .iter()
        .map(|o| 1.1 * o.radius as f64 + MARGIN_M)
        .collect();
    // Largest distance any object's centre travels in a step at its current velocity: a
    // contact within the step moves a body off its ballistic path by at most about twice that.
    // A supported body does not fall with the others: the step's free fall on top.
    let deflect = 2.0 * step.iter().map(|s| s.norm()).fold(0.0, f64::max) + fall.norm();
    (0..m)
        .map(|i| {
            let clears_floor = cfg
                .ground_z
                .is_none_or(|g| lowest_over_step(r, i, step[i].z + fall.z) > g as f64);
            clears_floor
                && (0..m).filter(|&j| j != i).all(|j| {
                    let gap = closest_on_segment(now[i] - now[j], step[i] - step[j]);
                    gap > reach[i] + reach[j] + deflect
                })
        })
        .collect()
}

/// A lower bound on the height of object `i`'s surface over the step, metres: its cloud's
/// lowest point at t, plus `drop` (the centre's height change over the step) when negative,
/// less the rotation's largest chord and the margin for the surface between points.
fn lowest_over_step(r: &SceneRequest<'_>, i: usize, drop: f64) -> f64 {
    let o = &r.scene.objects[i];
    let (now, before) = (&r.current[i], &r.previous[i]);
    let rot = now.unit_quaternion().cast::<f64>().to_rotation_matrix();
    let lowest = lowest_offset(&o.reference, rot.matrix()) + f64::from(now.translation[2]);
    let angle = f64::from(now.unit_quaternion().angle_to(&before.unit_quaternion()));
    let radius = f64::from(o.radius);
    lowest + drop.min(0.0) - angle.min(2.0) * radius - (0.1 * radius + MARGIN_M)
}

/// Smallest norm of `d + s v` for `s` in `[0, 1]`, metres.
fn closest_on_segment(d: Vector3<f64>, v: Vector3<f64>) -> f64 {
    let vv = v.norm_squared();
    let s = if vv > 0.0 {
        (-d.dot(&v) / vv).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (d + v * s).norm()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_approach_of_a_separation_over_the_step() {
        let d = Vector3::new(-1.0, 0.5, 0.0);
        // Passing by: the closest point is mid-step, 0.5 m away.
        assert!((closest_on_segment(d, Vector3::new(2.0, 0.0, 0.0)) - 0.5).abs() < 1e-12);
        // Moving apart: closest at the start.
        assert!((closest_on_segment(d, Vector3::new(-1.0, 0.0, 0.0)) - d.norm()).abs() < 1e-12);
        // Still: the start.
        assert!((closest_on_segment(d, Vector3::zeros()) - d.norm()).abs() < 1e-12);
    }
}
