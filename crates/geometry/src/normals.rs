//! Surface normals of a bare point cloud (no mesh), by local plane fitting.
//!
//! Each point's normal is the direction of least spread of its `neighbours` nearest points
//! (itself included): the eigenvector of their covariance with the smallest eigenvalue, the
//! normal of the plane that fits them best. Its sign is not defined by the fit; it is chosen to
//! point away from the cloud's centroid, which is outward everywhere on a convex body and on
//! most of a concave one (inside a cup or a torus's hole it points inward).
//!
//! Cost: `O(n^2)` distance evaluations (an exact nearest-neighbour search per point, fine for
//! the few hundred to few thousand points of one object) and one 3x3 eigen-decomposition per
//! point.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use crate::{GeometryError, Point};

/// Neighbours (the point itself included) whose plane gives a point's normal in
/// [`estimate_normals`] when a caller has no reason to choose otherwise.
pub const DEFAULT_NORMAL_NEIGHBOURS: usize = 8;

/// Unit outward normals of `points` (`[n, 3]`, metres, one object's surface samples in any
/// frame), `[n, 3]`, in the same frame: the least-spread direction of each point's
/// `neighbours` nearest points (at least 3, capped at `n`), signed away from the centroid.
///
/// Where no plane is defined (fewer than 3 points, or neighbours on a line or at one place)
/// the normal is the direction from the centroid to the point, or `[0, 0, 1]` for a point at
/// the centroid. Deterministic for given points.
///
/// Errors: empty `points`, a non-finite coordinate, or `neighbours < 3`.
pub fn estimate_normals(points: &[Point], neighbours: usize) -> Result<Vec<Point>, GeometryError> {
    let n = points.len();
    if n == 0 {
        return Err(GeometryError::Empty("normal estimation points"));
    }
    if !points.iter().flatten().all(|v| v.is_finite()) {
        return Err(GeometryError::NonFinite("normal estimation points"));
    }
    if neighbours < 3 {
        return Err(GeometryError::Invalid(format!(
            "normal estimation needs at least 3 neighbours, got {neighbours}"
        )));
    }
    let v = |p: &Point| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
    let centroid = points.iter().map(v).sum::<Vector3<f64>>() / n as f64;
    let k = neighbours.min(n);
    let mut order: Vec<(f32, usize)> = Vec::with_capacity(n);
    let mut out = Vec::with_capacity(n);
    for p in points {
        let outward = v(p) - centroid;
        let fallback = if outward.norm() > 1e-12 {
            outward.normalize()
        } else {
            Vector3::z()
        };
        let normal = if k < 3 {
            fallback
        } else {
            order.clear();
            order.extend(points.iter().enumerate().map(|(i, q)| {
                let d = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
                (d[0] * d[0] + d[1] * d[1] + d[2] * d[2], i)
            }));
            // The k nearest, ties towards the smaller index; their order does not matter.
            order.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            plane_normal(order[..k].iter().map(|&(_, i)| v(&points[i])))
                .map(|m| if m.dot(&outward) < 0.0 { -m } else { m })
                .unwrap_or(fallback)
        };
        out.push([normal.x as f32, normal.y as f32, normal.z as f32]);
    }
    Ok(out)
}

