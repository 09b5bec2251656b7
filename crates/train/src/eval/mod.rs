//! Evaluation core: autoregressive rollouts from two observed frames, scored at fixed physical
//! horizons. Every predictor (the baselines here, learned models through [`ModelPredictor`])
//! runs through exactly this code path; `docs/evaluation.md` describes the protocol and every
//! metric for readers of the reports.
//!
//! # Protocol
//!
//! For each scene and each step size `k` (frames): the predictor observes the poses at frames
//! `s - k` and `s`, where the start frame `s` is the same for every step size (default
//! [`DEFAULT_START_FRAME`] = 4, so `k` up to 4 fits), and rolls forward autoregressively in
//! steps of `k` frames. Its prediction after `h / k` steps is compared with the ground truth at
//! frame `s + h`, for the horizons `H` in seconds (default 0.5, 1, 2, 4 s; `h = H / dt_frame`,
//! so 12, 24, 48, 96 frames at 24 fps).
//!
//! A horizon is reported as missing, with the reason, never shifted to a nearby frame, when
//! `H / dt_frame` is not a whole number of frames, when `h` is not a multiple of `k`, when
//! `s + h` is beyond the last frame, or when `s - k < 0`.
//!
//! # Metrics (pooled)
//!
//! At each (step size, horizon): centre-of-mass translation RMSE in metres,
//! `sqrt(sum |p_pred - p_true|^2 / N)`, and orientation RMSE in degrees,
//! `sqrt(sum theta^2 / N)` with the geodesic angle `theta = 2 acos |<q_pred, q_true>|`, where
//! the sums run over all `N` objects of all scenes: the RMSE over the pool of objects, not the
//! mean of per-scene RMSEs (scenes with more objects weigh more). Sums are reduced in scene
//! order, so reports are reproducible bit for bit. The same RMSEs at every step inside the data
//! form the error-against-time curves ([`CurvePoint`]).
//!
//! Besides the errors, each report carries (see the types for the exact definitions):
//! - [`LongRolloutReport`]: a `k = 1` rollout of [`EvalOptions::long_rollout_steps`] steps
//!   (default 100, past the end of the data if need be) checked for finite poses and unit
//!   quaternions, plus the rigidity of the pose output (pairwise distances of transformed
//!   reference points) and, for RigidFormer, the pre-projection rigidity residual;
//! - [`RestingReport`]: the drift of the predicted poses over the last second of the data for
//!   the objects that are at rest in the ground truth.
//!
//! The physics scenario suite (`--suite physics`) is separate: [`physics_suite`] scores
//! scenario figures ([`scenario_figures`]) and one-step errors by contact regime ([`regimes`]).

pub mod baselines;
pub mod model;
pub mod physics_report;
pub mod physics_suite;
pub mod plot;
pub mod regimes;
pub mod report;
pub mod scenario_figures;
pub mod suite_cli;

use std::time::Instant;

