//! RMSNorm `y = alpha x / sqrt(mean(x^2) + eps)` over the last dimension as one CPU pass, with
//! a one-pass backward, for training (candle's fused `rms_norm` has no gradient and
//! `rms_norm_slow` runs six ops with six gradient steps). Other devices keep `rms_norm_slow`.

use candle_core::{CpuStorage, CustomOp2, CustomOp3, Layout, Shape, Tensor};

use super::simd::row_blocks;
use super::storage::f32_slice;

/// `1 / sqrt(mean(x^2) + eps)` of one row.
#[inline(always)]
fn inv_rms(x: &[f32], eps: f32) -> f32 {
    let ss: f32 = x.iter().map(|v| v * v).sum();
    1.0 / (ss / x.len() as f32 + eps).sqrt()
}

/// Checks `x [rows, n]` against `alpha [n]` (and `grad`, when given, of `x`'s size).
fn check(
    op: &str,
    x: &Layout,
    alpha: &[f32],
    n_x: usize,
    n_g: Option<usize>,
) -> candle_core::Result<usize> {
    let n = alpha.len();
    if n == 0 || x.shape().dims().last() != Some(&n) || n_g.is_some_and(|g| g != n_x) {
        candle_core::bail!("{op}: input {:?} does not match scale [{n}]", x.shape());
    }
    Ok(n)
}

/// RMSNorm of `x [.., n]` with scale `alpha [n]` (differentiable in both).
struct RmsNormOp {
    eps: f32,
}

impl CustomOp2 for RmsNormOp {
    fn name(&self) -> &'static str {
        "rms-norm"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = f32_slice(self.name(), s1, l1)?;
        let alpha = f32_slice(self.name(), s2, l2)?;
        let n = check(self.name(), l1, alpha, x.len(), None)?;
        let mut out = vec![0f32; x.len()];
        row_blocks(&mut out, n, |r0, block| {
            for (o, x) in block.chunks_exact_mut(n).zip(x[r0 * n..].chunks_exact(n)) {
                let r = inv_rms(x, self.eps);
                for ((o, x), a) in o.iter_mut().zip(x).zip(alpha) {
                    *o = x * r * a;
                }
            }
            Vec::new()
        });
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    fn bwd(
        &self,
        x: &Tensor,
        alpha: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        let n = alpha.elem_count();
        let rows = x.elem_count() / n.max(1);
        let both = x.contiguous()?.apply_op3_no_bwd(
            &alpha.contiguous()?,
            &grad.contiguous()?,
            &RmsNormGrad { eps: self.eps },
        )?;
        let gx = both.narrow(0, 0, rows)?.reshape(x.shape())?;
        let ga = both.narrow(0, rows, 1)?.reshape(alpha.shape())?;
        Ok((Some(gx), Some(ga)))
    }
}

/// Gradients of RMSNorm: `(x [rows, n], alpha [n], grad [rows, n])` -> `[rows + 1, n]`, the
/// gradient of `x` then that of `alpha`. With `r = 1 / rms(x)`, `h = x r`, `e = grad alpha`:
/// `dx = r (e - h mean(e h))`, `dalpha = sum_rows(grad h)`.
struct RmsNormGrad {
    eps: f32,
}

impl CustomOp3 for RmsNormGrad {
    fn name(&self) -> &'static str {
        "rms-norm-grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = f32_slice(self.name(), s1, l1)?;
        let alpha = f32_slice(self.name(), s2, l2)?;
        let g = f32_slice(self.name(), s3, l3)?;
        let n = check(self.name(), l1, alpha, x.len(), Some(g.len()))?;
        let rows = x.len() / n;
        let mut out = vec![0f32; (rows + 1) * n];
        let (gx, ga) = out.split_at_mut(rows * n);
        let sums = row_blocks(gx, n, |r0, block| {
            let mut col = vec![0f32; n];
            let x = x[r0 * n..].chunks_exact(n);
            let g = g[r0 * n..].chunks_exact(n);
            for ((o, x), g) in block.chunks_exact_mut(n).zip(x).zip(g) {
                let r = inv_rms(x, self.eps);
                let mut dot = 0f32;
                for (((x, g), a), c) in x.iter().zip(g).zip(alpha).zip(col.iter_mut()) {
                    let h = x * r;
                    dot += g * a * h;
                    *c += g * h;
                }
                let m = dot / n as f32;
                for (((o, x), g), a) in o.iter_mut().zip(x).zip(g).zip(alpha) {
                    *o = r * (g * a - x * r * m);
                }
            }
            col
        });
        ga.copy_from_slice(&sums);
        Ok((CpuStorage::F32(out), Shape::from((rows + 1, n))))
    }
}

/// RMSNorm of `x [.., n]` with scale `alpha [n]`: one fused pass with a one-pass gradient on
/// the CPU, candle's differentiable `rms_norm_slow` elsewhere.
pub fn rms_norm(x: &Tensor, alpha: &Tensor, eps: f32) -> candle_core::Result<Tensor> {
    if x.device().is_cpu() {
        x.contiguous()?.apply_op2(alpha, RmsNormOp { eps })
    } else {
        candle_nn::ops::rms_norm_slow(x, alpha, eps)
    }
}

#[cfg(test)]
mod tests {
    use candle_core::Var;

    use super::*;
    use crate::kernels::test_data::{max_diff, random};

    #[test]
    fn rms_norm_matches_the_composition_with_gradients() {
        // Small rows, and enough rows to split the pass over the thread pool.
        for (shape, seed) in [(vec![3, 5, 40], 1u64), (vec![700, 128], 2)] {
            let x = Var::from_tensor(&random(&shape, seed, 4.0)).unwrap();
            let n = shape[shape.len() - 1];
            let alpha = Var::from_tensor(&random(&[n], seed + 10, 2.0)).unwrap();
            let r = random(&shape, seed + 20, 2.0);
            let run = |fused: bool| {
                let (xt, at) = (x.as_tensor(), alpha.as_tensor());
                let y = if fused {
                    rms_norm(xt, at, 1e-6).unwrap()
                } else {
                    candle_nn::ops::rms_norm_slow(xt, at, 1e-6).unwrap()
                };
                let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
                let gx = grads.get(xt).unwrap().clone();
                let ga = grads.get(at).unwrap().clone();
                (y, gx, ga)
            };
            let (y1, gx1, ga1) = run(true);
            let (y2, gx2, ga2) = run(false);
            assert!(max_diff(&y1, &y2) < 1e-5, "value {}", max_diff(&y1, &y2));
            assert!(max_diff(&gx1, &gx2) < 1e-4, "dx {}", max_diff(&gx1, &gx2));
            let scale = ga2
                .abs()
                .unwrap()
                .max(0)
                .unwrap()
                .to_scalar::<f32>()
                .unwrap();
            let da = max_diff(&ga1, &ga2);
            assert!(da < 1e-5 * scale.max(1.0), "dalpha {da} of {scale}");
        }
    }

    #[test]
    fn mismatched_scale_is_an_error() {
        let x = random(&[4, 8], 3, 1.0);
        let alpha = random(&[7], 4, 1.0);
        assert!(rms_norm(&x, &alpha, 1e-6).is_err());
    }
}
