//! The flags of `dynaserve eval` and the evaluation options they ask for.

use std::path::PathBuf;

use crate::eval::{
    DEFAULT_LONG_ROLLOUT_STEPS, DEFAULT_PROJECTION_EVERY, DEFAULT_START_FRAME, EvalOptions,
    RestingOptions,
};

/// Baselines `dynaserve eval --baseline` knows.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BaselineKind {
    /// Every object stays at its last observed pose.
    Static,
    /// Constant angular velocity, free flight under the data's gravity, inelastic floor.
    Ballistic,
    /// rapier restarted from the observed frames: the exact shapes, materials and floor, the
    /// velocity from the two frames (how predictable the scenes are from what a model sees).
    Rapier,
}

/// Scenario suites `dynaserve eval --suite` knows.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SuiteKind {
    /// Rest, drop, slide, collide and stack-hit scenes: each scenario's own figures against
    /// rapier and the one-step error by contact regime.
    Physics,
    /// How well the model's own per-object spread (an ensemble's members' disagreement)
    /// predicts its error along rollouts of one `--data` split, against a baseline.
    Calibration,
}

/// Arguments of `dynaserve eval`.
///
/// With `--model`, one run evaluates the model with its nominal point count, with
/// `--variant-points` points and with `--occlude` of its points removed, plus the static and
/// ballistic baselines, all on the same scenes; `--no-variants` and `--no-baselines` turn
/// parts off.
#[derive(clap::Args, Debug, Clone)]
pub struct EvalArgs {
    /// Evaluate only this baseline.
    #[arg(
        long,
        value_enum,
        required_unless_present = "model",
        conflicts_with = "model"
    )]
    pub baseline: Option<BaselineKind>,
    /// Checkpoint directory of a trained model (config.json, model.safetensors) to evaluate.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Device the model runs on: `cpu`, `cuda` or `cuda:N` (CUDA needs a build with
    /// `--features cuda`). Baselines and rapier always run on the CPU.
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// Dataset split directory (holding manifest.json). With `--suite`, optional and
    /// repeatable: scenario datasets to score instead of the generated suite.
    #[arg(long, required_unless_present = "suite")]
    pub data: Vec<PathBuf>,
    /// Score a scenario suite instead of the error tables of a dataset.
    #[arg(long, value_enum)]
    pub suite: Option<SuiteKind>,
    /// Seed of the generated suite (split `test`).
    #[arg(long, default_value_t = crate::eval::physics_suite::DEFAULT_SUITE_SEED)]
    pub seed: u64,
    /// Scenes per group of the generated suite.
    #[arg(long, default_value_t = crate::eval::physics_suite::DEFAULT_SCENES_PER_GROUP)]
    pub suite_scenes: usize,
    /// Materials of the generated suite's objects: Kubric's two (as in MOVi-B and the
    /// training scenarios), or friction, restitution and density drawn independently per
    /// object (a test of materials between and beyond them).
    #[arg(long, value_enum, default_value_t = dynaserve_sim::Materials::Kubric)]
    pub suite_materials: dynaserve_sim::Materials,
    /// Calibration suite: horizons in steps of one frame, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = crate::eval::calibration::DEFAULT_CALIBRATION_STEPS)]
    pub calibration_steps: Vec<usize>,
    /// Suite: score every N-th one-step window of each scene in the regime table.
    #[arg(long, default_value_t = 1)]
    pub window_stride: usize,
    /// Step sizes in frames, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1u32, 2, 4])]
    pub step_sizes: Vec<u32>,
    /// Horizons in seconds after the start frame, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [0.5f64, 1.0, 2.0, 4.0])]
    pub horizons: Vec<f64>,
    /// Start frame s: the predictor observes frames s - k and s.
    #[arg(long, default_value_t = DEFAULT_START_FRAME)]
    pub start_frame: usize,
    /// Evaluate only the first N scenes.
    #[arg(long)]
    pub max_scenes: Option<usize>,
    /// Reference points per object given to the model (a prefix of the stored cloud); default
    /// the model's nominal count (`points_per_object` of its config.json).
    #[arg(long)]
    pub points_per_object: Option<usize>,
    /// Point count of the second model variant.
    #[arg(long, default_value_t = 768)]
    pub variant_points: usize,
    /// Fraction of each object's points removed (one side of a random plane) in the third
    /// model variant.
    #[arg(long, default_value_t = 0.25)]
    pub occlude: f32,
    /// Seed of the occlusion planes.
    #[arg(long, default_value_t = 0)]
    pub occlusion_seed: u64,
    /// Evaluate the model only at its nominal point count (no 768-point or occluded variant).
    #[arg(long)]
    pub no_variants: bool,
    /// Show the predictors only frames s - k and s (t - k and t in the regime table), as a
    /// client that sends two poses, not the frame before them that a model with history
    /// inputs reads on its first step.
    #[arg(long)]
    pub two_frames: bool,
    /// Do not evaluate the static and ballistic baselines next to the model.
    #[arg(long)]
    pub no_baselines: bool,
    /// Also evaluate rapier restarted from the observed frames next to the model (the
    /// `rapier` baseline; simulates every rollout: 40 s on 200 MOVi-B scenes, minutes in the
    /// suite's regime table, which restarts it at every window).
    #[arg(long)]
    pub rapier: bool,
    /// Rebuild every object of the rapier restart as the convex hull of the first N points of
    /// its reference cloud (the points a model evaluated with N points per object sees)
    /// instead of its exact shape: what the sampled geometry allows the simulator itself.
    #[arg(long, value_name = "N")]
    pub rapier_cloud_points: Option<usize>,
    /// Steps of the k = 1 stability rollout (0 turns it off).
    #[arg(long, default_value_t = DEFAULT_LONG_ROLLOUT_STEPS)]
    pub long_steps: usize,
    /// Check the pre-projection rigidity residual at every N-th state of the stability rollout
    /// (0 turns it off).
    #[arg(long, default_value_t = DEFAULT_PROJECTION_EVERY)]
    pub projection_every: usize,
    /// Do not report the resting drift.
    #[arg(long)]
    pub no_resting: bool,
    /// Write the report as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write the Markdown tables to this file.
    #[arg(long)]
    pub markdown: Option<PathBuf>,
    /// Physics suite: write every scored one-step window (predictor, scene, object, frame,
    /// step size, regime, impact, contact flags, errors) to this CSV file.
    #[arg(long)]
    pub windows: Option<PathBuf>,
    /// Write the error-against-time PNG to this file (default: next to --json, with .png).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// PhysiFormer models: samples drawn per scene (their mean and spread are reported).
    #[arg(long, default_value_t = 3)]
    pub samples: usize,
    /// PhysiFormer models: denoising steps per sample.
    #[arg(long, default_value_t = 25)]
    pub denoise_steps: usize,
    /// PhysiFormer models on a mesh dataset: score with the official PhysiFormer metrics
    /// (`mse`, `rigidity`, `momentum_drift_ratio`) instead of the per-frame report (the
    /// official data always gets them).
    #[arg(long)]
    pub official_metrics: bool,
}

impl EvalArgs {
    /// The evaluation options these arguments ask for.
    pub fn options(&self) -> EvalOptions {
        EvalOptions {
            start_frame: self.start_frame,
            step_sizes: self.step_sizes.clone(),
            horizons_s: self.horizons.clone(),
            max_scenes: self.max_scenes,
            long_rollout_steps: self.long_steps,
            projection_every: self.projection_every,
            resting: (!self.no_resting).then(RestingOptions::default),
            two_frames: self.two_frames,
            ..EvalOptions::default()
        }
    }

    /// Where the plot goes: `--plot`, else `--json` with the extension `.png`, else nowhere.
    pub fn plot_path(&self) -> Option<PathBuf> {
        self.plot
            .clone()
            .or_else(|| self.json.as_ref().map(|j| j.with_extension("png")))
    }
}
