//! Trajectory metrics. Inputs are `f32` (the storage precision); every sum runs in `f64`.
//!
//! | metric | formula | unit |
//! |---|---|---|
//! | [`translation_rmse`] | `sqrt(mean_i |p_pred,i - p_true,i|^2)` over objects `i` | m |
//! | [`orientation_rmse_deg`] | `sqrt(mean_i theta_i^2)`, `theta_i = 2 acos |<q_pred,i, q_true,i>|` | degrees |
//! | [`rigidity_residual`] | `min_{R, p} mean_k |R x_ref,k + p - x_k|^2` (Kabsch) | m^2 |
//! | [`momentum_drift_ratio`] | `drift(pred) / max(drift(true), eps)` | 1 |
//!
//! Pooling several scenes or frames into one RMSE: feed every squared error into one
//! [`RmseAccumulator`] (RMSE over the pool), which is not the mean of per-scene RMSEs.

use crate::quat::geodesic_angle;
use crate::{GeometryError, Point, kabsch};

/// Sum of squared errors and their count; [`RmseAccumulator::rmse`] is
/// `sqrt(sum / count)`. Merge accumulators to pool errors across scenes.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RmseAccumulator {
    /// Sum of the squared errors (unit of the error, squared).
    pub sum_sq: f64,
    /// Number of errors added.
    pub count: u64,
}

impl RmseAccumulator {
    /// Adds one error (not squared).
    pub fn add(&mut self, error: f64) {
        self.sum_sq += error * error;
        self.count += 1;
    }

    /// Adds one squared error.
    pub fn add_squared(&mut self, squared: f64) {
        self.sum_sq += squared;
        self.count += 1;
    }

    /// Pools another accumulator into this one.
    pub fn merge(&mut self, other: &RmseAccumulator) {
        self.sum_sq += other.sum_sq;
        self.count += other.count;
    }

    /// `sqrt(sum_sq / count)`, or `None` when nothing was added.
    pub fn rmse(&self) -> Option<f64> {
        (self.count > 0).then(|| (self.sum_sq / self.count as f64).sqrt())
    }
}

fn check_pair(what: &'static str, a: usize, b: usize) -> Result<(), GeometryError> {
    if a == 0 {
        return Err(GeometryError::Empty(what));
    }
    if a != b {
        return Err(GeometryError::LengthMismatch {
            what,
            expected: a,
            got: b,
        });
    }
    Ok(())
}

/// Squared distance `|a - b|^2` in `f64` (m^2 for positions).
pub fn squared_distance(a: &Point, b: &Point) -> f64 {
    (0..3)
        .map(|d| (f64::from(a[d]) - f64::from(b[d])).powi(2))
        .sum()
}

/// Centre-of-mass translation RMSE in metres:
/// `sqrt( (1/N) sum_i |p_pred,i - p_true,i|^2 )` over `N` objects (`[N, 3]` each).
///
/// Errors: empty input, length mismatch.
pub fn translation_rmse(predicted: &[Point], truth: &[Point]) -> Result<f64, GeometryError> {
    check_pair("translation_rmse inputs", predicted.len(), truth.len())?;
    let mut acc = RmseAccumulator::default();
    for (a, b) in predicted.iter().zip(truth) {
        acc.add_squared(squared_distance(a, b));
    }
    Ok(acc.rmse().unwrap_or(0.0))
}

/// Orientation RMSE in degrees: `sqrt( (1/N) sum_i theta_i^2 ) * 180 / pi` with the geodesic
/// angle `theta_i = 2 acos |<q_pred,i, q_true,i>|` (radians, see
/// [`geodesic_angle`]); quaternions `[x, y, z, w]`, `[N, 4]`.
///
/// Errors: empty input, length mismatch, a quaternion that is no rotation (zero or
/// non-finite).
pub fn orientation_rmse_deg(
    predicted: &[[f32; 4]],
    truth: &[[f32; 4]],
) -> Result<f64, GeometryError> {
    check_pair("orientation_rmse_deg inputs", predicted.len(), truth.len())?;
    let mut acc = RmseAccumulator::default();
    for (a, b) in predicted.iter().zip(truth) {
        let theta = geodesic_angle(*a, *b);
        if theta.is_nan() {
            return Err(GeometryError::NonFinite(
                "orientation_rmse_deg quaternions (zero or non-finite)",
            ));
        }
        acc.add(theta.to_degrees());
    }
    Ok(acc.rmse().unwrap_or(0.0))
}

