//! Scene-parallel execution of a batched step on the CPU: the batch is cut into as many
//! groups of whole scenes as the process has compute threads (balanced by object count), and
//! each group runs its passes on a one-thread pool of its own, all groups at once.
//!
//! Splitting each operation across threads instead (candle's and our kernels' row blocks)
//! pays a synchronisation of the pool per operation, several hundred per step, on matrices
//! of a few dozen rows: on these 2-core machines two threads gave 1.1-1.2x one thread's
//! throughput. Inside a group every operation sees a pool of one thread and runs on the
//! calling thread; groups share nothing but the weights (read-only).

use std::ops::Range;
use std::sync::OnceLock;

/// Cuts `objects` (objects per scene, in batch order) into at most `parts` consecutive,
/// non-empty ranges of scenes whose object sums are as even as a cut between scenes allows.
pub fn balanced_ranges(objects: &[usize], parts: usize) -> Vec<Range<usize>> {
    let n = objects.len();
    let parts = parts.clamp(1, n.max(1));
    if n == 0 {
        return Vec::new();
    }
    let total: usize = objects.iter().map(|&o| o.max(1)).sum();
    let mut ranges = Vec::with_capacity(parts);
    let (mut start, mut acc) = (0usize, 0usize);
    for (i, &o) in objects.iter().enumerate() {
        acc += o.max(1);
        let cut = ranges.len() + 1;
        // Close the current range once it reaches its share, or when every scene left is
        // needed to give each remaining range one.
        let left = n - (i + 1);
        if cut < parts && left >= parts - cut && (acc * parts >= cut * total || left == parts - cut)
        {
            ranges.push(start..i + 1);
            start = i + 1;
        }
    }
    ranges.push(start..n);
    ranges
}

/// One single-thread rayon pool per compute thread of the process, built on first use.
fn pools() -> &'static [rayon::ThreadPool] {
    static POOLS: OnceLock<Vec<rayon::ThreadPool>> = OnceLock::new();
    POOLS.get_or_init(|| {
        (0..rayon::current_num_threads())
            .filter_map(|i| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(1)
                    .thread_name(move |_| format!("dynaserve-scenes-{i}"))
                    .build()
                    .ok()
            })
            .collect()
    })
}

/// Number of scene groups a batch of `scenes` would run as: the calling pool's thread count
/// (1 inside a one-thread pool, so groups never nest), at most one group per scene.
pub fn groups_for(scenes: usize) -> usize {
    rayon::current_num_threads().min(scenes).max(1)
}

/// Runs `f` on every range of [`balanced_ranges`]`(objects, groups_for(objects.len()))`,
/// concurrently on the one-thread pools, and concatenates the results in batch order. With a
/// single group `f` runs on the calling thread. The first error is returned.
pub fn run_scene_groups<T, E, F>(objects: &[usize], f: F) -> Result<Vec<T>, E>
where
    T: Send,
    E: Send,
    F: Fn(Range<usize>) -> Result<Vec<T>, E> + Sync,
{
    use rayon::prelude::*;
    let groups = groups_for(objects.len());
    if groups < 2 {
        return f(0..objects.len());
    }
    let pools = pools();
    let ranges = balanced_ranges(objects, groups.min(pools.len()));
    let parts: Vec<Result<Vec<T>, E>> = ranges
        .into_par_iter()
        .zip(pools.par_iter())
        .map(|(r, pool)| pool.install(|| f(r)))
        .collect();
    let mut out = Vec::with_capacity(objects.len());
    for p in parts {
        out.extend(p?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_cover_the_batch_in_order_and_balance_objects() {
        let r = balanced_ranges(&[10, 10, 10, 10], 2);
        assert_eq!(r, vec![0..2, 2..4]);
        let r = balanced_ranges(&[217, 3, 3, 3], 2);
        assert_eq!(r, vec![0..1, 1..4]);
        let r = balanced_ranges(&[1, 1, 1, 30], 2);
        assert_eq!(r, vec![0..3, 3..4]);
        assert_eq!(balanced_ranges(&[5], 4), vec![0..1]);
        assert_eq!(balanced_ranges(&[2, 2, 2], 8), vec![0..1, 1..2, 2..3]);
        assert!(balanced_ranges(&[], 2).is_empty());
        for (objects, parts) in [(vec![3, 9, 1, 4, 4, 7, 2], 3usize), (vec![0, 0, 5], 2)] {
            let r = balanced_ranges(&objects, parts);
            assert_eq!(r.len(), parts);
            assert_eq!(r[0].start, 0);
            assert_eq!(r.last().unwrap().end, objects.len());
            assert!(r.windows(2).all(|w| w[0].end == w[1].start));
            assert!(r.iter().all(|x| !x.is_empty()));
        }
    }

    #[test]
    fn groups_run_concurrently_in_batch_order_and_errors_surface() {
        let objects = vec![4usize; 9];
        let out: Vec<usize> =
            run_scene_groups(&objects, |r| Ok::<_, String>(r.collect::<Vec<_>>())).unwrap();
        assert_eq!(out, (0..9).collect::<Vec<_>>());
        // Inside a group, operations see a one-thread pool.
        let inner: Vec<usize> = run_scene_groups(&objects, |r| {
            Ok::<_, String>(vec![rayon::current_num_threads(); r.len()])
        })
        .unwrap();
        if rayon::current_num_threads() > 1 {
            assert!(inner.iter().all(|&t| t == 1), "{inner:?}");
        }
        let err = run_scene_groups(&objects, |r| {
            if r.contains(&8) {
                Err("scene 8".to_string())
            } else {
                Ok(r.collect::<Vec<_>>())
            }
        });
        assert_eq!(err.unwrap_err(), "scene 8");
    }
}
