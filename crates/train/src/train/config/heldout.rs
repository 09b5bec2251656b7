//! The `[heldout]` section: what the held-out watch scores along a run and how often.

use serde::{Deserialize, Serialize};

use super::data::valid_step_sizes;
use crate::train::TrainError;

/// What the held-out watch scores and how often ([`TrainConfig::heldout`](super::TrainConfig)).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HeldoutConfig {
    /// Iterations between scores; 0 (the default) turns the watch off.
    pub every: u64,
    /// Seed of the generated suite (split `test`).
    pub seed: u64,
    /// Scenes per suite group.
    pub scenes: usize,
    /// Reference points per object of the generated scenes (the model samples its own count
    /// from them, as in `dynaserve eval`).
    pub points: usize,
    /// Step sizes of the regime rows, frames.
    pub step_sizes: Vec<u32>,
    /// Every `n`-th window of a scene enters the regime rows (1: all).
    pub window_stride: usize,
}

impl Default for HeldoutConfig {
    fn default() -> Self {
        HeldoutConfig {
            every: 0,
            seed: 8,
            scenes: 2,
            points: 1024,
            step_sizes: vec![1, 4],
            window_stride: 1,
        }
    }
}

impl HeldoutConfig {
    /// Checks ranges; every violation is named.
    pub fn validate(&self) -> Result<(), TrainError> {
        let bad = |m: &str| Err(TrainError::Config(format!("heldout.{m}")));
        if self.every == 0 {
            return Ok(());
        }
        if !(1..=64).contains(&self.scenes) {
            return bad("scenes must be in 1..=64");
        }
        if self.points < 16 {
            return bad("points must be at least 16");
        }
        if !valid_step_sizes(&self.step_sizes) {
            return bad("step_sizes must be non-empty, each in 1..=16");
        }
        if self.window_stride == 0 {
            return bad("window_stride must be at least 1");
        }
        Ok(())
    }
}
