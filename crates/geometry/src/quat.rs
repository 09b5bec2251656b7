//! Quaternion helpers between `[x, y, z, w]` arrays (scalar last, the project's storage order,
//! the same as nalgebra's `coords`) and nalgebra's `UnitQuaternion`, for `f32` and `f64`.
//!
//! A quaternion `q` stored as an array maps body to world coordinates: `x_world = R(q) x_body`.
//! `q` and `-q` are the same rotation.

use nalgebra::{Matrix3, Quaternion, RealField, Rotation3, UnitQuaternion, Vector3};

use crate::GeometryError;

/// The identity rotation as `[x, y, z, w]`.
pub const IDENTITY: [f32; 4] = [0.0, 0.0, 0.0, 1.0];

/// Normalises `[x, y, z, w]` to unit length.
///
/// Errors: a non-finite component ([`GeometryError::NonFinite`]) or zero norm
/// ([`GeometryError::Invalid`]).
pub fn normalize<T: RealField + Copy>(q: [T; 4]) -> Result<[T; 4], GeometryError> {
    if !q.iter().all(|v| v.is_finite()) {
        return Err(GeometryError::NonFinite("quaternion"));
    }
    let norm = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if norm <= T::zero() || !norm.is_finite() {
        return Err(GeometryError::Invalid(
            "quaternion has zero (or unrepresentable) norm and is no rotation".into(),
        ));
    }
    Ok([q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm])
}

/// `[x, y, z, w]` (any non-zero length) to a unit quaternion, normalising first.
///
/// Errors as [`normalize`].
pub fn to_unit_quaternion<T: RealField + Copy>(
    q: [T; 4],
) -> Result<UnitQuaternion<T>, GeometryError> {
    let [x, y, z, w] = normalize(q)?;
    Ok(UnitQuaternion::new_unchecked(Quaternion::new(w, x, y, z)))
}

/// A unit quaternion to `[x, y, z, w]`.
pub fn to_array<T: RealField + Copy>(q: &UnitQuaternion<T>) -> [T; 4] {
    let c = q.coords;
    [c.x, c.y, c.z, c.w]
}

/// Converts `[x, y, z, w]` from `f32` to `f64` (no renormalisation).
pub fn to_f64(q: [f32; 4]) -> [f64; 4] {
    q.map(f64::from)
}

/// Converts `[x, y, z, w]` from `f64` to `f32` and renormalises in `f32`.
///
/// Errors as [`normalize`].
pub fn to_f32(q: [f64; 4]) -> Result<[f32; 4], GeometryError> {
    normalize(normalize(q)?.map(|v| v as f32))
}

/// The sign of `q` (`q` and `-q` are the same rotation) chosen so that `w >= 0`; for `w = 0`
/// the first non-zero of `z`, `y`, `x` is made positive. Useful for deterministic output.
pub fn canonical_sign<T: RealField + Copy>(q: [T; 4]) -> [T; 4] {
    let zero = T::zero();
    let lead = [q[3], q[2], q[1], q[0]]
        .into_iter()
        .find(|v| *v != zero)
        .unwrap_or(zero);
    if lead < zero { q.map(|v| -v) } else { q }
}

/// Rotation matrix `[3, 3]` of `[x, y, z, w]` (normalised first).
///
/// Errors as [`normalize`].
pub fn to_rotation_matrix<T: RealField + Copy>(q: [T; 4]) -> Result<Matrix3<T>, GeometryError> {
    Ok(to_unit_quaternion(q)?.to_rotation_matrix().into_inner())
}

/// `[x, y, z, w]` with `w >= 0` (see [`canonical_sign`]) of a rotation matrix.
///
/// The matrix must be a proper rotation up to rounding (orthonormal, det +1), such as a
/// [`kabsch()`](crate::kabsch()) result; it is not re-orthonormalised. Errors: a non-finite entry.
pub fn from_rotation_matrix<T: RealField + Copy>(m: &Matrix3<T>) -> Result<[T; 4], GeometryError> {
    if !m.iter().all(|v| v.is_finite()) {
        return Err(GeometryError::NonFinite("rotation matrix"));
    }
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*m));
    Ok(canonical_sign(to_array(&q)))
}

