//! Weighted Kabsch alignment with a closed-form backward pass.
//!
//! Given reference points `a_ref_k` and target points `a_k` (metres) with non-negative weights
//! `w_k`, find the proper rotation `R` (det `R` = +1) and translation `p` minimising
//! `sum_k w_k |R a_ref_k + p - a_k|^2`.
//!
//! Forward: centroids `c_ref`, `c`; covariance `H = sum_k w_k (a_ref_k - c_ref)(a_k - c)^T`;
//! `R` is the rotation closest to `M = H^T` (its special polar factor): with `M = U S V^T`,
//! the column of `U` belonging to the smallest singular value (and that value) is negated when
//! `det(U V^T) < 0`, then `R = U V^T` and `p = c - R c_ref`.
//!
//! Backward (dL/dR, dL/dp -> dL/da, dL/da_ref): `B = U^T g_R V`,
//! `C_kl = (B_kl - B_lk) pinv(s_k + s_l)` with `pinv(x) = 0` for `|x| < 1e-5`, `g_M = U C V^T`,
//! then through the covariance and the centroids. The pseudo-inverse keeps the gradient finite
//! for planar, collinear and coincident sets, where the rotation about a degenerate axis is
//! undetermined and receives no gradient.

use nalgebra::{Matrix3, Vector3};

use crate::GeometryError;

/// Threshold below which `1 / (s_k + s_l)` is treated as zero in the backward pass.
pub const PINV_EPS: f64 = 1e-5;

/// Result of [`kabsch`]: the optimal rigid motion and the factors the backward pass needs.
#[derive(Clone, Debug)]
pub struct KabschSolution {
    /// Proper rotation (det +1) mapping reference to target.
    pub rotation: Matrix3<f64>,
    /// Translation in metres: `p = c - R c_ref`.
    pub translation: Vector3<f64>,
    /// Left singular vectors of `M = H^T`, with the reflection fix applied.
    pub u: Matrix3<f64>,
    /// Singular values of `M`, the smallest negated when a reflection was fixed.
    pub s: Vector3<f64>,
    /// Right singular vectors of `M`.
    pub v: Matrix3<f64>,
    /// Weighted centroid of the reference points (metres).
    pub reference_centroid: Vector3<f64>,
    /// Weighted centroid of the target points (metres).
    pub target_centroid: Vector3<f64>,
}

impl KabschSolution {
    /// Applies the solved motion to a point: `R x + p`.
    pub fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        let y = self.rotation * Vector3::from(x) + self.translation;
        [y.x, y.y, y.z]
    }
}

fn check_inputs(
    reference: &[[f64; 3]],
    target: &[[f64; 3]],
    weights: Option<&[f64]>,
) -> Result<f64, GeometryError> {
    if reference.is_empty() {
        return Err(GeometryError::Empty("kabsch reference"));
    }
    if reference.len() != target.len() {
        return Err(GeometryError::LengthMismatch {
            what: "kabsch target",
            expected: reference.len(),
            got: target.len(),
        });
    }
    let finite = |p: &[f64; 3]| p.iter().all(|v| v.is_finite());
    if !reference.iter().all(finite) || !target.iter().all(finite) {
        return Err(GeometryError::NonFinite("kabsch points"));
    }
    match weights {
        None => Ok(reference.len() as f64),
        Some(w) => {
            if w.len() != reference.len() {
                return Err(GeometryError::LengthMismatch {
                    what: "kabsch weights",
                    expected: reference.len(),
                    got: w.len(),
                });
            }
            if w.iter().any(|x| !x.is_finite() || *x < 0.0) {
                return Err(GeometryError::NonFinite(
                    "kabsch weights (must be finite and >= 0)",
                ));
            }
            let total: f64 = w.iter().sum();
            if total <= 0.0 {
                return Err(GeometryError::Empty("kabsch weights (all zero)"));
            }
            Ok(total)
        }
    }
}

fn weight(weights: Option<&[f64]>, k: usize) -> f64 {
    weights.map_or(1.0, |w| w[k])
}

fn centroid(points: &[[f64; 3]], weights: Option<&[f64]>, total: f64) -> Vector3<f64> {
    let mut c = Vector3::zeros();
    for (k, p) in points.iter().enumerate() {
        c += weight(weights, k) * Vector3::from(*p);
    }
    c / total
}