use dynaserve_geometry::geodesic_angle;
use dynaserve_geometry::metrics::{RmseAccumulator, squared_distance};
use dynaserve_model::{Pose, SceneState};
use dynaserve_sim::{DatasetReader, SceneRecord};
use nalgebra::{Quaternion, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub use baselines::{Ballistic, Static};
pub use model::{ModelPredictor, Occlusion, PointSelection};
pub use plot::{PlotStyle, plot_errors};
pub use report::{SuiteEntry, SuiteReport, format_markdown, format_suite};

/// Start frame `s` shared by all step sizes (the second observed frame).
pub const DEFAULT_START_FRAME: usize = 4;
/// Physical horizons in seconds after the start frame.
pub const DEFAULT_HORIZONS_S: [f64; 4] = [0.5, 1.0, 2.0, 4.0];
/// Step sizes in frames.
pub const DEFAULT_STEP_SIZES: [u32; 3] = [1, 2, 4];

/// Scenes evaluated per parallel batch when streaming a dataset.
const BATCH: usize = 16;

/// Errors of an evaluation; each says what and where.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Options or data that cannot be evaluated.
    #[error("evaluation: {0}")]
    Invalid(String),
    /// Dataset I/O failed.
    #[error(transparent)]
    Sim(#[from] dynaserve_sim::SimError),
    /// A learned model failed or rejected its input.
    #[error(transparent)]
    Model(#[from] dynaserve_model::ModelError),
    /// A predictor returned something unusable.
    #[error("predictor {predictor}, scene {scene}: {message}")]
    Predictor {
        /// Predictor name.
        predictor: String,
        /// Scene index in evaluation order.
        scene: usize,
        /// What was wrong.
        message: String,
    },
}

/// Anything that can roll a scene forward: baselines and learned world models alike.
///
/// `observed` holds the poses at frames `s - dt_steps` (`previous`) and `s` (`current`); the
/// result is `[steps][objects]`, entry `i` being the poses `(i + 1) * dt_steps` frames after
/// `s`. `scene` gives access to the reference clouds and physical parameters (never to the
/// future frames: predictors must not read `positions`/`rotations` beyond frame `s`, which the
/// evaluator cannot enforce; the baselines and [`ModelPredictor`] do not read them at all).
pub trait Predictor: Sync {
    /// Name for reports (a baseline name or the model's checkpoint name and input variant).
    fn name(&self) -> String;
    /// Rolls `scene` forward `steps` steps of `dt_steps` frames from `observed`.
    fn rollout(
        &self,
        scene: &SceneRecord,
        observed: &SceneState,
        dt_steps: u32,
        steps: usize,
    ) -> Result<Vec<Vec<Pose>>, EvalError>;

    /// Many independent rollouts; entry `i` of the result answers `requests[i]` exactly as
    /// [`Predictor::rollout`] would. The default runs the requests in parallel one by one;
    /// learned models override it to advance all requests together in batched steps.
    fn rollout_batch(
        &self,
        requests: &[RolloutRequest<'_>],
    ) -> Result<Vec<Vec<Vec<Pose>>>, EvalError> {
        requests
            .par_iter()
            .map(|r| self.rollout(r.scene, &r.observed, r.dt_steps, r.steps))
            .collect()
    }

    /// Rigidity residual before the projection to a rigid motion, for predictors that have
    /// one: for each window (a state and the predictor's own next poses) and each object, the
    /// root-mean-square distance in metres between the predicted points before projection and
    /// their rigid projection. Result `[windows * objects]`, window-major, or `None` when the
    /// predictor has no such intermediate (the baselines).
    fn projection_residuals(
        &self,
        scene: &SceneRecord,
        windows: &[ProjectionWindow],
    ) -> Result<Option<Vec<f64>>, EvalError> {
        let _ = (scene, windows);
        Ok(None)
    }
}

/// One rollout for [`Predictor::rollout_batch`].
#[derive(Clone, Debug)]
pub struct RolloutRequest<'a> {
    /// The scene (reference clouds and parameters).
    pub scene: &'a SceneRecord,
    /// Poses at frames `s - dt_steps` and `s`.
    pub observed: SceneState,
    /// Step size in frames.
    pub dt_steps: u32,
    /// Number of steps.
    pub steps: usize,
}

/// One step of a rollout for [`Predictor::projection_residuals`]: the input state and the
/// poses the predictor returned from it.
#[derive(Clone, Debug)]
pub struct ProjectionWindow {
    /// The two most recent poses per object.
    pub state: SceneState,
    /// The predicted poses `dt_steps` frames after `state.current`, `[objects]`.
    pub next: Vec<Pose>,
    /// Step size in frames.
    pub dt_steps: u32,
}

/// What to evaluate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalOptions {
    /// Start frame `s` (second observed frame), shared by all step sizes.
    pub start_frame: usize,
    /// Step sizes `k` in frames, each `>= 1`.
    pub step_sizes: Vec<u32>,
    /// Horizons in seconds after frame `s`, each `> 0`.
    pub horizons_s: Vec<f64>,
    /// Evaluate only the first `n` scenes.
    pub max_scenes: Option<usize>,
    /// Steps of the `k = 1` stability rollout from frame `s` (0 disables it); it may run past
    /// the end of the data.
    pub long_rollout_steps: usize,
    /// Check the pre-projection rigidity residual at every `n`-th state of the stability
    /// rollout (0 disables it; only predictors that expose it report it).
    pub projection_every: usize,
    /// Resting-drift settings; `None` disables the resting-drift report.
    pub resting: Option<RestingOptions>,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            start_frame: DEFAULT_START_FRAME,
            step_sizes: DEFAULT_STEP_SIZES.to_vec(),
            horizons_s: DEFAULT_HORIZONS_S.to_vec(),
            max_scenes: None,
            long_rollout_steps: DEFAULT_LONG_ROLLOUT_STEPS,
            projection_every: DEFAULT_PROJECTION_EVERY,
            resting: Some(RestingOptions::default()),
        }
    }
}

/// Which objects count as at rest in the ground truth, and over which window the drift of the
/// prediction is measured.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RestingOptions {
    /// Window length in seconds, ending at the last frame (a whole number of frames).
    pub window_s: f64,
    /// An object is at rest when its centre-of-mass speed between every pair of consecutive
    /// frames of the window is below this, m/s.
    pub max_speed_m_s: f64,
    /// ... and its angular speed between consecutive frames is below this, degrees/s.
    pub max_angular_speed_deg_s: f64,
}

impl Default for RestingOptions {
    fn default() -> Self {
        RestingOptions {
            window_s: 1.0,
            max_speed_m_s: 0.01,
            max_angular_speed_deg_s: 1.0,
        }
    }
}

/// Default length of the stability rollout, steps of one frame.
pub const DEFAULT_LONG_ROLLOUT_STEPS: usize = 100;
/// Default stride of the pre-projection rigidity check along the stability rollout.
pub const DEFAULT_PROJECTION_EVERY: usize = 4;
/// Largest accepted deviation of a predicted quaternion's norm from 1.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-4;
/// Reference points per object (the first ones of the cloud) whose pairwise distances are
/// compared with the transformed points in the pose-rigidity check.
pub const PAIRWISE_POINTS: usize = 16;

/// Result at one (step size, horizon).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HorizonReport {
    /// Horizon in seconds after the start frame.
    pub horizon_s: f64,
    /// Horizon in frames, when it is a whole number of frames.
    pub frames: Option<usize>,
    /// Rollout steps to reach it (`frames / dt_steps`), when available.
    pub steps: Option<usize>,
    /// Pooled centre-of-mass translation RMSE, metres; `None` when missing.
    pub translation_rmse_m: Option<f64>,
    /// Pooled geodesic orientation RMSE, degrees; `None` when missing.
    pub orientation_rmse_deg: Option<f64>,
    /// Number of objects pooled.
    pub objects: u64,
    /// Why the horizon is missing, if it is.
    pub missing: Option<String>,
}

/// Pooled errors after one rollout step (for error-against-time curves).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CurvePoint {
    /// Time after the start frame, seconds.
    pub time_s: f64,
    /// Frames after the start frame.
    pub frames: usize,
    /// Pooled translation RMSE, metres.
    pub translation_rmse_m: f64,
    /// Pooled orientation RMSE, degrees.
    pub orientation_rmse_deg: f64,
}

