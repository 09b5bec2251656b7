//! Process-wide compute settings for CPU inference and training: candle's thread counts and
//! the compute team's switch.
//!
//! candle sizes its CPU kernels from two environment variables: `RAYON_NUM_THREADS` (the
//! parallelism it hands to every matrix multiplication) and `CANDLE_NUM_THREADS` (its pool for
//! element-wise and reduction kernels). When `RAYON_NUM_THREADS` is unset, candle 0.11 derives
//! the count anew on every matrix multiplication, by parsing `/proc/cpuinfo` on Linux: a file
//! read and a few hundred lines of text per matmul, which made a one-scene step of the small
//! model several times slower than its arithmetic. [`configure_compute`] fixes both
//! variables once at start-up so the lookup is a cheap environment read.
//!
//! The binaries allocate with mimalloc, which by default hands freed memory back to the
//! operating system a second after it is freed. A step allocates and frees tens of megabytes
//! of intermediate tensors, so memory went back and forth: about 400 page faults per batch-8
//! step, each zeroing a fresh (often 2 MiB) page in the kernel, 4-8% of a profiled step.
//! [`keep_freed_memory`] lengthens the delay so a running server or training job reuses its
//! pages; an idle process still returns them.

/// Environment variable candle reads for the matmul parallelism (also rayon's global pool size).
pub const RAYON_THREADS_VAR: &str = "RAYON_NUM_THREADS";
/// Environment variable candle reads for its element-wise kernel pool.
pub const CANDLE_THREADS_VAR: &str = "CANDLE_NUM_THREADS";

/// Environment variable that switches the compute team ([`crate::team`]) off when set to `0`,
/// `off` or `false`: a one-scene step then keeps its small operations on the calling thread
/// and no helper spins between them (for machines shared with other work, or where CPU
/// utilisation should track the work done).
pub const TEAM_VAR: &str = "DYNASERVE_COMPUTE_TEAM";

/// Number of threads the process would use by default: the available parallelism (cores
/// allowed by the CPU affinity mask and cgroup quota), at least 1.
pub fn default_compute_threads() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
}

/// Element-wise kernel threads for a training process: the cores left once the data loader
/// has one, at least 1 (1 on a 2-core machine).
///
/// candle's element-wise pool runs `CANDLE_NUM_THREADS - 1` helper threads that spin between
/// kernels. A training process also prepares its next batches (normals, neighbour search,
/// grouping) on a loader thread, so on a small machine a helper spins on the core the loader
/// needs. Measured on 2 cores (`rigidformer-small-r77.toml`, 150 iterations, five alternating
/// pairs): without the helper a run takes 0.85x the wall time and 0.79x the CPU time.
pub fn training_elementwise_threads() -> usize {
    default_compute_threads().saturating_sub(1).max(1)
}

/// Sets `RAYON_NUM_THREADS` and `CANDLE_NUM_THREADS` to `threads` (or, when `None`, to
/// [`default_compute_threads`]) unless the variable is already set to a positive integer,
/// switches the compute team off when [`TEAM_VAR`] says so, and returns the matmul
/// parallelism in effect. Explicit environment settings always win, so
/// operators can still tune the two pools separately.
///
/// # Safety
///
/// Mutates the process environment: call it at the very start of `main`, before any other
/// thread exists (in particular before a tokio runtime or a rayon pool is built), as
/// [`std::env::set_var`] requires.
pub unsafe fn configure_compute(threads: Option<usize>) -> usize {
    // SAFETY: the caller's guarantee, passed on.
    unsafe { configure_compute_split(threads, threads) }
}

/// [`configure_compute`] with its own count for candle's element-wise pool (`elementwise`,
/// `CANDLE_NUM_THREADS`; `None`: the matmul count), e.g. [`training_elementwise_threads`]
/// for a training process. Returns the matmul parallelism in effect.
///
/// # Safety
///
/// As [`configure_compute`]: call it before any other thread exists.
pub unsafe fn configure_compute_split(matmul: Option<usize>, elementwise: Option<usize>) -> usize {
    let counts = wanted_counts(matmul, elementwise);
    let wanted = counts[0].1;
    for (var, n) in counts {
        if parse_positive(std::env::var(var).ok().as_deref()).is_none() {
            // SAFETY: the caller guarantees no other thread is running (see above).
            unsafe { std::env::set_var(var, n.to_string()) };
        }
    }
    if team_switched_off(std::env::var(TEAM_VAR).ok().as_deref()) {
        crate::team::set_enabled(false);
    }
    parse_positive(std::env::var(RAYON_THREADS_VAR).ok().as_deref()).unwrap_or(wanted)
}

