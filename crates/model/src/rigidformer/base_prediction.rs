//! The constant-velocity base prediction the network corrects: where an anchor goes if its
//! object keeps its motion for one more step, and how far the floor lifts the object there.

use nalgebra::{Matrix3, Vector3};

use super::projection::floor_rise;

/// The constant-velocity prediction of one anchor at body-frame position `x` (metres) of an
/// object at pose `(r, p)` now and `(r_prev, p_prev)` one step before, metres (world frame).
/// With `rigid` the object keeps its linear and angular velocity (`R_{t+k} = (R_t R_{t-k}^T)
/// R_t`, centre `2 p_t - p_{t-k}`), exact for a spinning body in free flight; otherwise the
/// anchor's own linear extrapolation `2 A_t - A_{t-k}`, which for a spinning body lags the
/// rotation (by about `5/6 theta^3` for `theta` radians per step) and leaves that to the network.
pub(crate) fn verlet_base(
    rigid: bool,
    x: &Vector3<f64>,
    (r, p): (&Matrix3<f64>, &Vector3<f64>),
    (r_prev, p_prev): (&Matrix3<f64>, &Vector3<f64>),
) -> [f64; 3] {
    let y = if rigid {
        r * r_prev.transpose() * (r * x) + p * 2.0 - p_prev
    } else {
        (r * x + p) * 2.0 - (r_prev * x + p_prev)
    };
    [y.x, y.y, y.z]
}

/// How far an object must be raised (metres, >= 0) so that none of its `reference` points
/// (body frame, metres) is below z = 0 at its rigid constant-velocity pose one step ahead,
/// `R_t R_{t-k}^T R_t` and `2 p_t - p_{t-k}`, shifted down by `-drop_z` metres (the free fall
/// of the step minus the floor's height: `drop_z` is the free-fall z plus `-ground_z`).
pub(crate) fn floor_lift(
    reference: &[[f32; 3]],
    (r, p): (&Matrix3<f64>, &Vector3<f64>),
    (r_prev, p_prev): (&Matrix3<f64>, &Vector3<f64>),
    drop_z: f64,
) -> f64 {
    let rb = r * r_prev.transpose() * r;
    floor_rise(reference, &rb, 2.0 * p.z - p_prev.z + drop_z, 0.0)
}
