//! Root-mean-square normalisation.

use candle_core::Tensor;

use super::Mode;

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
}