/// Results of one step size.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepSizeReport {
    /// Step size in frames.
    pub dt_steps: u32,
    /// One entry per requested horizon, in the requested order.
    pub horizons: Vec<HorizonReport>,
    /// The pooled errors after every step that lands inside the data.
    pub curve: Vec<CurvePoint>,
}

/// Mean and maximum of a non-negative quantity over a set of samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Stat {
    /// Mean over the samples (0 when there are none).
    pub mean: f64,
    /// Maximum over the samples (0 when there are none).
    pub max: f64,
    /// Number of samples.
    pub count: u64,
}

#[derive(Clone, Copy, Debug, Default)]
struct StatAcc {
    sum: f64,
    max: f64,
    count: u64,
}

impl StatAcc {
    fn add(&mut self, x: f64) {
        self.sum += x;
        self.max = self.max.max(x);
        self.count += 1;
    }
    fn merge(&mut self, o: &StatAcc) {
        self.sum += o.sum;
        self.max = self.max.max(o.max);
        self.count += o.count;
    }
    fn stat(&self) -> Stat {
        Stat {
            mean: if self.count > 0 {
                self.sum / self.count as f64
            } else {
                0.0
            },
            max: self.max,
            count: self.count,
        }
    }
}

/// Stability and rigidity of a `k = 1` rollout of many steps from the start frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LongRolloutReport {
    /// Step size, frames (always 1).
    pub dt_steps: u32,
    /// Steps per scene.
    pub steps: usize,
    /// Objects checked (every object of every scene).
    pub objects: u64,
    /// Objects with at least one pose that is not finite or whose quaternion norm differs
    /// from 1 by more than [`QUATERNION_NORM_TOLERANCE`].
    pub failed_objects: u64,
    /// Scenes with at least one failed object.
    pub failed_scenes: u64,
    /// Objects with a non-finite pose (a subset of the failures).
    pub non_finite_objects: u64,
    /// Largest `| |q| - 1 |` over all finite predicted quaternions.
    pub max_quaternion_norm_error: f64,
    /// Pose rigidity: the largest `| |R x_a + p - (R x_b + p)| - |x_a - x_b| |`, metres, over
    /// all steps, objects and pairs of the object's first [`PAIRWISE_POINTS`] reference
    /// points, with `R x` computed from the raw predicted quaternion as `q x q*` (so a
    /// non-unit quaternion shows up as a scaled distance).
    pub max_pairwise_deviation_m: f64,
    /// Pre-projection rigidity residual (see [`Predictor::projection_residuals`]) in metres at
    /// every [`EvalOptions::projection_every`]-th state of the rollout, over objects and
    /// states; `None` for predictors without a projection.
    pub projection_residual_m: Option<Stat>,
    /// Why the check did not run, if it did not.
    pub missing: Option<String>,
}

/// Drift of one predictor over the resting window at one step size.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DriftReport {
    /// Step size in frames (0 for the ground truth).
    pub dt_steps: u32,
    /// `|p(b) - p(a)|` over the resting objects, metres.
    pub translation_m: Option<Stat>,
    /// Geodesic angle between `q(a)` and `q(b)` over the resting objects, degrees.
    pub rotation_deg: Option<Stat>,
    /// Why it is missing, if it is.
    pub missing: Option<String>,
}

/// Drift of the predicted poses over the last second of the data, for objects that are at rest
/// in the ground truth over that window.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RestingReport {
    /// The settings.
    pub options: RestingOptions,
    /// First frame `a` of the window (`T - 1 - window frames`).
    pub first_frame: usize,
    /// Last frame `b` of the window (`T - 1`).
    pub last_frame: usize,
    /// Objects at rest in the ground truth over the window.
    pub objects_at_rest: u64,
    /// All objects evaluated.
    pub objects: u64,
    /// The same measure on the ground truth (below the thresholds by construction).
    pub truth: DriftReport,
    /// The prediction, one entry per step size.
    pub predicted: Vec<DriftReport>,
}

/// A full evaluation report of one predictor (what `dynaserve eval --baseline --json` writes).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Predictor name.
    pub predictor: String,
    /// Dataset directory, generator, split and seed when evaluated from a dataset.
    pub dataset: Option<DatasetInfo>,
    /// Scenes evaluated.
    pub scenes: usize,
    /// Objects in those scenes.
    pub objects: usize,
    /// Frames per scene.
    pub frames: usize,
    /// Seconds per frame.
    pub dt_frame: f64,
    /// Start frame `s`.
    pub start_frame: usize,
    /// How the metrics pool errors.
    pub pooling: String,
    /// Results per step size, in the requested order.
    pub step_sizes: Vec<StepSizeReport>,
    /// Stability of the long `k = 1` rollout; `None` when disabled.
    pub long_rollout: Option<LongRolloutReport>,
    /// Drift of objects at rest; `None` when disabled or when the window does not fit.
    pub resting: Option<RestingReport>,
    /// Wall-clock time of the evaluation, seconds.
    pub elapsed_s: f64,
}

impl EvalReport {
    /// The entry at step size `k` and horizon `horizon_s`, if requested.
    pub fn entry(&self, k: u32, horizon_s: f64) -> Option<&HorizonReport> {
        self.step_sizes
            .iter()
            .find(|s| s.dt_steps == k)
            .and_then(|s| s.horizons.iter().find(|h| h.horizon_s == horizon_s))
    }
}

/// Where evaluated data came from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DatasetInfo {
    /// Split directory.
    pub dir: String,
    /// Generator name from the manifest.
    pub generator: String,
    /// Split name.
    pub split: String,
    /// Dataset seed.
    pub seed: u64,
    /// Gravity recorded in the manifest, m/s^2.
    pub gravity: [f32; 3],
}

