//! A team of spinning helper threads that splits one small operation of a one-scene step
//! across the cores.
//!
//! A batch of several scenes runs as scene groups, one thread each ([`crate::scene_threads`]).
//! A single scene has nothing to split that way, and splitting each of its operations over
//! rayon's pool cost more than it saved: its products have 18-80 rows (5-40 µs of work), and a
//! rayon worker that finds no work goes to sleep, so every operation paid a wake-up. On these
//! 2-core machines a one-scene step ran no faster on two threads than on one.
//!
//! The team's helpers instead keep spinning for [`SPIN`] after each job, so the dozens of
//! operations of one step reach them within a fraction of a microsecond; after that they park
//! and cost nothing. One caller uses the team at a time: a second concurrent caller, a call
//! from inside a job, or a call from a rayon worker (a scene group, or a pool that is already
//! parallel) runs its work alone on its own thread, so nothing nests or waits on the team.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicUsize, Ordering};
use std::thread::Thread;
use std::time::{Duration, Instant};

/// How long an idle helper spins for the next job before it parks (a step's operations follow
/// each other within microseconds; steps of a stream are further apart).
pub const SPIN: Duration = Duration::from_micros(200);

/// A job: called with the part index (helpers run parts 1..).
type JobFn<'a> = &'a (dyn Fn(usize) + Sync);

struct Helper {
    thread: Thread,
    sleeping: AtomicBool,
}

struct Team {
    helpers: Vec<Helper>,
    /// Held by the one caller using the team.
    busy: AtomicBool,
    /// Incremented once per job; a helper runs a job when it sees a new value.
    epoch: AtomicUsize,
    /// The current job: a pointer to a [`JobFn`] on the caller's stack.
    job: AtomicPtr<()>,
    /// Helpers that have not finished the current job.
    pending: AtomicUsize,
    /// Set when a helper's part panicked (the caller then panics too).
    panicked: AtomicBool,
}

/// Whether callers may use the team (see [`set_enabled`]).
static ENABLED: AtomicBool = AtomicBool::new(true);

/// Allows (the default) or forbids splitting work over the team, process-wide; with it off
/// every operation runs on its caller's thread. Exists to compare the two.
pub fn set_enabled(on: bool) {
    ENABLED.store(on, Ordering::SeqCst);
}

/// The team: one helper per rayon thread beyond the caller's, started on first use.
fn team() -> &'static Team {
    static TEAM: OnceLock<&'static Team> = OnceLock::new();
    TEAM.get_or_init(|| {
        // Each helper waits for the finished team on its own channel, then serves it.
        let mut started = Vec::new();
        for i in 0..rayon::current_num_threads().saturating_sub(1) {
            let (send, receive) = std::sync::mpsc::channel::<&'static Team>();
            let spawned = std::thread::Builder::new()
                .name(format!("dynaserve-team-{}", i + 1))
                .spawn(move || {
                    if let Ok(team) = receive.recv() {
                        helper_loop(team, i + 1);
                    }
                });
            match spawned {
                Ok(handle) => started.push((handle.thread().clone(), send)),
                Err(_) => break,
            }
        }
        let team: &'static Team = Box::leak(Box::new(Team {
            helpers: started
                .iter()
                .map(|(thread, _)| Helper {
                    thread: thread.clone(),
                    sleeping: AtomicBool::new(false),
                })
                .collect(),
            busy: AtomicBool::new(false),
            epoch: AtomicUsize::new(0),
            job: AtomicPtr::new(std::ptr::null_mut()),
            pending: AtomicUsize::new(0),
            panicked: AtomicBool::new(false),
        }));
        for (_, send) in started {
            let _ = send.send(team);
        }
        team
    })
}

/// A helper: wait for a new epoch (spinning, then parked), run its part, report, repeat.
fn helper_loop(team: &'static Team, part: usize) {
    let me = &team.helpers[part - 1];
    let mut seen = 0usize;
    loop {
        let mut since = Instant::now();
        let mut spins = 0u32;
        loop {
            if team.epoch.load(Ordering::Acquire) != seen {
                break;
            }
            spins = spins.wrapping_add(1);
            if spins.is_multiple_of(256) && since.elapsed() > SPIN {
                me.sleeping.store(true, Ordering::SeqCst);
                if team.epoch.load(Ordering::SeqCst) == seen {
                    std::thread::park();
                }
                me.sleeping.store(false, Ordering::SeqCst);
                since = Instant::now();
            } else {
                std::hint::spin_loop();
            }
        }
        seen = team.epoch.load(Ordering::Acquire);
        let job = team.job.load(Ordering::Acquire) as *const JobFn<'static>;
        // SAFETY: the caller published a pointer to a live `JobFn` before the epoch changed
        // and keeps it alive until `pending` reaches zero, which this helper's decrement below
        // is part of.
        let ran = catch_unwind(AssertUnwindSafe(|| unsafe { (*job)(part) }));
        if ran.is_err() {
            team.panicked.store(true, Ordering::SeqCst);
        }
        team.pending.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Number of parts [`run`] would split into from this thread now: 1 + the helpers, or 1 when
/// the team is off, has no helpers, or the caller is a rayon worker.
pub fn parts() -> usize {
    if !ENABLED.load(Ordering::Relaxed) || rayon::current_thread_index().is_some() {
        return 1;
    }
    1 + team().helpers.len()
}

/// Releases the team (after the helpers finished) even if the caller's part panics.
struct Finish<'a>(&'a Team);

impl Drop for Finish<'_> {
    fn drop(&mut self) {
        while self.0.pending.load(Ordering::Acquire) != 0 {
            std::hint::spin_loop();
        }
        self.0.busy.store(false, Ordering::Release);
    }
}

