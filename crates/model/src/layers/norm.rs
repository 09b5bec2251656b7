//! Root-mean-square normalisation.

use candle_core::Tensor;

use super::{Exec, Mode};
use crate::kernels::norm::rms_norm;

/// Root-mean-square normalisation with a learned scale.
#[derive(Clone, Debug)]
pub(crate) struct RmsNorm {
    pub(crate) alpha: Tensor,
    pub(crate) eps: f32,
}

impl RmsNorm {
    pub fn forward(&self, x: &Tensor, mode: Mode) -> candle_core::Result<Tensor> {
        match mode {
            Mode::Inference => candle_nn::ops::rms_norm(&x.contiguous()?, &self.alpha, self.eps),
            Mode::Training => candle_nn::ops::rms_norm_slow(x, &self.alpha, self.eps),
        }
    }

    /// As [`RmsNorm::forward`]; in training with fused kernels allowed, the one-pass kernel
    /// with its one-pass gradient ([`crate::kernels::norm`]).
    pub fn forward_exec(&self, x: &Tensor, exec: Exec) -> candle_core::Result<Tensor> {
        if exec.fused && exec.mode == Mode::Training {
            rms_norm(x, &self.alpha, self.eps)
        } else {
            self.forward(x, exec.mode)
        }
    }
}