/// The counts [`configure_compute_split`] gives `RAYON_NUM_THREADS` and `CANDLE_NUM_THREADS`
/// (in that order) where the environment does not already set them: `matmul` or
/// [`default_compute_threads`], and `elementwise` or the matmul count (zero counts as absent).
fn wanted_counts(matmul: Option<usize>, elementwise: Option<usize>) -> [(&'static str, usize); 2] {
    let matmul = matmul
        .filter(|&n| n > 0)
        .unwrap_or_else(default_compute_threads);
    let elementwise = elementwise.filter(|&n| n > 0).unwrap_or(matmul);
    [
        (RAYON_THREADS_VAR, matmul),
        (CANDLE_THREADS_VAR, elementwise),
    ]
}

/// Whether a [`TEAM_VAR`] value switches the team off (`0`, `off`, `false`, any case).
fn team_switched_off(value: Option<&str>) -> bool {
    value.is_some_and(|v| {
        matches!(
            v.trim().to_ascii_lowercase().as_str(),
            "0" | "off" | "false"
        )
    })
}

/// mimalloc's option number for the purge delay (`mi_option_purge_delay` in `mimalloc.h`; the
/// same in its v2 and v3 series, and not among the constants `libmimalloc-sys` exports).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Delay before freed memory goes back to the OS, milliseconds, that [`keep_freed_memory`]
/// sets: long against a step (milliseconds), short against an idle server's lifetime.
pub const FREED_MEMORY_DELAY_MS: i64 = 10_000;

/// Makes mimalloc keep freed memory for [`FREED_MEMORY_DELAY_MS`] before returning it to the
/// operating system, unless `MIMALLOC_PURGE_DELAY` is set (an operator's setting wins). Only
/// affects processes whose global allocator is mimalloc (the `dynaserve` binaries); harmless
/// elsewhere.
pub fn keep_freed_memory() {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: sets one integer option; mimalloc reads options atomically at purge time.
        unsafe {
            libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, FREED_MEMORY_DELAY_MS as _)
        };
    }
}

/// Parses a positive thread count the way candle does (`None` for unset, zero or garbage).
fn parse_positive(value: Option<&str>) -> Option<usize> {
    value
        .and_then(|s| s.trim().parse::<usize>().ok())
        .filter(|&n| n > 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_like_candle() {
        assert_eq!(parse_positive(Some("3")), Some(3));
        assert_eq!(parse_positive(Some(" 2 ")), Some(2));
        assert_eq!(parse_positive(Some("0")), None);
        assert_eq!(parse_positive(Some("many")), None);
        assert_eq!(parse_positive(None), None);
        assert!(default_compute_threads() >= 1);
    }

    #[test]
    fn training_leaves_the_loader_a_core() {
        let cores = default_compute_threads();
        let n = training_elementwise_threads();
        assert!(n >= 1);
        assert_eq!(n, if cores > 1 { cores - 1 } else { 1 });
    }

    #[test]
    fn the_elementwise_count_follows_the_matmul_count_unless_given() {
        let cores = default_compute_threads();
        let counts = |m, e| wanted_counts(m, e).map(|(_, n)| n);
        assert_eq!(wanted_counts(None, None)[0].0, RAYON_THREADS_VAR);
        assert_eq!(wanted_counts(None, None)[1].0, CANDLE_THREADS_VAR);
        assert_eq!(counts(None, None), [cores, cores]);
        assert_eq!(counts(Some(3), None), [3, 3]);
        assert_eq!(counts(Some(3), Some(1)), [3, 1]);
        assert_eq!(counts(None, Some(1)), [cores, 1]);
        assert_eq!(counts(Some(0), Some(0)), [cores, cores]);
    }

    #[test]
    fn team_switch_reads_off_values_only() {
        for off in ["0", "off", "OFF", " false "] {
            assert!(team_switched_off(Some(off)), "{off}");
        }
        for on in ["1", "on", "", "yes"] {
            assert!(!team_switched_off(Some(on)), "{on}");
        }
        assert!(!team_switched_off(None));
    }

    #[test]
    fn freed_memory_delay_reaches_mimalloc() {
        if std::env::var_os("MIMALLOC_PURGE_DELAY").is_some() {
            return; // an operator's setting is kept; nothing of ours to check
        }
        keep_freed_memory();
        // SAFETY: reads one integer option.
        let got = unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) };
        assert_eq!(got as i64, FREED_MEMORY_DELAY_MS);
    }
}
