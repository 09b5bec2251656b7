//! The figures an evaluation reports (serialised as the `--json` report) and the accumulator
//! behind its mean/median/maximum statistics.

use serde::{Deserialize, Serialize};

use super::RestingOptions;

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
    /// Spread of the per-object translation error, metres: the RMSE's mean hides whether a
    /// few objects or all of them are off. `None` when missing (and in reports written before
    /// it existed).
    #[serde(default)]
    pub translation_m: Option<Stat>,
    /// Spread of the per-object geodesic orientation error, degrees, as `translation_m`.
    #[serde(default)]
    pub orientation_deg: Option<Stat>,
    /// The same errors split by what each object touched in the ground truth between the
    /// start frame and the horizon ([`ContactHistory`]), in the order of
    /// [`ContactHistory::ALL`], classes without objects left out. Empty when missing (and in
    /// reports written before it existed).
    #[serde(default)]
    pub by_contact: Vec<ContactSpread>,
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

/// Mean, median, upper percentiles and maximum of a non-negative quantity over a set of
/// samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Stat {
    /// Mean over the samples (0 when there are none).
    pub mean: f64,
    /// Median over the samples (0 when there are none; the mean of the two middle samples of
    /// an even count). Reports written before it existed read as 0.
    #[serde(default)]
    pub median: f64,
    /// 90th percentile (nearest rank: the smallest sample with at least 90% of the samples
    /// at or below it; 0 when there are none). Reports written before it existed read as 0.
    #[serde(default)]
    pub p90: f64,
    /// 99th percentile (nearest rank, as `p90`): with a mean decided by a few large samples
    /// (an object that falls over), it shows how many there are. Reports written before it
    /// existed read as 0.
    #[serde(default)]
    pub p99: f64,
    /// Maximum over the samples (0 when there are none).
    pub max: f64,
    /// Number of samples.
    pub count: u64,
}

/// Accumulates samples for a [`Stat`] (keeps them all, for the median).
#[derive(Clone, Debug, Default)]
pub(super) struct StatAcc {
    values: Vec<f64>,
}

impl StatAcc {
    pub(super) fn add(&mut self, x: f64) {
        self.values.push(x);
    }
    pub(super) fn merge(&mut self, o: &StatAcc) {
        self.values.extend_from_slice(&o.values);
    }
    /// Root mean square of the samples (0 without samples).
    pub(super) fn rms(&self) -> f64 {
        if self.values.is_empty() {
            return 0.0;
        }
        (self.values.iter().map(|v| v * v).sum::<f64>() / self.values.len() as f64).sqrt()
    }
    /// [`StatAcc::stat`], `None` without samples.
    pub(super) fn stat_if_any(&self) -> Option<Stat> {
        (!self.values.is_empty()).then(|| self.stat())
    }
    pub(super) fn stat(&self) -> Stat {
        let n = self.values.len();
        if n == 0 {
            return Stat::default();
        }
        let mut v = self.values.clone();
        v.sort_by(f64::total_cmp);
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        };
        let rank = |q: f64| v[((q * n as f64).ceil() as usize).clamp(1, n) - 1];
        Stat {
            mean: v.iter().sum::<f64>() / n as f64,
            median,
            p90: rank(0.9),
            p99: rank(0.99),
            max: v[n - 1],
            count: n as u64,
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
    /// from 1 by more than [`QUATERNION_NORM_TOLERANCE`](super::QUATERNION_NORM_TOLERANCE).
    pub failed_objects: u64,
    /// Scenes with at least one failed object.
    pub failed_scenes: u64,
    /// Objects with a non-finite pose (a subset of the failures).
    pub non_finite_objects: u64,
    /// Largest `| |q| - 1 |` over all finite predicted quaternions.
    pub max_quaternion_norm_error: f64,
    /// Pose rigidity: the largest `| |R x_a + p - (R x_b + p)| - |x_a - x_b| |`, metres, over
    /// all steps, objects and pairs of the object's first [`PAIRWISE_POINTS`](super::PAIRWISE_POINTS) reference
    /// points, with `R x` computed from the raw predicted quaternion as `q x q*` (so a
    /// non-unit quaternion shows up as a scaled distance).
    pub max_pairwise_deviation_m: f64,
    /// Pre-projection rigidity residual (see [`Predictor::projection_residuals`](super::Predictor::projection_residuals)) in metres at
    /// every [`EvalOptions::projection_every`](super::EvalOptions::projection_every)-th state of the rollout, over objects and
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
    /// The translation drift of the predicted resting objects per shape, by `shape_id` (empty
    /// for the ground truth, and in reports written before it existed).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub by_shape: Vec<ShapeDrift>,
}

/// What an object touched in the ground truth from the start frame to a horizon, by the
/// contact tests of the regime table ([`super::regimes::touched`]: distances, and the
/// acceleration for a bounce between two frames).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ContactHistory {
    /// Touched another object.
    Object,
    /// Touched the floor, never another object.
    FloorOnly,
    /// Neither: free flight throughout.
    None,
}

