//! The `[optim]` section: AdamW, the learning-rate schedule, clipping, batch size and length.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Optimiser, learning-rate schedule and length of training.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OptimConfig {
    /// Scenes per iteration (one window each).
    pub batch_size: usize,
    /// Total iterations; the cosine schedule reaches `min_lr_ratio * lr` here.
    pub iterations: u64,
    /// Peak learning rate.
    pub lr: f64,
    /// Linear warm-up length in iterations.
    pub warmup: u64,
    /// Learning rate at iteration 0 as a fraction of `lr` (default 0.1).
    pub warmup_start: f64,
    /// Final learning rate of the cosine decay as a fraction of `lr`.
    pub min_lr_ratio: f64,
    /// AdamW first-moment decay.
    pub beta1: f64,
    /// AdamW second-moment decay.
    pub beta2: f64,
    /// AdamW epsilon.
    pub eps: f64,
    /// Decoupled weight decay for matrices (norm scales, biases, registers, embeddings and the
    /// AVP bandwidth get none).
    pub weight_decay: f64,
    /// Global gradient-norm clip (over all parameters); 0 disables.
    pub grad_clip: f64,
    /// Decay of the exponential moving average of the weights kept beside the raw weights
    /// (exported when better); 0 disables.
    pub ema_decay: f64,
    /// Learning-rate factors by parameter-name prefix (`[optim.lr_scale]`, e.g.
    /// `"contact_summary." = 10.0`): every parameter whose name starts with a prefix trains at
    /// that multiple of the schedule's rate (the longest matching prefix wins; weight decay
    /// scales with it), the rest at the schedule's. For layers added to a trained model, which
    /// start at zero and would otherwise learn at the rate chosen to keep the trained weights
    /// near their optimum. Every factor must be finite and positive and every prefix must name
    /// at least one parameter. Empty by default.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub lr_scale: BTreeMap<String, f64>,
    /// Sharpness-aware minimisation's radius (0 disables, the default): each iteration takes
    /// the gradient again at the weights moved by this distance (global L2 norm over all
    /// parameters) along the batch's normalised gradient, and the update uses that second
    /// gradient at the unmoved weights. It seeks weights whose loss stays low in a
    /// neighbourhood, which tends to generalise better; each iteration costs two passes.
    #[serde(skip_serializing_if = "is_zero")]
    pub sam_rho: f64,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

impl Default for OptimConfig {
    fn default() -> Self {
        OptimConfig {
            batch_size: 16,
            iterations: 20_000,
            lr: 5e-4,
            warmup: 500,
            warmup_start: 0.1,
            min_lr_ratio: 0.02,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 0.05,
            grad_clip: 1.0,
            ema_decay: 0.999,
            lr_scale: BTreeMap::new(),
            sam_rho: 0.0,
        }
    }
}
