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
//! and cost nothing. The caller and the helpers claim a job's parts from one atomic word, so a
//! helper that another process keeps off its core leaves its part to the caller rather than
//! stalling it. One caller uses the team at a time: a second concurrent caller, a call from
//! inside a job, or a call from a rayon worker (a scene group, or a pool that is already
//! parallel) runs its work alone on its own thread, so nothing nests or waits on the team.
//!
//! rayon (which the rest of the crate uses) has no setting to keep its workers spinning; the
//! fork-join pools that do (OpenMP-style) would be a second pool library for these few
//! splits.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicU64, AtomicUsize, Ordering};
use std::thread::Thread;
use std::time::{Duration, Instant};

/// How long an idle helper spins for the next job before it parks (a step's operations follow
/// each other within microseconds; steps of a stream are further apart).
pub const SPIN: Duration = Duration::from_micros(200);

/// A job: called with the part index.
type JobFn<'a> = &'a (dyn Fn(usize) + Sync);

struct Helper {
    thread: Thread,
    sleeping: AtomicBool,
}

/// The claim word: job number (bits 32..64), its part count (16..32) and the next unclaimed
/// part (0..16), changed together so that a part is only ever claimed for the job it belongs to.
#[derive(Clone, Copy)]
struct Claim(u64);

impl Claim {
    fn new(job: u32, parts: usize) -> Claim {
        Claim(((job as u64) << 32) | ((parts as u64) << 16))
    }
    fn job(self) -> u32 {
        (self.0 >> 32) as u32
    }
    fn parts(self) -> usize {
        ((self.0 >> 16) & 0xffff) as usize
    }
    fn next(self) -> usize {
        (self.0 & 0xffff) as usize
    }
}

struct Team {
    helpers: Vec<Helper>,
    /// Held by the one caller using the team.
    busy: AtomicBool,
    /// The current job's [`Claim`] word.
    claim: AtomicU64,
    /// The current job: a pointer to a [`JobFn`] on the caller's stack.
    job: AtomicPtr<()>,
    /// Parts of the current job finished.
    done: AtomicUsize,
    /// Set when a part panicked (the caller then panics too).
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
            claim: AtomicU64::new(0),
            job: AtomicPtr::new(std::ptr::null_mut()),
            done: AtomicUsize::new(0),
            panicked: AtomicBool::new(false),
        }));
        for (_, send) in started {
            let _ = send.send(team);
        }
        team
    })
}

/// A helper: wait for a new job (spinning, then parked), claim and run its parts while any are
/// left, repeat.
fn helper_loop(team: &'static Team, index: usize) {
    let me = &team.helpers[index - 1];
    let mut seen = 0u32;
    loop {
        let mut since = Instant::now();
        let mut spins = 0u32;
        while Claim(team.claim.load(Ordering::Acquire)).job() == seen {
            spins = spins.wrapping_add(1);
            if spins.is_multiple_of(32) {
                // Give the core to any other runnable thread (a rayon worker of a large
                // operation between two team jobs, another process): spinning through those
                // made a PhysiFormer call 15% slower. With nothing else to run this returns
                // at once.
                std::thread::yield_now();
            }
            if spins.is_multiple_of(256) && since.elapsed() > SPIN {
                me.sleeping.store(true, Ordering::SeqCst);
                if Claim(team.claim.load(Ordering::SeqCst)).job() == seen {
                    std::thread::park();
                }
                me.sleeping.store(false, Ordering::SeqCst);
                since = Instant::now();
            } else {
                std::hint::spin_loop();
            }
        }
        seen = Claim(team.claim.load(Ordering::Acquire)).job();
        run_parts(team, seen);
    }
}

