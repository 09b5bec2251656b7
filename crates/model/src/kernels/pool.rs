//! The set-abstraction pooling: a bias added to `y [groups * g, n]` and the maximum over each
//! group of `g` consecutive rows, `[groups, n]`, as one CPU pass, and its gradient as another
//! (the gradient goes to the row that held the maximum, the first of tied rows, and the bias
//! gets the column sums; candle's `max` gives every tied row the whole gradient, so the two
//! differ where a group repeats a row, as when an object has fewer points than neighbours). The
//! composition materialises `y + b`, and its gradient runs a comparison, a cast, a product and
//! two broadcasts over `[groups * g, n]`. Other devices keep the composition.

use candle_core::{CpuStorage, CustomOp2, CustomOp3, Layout, Shape, Tensor};

use super::simd::row_blocks;
use super::storage::f32_slice;

/// Checks `y [rows, n]` against `b [n]` and the group size; returns `(rows, n)`.
fn check(op: &str, y: &Layout, b: &[f32], g: usize) -> candle_core::Result<(usize, usize)> {
    let n = b.len();
    let rows = y.shape().elem_count() / n.max(1);
    if n == 0 || g == 0 || y.shape().dims().last() != Some(&n) || !rows.is_multiple_of(g) {
        candle_core::bail!(
            "{op}: input {:?} with bias [{n}] does not split into groups of {g} rows",
            y.shape()
        );
    }
    Ok((rows, n))
}

/// For group `rows [g, n]` (plus bias), the maximum of every column and the row holding it.
#[inline(always)]
fn group_max(rows: &[f32], b: &[f32], n: usize, max: &mut [f32], arg: &mut [u32]) {
    max.copy_from_slice(&rows[..n]);
    for (m, b) in max.iter_mut().zip(b) {
        *m += b;
    }
    arg.fill(0);
    for (r, row) in rows.chunks_exact(n).enumerate().skip(1) {
        for (((m, a), y), b) in max.iter_mut().zip(arg.iter_mut()).zip(row).zip(b) {
            let v = y + b;
            if v > *m {
                *m = v;
                *a = r as u32;
            }
        }
    }
}

/// [`group_max`] without the rows holding the maxima (the forward pass needs only the values):
/// a branch-free column maximum the compiler vectorises, with the bias added once per group
/// (the same values: rounding `y + b` is monotone in `y`).
#[inline(always)]
pub(crate) fn group_max_value(rows: &[f32], b: &[f32], n: usize, max: &mut [f32]) {
    max.copy_from_slice(&rows[..n]);
    for row in rows.chunks_exact(n).skip(1) {
        for (m, y) in max.iter_mut().zip(row) {
            *m = if *y > *m { *y } else { *m };
        }
    }
    for (m, b) in max.iter_mut().zip(b) {
        *m += b;
    }
}

/// `max over each group of g rows of (y + b)`.
struct BiasGroupMax {
    g: usize,
}

impl CustomOp2 for BiasGroupMax {
    fn name(&self) -> &'static str {
        "bias-group-max"
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
        let (rows, n) = check(self.name(), l1, b, self.g)?;
        let groups = rows / self.g;
        let mut out = vec![0f32; groups * n];
        let gn = self.g * n;
        row_blocks(&mut out, n, |first, block| {
            for (i, m) in block.chunks_exact_mut(n).enumerate() {
                group_max_value(&y[(first + i) * gn..][..gn], b, n, m);
            }
            Vec::new()
        });
        Ok((CpuStorage::F32(out), Shape::from((groups, n))))
    }

    fn bwd(
        &self,
        y: &Tensor,
        b: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        let rows = y.dim(0)?;
        let both = y.contiguous()?.apply_op3_no_bwd(
            &b.contiguous()?,
            &grad.contiguous()?,
            &BiasGroupMaxGrad { g: self.g },
        )?;
        let gy = both.narrow(0, 0, rows)?;
        let gb = both.narrow(0, rows, 1)?.reshape(b.shape())?;
        Ok((Some(gy), Some(gb)))
    }
}

/// Gradients of [`BiasGroupMax`]: `(y [rows, n], b [n], grad [rows / g, n])` -> `[rows + 1,
/// n]`: the gradient of `y` (each group's gradient at its maximum's row, zero elsewhere), then
/// that of `b`.
struct BiasGroupMaxGrad {
    g: usize,
}

