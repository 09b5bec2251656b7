//! The plan of an evaluation, fixed before any rollout: for every step size, the steps to roll
//! out, the horizons it can score (or why not), the resting window and the stability rollout.

use super::{EvalError, EvalOptions, RestingOptions};

#[derive(Clone, Debug)]
pub(super) struct HorizonPlan {
    pub(super) horizon_s: f64,
    pub(super) frames: Option<usize>,
    /// `Some(steps)` when evaluated.
    pub(super) steps: Option<usize>,
    pub(super) missing: Option<String>,
}

#[derive(Clone, Debug)]
pub(super) struct StepPlan {
    pub(super) k: u32,
    /// Steps to roll out (the largest horizon, the resting window, the long rollout), 0 when
    /// nothing is available.
    pub(super) steps: usize,
    /// Steps scored on the curve (those inside the data), at most `steps`.
    pub(super) curve_steps: usize,
    pub(super) horizons: Vec<HorizonPlan>,
    /// Why the resting drift is not available at this step size, if it is not.
    pub(super) rest_missing: Option<String>,
}

/// The resting-drift window `a..=b` (frames).
#[derive(Clone, Debug)]
pub(super) struct RestPlan {
    pub(super) options: RestingOptions,
    pub(super) a: usize,
    pub(super) b: usize,
}

#[derive(Clone, Debug)]
pub(super) struct Plans {
    pub(super) steps: Vec<StepPlan>,
    pub(super) rest: Option<RestPlan>,
    /// Steps of the long rollout (`k = 1`), when it runs.
    pub(super) long_steps: Option<usize>,
    /// Why the long rollout does not run, if it does not.
    pub(super) long_missing: Option<String>,
}

/// `seconds / dt_frame` as a whole number of frames, if it is one.
fn whole_frames(seconds: f64, dt_frame: f64) -> Option<usize> {
    let exact = seconds / dt_frame;
    let rounded = exact.round();
    ((exact - rounded).abs() <= 1e-6 * exact.max(1.0)).then_some(rounded as usize)
}

/// Which rollouts an evaluation needs and which horizons it can score, for data of `frames`
/// frames of `dt_frame` seconds; invalid options are an error, unreachable horizons are kept
/// with the reason they are missing.
pub(super) fn plan(opts: &EvalOptions, frames: usize, dt_frame: f64) -> Result<Plans, EvalError> {
    if opts.step_sizes.is_empty() || opts.horizons_s.is_empty() {
        return Err(EvalError::Invalid(
            "need at least one step size and one horizon".into(),
        ));
    }
    if opts.step_sizes.contains(&0) {
        return Err(EvalError::Invalid("step sizes must be at least 1".into()));
    }
    if let Some(h) = opts
        .horizons_s
        .iter()
        .find(|h| !(h.is_finite() && **h > 0.0))
    {
        return Err(EvalError::Invalid(format!(
            "horizons must be positive seconds, got {h}"
        )));
    }
    if !(dt_frame.is_finite() && dt_frame > 0.0) {
        return Err(EvalError::Invalid(format!(
            "dt_frame must be positive, got {dt_frame}"
        )));
    }
    let s = opts.start_frame;
    if s >= frames {
        return Err(EvalError::Invalid(format!(
            "start frame {s} is beyond the data ({frames} frames)"
        )));
    }
    let last = frames - 1;
    let rest = match &opts.resting {
        None => None,
        Some(r) => {
            if !(r.window_s.is_finite()
                && r.window_s > 0.0
                && r.max_speed_m_s >= 0.0
                && r.max_angular_speed_deg_s >= 0.0)
            {
                return Err(EvalError::Invalid(format!(
                    "resting window and thresholds must be positive, got {r:?}"
                )));
            }
            let w = whole_frames(r.window_s, dt_frame).ok_or_else(|| {
                EvalError::Invalid(format!(
                    "resting window {} s is not a whole number of frames of {dt_frame} s",
                    r.window_s
                ))
            })?;
            // The window must lie after the start frame to be predicted at all.
            (w >= 1 && last >= s + w).then(|| RestPlan {
                options: r.clone(),
                a: last - w,
                b: last,
            })
        }
    };
    let (long_steps, long_missing) = match (opts.long_rollout_steps, s) {
        (0, _) => (None, Some("disabled".to_string())),
        (_, 0) => (
            None,
            Some("start frame 0 has no earlier frame for k = 1".to_string()),
        ),
        (n, _) => (Some(n), None),
    };
    let steps = opts
        .step_sizes
        .iter()
        .map(|&k| {
            let ku = k as usize;
            let horizons: Vec<HorizonPlan> = opts
                .horizons_s
                .iter()
                .map(|&horizon_s| {
                    let frames_h = whole_frames(horizon_s, dt_frame);
                    let missing = match frames_h {
                        None => Some(format!(
                            "{horizon_s} s is {:.3} frames of {dt_frame} s, not a whole number",
                            horizon_s / dt_frame
                        )),
                        Some(_) if ku > s => {
                            Some(format!("step size {k} needs frame {s} - {k} < 0"))
                        }
                        Some(h) if h % ku != 0 => {
                            Some(format!("{h} frames is not a multiple of the step size {k}"))
                        }
                        Some(h) if s + h > last => {
                            Some(format!("frame {s} + {h} is beyond the last frame {last}"))
                        }
                        Some(_) => None,
                    };
                    HorizonPlan {
                        horizon_s,
                        frames: frames_h,
                        steps: match (missing.is_none(), frames_h) {
                            (true, Some(h)) => Some(h / ku),
                            _ => None,
                        },
                        missing,
                    }
                })
                .collect();
            let mut steps = horizons.iter().filter_map(|h| h.steps).max().unwrap_or(0);
            let rest_missing = match &rest {
                None => Some("no resting window".to_string()),
                Some(_) if ku > s => Some(format!("step size {k} needs frame {s} - {k} < 0")),
                Some(r) if !(r.a - s).is_multiple_of(ku) || !(r.b - s).is_multiple_of(ku) => {
                    Some(format!(
                        "frames {} and {} are not reached in steps of {k} from frame {s}",
                        r.a, r.b
                    ))
                }
                Some(r) => {
                    steps = steps.max((r.b - s) / ku);
                    None
                }
            };
            if k == 1 {
                steps = steps.max(long_steps.unwrap_or(0));
            }
            let curve_steps = if ku > s || steps == 0 {
                0
            } else {
                steps.min((last - s) / ku)
            };
            StepPlan {
                k,
                steps: if ku > s { 0 } else { steps },
                curve_steps,
                horizons,
                rest_missing,
            }
        })
        .collect();
    Ok(Plans {
        steps,
        rest,
        long_steps,
        long_missing,
    })
}