/// The unit normal of the plane through `points` that fits them best (least squares), or
/// `None` when they do not span a plane (collinear or coincident within rounding).
fn plane_normal(points: impl Iterator<Item = Vector3<f64>> + Clone) -> Option<Vector3<f64>> {
    let count = points.clone().count() as f64;
    let mean = points.clone().sum::<Vector3<f64>>() / count;
    let cov = points.fold(Matrix3::zeros(), |acc, q| {
        let d = q - mean;
        acc + d * d.transpose()
    });
    let eig = SymmetricEigen::new(cov);
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    // A plane needs two clearly non-zero spreads (the inputs are finite, so are these); the
    // normal is the third direction.
    let (least, middle) = (eig.eigenvalues[idx[0]], eig.eigenvalues[idx[1]]);
    if middle <= 1e-12 * eig.eigenvalues[idx[2]].max(1e-300) || middle <= least {
        return None;
    }
    let m = eig.eigenvectors.column(idx[0]).into_owned();
    let len = m.norm();
    (len > 0.0).then(|| m / len)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dot(a: Point, b: Point) -> f32 {
        a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    }

    /// Points on the six faces of an axis-aligned cube of half-side `h`, a grid of `m x m`
    /// per face, away from the edges (so every neighbourhood is one face).
    fn cube_faces(h: f32, m: usize) -> Vec<(Point, Point)> {
        let mut out = Vec::new();
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                for i in 0..m {
                    for j in 0..m {
                        let u = (i as f32 + 0.5) / m as f32 * 1.2 * h - 0.6 * h;
                        let w = (j as f32 + 0.5) / m as f32 * 1.2 * h - 0.6 * h;
                        let mut p = [0.0; 3];
                        p[axis] = sign * h;
                        p[(axis + 1) % 3] = u;
                        p[(axis + 2) % 3] = w;
                        let mut nrm = [0.0; 3];
                        nrm[axis] = sign;
                        out.push((p, nrm));
                    }
                }
            }
        }
        out
    }

    #[test]
    fn cube_face_points_get_their_face_normal_outward() {
        let samples = cube_faces(0.5, 6);
        let points: Vec<Point> = samples.iter().map(|s| s.0).collect();
        let normals = estimate_normals(&points, DEFAULT_NORMAL_NEIGHBOURS).unwrap();
        for ((p, truth), got) in samples.iter().zip(&normals) {
            assert!((dot(*got, *got) - 1.0).abs() < 1e-5, "not unit at {p:?}");
            assert!(
                dot(*got, *truth) > 0.999,
                "{p:?}: {got:?} against {truth:?}"
            );
        }
    }

    #[test]
    fn sphere_normals_are_radial_in_any_order() {
        // A Fibonacci sphere of radius 0.3 about (1, 2, 3).
        let n = 300;
        let centre = [1.0f32, 2.0, 3.0];
        let mut points = Vec::new();
        for i in 0..n {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).sqrt();
            let phi = i as f32 * 2.399_963;
            points.push([
                centre[0] + 0.3 * r * phi.cos(),
                centre[1] + 0.3 * r * phi.sin(),
                centre[2] + 0.3 * z,
            ]);
        }
        let normals = estimate_normals(&points, DEFAULT_NORMAL_NEIGHBOURS).unwrap();
        for (p, got) in points.iter().zip(&normals) {
            let radial = [0, 1, 2].map(|d| (p[d] - centre[d]) / 0.3);
            assert!(dot(*got, radial) > 0.99, "{p:?}: {got:?}");
        }
        // Reversing the order of the points reverses the normals' order, nothing else.
        let reversed: Vec<Point> = points.iter().rev().copied().collect();
        let again = estimate_normals(&reversed, DEFAULT_NORMAL_NEIGHBOURS).unwrap();
        for (a, b) in normals.iter().zip(again.iter().rev()) {
            assert!(dot(*a, *b) > 0.9999);
        }
    }

    #[test]
    fn degenerate_clouds_fall_back_to_the_radial_direction() {
        let line: Vec<Point> = (0..5).map(|i| [i as f32 * 0.25 - 0.5, 0.0, 0.0]).collect();
        let normals = estimate_normals(&line, 4).unwrap();
        assert_eq!(normals[0], [-1.0, 0.0, 0.0]);
        assert_eq!(normals[4], [1.0, 0.0, 0.0]);
        // The middle point sits at the centroid.
        assert_eq!(normals[2], [0.0, 0.0, 1.0]);
        let one = estimate_normals(&[[0.2, 0.0, 0.0]], 8).unwrap();
        assert_eq!(one, vec![[0.0, 0.0, 1.0]]);
    }

    #[test]
    fn bad_input_is_refused() {
        assert!(matches!(
            estimate_normals(&[], 8),
            Err(GeometryError::Empty(_))
        ));
        assert!(matches!(
            estimate_normals(&[[f32::NAN, 0.0, 0.0]], 8),
            Err(GeometryError::NonFinite(_))
        ));
        assert!(matches!(
            estimate_normals(&[[0.0; 3]], 2),
            Err(GeometryError::Invalid(_))
        ));
    }
}
