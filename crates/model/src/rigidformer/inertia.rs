//! A point cloud's inertia per unit mass, floored and inverted: how a torque on an object
//! turns it ([`super::wrench`]), computed once per scene when it is prepared.

use nalgebra::{Matrix3, Vector3};

/// Share of the mean principal moment added to every principal moment of a cloud's inertia
/// before inverting it, so that a cloud with a vanishing moment (a thin rod about its axis)
/// does not turn an arbitrary torque into an unbounded angular acceleration.
pub(crate) const INERTIA_FLOOR: f32 = 0.05;

/// The inverse of a cloud's inertia per unit mass about `centroid` (`points` `[n, 3]` and
/// `centroid` in metres, any one frame; 1/m^2 out): `J = mean_i(|r_i|^2 E - r_i r_i^T)` plus
/// [`INERTIA_FLOOR`] of its mean principal moment. Zero for a cloud whose inertia is zero (one
/// point). Rigid-invariant: a rotated cloud's is `R J^-1 R^T`, so a scene computes it once.
pub(crate) fn floored_inertia_inverse(points: &[[f32; 3]], centroid: [f32; 3]) -> Matrix3<f32> {
    let c = Vector3::from(centroid);
    let mut inertia = Matrix3::zeros();
    for p in points {
        let r = Vector3::from(*p) - c;
        inertia += Matrix3::identity() * r.norm_squared() - r * r.transpose();
    }
    inertia /= points.len().max(1) as f32;
    let floor = INERTIA_FLOOR * inertia.trace() / 3.0;
    (inertia + Matrix3::identity() * floor)
        .try_inverse()
        .filter(|_| floor > 0.0)
        .unwrap_or_else(Matrix3::zeros)
}
