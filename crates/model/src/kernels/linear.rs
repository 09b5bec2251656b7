//! `y = x W^T + b` on the CPU as one `gemm` call whose output starts as the bias rows (or, with
//! no bias, is written only by the product). candle's matmul zero-fills every output before the
//! product (a memset of each layer's result, 4-6% of a profiled step) and the bias is a second
//! pass with its own allocation. The gradient is the usual three products, in candle ops.
//!
//! [`linear_frozen`] takes the weight already transposed to `[k, n]` (a copy an inference model
//! keeps): `gemm` packs the weight panel of each call, and reads a `[n, k]` weight one strided
//! element at a time where a `[k, n]` one is copied a vector at a time.

use std::ops::Range;

use candle_core::{CpuStorage, CustomOp2, CustomOp3, Layout, Shape, Tensor};

use super::product::{Destination, Operand, product};
use super::storage::f32_slice;
use crate::team::{self, part_range};

/// Multiply-adds from which a product is split by `gemm` over rayon's pool. Below, splitting
/// over the pool cost more than it saved (a one-scene step's decoder, products of 18 rows,
/// ran slower on two threads than on one: the workers sleep between operations), so smaller
/// products go to the spinning [`team`] instead.
const PARALLEL_MIN_MACS: usize = 1 << 22;

/// Output columns per part are a multiple of this (`gemm`'s kernel covers 32 per tile).
const TEAM_COLUMNS: usize = 32;

/// How a contiguous weight matrix is stored.
#[derive(Clone, Copy, PartialEq)]
enum WeightLayout {
    /// `[n, k]`: the layer's parameter.
    OutIn,
    /// `[k, n]`: its transpose.
    InOut,
}

/// `x [m, k]` (any 2-D strides) times `w [n, k]` (contiguous, or `[k, n]` with
/// [`WeightLayout::InOut`]) transposed, plus `b [n]`.
fn linear_product(
    op: &str,
    xs: &CpuStorage,
    xl: &Layout,
    (w, wl, layout): (&[f32], &Layout, WeightLayout),
    b: Option<&[f32]>,
) -> candle_core::Result<(CpuStorage, Shape)> {
    let (m, k) = xl.shape().dims2()?;
    let (n, kw) = match (wl.shape().dims2()?, layout) {
        ((n, k), WeightLayout::OutIn) | ((k, n), WeightLayout::InOut) => (n, k),
    };
    if kw != k || b.is_some_and(|b| b.len() != n) {
        candle_core::bail!(
            "{op}: input {:?}, weight {:?} and bias of {:?} values do not fit",
            xl.shape(),
            wl.shape(),
            b.map(<[f32]>::len)
        );
    }
    let CpuStorage::F32(data) = xs else {
        candle_core::bail!("{op}: expects f32 input");
    };
    let x = &data[xl.start_offset()..];
    let (rs, cs) = (xl.stride()[0], xl.stride()[1]);
    let mut y: Vec<f32> = Vec::with_capacity(m * n);
    if let Some(b) = b {
        for _ in 0..m {
            y.extend_from_slice(b);
        }
    } else if k == 0 {
        y.resize(m * n, 0.0);
    }
    if k > 0 && m > 0 && n > 0 {
        if (m - 1) * rs + (k - 1) * cs >= x.len() {
            candle_core::bail!("{op}: input layout {xl:?} outside its storage");
        }
        let (w_rs, w_cs) = match layout {
            WeightLayout::OutIn => (1, k),
            WeightLayout::InOut => (n, 1),
        };
        let x = Operand {
            ptr: x.as_ptr(),
            rs,
            cs,
        };
        let read = b.is_some();
        let dst = Destination(y.as_mut_ptr());
        // Output columns `cols` (all rows): y's row stride stays n, the weight's columns start
        // at its column `cols.start`.
        let columns = |cols: Range<usize>, par: gemm::Parallelism| {
            if cols.is_empty() {
                return;
            }
            let first = match layout {
                WeightLayout::OutIn => cols.start * k,
                WeightLayout::InOut => cols.start,
            };
            let w = Operand {
                ptr: w[first..].as_ptr(),
                rs: w_rs,
                cs: w_cs,
            };
            // SAFETY: x holds every element (m - 1) * rs + (k - 1) * cs past its start
            // (checked above); w is contiguous [n, k] (so w^T has column stride k, row stride
            // 1) or [k, n] (row stride n, column stride 1), of which columns `cols` are read;
            // y has capacity m * n and its columns `cols` are either initialised with the bias
            // (read) or written in full by the product (not read; alpha 0). Concurrent calls
            // (the team's parts) write disjoint columns and are joined before y's length is
            // set.
            unsafe {
                product(
                    (m, cols.len(), k),
                    dst.at(cols.start),
                    n,
                    read,
                    x,
                    w,
                    1.0,
                    par,
                )
            };
        };
        let macs = m * n * k;
        if macs >= PARALLEL_MIN_MACS {
            let par = match rayon::current_num_threads() {
                1 => gemm::Parallelism::None,
                threads => gemm::Parallelism::Rayon(threads),
            };
            columns(0..n, par);
        } else if macs >= team::SPLIT_MIN_MACS && n >= 2 * TEAM_COLUMNS {
            // A small product: its output columns split over the compute team, each part
            // reading only its share of the weight.
            team::run(|part, parts| {
                columns(
                    part_range(n, part, parts, TEAM_COLUMNS),
                    gemm::Parallelism::None,
                )
            });
        } else {
            columns(0..n, gemm::Parallelism::None);
        }
        // SAFETY: every element was written above (see the products' comments).
        unsafe {
            y.set_len(m * n);
        }
    }
    Ok((CpuStorage::F32(y), Shape::from((m, n))))
}

