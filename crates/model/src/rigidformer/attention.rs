//! Multi-head scaled dot-product attention with an additive key mask and optional 3D rotary
//! codes (ARoPE) on queries and keys.

use candle_core::Tensor;

use crate::layers::{Mode, rotate_pairs, softmax_last};

/// Rotary code `(cos, sin)`, each `[B, 1, T, P]`.
pub(crate) type Rope<'a> = (&'a Tensor, &'a Tensor);

/// Attention of `q [B, Tq, D]` over `k, v [B, Tk, D]` with `heads` heads, additive key mask
/// `[B, 1, 1, Tk]` and optional rotary codes for q (`[B, 1, Tq, P]`) and k (`[B, 1, Tk, P]`).
/// Returns `[B, H, Tq, D / H]`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn multi_head(
    q: &Tensor,
    k: &Tensor,
    v: &Tensor,
    mask: &Tensor,
    rope_q: Option<Rope<'_>>,
    rope_k: Option<Rope<'_>>,
    heads: usize,
    mode: Mode,
) -> candle_core::Result<Tensor> {
    let (b, tq, d) = q.dims3()?;
    let tk = k.dim(1)?;
    let dh = d / heads;
    let split = |x: &Tensor, t: usize| -> candle_core::Result<Tensor> {
        x.reshape((b, t, heads, dh))?.transpose(1, 2)?.contiguous()
    };
    let mut q = split(q, tq)?;
    let mut k = split(k, tk)?;
    let v = split(v, tk)?;
    if let Some((cos, sin)) = rope_q {
        q = rotate_pairs(&q, cos, sin)?;
    }
    if let Some((cos, sin)) = rope_k {
        k = rotate_pairs(&k, cos, sin)?;
    }
    let scores = (q.matmul(&k.t()?.contiguous()?)? * (1.0 / (dh as f64).sqrt()))?;
    let scores = scores.broadcast_add(mask)?;
    let att = softmax_last(&scores, mode)?;
    att.matmul(&v) // [B, H, Tq, dh]
}