const POOLING: &str = "RMSE over all objects of all scenes pooled at each horizon \
                       (not a mean of per-scene RMSEs)";

/// The poses of every object at frame `t`.
pub fn poses_at(scene: &SceneRecord, t: usize) -> Result<Vec<Pose>, EvalError> {
    scene
        .objects
        .iter()
        .enumerate()
        .map(|(j, o)| match (o.positions.get(t), o.rotations.get(t)) {
            (Some(p), Some(q)) => Ok(Pose {
                translation: *p,
                rotation: *q,
            }),
            _ => Err(EvalError::Invalid(format!(
                "object {j} has no frame {t} ({} frames)",
                o.positions.len().min(o.rotations.len())
            ))),
        })
        .collect()
}

/// The observed state for step size `k`: poses at frames `start - k` and `start`.
pub fn observed_state(scene: &SceneRecord, start: usize, k: u32) -> Result<SceneState, EvalError> {
    let k = k as usize;
    if k == 0 || k > start {
        return Err(EvalError::Invalid(format!(
            "step size {k} needs frame {start} - {k}, which does not exist"
        )));
    }
    Ok(SceneState {
        previous: poses_at(scene, start - k)?,
        current: poses_at(scene, start)?,
    })
}

#[derive(Clone, Debug)]
struct HorizonPlan {
    horizon_s: f64,
    frames: Option<usize>,
    /// `Some(steps)` when evaluated.
    steps: Option<usize>,
    missing: Option<String>,
}

#[derive(Clone, Debug)]
struct StepPlan {
    k: u32,
    /// Steps to roll out (the largest horizon, the resting window, the long rollout), 0 when
    /// nothing is available.
    steps: usize,
    /// Steps scored on the curve (those inside the data), at most `steps`.
    curve_steps: usize,
    horizons: Vec<HorizonPlan>,
    /// Why the resting drift is not available at this step size, if it is not.
    rest_missing: Option<String>,
}

/// The resting-drift window `a..=b` (frames).
#[derive(Clone, Debug)]
struct RestPlan {
    options: RestingOptions,
    a: usize,
    b: usize,
}

#[derive(Clone, Debug)]
struct Plans {
    steps: Vec<StepPlan>,
    rest: Option<RestPlan>,
    /// Steps of the long rollout (`k = 1`), when it runs.
    long_steps: Option<usize>,
    /// Why the long rollout does not run, if it does not.
    long_missing: Option<String>,
}

/// `seconds / dt_frame` as a whole number of frames, if it is one.
fn whole_frames(seconds: f64, dt_frame: f64) -> Option<usize> {
    let exact = seconds / dt_frame;
    let rounded = exact.round();
    ((exact - rounded).abs() <= 1e-6 * exact.max(1.0)).then_some(rounded as usize)
}