/// The gradient of `x W^T + b` with the weight stored as `layout`: all three products for a
/// parameter (`OutIn`); for a transposed constant (`InOut`) only the input's.
fn linear_grad(
    layout: WeightLayout,
    x: &Tensor,
    w: &Tensor,
    grad: &Tensor,
) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
    Ok(match layout {
        WeightLayout::OutIn => (Some(grad.matmul(w)?), Some(grad.t()?.matmul(x)?)),
        WeightLayout::InOut => (Some(grad.matmul(&w.t()?)?), None),
    })
}

/// `x W^T` (no bias), the weight stored as the layout says.
struct LinearNoBias(WeightLayout);

impl CustomOp2 for LinearNoBias {
    fn name(&self) -> &'static str {
        "linear"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let w = f32_slice(self.name(), s2, l2)?;
        linear_product(self.name(), s1, l1, (w, l2, self.0), None)
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        linear_grad(self.0, x, w, grad)
    }
}

/// `x W^T + b`, the weight stored as the layout says.
struct LinearBias(WeightLayout);

impl CustomOp3 for LinearBias {
    fn name(&self) -> &'static str {
        "linear-bias"
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
        let w = f32_slice(self.name(), s2, l2)?;
        let b = f32_slice(self.name(), s3, l3)?;
        linear_product(self.name(), s1, l1, (w, l2, self.0), Some(b))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _b: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (dx, dw) = linear_grad(self.0, x, w, grad)?;
        let db = match self.0 {
            WeightLayout::OutIn => Some(grad.sum(0)?),
            WeightLayout::InOut => None,
        };
        Ok((dx, dw, db))
    }
}

/// `x [m, k] W^T + b` with `w` stored as `layout`: one `gemm` call on the CPU for f32 rank-2
/// input; candle's matmul and broadcast add otherwise.
fn apply(
    x: &Tensor,
    w: &Tensor,
    b: Option<&Tensor>,
    layout: WeightLayout,
) -> candle_core::Result<Tensor> {
    let cpu_f32 = x.device().is_cpu()
        && x.dtype() == candle_core::DType::F32
        && w.dtype() == candle_core::DType::F32
        && b.is_none_or(|b| b.dtype() == candle_core::DType::F32);
    if !cpu_f32 || x.rank() != 2 {
        let y = match layout {
            WeightLayout::OutIn => x.matmul(&w.t()?)?,
            WeightLayout::InOut => x.matmul(w)?,
        };
        return match b {
            Some(b) => y.broadcast_add(b),
            None => Ok(y),
        };
    }
    let w = w.contiguous()?;
    match b {
        Some(b) => x.apply_op3(&w, &b.contiguous()?, LinearBias(layout)),
        None => x.apply_op2(&w, LinearNoBias(layout)),
    }
}

/// `x [m, k] W^T + b` for `w [n, k]`, `b [n]` -> `[m, n]`, differentiable in all three. One
/// `gemm` call on the CPU for f32 tensors; candle's matmul and broadcast add otherwise.
pub fn linear(x: &Tensor, w: &Tensor, b: Option<&Tensor>) -> candle_core::Result<Tensor> {
    apply(x, w, b, WeightLayout::OutIn)
}