/// Calls `f(part, parts)` for every `part` in `0..parts`, part 0 on the calling thread and the
/// others on the team's helpers at the same time, and returns when all are done. `parts` is
/// [`parts`] when the team is free, else 1 (then `f(0, 1)` runs alone). `f` must split its
/// work by `(part, parts)` so that parts never write the same memory.
///
/// # Panics
///
/// If a part panics (a helper's panic is reported here, after every part finished).
pub fn run(f: impl Fn(usize, usize) + Sync) {
    let parts = parts();
    if parts < 2 {
        return f(0, 1);
    }
    let team = team();
    if team
        .busy
        .compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed)
        .is_err()
    {
        return f(0, 1);
    }
    let job = |part: usize| f(part, parts);
    let job_ref: JobFn<'_> = &job;
    team.panicked.store(false, Ordering::Relaxed);
    team.pending.store(parts - 1, Ordering::Release);
    team.job
        .store(&job_ref as *const JobFn<'_> as *mut (), Ordering::Release);
    team.epoch.fetch_add(1, Ordering::SeqCst);
    for h in &team.helpers {
        if h.sleeping.load(Ordering::SeqCst) {
            h.thread.unpark();
        }
    }
    {
        // Waits for the helpers (and frees the team) on return or unwind, before `job` and
        // `job_ref` go out of scope.
        let _finish = Finish(team);
        f(0, parts);
    }
    if team.panicked.load(Ordering::SeqCst) {
        panic!("a compute team helper panicked");
    }
}

/// `(0..n).map(f).collect()`, over rayon's pool when there are at least `parallel_from`
/// items and the pool has two threads or more, else on the calling thread in order. (A
/// parallel iterator called from outside the pool hands even a single item to a pool worker
/// and waits for it: a wake-up and a sleep per call, tens of microseconds.)
pub fn map_indices<T: Send>(
    n: usize,
    parallel_from: usize,
    f: impl Fn(usize) -> T + Sync + Send,
) -> Vec<T> {
    use rayon::prelude::*;
    if n < parallel_from.max(2) || rayon::current_num_threads() < 2 {
        (0..n).map(f).collect()
    } else {
        (0..n).into_par_iter().map(f).collect()
    }
}

/// The `part`-th of `parts` contiguous ranges covering `0..len`, each (but the last) a
/// multiple of `align` long and the lengths as even as that allows.
pub fn part_range(len: usize, part: usize, parts: usize, align: usize) -> std::ops::Range<usize> {
    let align = align.max(1);
    let units = len.div_ceil(align);
    let parts = parts.max(1);
    let start = (units * part / parts * align).min(len);
    let end = (units * (part + 1) / parts * align).min(len);
    start..end
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    #[test]
    fn part_ranges_cover_in_order_and_align() {
        for (len, parts, align) in [
            (384usize, 2usize, 16usize),
            (130, 3, 16),
            (5, 4, 1),
            (0, 2, 8),
        ] {
            let r: Vec<_> = (0..parts)
                .map(|p| part_range(len, p, parts, align))
                .collect();
            assert_eq!(r[0].start, 0);
            assert_eq!(r.last().unwrap().end, len);
            assert!(r.windows(2).all(|w| w[0].end == w[1].start));
            assert!(r[..parts - 1].iter().all(|x| x.len() % align == 0));
        }
        assert_eq!(part_range(384, 1, 2, 16), 192..384);
    }

    #[test]
    fn every_part_runs_once_and_nested_calls_run_alone() {
        let seen = Mutex::new(Vec::new());
        for _ in 0..200 {
            seen.lock().unwrap().clear();
            run(|part, parts| {
                // A nested call finds the team busy (or is on a helper) and runs alone.
                let inner = AtomicUsize::new(0);
                run(|p, n| {
                    assert_eq!((p, n), (0, 1));
                    inner.fetch_add(1, Ordering::Relaxed);
                });
                assert_eq!(inner.load(Ordering::Relaxed), 1);
                seen.lock().unwrap().push((part, parts));
            });
            let mut s = seen.lock().unwrap().clone();
            s.sort();
            let parts = s[0].1;
            assert_eq!(s, (0..parts).map(|p| (p, parts)).collect::<Vec<_>>());
        }
    }

    #[test]
    fn concurrent_callers_and_parked_helpers_all_finish() {
        let total = AtomicUsize::new(0);
        std::thread::scope(|s| {
            for _ in 0..4 {
                s.spawn(|| {
                    for i in 0..50 {
                        run(|part, parts| {
                            let r = part_range(100, part, parts, 1);
                            total.fetch_add(r.len(), Ordering::Relaxed);
                        });
                        if i % 10 == 0 {
                            // Longer than the spin time: helpers park and must be woken.
                            std::thread::sleep(SPIN * 2);
                        }
                    }
                });
            }
        });
        assert_eq!(total.load(Ordering::Relaxed), 4 * 50 * 100);
    }

    #[test]
    fn a_helper_panic_reaches_the_caller_and_the_team_recovers() {
        let split = AtomicBool::new(false);
        let r = catch_unwind(AssertUnwindSafe(|| {
            run(|part, parts| {
                if parts > 1 {
                    split.store(true, Ordering::SeqCst);
                }
                if part == 1 {
                    panic!("part 1 fails");
                }
            })
        }));
        // Part 1 exists only when the team took the job (another test may hold it).
        assert_eq!(r.is_err(), split.load(Ordering::SeqCst));
        let count = AtomicUsize::new(0);
        run(|_, _| {
            count.fetch_add(1, Ordering::Relaxed);
        });
        assert!(count.load(Ordering::Relaxed) >= 1);
    }
}