/// Claims and runs parts of job `job` until none is left (or another job replaced it).
fn run_parts(team: &Team, job: u32) {
    loop {
        let c = Claim(team.claim.load(Ordering::Acquire));
        if c.job() != job || c.next() >= c.parts() {
            return;
        }
        let f = team.job.load(Ordering::Acquire) as *const JobFn<'static>;
        if team
            .claim
            .compare_exchange(c.0, c.0 + 1, Ordering::AcqRel, Ordering::Acquire)
            .is_err()
        {
            continue;
        }
        // SAFETY: the claim succeeded with part `c.next()` of `job` unclaimed until now, so
        // `job` could not have finished (its caller waits for every part) and no later job can
        // have replaced the pointer, which the caller published before the claim word; the
        // pointee lives until the caller has seen this part done.
        let ran = catch_unwind(AssertUnwindSafe(|| unsafe { (*f)(c.next()) }));
        if ran.is_err() {
            team.panicked.store(true, Ordering::SeqCst);
        }
        team.done.fetch_add(1, Ordering::AcqRel);
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

/// Calls `f(part, parts)` for every `part` in `0..parts` and returns when all are done. The
/// calling thread and the team's helpers claim parts one at a time, so a helper that is slow
/// to start (descheduled on a busy machine) leaves its part to the caller instead of stalling
/// it. `parts` is [`parts`] when the team is free, else 1 (then `f(0, 1)` runs alone). `f`
/// must split its work by `(part, parts)` so that parts never write the same memory.
///
/// # Panics
///
/// If a part panics (reported here, after every part finished).
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
    team.done.store(0, Ordering::Relaxed);
    team.job
        .store(&job_ref as *const JobFn<'_> as *mut (), Ordering::Release);
    let number = Claim(team.claim.load(Ordering::Relaxed))
        .job()
        .wrapping_add(1);
    team.claim
        .store(Claim::new(number, parts).0, Ordering::SeqCst);
    for h in &team.helpers {
        if h.sleeping.load(Ordering::SeqCst) {
            h.thread.unpark();
        }
    }
    run_parts(team, number);
    // Parts run under `catch_unwind`, so this wait is reached before `job` goes out of scope.
    while team.done.load(Ordering::Acquire) != parts {
        std::hint::spin_loop();
    }
    let panicked = team.panicked.load(Ordering::SeqCst);
    team.busy.store(false, Ordering::Release);
    if panicked {
        panic!("a part of a compute team job panicked");
    }
}

/// Multiply-adds from which a kernel splits one operation over the team (about a microsecond
/// of work: less is not worth a synchronisation).
pub const SPLIT_MIN_MACS: usize = 1 << 16;

/// `items.into_iter().map(f).collect()`, over rayon's pool when there are at least
/// `parallel_from` items and the pool has two threads or more, else on the calling thread in
/// order. (A parallel iterator called from outside the pool hands even a single item to a pool
/// worker and waits for it: a wake-up and a sleep per call, tens of microseconds.)
pub fn map_pooled<T: Send, U: Send>(
    items: Vec<T>,
    parallel_from: usize,
    f: impl Fn(T) -> U + Sync + Send,
) -> Vec<U> {
    use rayon::prelude::*;
    if items.len() < parallel_from.max(2) || rayon::current_num_threads() < 2 {
        items.into_iter().map(f).collect()
    } else {
        items.into_par_iter().map(f).collect()
    }
}

/// [`map_pooled`] over the indices `0..n`.
pub fn map_indices<T: Send>(
    n: usize,
    parallel_from: usize,
    f: impl Fn(usize) -> T + Sync + Send,
) -> Vec<T> {
    map_pooled((0..n).collect(), parallel_from, f)
}

/// `items.into_iter().map(f).collect()` with the items shared out over the team, contiguous
/// runs of them per part (all on this thread when the team is busy or off); results in item
/// order. Items may own disjoint `&mut` pieces of one buffer, which is how the kernels split
/// their outputs without raw pointers.
pub fn map_items<T: Send, U: Send>(items: Vec<T>, f: impl Fn(T) -> U + Sync) -> Vec<U> {
    use std::sync::Mutex;
    let n = items.len();
    let items: Vec<Mutex<Option<T>>> = items.into_iter().map(|t| Mutex::new(Some(t))).collect();
    let out: Vec<Mutex<Option<U>>> = (0..n).map(|_| Mutex::new(None)).collect();
    run(|part, parts| {
        for i in part_range(n, part, parts, 1) {
            // Each index belongs to exactly one part: the locks never wait.
            let item = items[i].lock().ok().and_then(|mut t| t.take());
            if let Some(item) = item {
                let y = f(item);
                if let Ok(mut slot) = out[i].lock() {
                    *slot = Some(y);
                }
            }
        }
    });
    out.into_iter()
        .map(|slot| {
            slot.into_inner()
                .ok()
                .flatten()
                .expect("every item was mapped by exactly one part")
        })
        .collect()
}

/// Calls `f(first_unit, piece)` on consecutive pieces of `out`, one per part of the team, each
/// a run of whole `unit`-value units (the last unit may be shorter) starting at unit
/// `first_unit`; the whole of `out` in one call when the team is busy or off.
pub fn split_mut<T: Send>(out: &mut [T], unit: usize, f: impl Fn(usize, &mut [T]) + Sync) {
    if out.is_empty() {
        return;
    }
    let unit = unit.max(1);
    let units = out.len().div_ceil(unit);
    let parts = parts().min(units).max(1);
    let mut pieces = Vec::with_capacity(parts);
    let mut rest = out;
    for part in 0..parts {
        let r = part_range(units, part, parts, 1);
        let len = (r.len() * unit).min(rest.len());
        let (piece, tail) = rest.split_at_mut(len);
        pieces.push((r.start, piece));
        rest = tail;
    }
    map_items(pieces, |(first, piece)| f(first, piece));
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
    fn items_map_in_order_and_pieces_cover_the_buffer_once() {
        let squares = map_items((0..37u64).collect(), |x| x * x);
        assert_eq!(squares, (0..37u64).map(|x| x * x).collect::<Vec<_>>());
        let pooled = map_indices(9, 2, |i| i + 1);
        assert_eq!(pooled, (1..10).collect::<Vec<_>>());
        for (len, unit) in [(100usize, 7usize), (64, 8), (3, 8), (0, 4)] {
            let mut out = vec![0u32; len];
            split_mut(&mut out, unit, |first, piece| {
                assert!(piece.len() <= len);
                for (j, v) in piece.iter_mut().enumerate() {
                    // The value each element gets from its own index: misplaced pieces show.
                    *v += (first * unit + j) as u32 + 1;
                }
            });
            assert_eq!(out, (1..=len as u32).collect::<Vec<_>>(), "{len} / {unit}");
        }
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
