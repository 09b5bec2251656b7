//! The small layers the networks are built from and the parameter store that creates them.
//! Every layer takes a [`Mode`]: inference may use fused kernels (candle's own or
//! [`crate::kernels`]), training must use ops that carry gradients: compositions or the
//! kernels of [`crate::kernels`] that have a backward pass (candle 0.11's fused
//! `softmax_last_dim` and `rms_norm` silently drop gradients).

mod linear;
mod norm;
mod params;

use candle_core::{D, Tensor};

pub(crate) use linear::{Linear, Mlp, SwiGlu};
pub(crate) use norm::RmsNorm;
pub(crate) use params::{Init, ParamStore};

/// Which kernels the forward pass uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Fast fused kernels; no gradients needed.
    Inference,
    /// Differentiable compositions only (every parameter receives its gradient).
    Training,
}

/// How one forward pass runs: the kernel [`Mode`] and whether the CPU's fused kernels
/// ([`crate::kernels`]) may replace compositions (never on other devices).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Exec {
    /// Inference or training kernels.
    pub mode: Mode,
    /// Fused CPU kernels allowed (those with a gradient in both modes, the others only in
    /// inference).
    pub fused: bool,
}

impl Exec {
    /// True when the inference-only fused kernels (attention, `exp`) may run.
    pub fn fused_inference(&self) -> bool {
        self.fused && self.mode == Mode::Inference
    }
}

/// Softmax over the last dimension.
pub fn softmax_last(x: &Tensor, mode: Mode) -> candle_core::Result<Tensor> {
    match mode {
        Mode::Inference => candle_nn::ops::softmax_last_dim(&x.contiguous()?),
        Mode::Training => candle_nn::ops::softmax(x, D::Minus1),
    }
}

/// Rotates the first `2 * cos.dim(-1)` channels of `x` (`[B, H, T, dh]`) as even/odd pairs by
/// `(cos, sin)` (`[B, 1, T, P]`); the remaining channels pass through.
pub(crate) fn rotate_pairs(x: &Tensor, cos: &Tensor, sin: &Tensor) -> candle_core::Result<Tensor> {
    let (b, h, t, dh) = x.dims4()?;
    let p = cos.dim(D::Minus1)?;
    let rot = x.narrow(D::Minus1, 0, 2 * p)?.reshape((b, h, t, p, 2))?;
    let e = rot.narrow(D::Minus1, 0, 1)?.squeeze(D::Minus1)?;
    let o = rot.narrow(D::Minus1, 1, 1)?.squeeze(D::Minus1)?;
    let re = (e.broadcast_mul(cos)? - o.broadcast_mul(sin)?)?;
    let ro = (e.broadcast_mul(sin)? + o.broadcast_mul(cos)?)?;
    let rotated = Tensor::stack(&[re, ro], D::Minus1)?.reshape((b, h, t, 2 * p))?;
    if 2 * p == dh {
        Ok(rotated)
    } else {
        Tensor::cat(
            &[rotated, x.narrow(D::Minus1, 2 * p, dh - 2 * p)?],
            D::Minus1,
        )
    }
}

/// Rows of `rows [P, C]` picked by `index [L]` (u32), where index `P` picks a zero row: how
/// packed rows are laid out in a padded layout. Differentiable in `rows`. Returns `[L, C]`.
pub(crate) fn gather_padded(rows: &Tensor, index: &Tensor) -> candle_core::Result<Tensor> {
    let c = rows.dim(1)?;
    let zero = Tensor::zeros((1, c), rows.dtype(), rows.device())?;
    Tensor::cat(&[rows, &zero], 0)?.index_select(index, 0)
}

/// Elementwise Smooth L1 of `diff` with transition `beta`, averaged over all elements.
pub fn smooth_l1_mean(diff: &Tensor, beta: f32) -> candle_core::Result<Tensor> {
    let a = diff.abs()?;
    let quad = (diff.sqr()? * (0.5 / beta as f64))?;
    let lin = (&a - 0.5 * beta as f64)?;
    let small = a.lt(beta as f64)?;
    small.where_cond(&quad, &lin)?.mean_all()
}
