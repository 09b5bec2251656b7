//! The `[run]` section: the run directory, checkpoint cadence, logging, threads and device.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// Where results go and how often.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Run directory: `checkpoint/`, `log.csv`, `loss.png`, `train-config.toml`.
    pub out_dir: PathBuf,
    /// Minutes between checkpoints (also written at the end and on Ctrl-C / SIGTERM).
    pub checkpoint_minutes: f64,
    /// Iterations between CSV log rows (losses are averaged over them).
    pub log_every: u64,
    /// Threads of the dedicated compute pool (model forward/backward).
    pub threads: usize,
    /// Threads that draw and prepare the samples of a batch (window, augmentation, anchors
    /// and encoder groups). 1 prepares them one after another on the loader thread; more
    /// keep a fast device fed. The batches are the same for any value.
    pub loader_threads: usize,
    /// Device the model trains on: `cpu`, `cuda` or `cuda:N` (a build with `--features
    /// cuda`). Not part of the run's identity: a run may be resumed on another device.
    pub device: String,
    /// Seed of the data order and augmentation.
    pub seed: u64,
    /// Show a progress bar (otherwise a plain line per log row).
    pub progress: bool,
    /// Iterations after which a copy of the checkpoint is kept as `checkpoint-NNNNN/` beside
    /// `checkpoint/` (weights, optimiser moments with the weight average, state), for
    /// averaging weights along a run (`dynaserve train export --run DIR/checkpoint-NNNNN
    /// --ema`, then `dynaserve train average`). Empty keeps none.
    pub keep_checkpoints: Vec<u64>,
}

impl Default for RunConfig {
    fn default() -> Self {
        RunConfig {
            out_dir: PathBuf::from("runs/rigidformer-small"),
            checkpoint_minutes: 5.0,
            log_every: 20,
            threads: 2,
            loader_threads: 1,
            device: "cpu".to_string(),
            seed: 0,
            progress: true,
            keep_checkpoints: Vec::new(),
        }
    }
}
