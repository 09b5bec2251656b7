//! Seconds flags: their check and their conversion to a duration, shared by every flag group.

use std::time::Duration;

/// A non-negative number of seconds as a duration; `None` for 0 (disabled). Callers validate
/// first; out-of-range values are clamped to a day.
pub(crate) fn secs(s: f64) -> Option<Duration> {
    if s.is_finite() && s > 0.0 {
        Some(Duration::from_secs_f64(s.min(86_400.0)))
    } else {
        None
    }
}

/// Checks that a seconds flag is a finite number >= 0.
pub(crate) fn check_secs(name: &str, s: f64) -> Result<(), String> {
    if s.is_finite() && s >= 0.0 {
        Ok(())
    } else {
        Err(format!("{name} must be a finite number >= 0"))
    }
}