fn plan(opts: &EvalOptions, frames: usize, dt_frame: f64) -> Result<Plans, EvalError> {
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

/// Pooled squared errors, `[step size][horizon or step]` of (translation m^2, orientation
/// deg^2).
type ErrorGrid = Vec<Vec<(RmseAccumulator, RmseAccumulator)>>;

/// Everything one predictor contributes for one scene (or, merged, for all scenes so far).
#[derive(Clone, Debug, Default)]
struct Tally {
    horizons: ErrorGrid,
    curves: ErrorGrid,
    /// Ground-truth drift of the resting objects: (translation m, rotation deg).
    rest_truth: (StatAcc, StatAcc),
    /// Predicted drift per step size.
    rest_pred: Vec<(StatAcc, StatAcc)>,
    at_rest: u64,
    long_objects: u64,
    long_failed_objects: u64,
    long_failed_scenes: u64,
    long_non_finite: u64,
    max_qnorm_error: f64,
    max_pairwise: f64,
    projection: StatAcc,
    projection_available: bool,
}

impl Tally {
    fn empty(plans: &Plans) -> Tally {
        let grid = |n: &dyn Fn(&StepPlan) -> usize| -> ErrorGrid {
            plans
                .steps
                .iter()
                .map(|p| vec![(RmseAccumulator::default(), RmseAccumulator::default()); n(p)])
                .collect()
        };
        Tally {
            horizons: grid(&|p| p.horizons.len()),
            curves: grid(&|p| p.curve_steps),
            rest_pred: vec![Default::default(); plans.steps.len()],
            ..Tally::default()
        }
    }

    fn merge(&mut self, o: &Tally) {
        for (a, b) in [
            (&mut self.horizons, &o.horizons),
            (&mut self.curves, &o.curves),
        ] {
            for (ra, rb) in a.iter_mut().zip(b) {
                for (x, y) in ra.iter_mut().zip(rb) {
                    x.0.merge(&y.0);
                    x.1.merge(&y.1);
                }
            }
        }
        self.rest_truth.0.merge(&o.rest_truth.0);
        self.rest_truth.1.merge(&o.rest_truth.1);
        for (x, y) in self.rest_pred.iter_mut().zip(&o.rest_pred) {
            x.0.merge(&y.0);
            x.1.merge(&y.1);
        }
        self.at_rest += o.at_rest;
        self.long_objects += o.long_objects;
        self.long_failed_objects += o.long_failed_objects;
        self.long_failed_scenes += o.long_failed_scenes;
        self.long_non_finite += o.long_non_finite;
        self.max_qnorm_error = self.max_qnorm_error.max(o.max_qnorm_error);
        self.max_pairwise = self.max_pairwise.max(o.max_pairwise);
        self.projection.merge(&o.projection);
        self.projection_available |= o.projection_available;
    }
}

fn translation_distance(a: &Pose, b: &Pose) -> f64 {
    squared_distance(&a.translation, &b.translation).sqrt()
}

/// `q x q*` with the raw (possibly non-unit) quaternion `q = [x, y, z, w]`, plus `p`.
fn raw_transform(pose: &Pose, x: [f32; 3]) -> Vector3<f64> {
    let [qx, qy, qz, qw] = pose.rotation.map(f64::from);
    let q = Quaternion::new(qw, qx, qy, qz);
    let v = Quaternion::from_imag(Vector3::new(
        f64::from(x[0]),
        f64::from(x[1]),
        f64::from(x[2]),
    ));
    (q * v * q.conjugate()).imag() + Vector3::from(pose.translation.map(f64::from))
}

fn pose_is_finite(p: &Pose) -> bool {
    p.translation
        .iter()
        .chain(&p.rotation)
        .all(|v| v.is_finite())
}

fn quaternion_norm_error(p: &Pose) -> f64 {
    (p.rotation
        .iter()
        .map(|v| f64::from(*v).powi(2))
        .sum::<f64>()
        .sqrt()
        - 1.0)
        .abs()
}

/// At rest over frames `a..=b`: every consecutive pair moves slower than the thresholds.
fn is_at_rest(o: &dynaserve_sim::ObjectRecord, r: &RestPlan, dt: f64) -> bool {
    (r.a..r.b).all(|t| {
        let v = squared_distance(&o.positions[t], &o.positions[t + 1]).sqrt() / dt;
        let w = geodesic_angle(o.rotations[t], o.rotations[t + 1]).to_degrees() / dt;
        v < r.options.max_speed_m_s && w < r.options.max_angular_speed_deg_s
    })
}

/// Poses of frame `s + step * k` from a rollout (`step = 0` is the observed frame).
fn rollout_pose<'a>(observed: &'a SceneState, rollout: &'a [Vec<Pose>], step: usize) -> &'a [Pose] {
    if step == 0 {
        &observed.current
    } else {
        &rollout[step - 1]
    }
}

/// Scores one scene's rollouts (`rollouts[p]` answers `plans.steps[p]`, `long` is the `k = 1`
/// rollout of the stability check).
#[allow(clippy::too_many_arguments)]
fn score_scene(
    predictor: &dyn Predictor,
    scene: &SceneRecord,
    scene_index: usize,
    start: usize,
    dt_frame: f64,
    plans: &Plans,
    projection_every: usize,
    rollouts: &[(SceneState, Vec<Vec<Pose>>)],
    long: Option<&(SceneState, Vec<Vec<Pose>>)>,
) -> Result<Tally, EvalError> {
    let bad = |message: String| EvalError::Predictor {
        predictor: predictor.name(),
        scene: scene_index,
        message,
    };
    let n = scene.objects.len();
    let mut tally = Tally::empty(plans);
    for (pi, (plan, (observed, rollout))) in plans.steps.iter().zip(rollouts).enumerate() {
        if rollout.len() != plan.steps {
            return Err(bad(format!(
                "returned {} steps, expected {} (k = {})",
                rollout.len(),
                plan.steps,
                plan.k
            )));
        }
        for (i, poses) in rollout.iter().enumerate() {
            if poses.len() != n {
                return Err(bad(format!(
                    "returned {} poses at step {} (k = {}), the scene has {n} objects",
                    poses.len(),
                    i + 1,
                    plan.k
                )));
            }
        }
        // Every step inside the data: the curve; the horizons are a subset of it.
        let mut step_errors = Vec::with_capacity(plan.curve_steps);
        for i in 1..=plan.curve_steps {
            let truth = poses_at(scene, start + i * plan.k as usize)?;
            let mut acc = (RmseAccumulator::default(), RmseAccumulator::default());
            for (j, (p, t)) in rollout[i - 1].iter().zip(&truth).enumerate() {
                let d2 = squared_distance(&p.translation, &t.translation);
                let theta = geodesic_angle(p.rotation, t.rotation);
                if !d2.is_finite() || !theta.is_finite() {
                    return Err(bad(format!(
                        "non-finite pose for object {j} at step {i} (k = {}): {p:?}",
                        plan.k
                    )));
                }
                acc.0.add_squared(d2);
                acc.1.add(theta.to_degrees());
            }
            step_errors.push(acc);
        }
        for (h, acc) in plan.horizons.iter().zip(tally.horizons[pi].iter_mut()) {
            if let Some(steps) = h.steps {
                *acc = step_errors[steps - 1];
            }
        }
        tally.curves[pi] = step_errors;
        if let (Some(r), None) = (&plans.rest, &plan.rest_missing) {
            let ku = plan.k as usize;
            let pa = rollout_pose(observed, rollout, (r.a - start) / ku);
            let pb = rollout_pose(observed, rollout, (r.b - start) / ku);
            for (j, o) in scene.objects.iter().enumerate() {
                if is_at_rest(o, r, dt_frame) {
                    let acc = &mut tally.rest_pred[pi];
                    acc.0.add(translation_distance(&pa[j], &pb[j]));
                    acc.1
                        .add(geodesic_angle(pa[j].rotation, pb[j].rotation).to_degrees());
                }
            }
        }
    }
    if let Some(r) = &plans.rest {
        for o in &scene.objects {
            if is_at_rest(o, r, dt_frame) {
                tally.at_rest += 1;
                tally
                    .rest_truth
                    .0
                    .add(squared_distance(&o.positions[r.a], &o.positions[r.b]).sqrt());
                tally
                    .rest_truth
                    .1
                    .add(geodesic_angle(o.rotations[r.a], o.rotations[r.b]).to_degrees());
            }
        }
    }
    if let (Some(long_steps), Some((observed, rollout))) = (plans.long_steps, long) {
        if rollout.len() < long_steps || rollout.iter().any(|p| p.len() != n) {
            return Err(bad(format!(
                "returned {} steps for the {long_steps}-step stability rollout",
                rollout.len()
            )));
        }
        let rollout = &rollout[..long_steps];
        let mut scene_failed = false;
        for (j, o) in scene.objects.iter().enumerate() {
            let pts = &o.reference_points[..o.reference_points.len().min(PAIRWISE_POINTS)];
            let mut non_finite = false;
            let mut failed = false;
            for poses in rollout {
                let p = &poses[j];
                if !pose_is_finite(p) {
                    non_finite = true;
                    failed = true;
                    continue;
                }
                let qe = quaternion_norm_error(p);
                tally.max_qnorm_error = tally.max_qnorm_error.max(qe);
                failed |= qe > QUATERNION_NORM_TOLERANCE;
                let world: Vec<Vector3<f64>> = pts.iter().map(|x| raw_transform(p, *x)).collect();
                for a in 0..pts.len() {
                    for b in a + 1..pts.len() {
                        let reference = squared_distance(&pts[a], &pts[b]).sqrt();
                        let dev = ((world[a] - world[b]).norm() - reference).abs();
                        tally.max_pairwise = tally.max_pairwise.max(dev);
                    }
                }
            }
            tally.long_objects += 1;
            tally.long_failed_objects += u64::from(failed);
            tally.long_non_finite += u64::from(non_finite);
            scene_failed |= failed;
        }
        tally.long_failed_scenes += u64::from(scene_failed);
        if projection_every > 0 && !scene_failed {
            let windows: Vec<ProjectionWindow> = (0..long_steps)
                .step_by(projection_every)
                .map(|i| ProjectionWindow {
                    state: SceneState {
                        previous: match i {
                            0 => observed.previous.clone(),
                            _ => rollout_pose(observed, rollout, i - 1).to_vec(),
                        },
                        current: rollout_pose(observed, rollout, i).to_vec(),
                    },
                    next: rollout[i].clone(),
                    dt_steps: 1,
                })
                .collect();
            if let Some(residuals) = predictor.projection_residuals(scene, &windows)? {
                tally.projection_available = true;
                for r in residuals {
                    tally.projection.add(r);
                }
            }
        }
    }
    Ok(tally)
}

/// Accumulates one predictor's pooled errors over scenes in a fixed order.
struct Evaluator<'a> {
    predictor: &'a dyn Predictor,
    opts: EvalOptions,
    frames: usize,
    dt_frame: f64,
    plans: Plans,
    totals: Tally,
    scenes: usize,
    objects: usize,
    busy: std::time::Duration,
}

