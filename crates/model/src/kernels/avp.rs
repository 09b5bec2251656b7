//! Anchor-vertex pooling (AVP) as one CPU pass over the real points only: for each object's
//! anchor `k`, `avp[k] = sum_i w_ki h_i / sum_i w_ki` with `w_ki = exp(-d2_ki / sigma^2)`.
//!
//! The composition it replaces lays the packed point features out per object with zero rows
//! for padding (a gather), materialises the weights `[O, K, N]` and a mask, and runs `O`
//! small `[K, N] x [N, C]` products. Here each object is one task: its weights are computed
//! and exponentiated in place, and the weighted sums accumulate in a `[K, C]` block that stays
//! in L1. No gradient: for inference only (training keeps the composition, whose gradient
//! also reaches the learned bandwidth).

use candle_core::{CpuStorage, CustomOp1, Layout, Shape, Tensor};

use super::activation::exp_inference;
use super::simd::{axpy, exp_slice, row_blocks};
use super::storage::f32_slice;
use crate::layers::gather_padded;
use crate::team;

/// The pooling of one batch: per-object point ranges and distances, host data borrowed from
/// the batch inputs.
pub struct AnchorPooling<'a> {
    /// Anchors per object (`K`).
    pub anchors: usize,
    /// First packed point row and point count of every object, `[O]`.
    pub objects: &'a [(usize, usize)],
    /// Squared anchor-to-point distances of every object, `[K, n]` each (`n` its point count),
    /// m^2.
    pub d2: &'a [&'a [f32]],
    /// `1 / sigma^2`, 1/m^2.
    pub inv_sigma2: f32,
}

impl AnchorPooling<'_> {
    /// Pools object `o` into `out [K, C]`, with `w` as scratch of at least `K * n` values.
    #[inline(always)]
    fn object(&self, h: &[f32], c: usize, o: usize, out: &mut [f32], w: &mut Vec<f32>) {
        let (first, n) = self.objects[o];
        let k = self.anchors;
        w.clear();
        for kk in 0..k {
            let row = &self.d2[o][kk * n..(kk + 1) * n];
            w.extend(row.iter().map(|d| -d * self.inv_sigma2));
        }
        exp_slice(w);
        out.fill(0.0);
        let points = &h[first * c..(first + n) * c];
        // Four anchors at a time with their sums in registers where the width allows; the
        // rest (other widths, fewer than four anchors left) one row update at a time.
        let done = match c {
            16 => pool_four_anchors::<16>(w, n, points, out),
            32 => pool_four_anchors::<32>(w, n, points, out),
            64 => pool_four_anchors::<64>(w, n, points, out),
            _ => 0,
        };
        for (i, hi) in points.chunks_exact(c).enumerate() {
            for (kk, acc) in out.chunks_exact_mut(c).enumerate().skip(done) {
                axpy(acc, w[kk * n + i], hi);
            }
        }
        for (kk, acc) in out.chunks_exact_mut(c).enumerate() {
            let den: f32 = w[kk * n..(kk + 1) * n].iter().sum();
            let inv = if den > 0.0 { 1.0 / den } else { 0.0 };
            acc.iter_mut().for_each(|v| *v *= inv);
        }
    }

    /// Pools every object of `out [O, K * C]` (a block of whole objects starting at `first`).
    fn block(&self, h: &[f32], c: usize, first: usize, out: &mut [f32]) {
        #[inline(always)]
        fn body(p: &AnchorPooling<'_>, h: &[f32], c: usize, first: usize, out: &mut [f32]) {
            let mut w = Vec::new();
            for (i, obj) in out.chunks_exact_mut(p.anchors * c).enumerate() {
                p.object(h, c, first + i, obj, &mut w);
            }
        }
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx512f")]
            unsafe fn avx512(p: &AnchorPooling<'_>, h: &[f32], c: usize, f: usize, o: &mut [f32]) {
                body(p, h, c, f, o)
            }
            #[target_feature(enable = "avx2,fma")]
            unsafe fn avx2(p: &AnchorPooling<'_>, h: &[f32], c: usize, f: usize, o: &mut [f32]) {
                body(p, h, c, f, o)
            }
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU supports AVX-512F (checked just above).
                return unsafe { avx512(self, h, c, first, out) };
            }
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the CPU supports AVX2 and FMA (checked just above).
                return unsafe { avx2(self, h, c, first, out) };
            }
        }
        body(self, h, c, first, out)
    }
}

