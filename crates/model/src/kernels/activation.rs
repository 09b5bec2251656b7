//! Fused activations: `silu(y + b)` after a biased linear layer, the SwiGLU product
//! `silu(a) * b`, and `exp`, each one pass with the vectorised maps of [`super::simd`]. The
//! first two carry their gradient (one-pass kernels of [`super::activation_grad`] on the CPU,
//! candle ops elsewhere); `exp` is for inference only. On devices other than the CPU the callers keep the plain composition.

use candle_core::{CpuStorage, CustomOp1, CustomOp2, D, Layout, Shape, Tensor};

use super::activation_grad::{bias_silu_grad, swiglu_grad};
use super::simd::{exp_slice, par_map, sigmoid_slice, silu_slice};
use super::storage::f32_slice;

/// `silu(x) = x sigmoid(x)` derivative: `s (1 + x (1 - s))`.
fn silu_grad(x: &Tensor) -> candle_core::Result<Tensor> {
    let s = candle_nn::ops::sigmoid(x)?;
    let one_minus = s.affine(-1.0, 1.0)?;
    s.mul(&(x.mul(&one_minus)? + 1.0)?)
}

/// `silu(y + b)` for `y [rows, n]` and a bias `b [n]`.
struct BiasSilu;

impl CustomOp2 for BiasSilu {
    fn name(&self) -> &'static str {
        "bias-silu"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let y = f32_slice(self.name(), s1, l1)?;
        let b = f32_slice(self.name(), s2, l2)?;
        let n = b.len();
        if n == 0 || l1.shape().dims().last() != Some(&n) {
            candle_core::bail!("bias-silu: {:?} with bias {:?}", l1.shape(), l2.shape());
        }
        let mut out: Vec<f32> = Vec::with_capacity(y.len());
        for row in y.chunks_exact(n) {
            out.extend(row.iter().zip(b).map(|(y, b)| y + b));
        }
        par_map(&mut out, silu_slice);
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    fn bwd(
        &self,
        y: &Tensor,
        b: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        if y.device().is_cpu() {
            let (gy, gb) = bias_silu_grad(y, b, grad)?;
            return Ok((Some(gy), Some(gb)));
        }
        let z = y.broadcast_add(b)?;
        let gz = grad.mul(&silu_grad(&z)?)?;
        let rows = gz.elem_count() / b.elem_count();
        let gb = gz.reshape((rows, b.elem_count()))?.sum(0)?;
        Ok((Some(gz), Some(gb)))
    }
}

/// `silu(y + b)` (`y [.., n]`, `b [n]`) in one pass on the CPU; the composition elsewhere.
/// Differentiable in both arguments.
pub fn bias_silu(y: &Tensor, b: &Tensor) -> candle_core::Result<Tensor> {
    if y.device().is_cpu() {
        y.contiguous()?.apply_op2(b, BiasSilu)
    } else {
        y.broadcast_add(b)?.silu()
    }
}

/// `silu(u[.., :h]) * u[.., h:]` for `u [.., 2h]` -> `[.., h]`.
struct SwiGluProduct;

impl CustomOp1 for SwiGluProduct {
    fn name(&self) -> &'static str {
        "swiglu"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let u = f32_slice(self.name(), s, l)?;
        let dims = l.shape().dims();
        let two_h = dims.last().copied().unwrap_or(0);
        if two_h == 0 || !two_h.is_multiple_of(2) {
            candle_core::bail!("swiglu: last dimension of {:?} must be even", l.shape());
        }
        let h = two_h / 2;
        let mut out: Vec<f32> = Vec::with_capacity(u.len() / 2);
        for row in u.chunks_exact(two_h) {
            out.extend_from_slice(&row[..h]);
        }
        par_map(&mut out, silu_slice);
        for (o, row) in out.chunks_exact_mut(h).zip(u.chunks_exact(two_h)) {
            for (o, b) in o.iter_mut().zip(&row[h..]) {
                *o *= b;
            }
        }
        let mut shape = dims.to_vec();
        *shape.last_mut().expect("non-empty") = h;
        Ok((CpuStorage::F32(out), Shape::from(shape)))
    }

    fn bwd(&self, u: &Tensor, _res: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        if u.device().is_cpu() {
            return Ok(Some(swiglu_grad(u, grad)?));
        }
        let h = u.dim(D::Minus1)? / 2;
        let a = u.narrow(D::Minus1, 0, h)?;
        let b = u.narrow(D::Minus1, h, h)?;
        let ga = grad.mul(&b)?.mul(&silu_grad(&a)?)?;
        let gb = grad.mul(&a.silu()?)?;
        Ok(Some(Tensor::cat(&[ga, gb], D::Minus1)?))
    }
}

/// The SwiGLU product `silu(u[.., :h]) * u[.., h:]` (`u [.., 2h]` -> `[.., h]`) in one pass on
/// the CPU; the composition elsewhere. Differentiable.
pub fn swiglu_product(u: &Tensor) -> candle_core::Result<Tensor> {
    if u.device().is_cpu() {
        u.contiguous()?.apply_op1(SwiGluProduct)
    } else {
        let h = u.dim(D::Minus1)? / 2;
        u.narrow(D::Minus1, 0, h)?.silu()? * u.narrow(D::Minus1, h, h)?
    }
}