impl<'a> Evaluator<'a> {
    fn new(
        predictor: &'a dyn Predictor,
        opts: &EvalOptions,
        frames: usize,
        dt_frame: f64,
    ) -> Result<Self, EvalError> {
        let plans = plan(opts, frames, dt_frame)?;
        Ok(Evaluator {
            predictor,
            opts: opts.clone(),
            frames,
            dt_frame,
            totals: Tally::empty(&plans),
            plans,
            scenes: 0,
            objects: 0,
            busy: std::time::Duration::ZERO,
        })
    }

    /// Evaluates a batch of scenes (rollouts batched by the predictor, scoring in parallel)
    /// and adds them in order.
    fn add(&mut self, scenes: &[SceneRecord]) -> Result<(), EvalError> {
        let t0 = Instant::now();
        let start = self.opts.start_frame;
        for (i, s) in scenes.iter().enumerate() {
            let index = self.scenes + i;
            if (f64::from(s.dt_frame) - self.dt_frame).abs() > 1e-9 * self.dt_frame.max(1.0) {
                return Err(EvalError::Invalid(format!(
                    "scene {index} has dt_frame {} s, the evaluation uses {} s",
                    s.dt_frame, self.dt_frame
                )));
            }
            if s.objects.is_empty() {
                return Err(EvalError::Invalid(format!("scene {index} has no objects")));
            }
            for (j, o) in s.objects.iter().enumerate() {
                if o.positions.len() != self.frames || o.rotations.len() != self.frames {
                    return Err(EvalError::Invalid(format!(
                        "scene {index} object {j} has {} positions and {} rotations, expected \
                         {} frames",
                        o.positions.len(),
                        o.rotations.len(),
                        self.frames
                    )));
                }
                if o.reference_points.is_empty() {
                    return Err(EvalError::Invalid(format!(
                        "scene {index} object {j} has no reference points"
                    )));
                }
            }
        }
        // One request per (scene, step size), plus a k = 1 stability rollout when no step size
        // of 1 is evaluated.
        let has_k1 = self.plans.steps.iter().any(|p| p.k == 1 && p.steps > 0);
        let extra_long = self.plans.long_steps.filter(|_| !has_k1);
        let mut requests = Vec::new();
        for s in scenes {
            for p in &self.plans.steps {
                if p.steps > 0 {
                    requests.push(RolloutRequest {
                        scene: s,
                        observed: observed_state(s, start, p.k)?,
                        dt_steps: p.k,
                        steps: p.steps,
                    });
                }
            }
            if let Some(n) = extra_long {
                requests.push(RolloutRequest {
                    scene: s,
                    observed: observed_state(s, start, 1)?,
                    dt_steps: 1,
                    steps: n,
                });
            }
        }
        let results = self.predictor.rollout_batch(&requests)?;
        if results.len() != requests.len() {
            return Err(EvalError::Predictor {
                predictor: self.predictor.name(),
                scene: self.scenes,
                message: format!(
                    "answered {} of {} rollout requests",
                    results.len(),
                    requests.len()
                ),
            });
        }
        let mut answers = requests.into_iter().zip(results);
        let mut per_scene = Vec::with_capacity(scenes.len());
        for _ in scenes {
            let mut rollouts = Vec::with_capacity(self.plans.steps.len());
            for p in &self.plans.steps {
                if p.steps > 0 {
                    let (req, out) = answers.next().ok_or_else(|| {
                        EvalError::Invalid("internal: rollout requests out of order".into())
                    })?;
                    rollouts.push((req.observed, out));
                } else {
                    rollouts.push((
                        SceneState {
                            previous: Vec::new(),
                            current: Vec::new(),
                        },
                        Vec::new(),
                    ));
                }
            }
            let long = match extra_long {
                Some(_) => answers.next().map(|(req, out)| (req.observed, out)),
                None => None,
            };
            per_scene.push((rollouts, long));
        }
        let first = self.scenes;
        let long_plan = self
            .plans
            .steps
            .iter()
            .position(|p| p.k == 1 && p.steps > 0);
        let results: Vec<Tally> = scenes
            .par_iter()
            .zip(&per_scene)
            .enumerate()
            .map(|(i, (s, (rollouts, long)))| {
                let long = match (self.plans.long_steps, long_plan) {
                    (None, _) => None,
                    (Some(_), Some(p)) => Some(&rollouts[p]),
                    (Some(_), None) => long.as_ref(),
                };
                score_scene(
                    self.predictor,
                    s,
                    first + i,
                    start,
                    self.dt_frame,
                    &self.plans,
                    self.opts.projection_every,
                    rollouts,
                    long,
                )
            })
            .collect::<Result<_, _>>()?;
        for (scene, tally) in scenes.iter().zip(&results) {
            self.totals.merge(tally);
            self.scenes += 1;
            self.objects += scene.objects.len();
        }
        self.busy += t0.elapsed();
        Ok(())
    }