/// Solves the weighted Kabsch problem (see the module docs).
///
/// `reference` and `target`: `[n, 3]` points in metres, `n >= 1`; `weights`: `[n]`, finite,
/// non-negative, not all zero, or `None` for uniform weights. Degenerate sets (one point,
/// coincident, collinear, planar) give a finite proper rotation.
pub fn kabsch(
    reference: &[[f64; 3]],
    target: &[[f64; 3]],
    weights: Option<&[f64]>,
) -> Result<KabschSolution, GeometryError> {
    let total = check_inputs(reference, target, weights)?;
    let c_ref = centroid(reference, weights, total);
    let c = centroid(target, weights, total);
    // M = H^T = sum_k w_k (a_k - c)(a_ref_k - c_ref)^T, so that R = polar(M) maps ref to target.
    let mut m = Matrix3::zeros();
    for k in 0..reference.len() {
        let d = Vector3::from(target[k]) - c;
        let r = Vector3::from(reference[k]) - c_ref;
        m += weight(weights, k) * d * r.transpose();
    }
    let svd = m.svd(true, true);
    let mut u = svd
        .u
        .ok_or(GeometryError::Numerical("SVD did not converge"))?;
    let v_t = svd
        .v_t
        .ok_or(GeometryError::Numerical("SVD did not converge"))?;
    let mut s = svd.singular_values;
    if !(u.iter().all(|x| x.is_finite()) && v_t.iter().all(|x| x.is_finite())) {
        return Err(GeometryError::Numerical("SVD produced non-finite factors"));
    }
    let v = v_t.transpose();
    if (u * v_t).determinant() < 0.0 {
        let j = s.imin();
        s[j] = -s[j];
        for row in 0..3 {
            u[(row, j)] = -u[(row, j)];
        }
    }
    let rotation = u * v_t;
    let translation = c - rotation * c_ref;
    Ok(KabschSolution {
        rotation,
        translation,
        u,
        s,
        v,
        reference_centroid: c_ref,
        target_centroid: c,
    })
}

fn pinv(x: f64) -> f64 {
    if x.abs() < PINV_EPS { 0.0 } else { 1.0 / x }
}