/// Weighted sums of `points [n, C]` for the anchors of `out [K, C]` in groups of four, weights
/// `w [K, n]`: each group's four `C`-wide sums stay in registers over all points (the same
/// additions in the same order as one row update at a time). Returns the anchors done.
#[inline(always)]
fn pool_four_anchors<const C: usize>(
    w: &[f32],
    n: usize,
    points: &[f32],
    out: &mut [f32],
) -> usize {
    let groups = out.len() / (4 * C);
    for (g, rows) in out.chunks_exact_mut(4 * C).enumerate() {
        let wg = &w[g * 4 * n..(g + 1) * 4 * n];
        let (w0, rest) = wg.split_at(n);
        let (w1, rest) = rest.split_at(n);
        let (w2, w3) = rest.split_at(n);
        let mut acc = [[0f32; C]; 4];
        for (i, hi) in points.chunks_exact(C).enumerate() {
            let Ok(hi) = <&[f32; C]>::try_from(hi) else {
                continue;
            };
            let a = [w0[i], w1[i], w2[i], w3[i]];
            for (acc, a) in acc.iter_mut().zip(a) {
                for (s, x) in acc.iter_mut().zip(hi) {
                    *s += a * *x;
                }
            }
        }
        for (row, acc) in rows.chunks_exact_mut(C).zip(&acc) {
            row.copy_from_slice(acc);
        }
    }
    4 * groups
}

impl CustomOp1 for AnchorPooling<'_> {
    fn name(&self) -> &'static str {
        "anchor-vertex-pooling"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let h = f32_slice(self.name(), s, l)?;
        let (rows, c) = l.shape().dims2()?;
        let o = self.objects.len();
        let k = self.anchors;
        if let Some(&(first, n)) = self.objects.iter().find(|(first, n)| first + n > rows) {
            candle_core::bail!(
                "{}: object rows {first}..{} outside the {rows} points",
                self.name(),
                first + n
            );
        }
        let mismatched = self.d2.len() != o
            || self
                .d2
                .iter()
                .zip(self.objects)
                .any(|(d2, (_, n))| d2.len() != k * n);
        if mismatched {
            candle_core::bail!(
                "{}: distances of {} objects for {o} objects of {k} anchors x their points",
                self.name(),
                self.d2.len()
            );
        }
        let mut out = vec![0f32; o * k * c];
        let macs: usize = self.objects.iter().map(|(_, n)| n * k * c).sum();
        if o > 1 && c > 0 && macs >= team::SPLIT_MIN_MACS && team::parts() > 1 {
            // One scene's objects shared out over the compute team.
            team::split_mut(&mut out, k * c, |first, rows| self.block(h, c, first, rows));
        } else if o > 0 && c > 0 {
            row_blocks(&mut out, k * c, |first, block| {
                self.block(h, c, first, block);
                Vec::new()
            });
        }
        Ok((CpuStorage::F32(out), Shape::from((o, k, c))))
    }
}

/// Each object's distances `[K, n]` (as [`AnchorPooling::d2`] takes them) laid out
/// `[O, K, nmax]` with zero padding, the layout [`anchor_pooling_composed`] takes.
pub fn padded_distances(rows: &[&[f32]], k: usize, nmax: usize) -> Vec<f32> {
    let mut out = vec![0f32; rows.len() * k * nmax];
    for (obj, d2) in rows.iter().enumerate() {
        let n = d2.len() / k.max(1);
        for (kk, row) in d2.chunks_exact(n.max(1)).enumerate().take(k) {
            out[(obj * k + kk) * nmax..][..n].copy_from_slice(row);
        }
    }
    out
}

/// AVP of the packed point features `h [P, C]` on the CPU: `[O, K, C]`.
pub fn anchor_pooling(h: &Tensor, op: &AnchorPooling<'_>) -> candle_core::Result<Tensor> {
    h.contiguous()?.apply_op1_no_bwd(op)
}

