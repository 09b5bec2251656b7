//! The exhaustive `O(n^2)` reference search, for tests and benchmarks.

use super::config::{ContactConfig, validate_offsets};
use super::hit::{ContactHit, ContactSource, dist2, ground_fallback};
use crate::Point;

/// Reference implementation of [`contact_features`](super::contact_features) by exhaustive search, `O(n^2)`; same
/// definition and bit-identical results (see the module docs). For tests and benchmarks.
///
/// # Panics
/// If `offsets` is malformed (see [`validate_offsets`]).
pub fn contact_features_brute_force(
    points: &[Point],
    offsets: &[usize],
    cfg: &ContactConfig,
) -> Vec<Point> {
    contact_hits_brute_force(points, offsets, cfg)
        .into_iter()
        .map(|h| h.displacement)
        .collect()
}

/// Reference implementation of [`contact_hits`](super::contact_hits) by exhaustive search, `O(n^2)`; bit-identical
/// displacements and the same sources. For tests and benchmarks.
///
/// # Panics
/// If `offsets` is malformed (see [`validate_offsets`]).
pub fn contact_hits_brute_force(
    points: &[Point],
    offsets: &[usize],
    cfg: &ContactConfig,
) -> Vec<ContactHit> {
    if let Err(e) = validate_offsets(points.len(), offsets) {
        panic!("contact_features_brute_force: {e}");
    }
    let r = cfg.effective_radius();
    let mut out = Vec::with_capacity(points.len());
    for i in 0..offsets.len() - 1 {
        for x in &points[offsets[i]..offsets[i + 1]] {
            let (mut best_d2, fallback, kind) = ground_fallback(x, r, cfg.ground_z);
            let mut best = None;
            for j in 0..offsets.len() - 1 {
                if j == i {
                    continue;
                }
                for (k, y) in points
                    .iter()
                    .enumerate()
                    .take(offsets[j + 1])
                    .skip(offsets[j])
                {
                    let d2 = dist2(x, y);
                    if d2 < best_d2 {
                        best_d2 = d2;
                        best = Some((y, k));
                    }
                }
            }
            out.push(match best {
                Some((y, k)) => ContactHit::new(
                    [y[0] - x[0], y[1] - x[1], y[2] - x[2]],
                    ContactSource::Point(k as u32),
                ),
                None => ContactHit::new(fallback, kind),
            });
        }
    }
    out
}