/// Rigidity residual of one object in one frame, m^2: Kabsch-align the reference cloud
/// (`[P, 3]`) onto the predicted cloud (`[P, 3]`, same point order), then
/// `(1/P) sum_k |R x_ref,k + p - x_pred,k|^2`. Zero exactly when the prediction is a rigid
/// motion of the reference.
///
/// Errors: empty input, length mismatch, non-finite points.
pub fn rigidity_residual(reference: &[Point], predicted: &[Point]) -> Result<f64, GeometryError> {
    check_pair("rigidity_residual clouds", reference.len(), predicted.len())?;
    let a: Vec<[f64; 3]> = reference.iter().map(|p| p.map(f64::from)).collect();
    let b: Vec<[f64; 3]> = predicted.iter().map(|p| p.map(f64::from)).collect();
    let sol = kabsch(&a, &b, None)?;
    let sum: f64 = a
        .iter()
        .zip(&b)
        .map(|(x, y)| {
            let z = sol.apply(*x);
            (0..3).map(|d| (z[d] - y[d]).powi(2)).sum::<f64>()
        })
        .sum();
    Ok(sum / a.len() as f64)
}

fn check_offsets(n: usize, offsets: &[usize]) -> Result<usize, GeometryError> {
    crate::contact::validate_offsets(n, offsets)?;
    if offsets.windows(2).any(|w| w[0] == w[1]) {
        return Err(GeometryError::Invalid(
            "every object needs at least one point".into(),
        ));
    }
    Ok(offsets.len() - 1)
}

/// Mean rigidity residual, m^2: [`rigidity_residual`] of every object in every frame,
/// averaged over objects and frames (`(1/(T M)) sum_t sum_i residual_{t,i}`).
///
/// `reference`: `[N, 3]` points of all objects in their reference pose (for example frame 0);
/// `frames`: `[T][N, 3]`; `offsets`: `[M + 1]`, object `i` owns points
/// `offsets[i]..offsets[i + 1]` (every object non-empty).
pub fn mean_rigidity_residual(
    reference: &[Point],
    frames: &[Vec<Point>],
    offsets: &[usize],
) -> Result<f64, GeometryError> {
    let objects = check_offsets(reference.len(), offsets)?;
    if frames.is_empty() {
        return Err(GeometryError::Empty("mean_rigidity_residual frames"));
    }
    let mut sum = 0.0;
    for frame in frames {
        check_pair("mean_rigidity_residual frame", reference.len(), frame.len())?;
        for i in 0..objects {
            let r = offsets[i]..offsets[i + 1];
            sum += rigidity_residual(&reference[r.clone()], &frame[r])?;
        }
    }
    Ok(sum / (frames.len() * objects) as f64)
}

/// Total linear momentum per frame interval, kg m/s: for `t = 0..T-1`,
/// `P_t = sum_i m_i (c_i(t+1) - c_i(t)) / dt`, with `c_i` the centroid of object `i`'s points
/// (pass one point per object, its centre of mass, for rigid trajectories).
///
/// `frames`: `[T][N, 3]`, `T >= 2`; `offsets`: `[M + 1]`; `masses`: `[M]` kg; `dt`: seconds
/// between frames. Returns `[T - 1][3]`.
pub fn total_momentum(
    frames: &[Vec<Point>],
    offsets: &[usize],
    masses: &[f32],
    dt: f64,
) -> Result<Vec<[f64; 3]>, GeometryError> {
    if frames.len() < 2 {
        return Err(GeometryError::Invalid(
            "momentum needs at least two frames".into(),
        ));
    }
    let objects = check_offsets(frames[0].len(), offsets)?;
    check_pair("total_momentum masses", objects, masses.len())?;
    if !(dt.is_finite() && dt > 0.0) {
        return Err(GeometryError::Invalid(format!(
            "frame interval must be finite and > 0, got {dt}"
        )));
    }
    let centroids = |frame: &Vec<Point>| -> Vec<[f64; 3]> {
        (0..objects)
            .map(|i| {
                let pts = &frame[offsets[i]..offsets[i + 1]];
                let mut c = [0.0f64; 3];
                for p in pts {
                    for d in 0..3 {
                        c[d] += f64::from(p[d]);
                    }
                }
                c.map(|v| v / pts.len() as f64)
            })
            .collect()
    };
    for f in frames {
        check_pair("total_momentum frame", frames[0].len(), f.len())?;
    }
    let c: Vec<Vec<[f64; 3]>> = frames.iter().map(centroids).collect();
    Ok(c.windows(2)
        .map(|w| {
            let mut p = [0.0f64; 3];
            for i in 0..objects {
                for d in 0..3 {
                    p[d] += f64::from(masses[i]) * (w[1][i][d] - w[0][i][d]) / dt;
                }
            }
            p
        })
        .collect())
}