/// AVP as a composition of candle ops, on any device and differentiable (also in the
/// bandwidth): the reference [`anchor_pooling`] is tested against, and the path of training
/// and of non-CPU devices.
///
/// `h [P, C]` packed point features; `d2 [O, K, N]` squared anchor-to-point distances, m^2;
/// `mask [O, 1, N]` 1 for real points, 0 for padding; `pad_idx [O * N]` (u32) the packed row of
/// every padded slot, `P` for padding; `inv_sigma2 [1]` 1/m^2. `fast_exp` uses the vectorised
/// inference `exp` (no gradient). Returns `[O, K, C]`.
pub fn anchor_pooling_composed(
    h: &Tensor,
    d2: &Tensor,
    mask: &Tensor,
    pad_idx: &Tensor,
    inv_sigma2: &Tensor,
    fast_exp: bool,
) -> candle_core::Result<Tensor> {
    let (o, _, n) = d2.dims3()?;
    let c = h.dim(1)?;
    let arg = d2.broadcast_mul(inv_sigma2)?.neg()?;
    let w = if fast_exp {
        exp_inference(&arg)?
    } else {
        arg.exp()?
    };
    let w = w.broadcast_mul(mask)?; // [O, K, N]
    // The packed features laid out per object `[O, N, C]`, zero rows for padding.
    let hp = gather_padded(h, pad_idx)?.reshape((o, n, c))?;
    let num = w.matmul(&hp)?; // [O, K, C]
    let den = w.sum_keepdim(2)?; // > 0 wherever an object has a point
    num.broadcast_div(&den)
}

#[cfg(test)]
mod tests {
    use super::super::test_data::{max_diff, random, uniform};
    use super::*;
    use candle_core::Device;

    /// [`anchor_pooling_composed`] on the ragged objects' padded layout.
    fn composed(
        h: &Tensor,
        objects: &[(usize, usize)],
        d2: &[f32],
        k: usize,
        nmax: usize,
        inv_s2: f32,
    ) -> Tensor {
        let dev = Device::Cpu;
        let p = h.dim(0).unwrap();
        let o = objects.len();
        let mut pad = vec![p as u32; o * nmax];
        let mut mask = vec![0f32; o * nmax];
        for (j, &(first, n)) in objects.iter().enumerate() {
            for i in 0..n {
                pad[j * nmax + i] = (first + i) as u32;
                mask[j * nmax + i] = 1.0;
            }
        }
        anchor_pooling_composed(
            h,
            &Tensor::from_slice(d2, (o, k, nmax), &dev).unwrap(),
            &Tensor::from_vec(mask, (o, 1, nmax), &dev).unwrap(),
            &Tensor::from_vec(pad, o * nmax, &dev).unwrap(),
            &Tensor::new(&[inv_s2], &dev).unwrap(),
            false,
        )
        .unwrap()
    }

    #[test]
    fn matches_the_composition_on_ragged_objects() {
        let (k, c, nmax) = (8, 32, 97);
        // Objects of different point counts, one with a single point.
        let counts = [97, 40, 1, 64, 13];
        let mut objects = Vec::new();
        let mut first = 0;
        for &n in &counts {
            objects.push((first, n));
            first += n;
        }
        let h = random(&[first, c], 3, 2.0);
        // Each object's [K, n] distances; the anchor is one of its object's points (distance
        // 0 to it).
        let rows: Vec<Vec<f32>> = counts
            .iter()
            .enumerate()
            .map(|(j, &n)| {
                let mut d2: Vec<f32> = uniform(k * n, 5 + j as u64, 0.08)
                    .into_iter()
                    .map(|x| x * x)
                    .collect();
                for kk in 0..k {
                    d2[kk * n + (kk * 7) % n] = 0.0;
                }
                d2
            })
            .collect();
        let rows: Vec<&[f32]> = rows.iter().map(Vec::as_slice).collect();
        let d2 = padded_distances(&rows, k, nmax);
        let inv_s2 = 1.0 / (0.05f32 * 0.05);
        let op = AnchorPooling {
            anchors: k,
            objects: &objects,
            d2: &rows,
            inv_sigma2: inv_s2,
        };
        let fused = anchor_pooling(&h, &op).unwrap();
        let want = composed(&h, &objects, &d2, k, nmax, inv_s2);
        assert_eq!(fused.dims(), &[counts.len(), k, c]);
        let diff = max_diff(&fused, &want);
        assert!(
            diff < 1e-5,
            "fused AVP differs from the composition by {diff}"
        );
    }

    #[test]
    fn rejects_ranges_outside_the_points() {
        let h = random(&[10, 4], 1, 1.0);
        let d2 = vec![0.0; 2 * 8];
        let objects = [(0, 8), (8, 8)];
        let op = AnchorPooling {
            anchors: 2,
            objects: &objects,
            d2: &[&d2, &d2],
            inv_sigma2: 1.0,
        };
        assert!(anchor_pooling(&h, &op).is_err());
        // Distances that do not match an object's point count.
        let objects = [(0, 8), (8, 2)];
        let op = AnchorPooling {
            anchors: 2,
            objects: &objects,
            d2: &[&d2, &d2],
            inv_sigma2: 1.0,
        };
        assert!(anchor_pooling(&h, &op).is_err());
    }
}
