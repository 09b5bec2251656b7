//! Seeded, area-weighted sampling of points on a mesh surface.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::TriMesh;
use crate::Point;

/// `n` points drawn uniformly (area-weighted) from the surface of `mesh`, deterministic for a
/// given `seed` (ChaCha8). Faces are chosen with probability proportional to their area, then a
/// point uniformly inside the chosen triangle. A mesh without area yields copies of its first
/// vertex; a mesh without vertices yields an empty vector.
pub fn sample_surface(mesh: &TriMesh, n: usize, seed: u64) -> Vec<Point> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    sample_surface_with(mesh, n, &mut rng)
}

/// [`sample_surface`] drawing from a caller's random number generator.
pub fn sample_surface_with<R: Rng + ?Sized>(mesh: &TriMesh, n: usize, rng: &mut R) -> Vec<Point> {
    let Some(&first) = mesh.vertices.first() else {
        return Vec::new();
    };
    let mut cumulative = Vec::with_capacity(mesh.faces.len());
    let mut total = 0.0f64;
    for a in mesh.face_areas() {
        total += a;
        cumulative.push(total);
    }
    if total.is_nan() || total <= 0.0 {
        return vec![first; n];
    }
    (0..n)
        .map(|_| {
            let u = rng.random::<f64>() * total;
            let i = cumulative
                .partition_point(|&c| c <= u)
                .min(cumulative.len() - 1);
            let [a, b, c] = mesh.corners(&mesh.faces[i]);
            let r1 = rng.random::<f64>().sqrt();
            let r2 = rng.random::<f64>();
            let (wa, wb, wc) = (1.0 - r1, r1 * (1.0 - r2), r1 * r2);
            [
                (wa * a[0] + wb * b[0] + wc * c[0]) as f32,
                (wa * a[1] + wb * b[1] + wc * c[1]) as f32,
                (wa * a[2] + wb * b[2] + wc * c[2]) as f32,
            ]
        })
        .collect()
}
