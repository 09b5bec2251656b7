//! Backward kernels of the fused activations of [`super::activation`]: each reads the saved
//! input and the incoming gradient once and writes the input gradients in one pass, where the
//! candle composition materialised about eight full-size temporaries. CPU only (the forward ops
//! they differentiate only run on the CPU); no gradient of their own.

use candle_core::{CpuStorage, CustomOp2, CustomOp3, Layout, Shape, Tensor};

use super::simd::{axpy, row_blocks, sigmoid_slice};
use super::storage::f32_slice;

/// `s (1 + z (1 - s))` with `s = sigmoid(z)`: the derivative of `silu(z)`.
#[inline(always)]
fn silu_slope(z: f32, s: f32) -> f32 {
    s * (1.0 + z * (1.0 - s))
}

/// Gradients of `silu(y + b)`: `(y [rows, n], b [n], grad [rows, n])` -> `[rows + 1, n]`, the
/// first `rows` rows the gradient of `y`, the last the gradient of `b` (column sums).
struct BiasSiluGrad;

impl CustomOp3 for BiasSiluGrad {
    fn name(&self) -> &'static str {
        "bias-silu-grad"
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
        let y = f32_slice(self.name(), s1, l1)?;
        let b = f32_slice(self.name(), s2, l2)?;
        let g = f32_slice(self.name(), s3, l3)?;
        let n = b.len();
        if n == 0 || !y.len().is_multiple_of(n) || g.len() != y.len() {
            candle_core::bail!(
                "{}: y {:?}, bias {:?}, grad {:?}",
                self.name(),
                l1.shape(),
                l2.shape(),
                l3.shape()
            );
        }
        let rows = y.len() / n;
        let mut out = vec![0f32; (rows + 1) * n];
        let (gy, gb) = out.split_at_mut(rows * n);
        let sums = row_blocks(gy, n, |r0, block| {
            let (y, g) = (&y[r0 * n..][..block.len()], &g[r0 * n..][..block.len()]);
            for (row, y) in block.chunks_exact_mut(n).zip(y.chunks_exact(n)) {
                for ((o, y), b) in row.iter_mut().zip(y).zip(b) {
                    *o = y + b;
                }
            }
            let mut s = block.to_vec();
            sigmoid_slice(&mut s);
            for ((o, s), g) in block.iter_mut().zip(&s).zip(g) {
                *o = g * silu_slope(*o, *s);
            }
            let mut col = vec![0f32; n];
            for row in block.chunks_exact(n) {
                axpy(&mut col, 1.0, row);
            }
            col
        });
        gb.copy_from_slice(&sums);
        Ok((CpuStorage::F32(out), Shape::from((rows + 1, n))))
    }
}

/// Gradients `(of y, of b)` of `silu(y + b)` for `y [.., n]`, `b [n]` and the incoming
/// gradient `grad` of `y`'s shape, in one pass (CPU tensors).
pub fn bias_silu_grad(
    y: &Tensor,
    b: &Tensor,
    grad: &Tensor,
) -> candle_core::Result<(Tensor, Tensor)> {
    let n = b.elem_count();
    let rows = y.elem_count() / n.max(1);
    let both =
        y.contiguous()?
            .apply_op3_no_bwd(&b.contiguous()?, &grad.contiguous()?, &BiasSiluGrad)?;
    let gy = both.narrow(0, 0, rows)?.reshape(y.shape())?;
    let gb = both.narrow(0, rows, 1)?.reshape(b.shape())?;
    Ok((gy, gb))
}

/// Gradient of the SwiGLU product `silu(a) * c` with `u = [a, c]`: `(u [rows, 2h], grad
/// [rows, h])` -> `[rows, 2h]` (`grad c silu'(a)` then `grad silu(a)`).
struct SwiGluGrad;

impl CustomOp2 for SwiGluGrad {
    fn name(&self) -> &'static str {
        "swiglu-grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let u = f32_slice(self.name(), s1, l1)?;
        let g = f32_slice(self.name(), s2, l2)?;
        let two_h = l1.shape().dims().last().copied().unwrap_or(0);
        let h = two_h / 2;
        if h == 0 || two_h != 2 * h || g.len() * 2 != u.len() {
            candle_core::bail!(
                "{}: u {:?} and grad {:?}",
                self.name(),
                l1.shape(),
                l2.shape()
            );
        }
        let mut out = vec![0f32; u.len()];
        row_blocks(&mut out, two_h, |r0, block| {
            let rows = block.len() / two_h;
            let u = &u[r0 * two_h..][..block.len()];
            let g = &g[r0 * h..][..rows * h];
            for ((o, u), g) in block
                .chunks_exact_mut(two_h)
                .zip(u.chunks_exact(two_h))
                .zip(g.chunks_exact(h))
            {
                let (oa, oc) = o.split_at_mut(h);
                let (a, c) = u.split_at(h);
                oa.copy_from_slice(a);
                sigmoid_slice(oa);
                for ((((oa, oc), a), c), g) in oa.iter_mut().zip(oc).zip(a).zip(c).zip(g) {
                    let s = *oa;
                    *oc = g * a * s;
                    *oa = g * c * silu_slope(*a, s);
                }
            }
            Vec::new()
        });
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }
}

/// Gradient of the SwiGLU product `silu(u[.., :h]) * u[.., h:]` with respect to `u [.., 2h]`
/// given the incoming gradient `grad [.., h]`, in one pass (CPU tensors).
pub fn swiglu_grad(u: &Tensor, grad: &Tensor) -> candle_core::Result<Tensor> {
    u.contiguous()?
        .apply_op2_no_bwd(&grad.contiguous()?, &SwiGluGrad)
}