impl ContactHistory {
    /// Every class, in report order.
    pub const ALL: [ContactHistory; 3] = [
        ContactHistory::Object,
        ContactHistory::FloorOnly,
        ContactHistory::None,
    ];

    /// Position in [`ContactHistory::ALL`].
    pub fn index(self) -> usize {
        match self {
            ContactHistory::Object => 0,
            ContactHistory::FloorOnly => 1,
            ContactHistory::None => 2,
        }
    }

    /// Label in tables.
    pub fn name(self) -> &'static str {
        match self {
            ContactHistory::Object => "another object",
            ContactHistory::FloorOnly => "floor only",
            ContactHistory::None => "nothing",
        }
    }
}

/// The per-object errors at one horizon of the objects of one [`ContactHistory`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ContactSpread {
    /// What these objects touched.
    pub contact: ContactHistory,
    /// Their translation RMSE, metres (pooled like the horizon's).
    pub translation_rmse_m: f64,
    /// Their orientation RMSE, degrees.
    pub orientation_rmse_deg: f64,
    /// Spread of their translation errors, metres (`count` is the number of objects).
    pub translation_m: Stat,
    /// Spread of their orientation errors, degrees.
    pub orientation_deg: Stat,
}

/// Translation drift over the resting window of the resting objects of one shape.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShapeDrift {
    /// The objects' `shape_id`.
    pub shape_id: i32,
    /// The shape's name in the dataset's manifest (empty when not known).
    pub shape: String,
    /// `|p(b) - p(a)|`, metres.
    pub translation_m: Stat,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_nearest_rank() {
        let mut acc = StatAcc::default();
        // 1..=200 shuffled: p90 is the 180th smallest, p99 the 198th.
        for i in 0..200u32 {
            acc.add(f64::from((i * 7) % 200 + 1));
        }
        let s = acc.stat();
        assert_eq!(
            (s.median, s.p90, s.p99, s.max),
            (100.5, 180.0, 198.0, 200.0)
        );
        let mut one = StatAcc::default();
        one.add(3.0);
        let s = one.stat();
        assert_eq!((s.p90, s.p99, s.count), (3.0, 3.0, 1));
        assert_eq!(StatAcc::default().stat().p99, 0.0);
    }

    #[test]
    fn stat_has_mean_median_and_max() {
        let mut a = StatAcc::default();
        assert_eq!(a.stat(), Stat::default());
        for x in [10.0, 1.0, 2.0] {
            a.add(x);
        }
        let s = a.stat();
        assert_eq!((s.median, s.max, s.count), (2.0, 10.0, 3));
        assert!((s.mean - 13.0 / 3.0).abs() < 1e-12);
        let mut b = StatAcc::default();
        b.add(4.0);
        a.merge(&b);
        assert_eq!(a.stat().median, 3.0);
        // Reports written before the median existed still load.
        let old: Stat = serde_json::from_str(r#"{"mean":1.0,"max":2.0,"count":3}"#).unwrap();
        assert_eq!(old.median, 0.0);
    }
}
