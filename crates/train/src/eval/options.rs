//! What to evaluate: step sizes, horizons, the stability rollout and the resting window, with
//! their defaults.

use dynaserve_geometry::geodesic_angle;
use dynaserve_geometry::metrics::squared_distance;
use dynaserve_sim::ObjectRecord;
use serde::{Deserialize, Serialize};

/// Start frame `s` shared by all step sizes (the second observed frame).
pub const DEFAULT_START_FRAME: usize = 4;
/// Physical horizons in seconds after the start frame.
pub const DEFAULT_HORIZONS_S: [f64; 4] = [0.5, 1.0, 2.0, 4.0];
/// Step sizes in frames.
pub const DEFAULT_STEP_SIZES: [u32; 3] = [1, 2, 4];

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
    /// Gravity of the scenes, m/s^2: it tells a bounce between two frames from free flight in
    /// the per-object error by contact. A dataset's manifest overrides it.
    pub gravity: [f32; 3],
    /// Observe only frames `s - k` and `s`, not `s - 2k` (which a model with history inputs
    /// reads on its first step), as a client that sends two poses.
    #[serde(default)]
    pub two_frames: bool,
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
            gravity: [0.0, 0.0, -10.0],
            two_frames: false,
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

impl RestingOptions {
    /// The window `(a, b)`, frames `a..=b`, of a recording of `frames` frames `dt` seconds
    /// apart: its last `window_s` seconds (rounded to whole frames), or `None` when the
    /// recording is not longer than that.
    pub fn window(&self, frames: usize, dt: f64) -> Option<(usize, usize)> {
        let w = (self.window_s / dt).round() as usize;
        (frames > w).then(|| (frames - 1 - w, frames - 1))
    }

    /// Whether `o` is at rest over frames `a..=b` of its recording: every consecutive pair of
    /// frames (`dt` seconds apart) moves its centre slower than `max_speed_m_s` and turns it
    /// slower than `max_angular_speed_deg_s`.
    pub fn at_rest(&self, o: &ObjectRecord, a: usize, b: usize, dt: f64) -> bool {
        (a..b).all(|t| {
            let v = squared_distance(&o.positions[t], &o.positions[t + 1]).sqrt() / dt;
            let w = geodesic_angle(o.rotations[t], o.rotations[t + 1]).to_degrees() / dt;
            v < self.max_speed_m_s && w < self.max_angular_speed_deg_s
        })
    }
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
