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
//! The calibration suite (`--suite calibration`, [`calibration`]) scores how well a model's own
//! spread predicts its error.

pub mod baselines;
pub mod calibration;
pub mod driven;
mod error;
mod evaluator;
mod frames;
mod horizon_plan;
pub mod model;
mod options;
pub mod physics_report;
pub mod physics_suite;
pub mod plot;
mod predictor;
pub mod rapier_restart;
pub mod regimes;
pub mod report;
mod results;
pub mod scenario_figures;
mod scoring;
mod table;

pub use baselines::{Ballistic, Static};
pub use error::EvalError;
pub use evaluator::{evaluate_dataset, evaluate_dataset_many, evaluate_scenes};
pub use frames::{observed_frames, observed_state, poses_at};
pub use model::{ModelPredictor, Occlusion, PointSelection};
pub use options::{
    DEFAULT_HORIZONS_S, DEFAULT_LONG_ROLLOUT_STEPS, DEFAULT_PROJECTION_EVERY, DEFAULT_START_FRAME,
    DEFAULT_STEP_SIZES, EvalOptions, PAIRWISE_POINTS, QUATERNION_NORM_TOLERANCE, RestingOptions,
};
pub use plot::{PlotStyle, plot_errors};
pub use predictor::{Predictor, ProjectionWindow, RolloutRequest};
pub use rapier_restart::RapierRestart;
pub use report::{SuiteEntry, SuiteReport, format_markdown, format_suite};
pub use results::{
    ContactHistory, ContactSpread, CurvePoint, DatasetInfo, DriftReport, EvalReport, HorizonReport,
    LongRolloutReport, RestingReport, ShapeDrift, Stat, StepSizeReport,
};
pub use table::format_table;
pub(crate) use table::write_missing_horizons;

#[cfg(test)]
pub(crate) mod tests;