/// `x [m, k] W^T + b` from the transposed weight `wt [k, n]` and `b [n]` -> `[m, n]`; the same
/// values as [`linear`] with `w = wt^T`. For weights that do not train: the gradient reaches
/// `x` only.
pub fn linear_frozen(x: &Tensor, wt: &Tensor, b: Option<&Tensor>) -> candle_core::Result<Tensor> {
    apply(x, wt, b, WeightLayout::InOut)
}

#[cfg(test)]
mod tests {
    use candle_core::Var;

    use super::*;
    use crate::kernels::test_data::{max_diff, random};

    #[test]
    fn linear_matches_the_composition_with_gradients() {
        // Small, odd sizes; a product large enough for the threaded gemm; a transposed input.
        for (m, k, n, bias, transposed, seed) in [
            (5usize, 3usize, 7usize, true, false, 1u64),
            (300, 64, 96, true, false, 2),
            (40, 17, 9, false, false, 3),
            (12, 8, 6, true, true, 4),
        ] {
            let x = if transposed {
                Var::from_tensor(&random(&[k, m], seed, 2.0)).unwrap()
            } else {
                Var::from_tensor(&random(&[m, k], seed, 2.0)).unwrap()
            };
            let w = Var::from_tensor(&random(&[n, k], seed + 1, 1.0)).unwrap();
            let b = Var::from_tensor(&random(&[n], seed + 2, 1.0)).unwrap();
            let r = random(&[m, n], seed + 3, 1.0);
            let run = |fused: bool| {
                let xt = if transposed {
                    x.as_tensor().t().unwrap()
                } else {
                    x.as_tensor().clone()
                };
                let bt = bias.then(|| b.as_tensor());
                let y = if fused {
                    linear(&xt, w.as_tensor(), bt).unwrap()
                } else {
                    let y = xt.matmul(&w.as_tensor().t().unwrap()).unwrap();
                    match bt {
                        Some(bt) => y.broadcast_add(bt).unwrap(),
                        None => y,
                    }
                };
                let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
                let gx = grads.get(x.as_tensor()).unwrap().clone();
                let gw = grads.get(w.as_tensor()).unwrap().clone();
                let gb = bias.then(|| grads.get(b.as_tensor()).unwrap().clone());
                (y, gx, gw, gb)
            };
            let (y1, gx1, gw1, gb1) = run(true);
            let (y2, gx2, gw2, gb2) = run(false);
            assert_eq!(y1.dims(), &[m, n]);
            for (what, a, b) in [("y", &y1, &y2), ("dx", &gx1, &gx2), ("dw", &gw1, &gw2)] {
                let d = max_diff(a, b);
                assert!(d < 1e-4, "{m}x{k}x{n} {what}: {d}");
            }
            if let (Some(a), Some(b)) = (gb1, gb2) {
                assert!(max_diff(&a, &b) < 1e-4);
            }
        }
    }

    #[test]
    fn transposed_weight_gives_the_same_values_and_input_gradient() {
        for (m, k, n, bias, seed) in [
            (18usize, 128usize, 512usize, false, 5u64),
            (7, 5, 3, true, 6),
        ] {
            let x = Var::from_tensor(&random(&[m, k], seed, 2.0)).unwrap();
            let w = random(&[n, k], seed + 1, 1.0);
            let wt = w.t().unwrap().contiguous().unwrap();
            let b = random(&[n], seed + 2, 1.0);
            let r = random(&[m, n], seed + 3, 1.0);
            let bt = bias.then_some(&b);
            let y1 = linear_frozen(x.as_tensor(), &wt, bt).unwrap();
            let y2 = linear(x.as_tensor(), &w, bt).unwrap();
            assert_eq!(y1.dims(), &[m, n]);
            assert!(max_diff(&y1, &y2) < 1e-4, "{}", max_diff(&y1, &y2));
            let g = |y: &Tensor| {
                let grads = (y * &r).unwrap().sum_all().unwrap().backward().unwrap();
                grads.get(x.as_tensor()).unwrap().clone()
            };
            assert!(max_diff(&g(&y1), &g(&y2)) < 1e-4);
        }
        let x = random(&[4, 3], 1, 1.0);
        assert!(linear_frozen(&x, &random(&[2, 5], 2, 1.0), None).is_err());
    }

    #[test]
    fn mismatched_shapes_are_errors() {
        let x = random(&[4, 3], 1, 1.0);
        assert!(linear(&x, &random(&[5, 2], 2, 1.0), None).is_err());
        let w = random(&[5, 3], 3, 1.0);
        assert!(linear(&x, &w, Some(&random(&[4], 4, 1.0))).is_err());
        assert_eq!(linear(&x, &w, None).unwrap().dims(), &[4, 5]);
    }
}