/// Rotates a point (or vector) by `[x, y, z, w]`: `R(q) p`. Errors as [`normalize`].
pub fn rotate<T: RealField + Copy>(q: [T; 4], p: [T; 3]) -> Result<[T; 3], GeometryError> {
    let v = to_unit_quaternion(q)? * Vector3::from(p);
    Ok([v.x, v.y, v.z])
}

/// Anything [`geodesic_angle`] accepts: `[x, y, z, w]` arrays and unit quaternions in `f32`
/// or `f64`.
pub trait QuatLike {
    /// The components as `[x, y, z, w]` in `f64` (not normalised).
    fn xyzw_f64(&self) -> [f64; 4];
}

impl QuatLike for [f32; 4] {
    fn xyzw_f64(&self) -> [f64; 4] {
        to_f64(*self)
    }
}

impl QuatLike for [f64; 4] {
    fn xyzw_f64(&self) -> [f64; 4] {
        *self
    }
}

impl QuatLike for UnitQuaternion<f32> {
    fn xyzw_f64(&self) -> [f64; 4] {
        to_f64(to_array(self))
    }
}

impl QuatLike for UnitQuaternion<f64> {
    fn xyzw_f64(&self) -> [f64; 4] {
        to_array(self)
    }
}

impl<Q: QuatLike> QuatLike for &Q {
    fn xyzw_f64(&self) -> [f64; 4] {
        (*self).xyzw_f64()
    }
}

