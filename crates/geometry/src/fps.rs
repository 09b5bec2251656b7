//! Farthest point sampling (FPS).
//!
//! Greedy max-min sampling: the first sample is `start`; each next sample is the point whose
//! squared Euclidean distance to the nearest already chosen sample is largest. The result is
//! deterministic for given points, `k` and `start`:
//!
//! - ties are broken towards the smallest index;
//! - a point is never chosen twice while unchosen points remain (duplicated coordinates are
//!   picked in index order once every distinct location is taken);
//! - the sequence for `k` is a prefix of the sequence for `k + 1`.
//!
//! Cost: `O(n k)` time, one `[n]` scratch buffer.

use crate::{GeometryError, Point};

/// Farthest point sampling: `k` indices into `points` (`[n, 3]`, metres), the first being
/// `start`; deterministic (see the module docs for tie-breaking).
///
/// If `k >= n`, the result holds every index `0..n` exactly once, in farthest-point order from
/// `start`, followed by repeats of that same sequence from its beginning, so it always has
/// exactly `k` entries. `k = 0` gives an empty vector.
///
/// Errors: empty `points`, `start >= n`, or a non-finite coordinate.
pub fn farthest_point_sampling(
    points: &[Point],
    k: usize,
    start: usize,
) -> Result<Vec<usize>, GeometryError> {
    let n = points.len();
    if n == 0 {
        return Err(GeometryError::Empty("farthest point sampling points"));
    }
    if start >= n {
        return Err(GeometryError::Invalid(format!(
            "farthest point sampling start index {start} is out of range for {n} points"
        )));
    }
    if !points.iter().flatten().all(|v| v.is_finite()) {
        return Err(GeometryError::NonFinite("farthest point sampling points"));
    }
    let mut out = Vec::with_capacity(k);
    if k == 0 {
        return Ok(out);
    }
    let distinct = k.min(n);
    // Squared distance to the nearest chosen sample; chosen points hold -1 so that they lose
    // every comparison against an unchosen point, even a coincident one (distance 0).
    let mut nearest = vec![f32::INFINITY; n];
    let mut current = start;
    out.push(current);
    nearest[current] = -1.0;
    while out.len() < distinct {
        let c = points[current];
        let mut best = usize::MAX;
        let mut best_d = f32::NEG_INFINITY;
        for (i, (p, d)) in points.iter().zip(nearest.iter_mut()).enumerate() {
            if *d >= 0.0 {
                let dx = p[0] - c[0];
                let dy = p[1] - c[1];
                let dz = p[2] - c[2];
                let e = dx * dx + dy * dy + dz * dz;
                if e < *d {
                    *d = e;
                }
            }
            if *d > best_d {
                best_d = *d;
                best = i;
            }
        }
        current = best;
        nearest[current] = -1.0;
        out.push(current);
    }
    // k > n: repeat the full permutation cyclically.
    let mut i = 0;
    while out.len() < k {
        out.push(out[i]);
        i += 1;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn dist2(a: Point, b: Point) -> f32 {
        (0..3).map(|d| (a[d] - b[d]) * (a[d] - b[d])).sum()
    }

    /// Straightforward O(n k^2) reference with the same tie-breaking.
    fn reference_fps(points: &[Point], k: usize, start: usize) -> Vec<usize> {
        let mut chosen = vec![start];
        while chosen.len() < k.min(points.len()) {
            let mut best = None;
            let mut best_d = f32::NEG_INFINITY;
            for (i, p) in points.iter().enumerate() {
                if chosen.contains(&i) {
                    continue;
                }
                let d = chosen
                    .iter()
                    .map(|&c| dist2(*p, points[c]))
                    .fold(f32::INFINITY, f32::min);
                if d > best_d {
                    best_d = d;
                    best = Some(i);
                }
            }
            chosen.push(best.unwrap());
        }
        chosen
    }

    #[test]
    fn matches_reference_on_random_clouds() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..30 {
            let n = rng.random_range(1..200);
            let pts: Vec<Point> = (0..n)
                .map(|_| {
                    [
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                    ]
                })
                .collect();
            let k = rng.random_range(1..=n);
            let start = rng.random_range(0..n);
            let got = farthest_point_sampling(&pts, k, start).unwrap();
            assert_eq!(got, reference_fps(&pts, k, start));
            assert_eq!(got[0], start);
        }
    }

    #[test]
    fn picks_extremes_of_a_segment() {
        // Points on a line 0..=10: from 0 the farthest is 10, then the middle 5.
        let pts: Vec<Point> = (0..=10).map(|i| [i as f32, 0.0, 0.0]).collect();
        assert_eq!(farthest_point_sampling(&pts, 3, 0).unwrap(), vec![0, 10, 5]);
        // Deterministic and a prefix of the longer sequence.
        let long = farthest_point_sampling(&pts, 6, 0).unwrap();
        assert_eq!(&long[..3], &[0, 10, 5]);
        assert_eq!(long, farthest_point_sampling(&pts, 6, 0).unwrap());
    }

    #[test]
    fn k_at_least_n_returns_every_index_then_repeats() {
        let pts: Vec<Point> = vec![[0.0; 3], [1.0, 0.0, 0.0], [0.25, 0.0, 0.0]];
        let got = farthest_point_sampling(&pts, 7, 2).unwrap();
        assert_eq!(got.len(), 7);
        let mut first: Vec<usize> = got[..3].to_vec();
        assert_eq!(got[..3], [2, 1, 0]);
        first.sort();
        assert_eq!(first, vec![0, 1, 2]);
        assert_eq!(got[3..], [2, 1, 0, 2]);
        assert!(farthest_point_sampling(&pts, 0, 0).unwrap().is_empty());
    }

    #[test]
    fn duplicates_are_not_chosen_twice_before_all_points() {
        let pts: Vec<Point> = vec![[0.0; 3]; 4];
        assert_eq!(
            farthest_point_sampling(&pts, 4, 1).unwrap(),
            vec![1, 0, 2, 3]
        );
    }

    #[test]
    fn rejects_bad_input() {
        assert!(matches!(
            farthest_point_sampling(&[], 3, 0),
            Err(GeometryError::Empty(_))
        ));
        assert!(farthest_point_sampling(&[[0.0; 3]], 1, 1).is_err());
        assert!(matches!(
            farthest_point_sampling(&[[f32::NAN, 0.0, 0.0]], 1, 0),
            Err(GeometryError::NonFinite(_))
        ));
    }
}