    fn finish(self, dataset: Option<DatasetInfo>) -> EvalReport {
        let t = &self.totals;
        let step_sizes = self
            .plans
            .steps
            .iter()
            .zip(t.horizons.iter().zip(&t.curves))
            .map(|(plan, (totals, curve))| StepSizeReport {
                dt_steps: plan.k,
                horizons: plan
                    .horizons
                    .iter()
                    .zip(totals)
                    .map(|(h, (trans, rot))| HorizonReport {
                        horizon_s: h.horizon_s,
                        frames: h.frames,
                        steps: h.steps,
                        translation_rmse_m: h.steps.and(trans.rmse()),
                        orientation_rmse_deg: h.steps.and(rot.rmse()),
                        objects: trans.count,
                        missing: h.missing.clone().or_else(|| {
                            (trans.count == 0).then(|| "no scenes evaluated".to_string())
                        }),
                    })
                    .collect(),
                curve: curve
                    .iter()
                    .enumerate()
                    .filter_map(|(i, (trans, rot))| {
                        let frames = (i + 1) * plan.k as usize;
                        Some(CurvePoint {
                            time_s: frames as f64 * self.dt_frame,
                            frames,
                            translation_rmse_m: trans.rmse()?,
                            orientation_rmse_deg: rot.rmse()?,
                        })
                    })
                    .collect(),
            })
            .collect();
        let long_rollout = match self.plans.long_steps {
            None => None,
            Some(steps) => Some(LongRolloutReport {
                dt_steps: 1,
                steps,
                objects: t.long_objects,
                failed_objects: t.long_failed_objects,
                failed_scenes: t.long_failed_scenes,
                non_finite_objects: t.long_non_finite,
                max_quaternion_norm_error: t.max_qnorm_error,
                max_pairwise_deviation_m: t.max_pairwise,
                projection_residual_m: t.projection_available.then(|| t.projection.stat()),
                missing: self.plans.long_missing.clone(),
            }),
        };
        let resting = self.plans.rest.as_ref().map(|r| {
            let drift =
                |dt_steps: u32, acc: &(StatAcc, StatAcc), missing: Option<String>| DriftReport {
                    dt_steps,
                    translation_m: missing.is_none().then(|| acc.0.stat()),
                    rotation_deg: missing.is_none().then(|| acc.1.stat()),
                    missing,
                };
            RestingReport {
                options: r.options.clone(),
                first_frame: r.a,
                last_frame: r.b,
                objects_at_rest: t.at_rest,
                objects: self.objects as u64,
                truth: drift(0, &t.rest_truth, None),
                predicted: self
                    .plans
                    .steps
                    .iter()
                    .zip(&t.rest_pred)
                    .map(|(p, acc)| drift(p.k, acc, p.rest_missing.clone()))
                    .collect(),
            }
        });
        EvalReport {
            predictor: self.predictor.name(),
            dataset,
            scenes: self.scenes,
            objects: self.objects,
            frames: self.frames,
            dt_frame: self.dt_frame,
            start_frame: self.opts.start_frame,
            pooling: POOLING.to_string(),
            step_sizes,
            long_rollout,
            resting,
            elapsed_s: self.busy.as_secs_f64(),
        }
    }
}

/// Evaluates `predictor` on in-memory scenes (all with the same frame count and `dt_frame`).
pub fn evaluate_scenes(
    predictor: &dyn Predictor,
    scenes: &[SceneRecord],
    opts: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    let first = scenes
        .first()
        .ok_or_else(|| EvalError::Invalid("no scenes to evaluate".into()))?;
    let frames = first
        .objects
        .first()
        .map(|o| o.positions.len())
        .ok_or_else(|| EvalError::Invalid("scene 0 has no objects".into()))?;
    let take = opts.max_scenes.unwrap_or(scenes.len()).min(scenes.len());
    let mut ev = Evaluator::new(predictor, opts, frames, f64::from(first.dt_frame))?;
    for chunk in scenes[..take].chunks(BATCH) {
        ev.add(chunk)?;
    }
    Ok(ev.finish(None))
}