/// An element-wise map with no gradient (inference only).
struct Map(&'static str, fn(&mut [f32]));

impl CustomOp1 for Map {
    fn name(&self) -> &'static str {
        self.0
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let mut out = f32_slice(self.name(), s, l)?.to_vec();
        par_map(&mut out, self.1);
        Ok((CpuStorage::F32(out), l.shape().clone()))
    }
}

/// `exp(x)` with the vectorised map on the CPU (candle's `exp` elsewhere). No gradient: for
/// inference only.
pub fn exp_inference(x: &Tensor) -> candle_core::Result<Tensor> {
    if x.device().is_cpu() {
        x.contiguous()?.apply_op1_no_bwd(&Map("exp", exp_slice))
    } else {
        x.exp()
    }
}

/// `sigmoid(x)` with the vectorised map on the CPU (candle's elsewhere). No gradient: for
/// inference only.
pub fn sigmoid_inference(x: &Tensor) -> candle_core::Result<Tensor> {
    if x.device().is_cpu() {
        x.contiguous()?
            .apply_op1_no_bwd(&Map("sigmoid", sigmoid_slice))
    } else {
        candle_nn::ops::sigmoid(x)
    }
}

/// `silu(x)` with the vectorised map on the CPU (candle's elsewhere). No gradient: for
/// inference only.
pub fn silu_inference(x: &Tensor) -> candle_core::Result<Tensor> {
    if x.device().is_cpu() {
        x.contiguous()?.apply_op1_no_bwd(&Map("silu", silu_slice))
    } else {
        x.silu()
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{Tensor, Var};

    use super::*;
    use crate::kernels::test_data::max_diff;

    fn random(shape: &[usize], seed: u64) -> Tensor {
        crate::kernels::test_data::random(shape, seed, 8.0)
    }

    /// Value and gradients of `sum(f(args) * r)` for a random `r`.
    fn value_and_grads(
        args: &[Tensor],
        f: impl Fn(&[Tensor]) -> candle_core::Result<Tensor>,
    ) -> (Tensor, Vec<Tensor>) {
        let vars: Vec<Var> = args.iter().map(|a| Var::from_tensor(a).unwrap()).collect();
        let ts: Vec<Tensor> = vars.iter().map(|v| v.as_tensor().clone()).collect();
        let y = f(&ts).unwrap();
        let r = random(y.dims(), 99);
        let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
        let g = ts.iter().map(|t| grads.get(t).unwrap().clone()).collect();
        (y, g)
    }

    #[test]
    fn bias_silu_matches_the_composition_with_gradients() {
        // A small case, and one large enough to split the kernels over the thread pool.
        for (rows, n) in [(vec![3, 7], 33), (vec![600], 130)] {
            let shape = [rows, vec![n]].concat();
            let args = [random(&shape, 1), random(&[n], 2)];
            let (a, ga) = value_and_grads(&args, |t| bias_silu(&t[0], &t[1]));
            let (b, gb) = value_and_grads(&args, |t| t[0].broadcast_add(&t[1])?.silu());
            assert!(max_diff(&a, &b) < 1e-5);
            for (x, y) in ga.iter().zip(&gb) {
                assert_eq!(x.dims(), y.dims());
                // The bias gradient sums up to 600 rows of values up to ~10.
                let tol = 1e-4 * (1.0 + y.dim(0).unwrap() as f32).sqrt();
                assert!(
                    max_diff(x, y) < tol,
                    "gradient differs by {}",
                    max_diff(x, y)
                );
            }
        }
    }

    #[test]
    fn swiglu_matches_the_composition_with_gradients() {
        for (shape, h) in [(vec![5, 4], 24), (vec![300], 160)] {
            let args = [random(&[shape, vec![2 * h]].concat(), 3)];
            let (a, ga) = value_and_grads(&args, |t| swiglu_product(&t[0]));
            let (b, gb) = value_and_grads(&args, |t| {
                t[0].narrow(D::Minus1, 0, h)?.silu()? * t[0].narrow(D::Minus1, h, h)?
            });
            assert!(max_diff(&a, &b) < 1e-4);
            assert_eq!(ga[0].dims(), gb[0].dims());
            assert!(
                max_diff(&ga[0], &gb[0]) < 1e-4,
                "{}",
                max_diff(&ga[0], &gb[0])
            );
        }
    }

    #[test]
    fn inference_maps_match_candle() {
        let x = random(&[9, 31], 4);
        assert!(max_diff(&exp_inference(&x).unwrap(), &x.exp().unwrap()) < 1e-4 * 55.0);
        let s = candle_nn::ops::sigmoid(&x).unwrap();
        assert!(max_diff(&sigmoid_inference(&x).unwrap(), &s) < 1e-6);
        assert!(max_diff(&silu_inference(&x).unwrap(), &x.silu().unwrap()) < 1e-5);
    }
}