/// Momentum drift, kg m/s: `(1/(T-1)) sum_t |P_t - P_0|` over the momenta of
/// [`total_momentum`] (the `t = 0` term is zero and counted).
pub fn momentum_drift(
    frames: &[Vec<Point>],
    offsets: &[usize],
    masses: &[f32],
    dt: f64,
) -> Result<f64, GeometryError> {
    let p = total_momentum(frames, offsets, masses, dt)?;
    let p0 = p[0];
    let sum: f64 = p
        .iter()
        .map(|q| (0..3).map(|d| (q[d] - p0[d]).powi(2)).sum::<f64>().sqrt())
        .sum();
    Ok(sum / p.len() as f64)
}

/// Momentum drift ratio (dimensionless, closer to 1 is better):
/// `momentum_drift(predicted) / max(momentum_drift(truth), eps)`, `eps` in kg m/s (for
/// example `1e-6`). Both trajectories share `offsets`, `masses` and `dt`.
pub fn momentum_drift_ratio(
    predicted: &[Vec<Point>],
    truth: &[Vec<Point>],
    offsets: &[usize],
    masses: &[f32],
    dt: f64,
    eps: f64,
) -> Result<f64, GeometryError> {
    if !(eps.is_finite() && eps > 0.0) {
        return Err(GeometryError::Invalid(format!(
            "eps must be finite and > 0, got {eps}"
        )));
    }
    let pred = momentum_drift(predicted, offsets, masses, dt)?;
    let true_drift = momentum_drift(truth, offsets, masses, dt)?;
    Ok(pred / true_drift.max(eps))
}