/// Evaluates `predictor` on a dataset split, streaming it shard by shard; `progress(done)` is
/// called after each batch of scenes with the number of scenes done so far.
pub fn evaluate_dataset(
    predictor: &dyn Predictor,
    reader: &DatasetReader,
    opts: &EvalOptions,
    progress: &dyn Fn(usize),
) -> Result<EvalReport, EvalError> {
    let mut reports = evaluate_dataset_many(&[predictor], reader, opts, &|_, done| progress(done))?;
    reports
        .pop()
        .ok_or_else(|| EvalError::Invalid("no report".into()))
}

/// Evaluates several predictors on the same scenes of a dataset split in one streaming pass
/// (each batch of scenes is read once and given to every predictor in turn). Reports are in
/// the order of `predictors`. `progress(predictor, done)` is called after each predictor's
/// batch with the number of scenes that predictor has done.
pub fn evaluate_dataset_many(
    predictors: &[&dyn Predictor],
    reader: &DatasetReader,
    opts: &EvalOptions,
    progress: &dyn Fn(usize, usize),
) -> Result<Vec<EvalReport>, EvalError> {
    if predictors.is_empty() {
        return Err(EvalError::Invalid("no predictor to evaluate".into()));
    }
    let m = reader.manifest();
    let mut evs = predictors
        .iter()
        .map(|p| Evaluator::new(*p, opts, m.frames, f64::from(m.dt_frame)))
        .collect::<Result<Vec<_>, _>>()?;
    let limit = opts.max_scenes.unwrap_or(usize::MAX).min(reader.len());
    let mut batch = Vec::with_capacity(BATCH);
    let mut read = 0;
    let mut flush = |batch: &mut Vec<SceneRecord>| -> Result<(), EvalError> {
        for (i, ev) in evs.iter_mut().enumerate() {
            ev.add(batch)?;
            progress(i, ev.scenes);
        }
        batch.clear();
        Ok(())
    };
    for scene in reader.iter() {
        if read >= limit {
            break;
        }
        batch.push(scene?);
        read += 1;
        if batch.len() == BATCH {
            flush(&mut batch)?;
        }
    }
    if !batch.is_empty() {
        flush(&mut batch)?;
    }
    if read == 0 {
        return Err(EvalError::Invalid(format!(
            "{} holds no scenes to evaluate",
            reader.dir().display()
        )));
    }
    let info = DatasetInfo {
        dir: reader.dir().display().to_string(),
        generator: m.generator.clone(),
        split: m.split.clone(),
        seed: m.seed,
        gravity: m.gravity,
    };
    Ok(evs
        .into_iter()
        .map(|ev| ev.finish(Some(info.clone())))
        .collect())
}

fn fmt_metric(v: Option<f64>, decimals: usize) -> String {
    match v {
        Some(x) => format!("{x:.decimals$}"),
        None => "-".to_string(),
    }
}

/// The report as a plain-text table: one row per horizon, translation RMSE (m) and
/// orientation RMSE (deg) per step size as columns, missing entries as `-` with the reasons
/// listed below the table.
pub fn format_table(report: &EvalReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let source = match &report.dataset {
        Some(d) => format!(
            "{} ({} split, seed {}, {})",
            d.generator, d.split, d.seed, d.dir
        ),
        None => "in-memory scenes".to_string(),
    };
    let _ = writeln!(s, "predictor: {}   data: {source}", report.predictor);
    let _ = writeln!(
        s,
        "{} scenes, {} objects, {} frames of {:.4} s; observed frames s-k and s = {}; {}",
        report.scenes,
        report.objects,
        report.frames,
        report.dt_frame,
        report.start_frame,
        report.pooling
    );
    let mut header = format!("{:<18}", "horizon");
    for k in &report.step_sizes {
        let _ = write!(
            header,
            " | {:>11} {:>11}",
            format!("k={} trans m", k.dt_steps),
            format!("k={} rot deg", k.dt_steps)
        );
    }
    let _ = writeln!(s, "{header}");
    let _ = writeln!(s, "{}", "-".repeat(header.len()));
    let rows = report
        .step_sizes
        .first()
        .map(|k| k.horizons.len())
        .unwrap_or(0);
    for r in 0..rows {
        let h = &report.step_sizes[0].horizons[r];
        let label = match h.frames {
            Some(f) => format!("{} s ({f} fr)", h.horizon_s),
            None => format!("{} s", h.horizon_s),
        };
        let mut line = format!("{label:<18}");
        for k in &report.step_sizes {
            let e = &k.horizons[r];
            let _ = write!(
                line,
                " | {:>11} {:>11}",
                fmt_metric(e.translation_rmse_m, 4),
                fmt_metric(e.orientation_rmse_deg, 2)
            );
        }
        let _ = writeln!(s, "{line}");
    }
    write_missing_horizons(&mut s, report);
    s
}

/// Appends the horizons `report` could not score, with the reason, to a text report.
pub(crate) fn write_missing_horizons(s: &mut String, report: &EvalReport) {
    use std::fmt::Write;
    let mut notes = Vec::new();
    for k in &report.step_sizes {
        for h in &k.horizons {
            if let Some(why) = &h.missing {
                notes.push(format!("  k={} at {} s: {why}", k.dt_steps, h.horizon_s));
            }
        }
    }
    if !notes.is_empty() {
        let _ = writeln!(s, "missing (never shifted to another frame):");
        for n in notes {
            let _ = writeln!(s, "{n}");
        }
    }
}

#[cfg(test)]
pub(crate) mod tests;
