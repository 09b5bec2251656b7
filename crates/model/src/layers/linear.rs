//! Fully connected layers: [`Linear`], the two-layer SiLU [`Mlp`] and the [`SwiGlu`]
//! feed-forward.

use candle_core::{D, DType, Tensor};

use super::ParamStore;
use crate::ModelError;
use crate::kernels::activation::{bias_silu, swiglu_product};
use crate::kernels::grouped_mlp::MlpWeights;
use crate::kernels::linear::linear;
use crate::kernels::pool::bias_group_max;

/// `y = x W^T + b` over the last dimension of any-rank input.
#[derive(Clone, Debug)]
pub(crate) struct Linear {
    pub(crate) w: Tensor,
    pub(crate) b: Option<Tensor>,
}

impl Linear {
    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        if x.rank() == 2 {
            // No reshapes: each would be one more node with a full-size gradient copy.
            return linear(x, &self.w, self.b.as_ref());
        }
        let dims = x.dims().to_vec();
        let last = dims[dims.len() - 1];
        let rows = x.elem_count() / last.max(1);
        let y = linear(&x.reshape((rows, last))?, &self.w, self.b.as_ref())?;
        let mut out = dims;
        let n = out.len();
        out[n - 1] = self.w.dim(0)?;
        y.reshape(out)
    }

    /// `silu(x W^T + b)`; with `fused`, the bias and SiLU run as one kernel (same gradient).
    pub fn forward_silu(&self, x: &Tensor, fused: bool) -> candle_core::Result<Tensor> {
        match (&self.b, fused) {
            (Some(b), true) => {
                let no_bias = Linear {
                    w: self.w.clone(),
                    b: None,
                };
                bias_silu(&no_bias.forward(x)?, b)
            }
            _ => self.forward(x)?.silu(),
        }
    }
}

/// Two-layer MLP with SiLU: `in -> hidden -> out`.
#[derive(Clone, Debug)]
pub(crate) struct Mlp {
    a: Linear,
    b: Linear,
}

impl Mlp {
    pub fn new(
        p: &mut ParamStore,
        name: &str,
        input: usize,
        hidden: usize,
        output: usize,
    ) -> Result<Mlp, ModelError> {
        Ok(Mlp {
            a: p.linear(&format!("{name}.0"), input, hidden, true)?,
            b: p.linear(&format!("{name}.1"), hidden, output, true)?,
        })
    }

    /// Host copy of the parameters for the CPU kernel of
    /// [`crate::kernels::grouped_mlp`] (both layers must have biases).
    pub fn host_weights(&self) -> candle_core::Result<MlpWeights> {
        let v = |t: &Tensor| t.flatten_all()?.to_dtype(DType::F32)?.to_vec1::<f32>();
        let (Some(b1), Some(b2)) = (&self.a.b, &self.b.b) else {
            candle_core::bail!("grouped MLP: both layers need a bias");
        };
        Ok(MlpWeights {
            w1: v(&self.a.w)?,
            b1: v(b1)?,
            w2: v(&self.b.w)?,
            b2: v(b2)?,
        })
    }

    /// `[.., in]` -> `[.., out]`; `fused` as in [`Linear::forward_silu`].
    pub fn forward(&self, x: &Tensor, fused: bool) -> candle_core::Result<Tensor> {
        self.b.forward(&self.a.forward_silu(x, fused)?)
    }

    /// `[rows, in]` -> `[rows / g, out]`: the MLP, then the maximum over each group of `g`
    /// consecutive rows; with `fused`, the output bias and the pooling are one kernel (same
    /// gradient).
    pub fn forward_max_pool(
        &self,
        x: &Tensor,
        g: usize,
        fused: bool,
    ) -> candle_core::Result<Tensor> {
        let h = self.a.forward_silu(x, fused)?;
        match (&self.b.b, fused) {
            (Some(bias), true) => {
                let no_bias = Linear {
                    w: self.b.w.clone(),
                    b: None,
                };
                bias_group_max(&no_bias.forward(&h)?, bias, g)
            }
            _ => {
                let y = self.b.forward(&h)?;
                let (rows, n) = y.dims2()?;
                if g == 0 || !rows.is_multiple_of(g) {
                    candle_core::bail!("max-pool: {rows} rows do not split into groups of {g}");
                }
                y.reshape((rows / g, g, n))?.max(1)
            }
        }
    }
}

/// SwiGLU feed-forward: `W2 (silu(W1a x) * W1b x)`.
#[derive(Clone, Debug)]
pub(crate) struct SwiGlu {
    up: Linear,
    down: Linear,
    hidden: usize,
}

impl SwiGlu {
    pub fn new(
        p: &mut ParamStore,
        name: &str,
        dim: usize,
        hidden: usize,
    ) -> Result<SwiGlu, ModelError> {
        Ok(SwiGlu {
            up: p.linear(&format!("{name}.up"), dim, 2 * hidden, false)?,
            down: p.linear(&format!("{name}.down"), hidden, dim, false)?,
            hidden,
        })
    }

    /// `[.., dim]` -> `[.., dim]`; with `fused` the gate product is one kernel (same
    /// gradient).
    pub fn forward(&self, x: &Tensor, fused: bool) -> candle_core::Result<Tensor> {
        let u = self.up.forward(x)?;
        let g = if fused {
            swiglu_product(&u)?
        } else {
            let a = u.narrow(D::Minus1, 0, self.hidden)?;
            let b = u.narrow(D::Minus1, self.hidden, self.hidden)?;
            (a.silu()? * b)?
        };
        self.down.forward(&g)
    }
}