/// Per-vertex mean squared error, m^2: `(1/N) sum_k |x_pred,k - x_true,k|^2`.
pub fn mean_squared_error(predicted: &[Point], truth: &[Point]) -> Result<f64, GeometryError> {
    check_pair("mean_squared_error inputs", predicted.len(), truth.len())?;
    let sum: f64 = predicted
        .iter()
        .zip(truth)
        .map(|(a, b)| squared_distance(a, b))
        .sum();
    Ok(sum / predicted.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    #[test]
    fn translation_rmse_hand_case() {
        // Errors of length 3 and 4 (a 3-4-5 pair and one axis): sqrt((9 + 16) / 2).
        let pred = [[3.0, 0.0, 0.0], [1.0, 1.0, 5.0]];
        let truth = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]];
        let got = translation_rmse(&pred, &truth).unwrap();
        assert!((got - 12.5f64.sqrt()).abs() < 1e-12);
        assert_eq!(translation_rmse(&truth, &truth).unwrap(), 0.0);
        assert!(translation_rmse(&[], &[]).is_err());
        assert!(translation_rmse(&pred, &truth[..1]).is_err());
    }

    #[test]
    fn orientation_rmse_hand_case() {
        // 90 and 0 degree errors: sqrt((90^2 + 0^2) / 2) = 63.6396...
        let z = Vector3::z_axis();
        let q90 = UnitQuaternion::from_axis_angle(&z, std::f32::consts::FRAC_PI_2);
        let c = q90.coords;
        let pred = [[c.x, c.y, c.z, c.w], [0.0, 0.0, 0.0, 1.0]];
        let truth = [[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, -1.0]];
        let got = orientation_rmse_deg(&pred, &truth).unwrap();
        assert!((got - 90.0 / 2f64.sqrt()).abs() < 1e-4, "{got}");
        assert!(orientation_rmse_deg(&[[0.0; 4]], &[[0.0, 0.0, 0.0, 1.0]]).is_err());
    }

    #[test]
    fn accumulator_pools_rather_than_averaging_rmses() {
        let mut a = RmseAccumulator::default();
        a.add(1.0);
        let mut b = RmseAccumulator::default();
        for _ in 0..3 {
            b.add(3.0);
        }
        a.merge(&b);
        // Pool: sqrt((1 + 27) / 4) = sqrt(7), not (1 + 3) / 2.
        assert!((a.rmse().unwrap() - 7f64.sqrt()).abs() < 1e-12);
        assert_eq!(RmseAccumulator::default().rmse(), None);
    }

    #[test]
    fn rigidity_residual_zero_for_rigid_motion_and_known_for_stretch() {
        let reference: Vec<Point> = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ];
        let q = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1);
        let moved: Vec<Point> = reference
            .iter()
            .map(|p| {
                let v = q * Vector3::from(*p) + Vector3::new(1.0, 2.0, 3.0);
                [v.x, v.y, v.z]
            })
            .collect();
        assert!(rigidity_residual(&reference, &moved).unwrap() < 1e-12);
        // Two points 2 m apart predicted 4 m apart: best fit leaves 1 m at each end.
        let a = [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let b = [[-2.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
        assert!((rigidity_residual(&a, &b).unwrap() - 1.0).abs() < 1e-12);
        // Averaged over objects and frames: (0 + 1) / 2 for the stretched second object.
        let reference2: Vec<Point> = reference.iter().copied().chain(a).collect();
        let frame: Vec<Point> = moved.iter().copied().chain(b).collect();
        let mean = mean_rigidity_residual(&reference2, &[frame], &[0, 4, 6]).unwrap();
        assert!((mean - 0.5).abs() < 1e-12);
    }

    #[test]
    fn momentum_drift_hand_case() {
        // Two objects (one point each), masses 1 and 2 kg, dt = 0.5 s.
        // Truth: constant velocities (1, 0, 0) and (0, 1, 0) m/s: no drift.
        // Prediction: object 1 slows to rest after the first interval.
        let truth: Vec<Vec<Point>> = (0..4)
            .map(|t| {
                let s = t as f32 * 0.5;
                vec![[s, 0.0, 0.0], [0.0, s, 0.0]]
            })
            .collect();
        let pred: Vec<Vec<Point>> = vec![
            vec![[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
            vec![[0.5, 0.0, 0.0], [0.0, 0.5, 0.0]],
            vec![[1.0, 0.0, 0.0], [0.0, 0.5, 0.0]],
            vec![[1.5, 0.0, 0.0], [0.0, 0.5, 0.0]],
        ];
        let offsets = [0, 1, 2];
        let masses = [1.0, 2.0];
        let p = total_momentum(&truth, &offsets, &masses, 0.5).unwrap();
        assert_eq!(p, vec![[1.0, 2.0, 0.0]; 3]);
        assert_eq!(momentum_drift(&truth, &offsets, &masses, 0.5).unwrap(), 0.0);
        // Predicted P: (1,2,0), (1,0,0), (1,0,0): drift = (0 + 2 + 2) / 3.
        let drift = momentum_drift(&pred, &offsets, &masses, 0.5).unwrap();
        assert!((drift - 4.0 / 3.0).abs() < 1e-12);
        let ratio = momentum_drift_ratio(&pred, &truth, &offsets, &masses, 0.5, 0.1).unwrap();
        assert!((ratio - 40.0 / 3.0).abs() < 1e-9);
        let same = momentum_drift_ratio(&pred, &pred, &offsets, &masses, 0.5, 1e-6).unwrap();
        assert!((same - 1.0).abs() < 1e-12);
        assert!(momentum_drift(&truth[..1], &offsets, &masses, 0.5).is_err());
        assert!(momentum_drift(&truth, &offsets, &masses[..1], 0.5).is_err());
    }

    #[test]
    fn centroids_of_several_points_per_object() {
        // One object of two points moving together at 2 m/s along z: P = m * 2.
        let frames: Vec<Vec<Point>> = (0..3)
            .map(|t| {
                let z = t as f32 * 0.2;
                vec![[0.0, 0.0, z], [1.0, 0.0, z]]
            })
            .collect();
        let p = total_momentum(&frames, &[0, 2], &[3.0], 0.1).unwrap();
        for v in p {
            assert!((v[2] - 6.0).abs() < 1e-5 && v[0] == 0.0);
        }
        assert!((mean_squared_error(&frames[0], &frames[1]).unwrap() - 0.04).abs() < 1e-7);
    }
}