/// Gradients of a scalar loss with respect to the target and reference points, given the
/// gradients with respect to the rotation (`[3, 3]`) and translation (`[3]`, per metre) of
/// `sol = kabsch(reference, target, weights)`.
///
/// Returns `(dL/dtarget, dL/dreference)`, each `[n, 3]`. Weights are treated as constants.
pub fn kabsch_backward(
    reference: &[[f64; 3]],
    target: &[[f64; 3]],
    weights: Option<&[f64]>,
    sol: &KabschSolution,
    grad_rotation: &Matrix3<f64>,
    grad_translation: &Vector3<f64>,
) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let n = reference.len();
    let total: f64 = match weights {
        None => n as f64,
        Some(w) => w.iter().sum(),
    };
    // p = c - R c_ref contributes to R, c and c_ref.
    let g_r = grad_rotation - grad_translation * sol.reference_centroid.transpose();
    let g_c = *grad_translation;
    let g_c_ref = -(sol.rotation.transpose() * grad_translation);
    // Polar factor backward: R = U V^T.
    let b = sol.u.transpose() * g_r * sol.v;
    let mut c = Matrix3::zeros();
    for k in 0..3 {
        for l in 0..3 {
            c[(k, l)] = (b[(k, l)] - b[(l, k)]) * pinv(sol.s[k] + sol.s[l]);
        }
    }
    let g_m = sol.u * c * sol.v.transpose();
    // M = sum_k w_k (a_k - c)(a_ref_k - c_ref)^T; the centroid terms vanish because the
    // centred sets sum to zero.
    let mut g_target = Vec::with_capacity(n);
    let mut g_reference = Vec::with_capacity(n);
    for k in 0..n {
        let w = weight(weights, k);
        let r = Vector3::from(reference[k]) - sol.reference_centroid;
        let d = Vector3::from(target[k]) - sol.target_centroid;
        let gt = w * (g_m * r) + (w / total) * g_c;
        let gr = w * (g_m.transpose() * d) + (w / total) * g_c_ref;
        g_target.push([gt.x, gt.y, gt.z]);
        g_reference.push([gr.x, gr.y, gr.z]);
    }
    (g_target, g_reference)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Unit};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_points(rng: &mut ChaCha8Rng, n: usize) -> Vec<[f64; 3]> {
        (0..n)
            .map(|_| {
                [
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                ]
            })
            .collect()
    }

    fn random_rotation(rng: &mut ChaCha8Rng) -> Matrix3<f64> {
        let axis = Unit::new_normalize(Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        ));
        Rotation3::from_axis_angle(&axis, rng.random_range(-3.1..3.1)).into_inner()
    }

    #[test]
    fn recovers_random_rigid_motion() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..50 {
            let n = rng.random_range(3..40);
            let reference = random_points(&mut rng, n);
            let r = random_rotation(&mut rng);
            let p = Vector3::new(1.5, -2.0, 0.25);
            let target: Vec<[f64; 3]> = reference
                .iter()
                .map(|x| {
                    let y = r * Vector3::from(*x) + p;
                    [y.x, y.y, y.z]
                })
                .collect();
            let weights: Vec<f64> = (0..n).map(|_| rng.random_range(0.1..2.0)).collect();
            for w in [None, Some(weights.as_slice())] {
                let sol = kabsch(&reference, &target, w).unwrap();
                assert!(
                    (sol.rotation - r).abs().max() < 1e-5,
                    "rotation {sol:?} vs {r}"
                );
                assert!((sol.translation - p).abs().max() < 1e-5);
                assert!((sol.rotation.determinant() - 1.0).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn reflection_is_excluded() {
        // A mirrored set: the best proper rotation, never a reflection.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let reference = random_points(&mut rng, 12);
        let target: Vec<[f64; 3]> = reference.iter().map(|p| [-p[0], p[1], p[2]]).collect();
        let sol = kabsch(&reference, &target, None).unwrap();
        assert!((sol.rotation.determinant() - 1.0).abs() < 1e-9);
        assert!(
            (sol.rotation * sol.rotation.transpose() - Matrix3::identity())
                .abs()
                .max()
                < 1e-9
        );
    }

    /// Scalar test loss L = <G_R, R> + <g_p, p> for fixed random G_R, g_p.
    fn loss(
        reference: &[[f64; 3]],
        target: &[[f64; 3]],
        gr: &Matrix3<f64>,
        gp: &Vector3<f64>,
    ) -> f64 {
        let sol = kabsch(reference, target, None).unwrap();
        gr.component_mul(&sol.rotation).sum() + gp.dot(&sol.translation)
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..10 {
            let reference = random_points(&mut rng, 8);
            let target = random_points(&mut rng, 8);
            let gr = Matrix3::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let gp = Vector3::new(rng.random_range(-1.0..1.0), 0.3, -0.7);
            let sol = kabsch(&reference, &target, None).unwrap();
            let (g_t, g_r) = kabsch_backward(&reference, &target, None, &sol, &gr, &gp);
            let h = 1e-6;
            for k in 0..8 {
                for d in 0..3 {
                    let mut plus = target.clone();
                    let mut minus = target.clone();
                    plus[k][d] += h;
                    minus[k][d] -= h;
                    let fd = (loss(&reference, &plus, &gr, &gp)
                        - loss(&reference, &minus, &gr, &gp))
                        / (2.0 * h);
                    assert!(
                        (fd - g_t[k][d]).abs() < 1e-6,
                        "target grad {k},{d}: fd {fd} vs {}",
                        g_t[k][d]
                    );
                    let mut plus = reference.clone();
                    let mut minus = reference.clone();
                    plus[k][d] += h;
                    minus[k][d] -= h;
                    let fd = (loss(&plus, &target, &gr, &gp) - loss(&minus, &target, &gr, &gp))
                        / (2.0 * h);
                    assert!(
                        (fd - g_r[k][d]).abs() < 1e-6,
                        "reference grad {k},{d}: fd {fd} vs {}",
                        g_r[k][d]
                    );
                }
            }
        }
    }

    #[test]
    fn degenerate_sets_stay_finite() {
        let coincident = vec![[0.3, 0.3, 0.3]; 5];
        let collinear: Vec<[f64; 3]> = (0..5).map(|i| [i as f64 * 0.1, 0.0, 0.0]).collect();
        let planar: Vec<[f64; 3]> = (0..6)
            .map(|i| [(i % 3) as f64, (i / 3) as f64, 0.0])
            .collect();
        let single = vec![[1.0, 2.0, 3.0]];
        for set in [coincident, collinear, planar, single] {
            let target: Vec<[f64; 3]> = set.iter().map(|p| [p[1], -p[0], p[2] + 1.0]).collect();
            let sol = kabsch(&set, &target, None).unwrap();
            assert!(sol.rotation.iter().all(|x| x.is_finite()));
            assert!((sol.rotation.determinant() - 1.0).abs() < 1e-9);
            // The aligned reference must still fit the target: the motion is exact here.
            for (a, b) in set.iter().zip(&target) {
                let y = sol.apply(*a);
                for d in 0..3 {
                    assert!((y[d] - b[d]).abs() < 1e-9, "{y:?} vs {b:?}");
                }
            }
            let (g_t, g_r) = kabsch_backward(
                &set,
                &target,
                None,
                &sol,
                &Matrix3::from_element(1.0),
                &Vector3::from_element(1.0),
            );
            assert!(g_t.iter().chain(&g_r).flatten().all(|x| x.is_finite()));
        }
    }

    #[test]
    fn rejects_bad_input() {
        assert!(kabsch(&[], &[], None).is_err());
        assert!(kabsch(&[[0.0; 3]], &[[0.0; 3], [1.0; 3]], None).is_err());
        assert!(kabsch(&[[f64::NAN, 0.0, 0.0]], &[[0.0; 3]], None).is_err());
        assert!(kabsch(&[[0.0; 3]], &[[0.0; 3]], Some(&[0.0])).is_err());
    }
}