impl CustomOp3 for BiasGroupMaxGrad {
    fn name(&self) -> &'static str {
        "bias-group-max-grad"
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
        let grad = f32_slice(self.name(), s3, l3)?;
        let (rows, n) = check(self.name(), l1, b, self.g)?;
        if grad.len() != rows / self.g * n {
            candle_core::bail!("{}: gradient {:?}", self.name(), l3.shape());
        }
        let gn = self.g * n;
        let mut out = vec![0f32; (rows + 1) * n];
        let (gy, gb) = out.split_at_mut(rows * n);
        // Blocks of whole groups: rows of g * n values.
        row_blocks(gy, gn, |first, block| {
            let (mut max, mut arg) = (vec![0f32; n], vec![0u32; n]);
            for (i, o) in block.chunks_exact_mut(gn).enumerate() {
                let grp = first + i;
                group_max(&y[grp * gn..][..gn], b, n, &mut max, &mut arg);
                for (c, (a, g)) in arg.iter().zip(&grad[grp * n..][..n]).enumerate() {
                    o[*a as usize * n + c] = *g;
                }
            }
            Vec::new()
        });
        for row in grad.chunks_exact(n) {
            for (s, g) in gb.iter_mut().zip(row) {
                *s += g;
            }
        }
        Ok((CpuStorage::F32(out), Shape::from((rows + 1, n))))
    }
}

/// `max over each group of g consecutive rows of (y + b)`: `y [rows, n]`, `b [n]` -> `[rows /
/// g, n]`, differentiable in both. One pass on the CPU; the composition elsewhere.
pub fn bias_group_max(y: &Tensor, b: &Tensor, g: usize) -> candle_core::Result<Tensor> {
    let (rows, n) = y.dims2()?;
    if y.device().is_cpu() {
        y.contiguous()?.apply_op2(b, BiasGroupMax { g })
    } else {
        if g == 0 || !rows.is_multiple_of(g) {
            candle_core::bail!("bias-group-max: {rows} rows do not split into groups of {g}");
        }
        y.broadcast_add(b)?.reshape((rows / g, g, n))?.max(1)
    }
}

#[cfg(test)]
mod tests {
    use candle_core::Var;

    use super::*;
    use crate::kernels::test_data::max_diff;

    fn random(shape: &[usize], seed: u64) -> Tensor {
        crate::kernels::test_data::random(shape, seed, 6.0)
    }

    #[test]
    fn bias_group_max_matches_the_composition_with_gradients() {
        // A few groups, and enough to split the pass over the thread pool.
        for (groups, g, n, seed) in [(5usize, 3usize, 7usize, 1u64), (1200, 8, 64, 2)] {
            let y = Var::from_tensor(&random(&[groups * g, n], seed)).unwrap();
            let b = Var::from_tensor(&random(&[n], seed + 1)).unwrap();
            let r = random(&[groups, n], seed + 2);
            let run = |fused: bool| {
                let (yt, bt) = (y.as_tensor(), b.as_tensor());
                let out = if fused {
                    bias_group_max(yt, bt, g).unwrap()
                } else {
                    let z = yt.broadcast_add(bt).unwrap();
                    z.reshape((groups, g, n)).unwrap().max(1).unwrap()
                };
                let grads = (&out * &r).unwrap().sum_all().unwrap().backward().unwrap();
                let gy = grads.get(yt).unwrap().clone();
                let gb = grads.get(bt).unwrap().clone();
                (out, gy, gb)
            };
            let (o1, gy1, gb1) = run(true);
            let (o2, gy2, gb2) = run(false);
            assert_eq!(o1.dims(), &[groups, n]);
            assert_eq!(max_diff(&o1, &o2), 0.0);
            assert_eq!(max_diff(&gy1, &gy2), 0.0);
            assert!(max_diff(&gb1, &gb2) < 1e-3, "db {}", max_diff(&gb1, &gb2));
        }
    }

    #[test]
    fn tied_rows_share_one_gradient() {
        // Every group holds the same row twice: the gradient goes to the first copy only.
        let row = random(&[1, 4], 6);
        let y = Var::from_tensor(&Tensor::cat(&[&row, &row, &(&row - 1.0).unwrap()], 0).unwrap())
            .unwrap();
        let b = Var::from_tensor(&random(&[4], 7)).unwrap();
        let out = bias_group_max(y.as_tensor(), b.as_tensor(), 3).unwrap();
        let grads = out.sum_all().unwrap().backward().unwrap();
        let gy = grads.get(y.as_tensor()).unwrap().to_vec2::<f32>().unwrap();
        assert_eq!(gy, vec![vec![1.0; 4], vec![0.0; 4], vec![0.0; 4]]);
    }

    #[test]
    fn rows_that_do_not_split_into_groups_are_an_error() {
        let y = random(&[10, 4], 3);
        let b = random(&[4], 4);
        assert!(bias_group_max(&y, &b, 3).is_err());
        assert!(bias_group_max(&y, &b, 0).is_err());
        assert!(bias_group_max(&y, &random(&[5], 5), 2).is_err());
    }
}