/// Geodesic angle between two rotations, radians in `[0, pi]`:
/// `theta = 2 acos(min(1, |<a, b>|))` for unit `a`, `b` (inputs are normalised in `f64`
/// first).
///
/// Evaluated as `4 atan2(|a - s b|, |a + s b|)` with `s = sign(<a, b>)`, which equals the acos
/// form but keeps full precision for small angles (where `acos` near 1 loses about half the
/// digits). Sign-invariant: `geodesic_angle(q, -q) = 0`. Returns NaN when either input is not
/// a valid rotation (zero norm or non-finite); validate with [`normalize`] when that matters.
pub fn geodesic_angle(a: impl QuatLike, b: impl QuatLike) -> f64 {
    let (Ok(a), Ok(b)) = (normalize(a.xyzw_f64()), normalize(b.xyzw_f64())) else {
        return f64::NAN;
    };
    let dot: f64 = (0..4).map(|k| a[k] * b[k]).sum();
    let s = if dot < 0.0 { -1.0 } else { 1.0 };
    let diff = (0..4)
        .map(|k| (a[k] - s * b[k]).powi(2))
        .sum::<f64>()
        .sqrt();
    let sum = (0..4)
        .map(|k| (a[k] + s * b[k]).powi(2))
        .sum::<f64>()
        .sqrt();
    (4.0 * diff.atan2(sum)).clamp(0.0, std::f64::consts::PI)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Unit;
    use std::f64::consts::PI;

    #[test]
    fn array_round_trip_and_order() {
        // 90 degrees about z: [0, 0, sin 45, cos 45].
        let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
        let a = to_array(&q);
        assert!((a[2] - 0.5f64.sqrt()).abs() < 1e-12 && (a[3] - 0.5f64.sqrt()).abs() < 1e-12);
        let back = to_unit_quaternion(a).unwrap();
        assert!(back.angle_to(&q) < 1e-12);
        let r = rotate(a, [1.0, 0.0, 0.0]).unwrap();
        assert!((r[0]).abs() < 1e-12 && (r[1] - 1.0).abs() < 1e-12);
        let f = to_f32(a).unwrap();
        assert!((f[3] - 0.70710677).abs() < 1e-7);
    }

    #[test]
    fn normalisation_and_errors() {
        assert_eq!(
            normalize([0.0f32, 0.0, 0.0, 2.0]).unwrap(),
            [0.0, 0.0, 0.0, 1.0]
        );
        let n = normalize([1.0f64, 1.0, 1.0, 1.0]).unwrap();
        assert!(n.iter().all(|v| (v - 0.5).abs() < 1e-15));
        assert!(matches!(
            normalize([0.0f32; 4]),
            Err(GeometryError::Invalid(_))
        ));
        assert!(matches!(
            to_unit_quaternion([f32::NAN, 0.0, 0.0, 1.0]),
            Err(GeometryError::NonFinite(_))
        ));
        assert!(normalize([f64::INFINITY, 0.0, 0.0, 1.0]).is_err());
        assert!(geodesic_angle([0.0f32; 4], IDENTITY).is_nan());
    }

    #[test]
    fn rotation_matrix_round_trip() {
        let axis = Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8));
        for angle in [0.0, 0.4, 2.0, 3.1, PI] {
            let q = UnitQuaternion::from_axis_angle(&axis, angle);
            let m = to_rotation_matrix(to_array(&q)).unwrap();
            assert!((m - q.to_rotation_matrix().into_inner()).abs().max() < 1e-12);
            let back = from_rotation_matrix(&m).unwrap();
            assert!(back[3] >= 0.0);
            assert!(geodesic_angle(back, q) < 1e-7, "angle {angle}");
        }
        assert!(from_rotation_matrix(&Matrix3::from_element(f64::NAN)).is_err());
    }

    #[test]
    fn geodesic_angle_known_values() {
        let z = Vector3::z_axis();
        let a = UnitQuaternion::from_axis_angle(&z, 0.3);
        let b = UnitQuaternion::from_axis_angle(&z, 1.0);
        assert!((geodesic_angle(a, b) - 0.7).abs() < 1e-12);
        // Sign invariance and the pi end.
        let q = to_array(&a);
        assert!(geodesic_angle(q, q.map(|v| -v)) < 1e-12);
        let half_turn = UnitQuaternion::from_axis_angle(&z, PI);
        assert!((geodesic_angle(UnitQuaternion::<f64>::identity(), half_turn) - PI).abs() < 1e-12);
        // Beyond pi the shorter way round is measured: 1.5 pi apart is 0.5 pi.
        let c = UnitQuaternion::from_axis_angle(&z, 1.5 * PI);
        assert!((geodesic_angle(UnitQuaternion::<f64>::identity(), c) - 0.5 * PI).abs() < 1e-12);
        // Small angles keep their precision.
        let tiny = UnitQuaternion::from_axis_angle(&z, 1e-9);
        let got = geodesic_angle(UnitQuaternion::<f64>::identity(), tiny);
        assert!((got - 1e-9).abs() < 1e-18, "{got}");
        // Matches 2 acos |<a, b>| where that is well conditioned; f32 arrays work too.
        let qa = [0.1f32, -0.2, 0.3, 0.9];
        let qb = [0.4f32, 0.1, -0.2, 0.8];
        let na = normalize(to_f64(qa)).unwrap();
        let nb = normalize(to_f64(qb)).unwrap();
        let dot: f64 = (0..4).map(|k| na[k] * nb[k]).sum();
        assert!((geodesic_angle(qa, qb) - 2.0 * dot.abs().min(1.0).acos()).abs() < 1e-12);
    }

    #[test]
    fn canonical_sign_prefers_positive_w() {
        assert_eq!(
            canonical_sign([0.0, 0.0, 0.6, -0.8]),
            [-0.0, -0.0, -0.6, 0.8]
        );
        assert_eq!(
            canonical_sign([0.0, -1.0, 0.0, 0.0]),
            [-0.0, 1.0, -0.0, -0.0]
        );
        assert_eq!(
            canonical_sign([0.5f32, 0.5, 0.5, 0.5]),
            [0.5, 0.5, 0.5, 0.5]
        );
    }
}
