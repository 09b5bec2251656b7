//! The fused attention ops' definitions (what each op holds: heads, key biases, rotary
//! codes) and the per-row helpers that the forward kernels of [`super::attention`] and the
//! backward kernels of [`super::attention_grad`] share.

use std::sync::Arc;

use super::simd::exp_slice;

/// Rows of rotary cosines and sines, each `[rows, P]`.
#[derive(Clone, Debug, Default)]
pub struct RotaryRows {
    /// Cosines `[rows, P]`.
    pub cos: Vec<f32>,
    /// Sines `[rows, P]`.
    pub sin: Vec<f32>,
    /// Rotated channel pairs per head (`P`).
    pub pairs: usize,
}

impl RotaryRows {
    /// Cosines and sines of row `r`, `[P]` each.
    pub(crate) fn row(&self, r: usize) -> (&[f32], &[f32]) {
        let p = self.pairs;
        (&self.cos[r * p..(r + 1) * p], &self.sin[r * p..(r + 1) * p])
    }
}

/// Self-attention of a padded pass: `qkv [B, T, 3D]` (queries, keys, values) and gate logits
/// `[B, T, H]` -> `sigmoid(gate) * attention` `[B, T, D]`, heads side by side.
#[derive(Clone, Debug)]
pub struct SelfAttention {
    /// Heads (`D / H` channels each).
    pub heads: usize,
    /// Additive bias per key `[B, T]` (0, or a large negative value for a padded slot).
    pub key_bias: Arc<Vec<f32>>,
    /// Rotary code of every token `[B * T, P]` (applied to queries and keys).
    pub rope: Arc<RotaryRows>,
}

/// Cross-attention of ragged query rows: `q [Nq, D]`, row `r` belonging to scene
/// `query_scene[r]`, over `kv [B, Tk, 2D]` (keys then values) -> `[Nq, D]`.
#[derive(Clone, Debug)]
pub struct CrossAttention {
    /// Heads (`D / H` channels each).
    pub heads: usize,
    /// Scene of each query row `[Nq]`.
    pub query_scene: Arc<Vec<u32>>,
    /// Additive bias per key `[B, Tk]`.
    pub key_bias: Arc<Vec<f32>>,
    /// Rotary code of every query row `[Nq, P]`.
    pub q_rope: Arc<RotaryRows>,
    /// Rotary code of every key `[B * Tk, P]`.
    pub k_rope: Arc<RotaryRows>,
}

/// Rotates the channel pairs `(2i, 2i + 1)`, `i < P`, of `x` by `(cos_i, sin_i)`.
pub(crate) fn rotate(x: &mut [f32], cos: &[f32], sin: &[f32]) {
    for (i, (c, s)) in cos.iter().zip(sin).enumerate() {
        let (e, o) = (x[2 * i], x[2 * i + 1]);
        x[2 * i] = e * c - o * s;
        x[2 * i + 1] = e * s + o * c;
    }
}

/// `x <- exp(x - max(x))` in place (a softmax before its division); returns the sum.
#[inline(always)]
pub(crate) fn exp_shifted(x: &mut [f32]) -> f32 {
    let max = x.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
    x.iter_mut().for_each(|v| *v -= max);
    exp_slice(x);
    x.iter().sum()
}
