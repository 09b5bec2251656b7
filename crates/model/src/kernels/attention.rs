//! Fused multi-head attention for short sequences (a few dozen to a few hundred keys) on the
//! CPU, also for training, with the backward passes of [`super::attention_grad`]. Per query row and head, the rotary code, the scores against
//! every key of its scene, the masked softmax, the weighted values and (self-attention) the
//! per-head sigmoid gate run in one pass, with no `[B, H, Tq, Tk]` tensor, no head transposes
//! and no padded query slots. Keys of a scene are rotated and transposed once (`[H, dh, Tk]`).
//! Query rows are split over rayon's pool in chunks when the pass is large.
//!
//! Rotary codes rotate channel pairs `(2i, 2i + 1)`, `i < P`, of every head by the row's
//! `(cos_i, sin_i)`, as `crate::layers::rotate_pairs` does.
//!
//! The ops' definitions are in `attention_ops`, the key layout both forward paths
//! read in `attention_keys`, and the blocked path for long key lists in
//! `attention_long`; this file holds the row kernel and the ops' forward and
//! backward entry points.

use candle_core::{CpuStorage, CustomOp2, Layout, Shape, Tensor};
use rayon::prelude::*;

use super::attention_grad::{cross_attention_grad, self_attention_grad};
pub use super::attention_keys::LONG_KEYS;
use super::attention_keys::{KeySource, SceneKeys, scene_keys};
use super::attention_long::{LongQueries, attend_long, scene_ranges};
pub use super::attention_ops::{CrossAttention, RotaryRows, SelfAttention};
use super::attention_ops::{exp_shifted, rotate};
use super::simd::axpy;
use super::storage::f32_slice;
use crate::team;

/// The factor on head `h`'s weighted values: the softmax's `1 / sum`, times the sigmoid of the
/// head's gate logit when the row has gates.
#[inline(always)]
fn head_scale(sum: f32, gate: Option<&[f32]>, h: usize) -> f32 {
    let w = 1.0 / sum;
    match gate {
        Some(g) => w / (1.0 + (-g[h]).exp()),
        None => w,
    }
}

/// What one query row needs besides the keys.
struct QueryRow<'a> {
    q: &'a [f32],
    cos: &'a [f32],
    sin: &'a [f32],
    bias: &'a [f32],
    gate: Option<&'a [f32]>,
}

#[inline(always)]
fn attend_row_body(
    row: &QueryRow<'_>,
    keys: &SceneKeys,
    heads: usize,
    out: &mut [f32],
    scores: &mut Vec<f32>,
) {
    let dh = out.len() / heads;
    let tk = row.bias.len();
    match (dh, keys.stride) {
        (32, 16) => return attend_row_fixed::<32, 16>(row, keys, heads, out),
        (32, 32) => return attend_row_fixed::<32, 32>(row, keys, heads, out),
        (32, 48) => return attend_row_fixed::<32, 48>(row, keys, heads, out),
        (32, 64) => return attend_row_fixed::<32, 64>(row, keys, heads, out),
        _ => {}
    }
    let stride = keys.stride;
    let scale = 1.0 / (dh as f32).sqrt();
    let mut q = [0f32; 256];
    let q = &mut q[..dh];
    for h in 0..heads {
        q.copy_from_slice(&row.q[h * dh..(h + 1) * dh]);
        rotate(q, row.cos, row.sin);
        scores.clear();
        scores.extend_from_slice(row.bias);
        let kt = &keys.kt[h * dh * stride..(h + 1) * dh * stride];
        for (d, &qd) in q.iter().enumerate() {
            axpy(scores, qd * scale, &kt[d * stride..d * stride + tk]);
        }
        let sum = exp_shifted(scores);
        let o = &mut out[h * dh..(h + 1) * dh];
        o.fill(0.0);
        let v = &keys.v[h * tk * dh..(h + 1) * tk * dh];
        for (j, &p) in scores.iter().enumerate() {
            axpy(o, p, &v[j * dh..(j + 1) * dh]);
        }
        let w = head_scale(sum, row.gate, h);
        o.iter_mut().for_each(|x| *x *= w);
    }
}

/// [`attend_row_body`] for `DH` channels per head and keys padded to `TKP`: a head's scores
/// (`TKP` lanes) and its weighted value sum (`DH` lanes) stay in registers; the same sums in
/// the same order as the general loop.
#[inline(always)]
fn attend_row_fixed<const DH: usize, const TKP: usize>(
    row: &QueryRow<'_>,
    keys: &SceneKeys,
    heads: usize,
    out: &mut [f32],
) {
    let tk = row.bias.len();
    let scale = 1.0 / (DH as f32).sqrt();
    for h in 0..heads {
        let mut q = [0f32; DH];
        q.copy_from_slice(&row.q[h * DH..(h + 1) * DH]);
        rotate(&mut q, row.cos, row.sin);
        let mut sc = [0f32; TKP];
        sc[..tk].copy_from_slice(row.bias);
        let kt = &keys.kt[h * DH * TKP..(h + 1) * DH * TKP];
        for (qd, kr) in q.iter().zip(kt.chunks_exact(TKP)) {
            let qd = qd * scale;
            for (s, k) in sc.iter_mut().zip(kr) {
                *s += qd * *k;
            }
        }
        let sc = &mut sc[..tk];
        let sum = exp_shifted(sc);
        let mut o = [0f32; DH];
        let v = &keys.v[h * tk * DH..(h + 1) * tk * DH];
        for (&p, vr) in sc.iter().zip(v.chunks_exact(DH)) {
            for (a, x) in o.iter_mut().zip(vr) {
                *a += p * *x;
            }
        }
        let w = head_scale(sum, row.gate, h);
        for (dst, a) in out[h * DH..(h + 1) * DH].iter_mut().zip(o) {
            *dst = a * w;
        }
    }
}

fn attend_row(
    row: &QueryRow<'_>,
    keys: &SceneKeys,
    heads: usize,
    out: &mut [f32],
    scores: &mut Vec<f32>,
) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f")]
        unsafe fn avx512(
            row: &QueryRow<'_>,
            keys: &SceneKeys,
            heads: usize,
            out: &mut [f32],
            scores: &mut Vec<f32>,
        ) {
            attend_row_body(row, keys, heads, out, scores)
        }
        #[target_feature(enable = "avx2,fma")]
        unsafe fn avx2(
            row: &QueryRow<'_>,
            keys: &SceneKeys,
            heads: usize,
            out: &mut [f32],
            scores: &mut Vec<f32>,
        ) {
            attend_row_body(row, keys, heads, out, scores)
        }
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above).
            return unsafe { avx512(row, keys, heads, out, scores) };
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked just above).
            return unsafe { avx2(row, keys, heads, out, scores) };
        }
    }
    attend_row_body(row, keys, heads, out, scores)
}

/// Multiply-adds (query rows x keys x width) from which one pass's rows are split over the
/// compute team ([`team`]): one scene's self-attention (18 x 18 x 128) is just above.
const TEAM_MIN_MACS: usize = 1 << 14;

/// Query rows per rayon task: enough multiply-adds (about 256 k) to pay for a task.
fn rows_per_task(tk: usize, d: usize) -> usize {
    (262_144 / (2 * tk * d).max(1)).max(1)
}

/// Runs `nq` query rows: row `r` reads its query through `query(r)` and writes `[D]` outputs.
fn run_rows<'a>(
    nq: usize,
    d: usize,
    heads: usize,
    keys: &[SceneKeys],
    tk: usize,
    query: impl Fn(usize) -> (usize, QueryRow<'a>) + Sync,
) -> Vec<f32> {
    let mut out = vec![0f32; nq * d];
    let chunk = rows_per_task(tk, d);
    let work = |(c, block): (usize, &mut [f32])| {
        let mut scores = Vec::with_capacity(tk);
        for (i, o) in block.chunks_exact_mut(d).enumerate() {
            let (s, row) = query(c * chunk + i);
            attend_row(&row, &keys[s], heads, o, &mut scores);
        }
    };
    if nq * tk * d >= TEAM_MIN_MACS && team::parts() > 1 {
        // One scene's rows shared out over the compute team.
        team::split_mut(&mut out, d, |first, rows| {
            let mut scores = Vec::with_capacity(tk);
            for (i, o) in rows.chunks_exact_mut(d).enumerate() {
                let (s, row) = query(first + i);
                attend_row(&row, &keys[s], heads, o, &mut scores);
            }
        });
    } else if nq > chunk && rayon::current_num_threads() > 1 {
        out.par_chunks_mut(chunk * d).enumerate().for_each(work);
    } else {
        out.chunks_mut(chunk * d).enumerate().for_each(work);
    }
    out
}

fn check_heads(op: &str, d: usize, heads: usize, pairs: usize) -> candle_core::Result<usize> {
    if heads == 0 || !d.is_multiple_of(heads) || d / heads > 256 || 2 * pairs > d / heads {
        candle_core::bail!(
            "{op}: width {d} does not split into {heads} heads with {pairs} rotary pairs"
        );
    }
    Ok(d / heads)
}

impl CustomOp2 for SelfAttention {
    fn name(&self) -> &'static str {
        "fused-self-attention"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let qkv = f32_slice(self.name(), s1, l1)?;
        let gate = f32_slice(self.name(), s2, l2)?;
        let (b, t, d3) = l1.shape().dims3()?;
        let d = d3 / 3;
        let h = self.heads;
        let dh = check_heads(self.name(), d, h, self.rope.pairs)?;
        if l2.shape().dims3()? != (b, t, h)
            || self.key_bias.len() != b * t
            || self.rope.cos.len() != b * t * self.rope.pairs
        {
            candle_core::bail!(
                "{}: qkv {:?}, gate {:?} and the held codes disagree",
                self.name(),
                l1.shape(),
                l2.shape()
            );
        }
        let src = KeySource {
            data: qkv,
            stride: d3,
            k_off: d,
            v_off: 2 * d,
            tk: t,
        };
        let keys: Vec<SceneKeys> =
            team::map_indices(b, 2, |s| scene_keys(src, s, h, dh, &self.rope));
        if t >= LONG_KEYS {
            let ranges: Vec<_> = (0..b).map(|s| s * t..(s + 1) * t).collect();
            let queries = LongQueries {
                q: qkv,
                stride: d3,
                rope: &self.rope,
                ranges: &ranges,
                key_bias: &self.key_bias,
                gate: Some(gate),
            };
            let out = attend_long(&queries, h, d, &keys, t);
            return Ok((CpuStorage::F32(out), Shape::from((b, t, d))));
        }
        let out = run_rows(b * t, d, h, &keys, t, |r| {
            let s = r / t;
            let (cos, sin) = self.rope.row(r);
            (
                s,
                QueryRow {
                    q: &qkv[r * d3..r * d3 + d],
                    cos,
                    sin,
                    bias: &self.key_bias[s * t..(s + 1) * t],
                    gate: Some(&gate[r * h..(r + 1) * h]),
                },
            )
        });
        Ok((CpuStorage::F32(out), Shape::from((b, t, d))))
    }

    fn bwd(
        &self,
        qkv: &Tensor,
        gate: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        let (dqkv, dgate) = self_attention_grad(self, qkv, gate, grad)?;
        Ok((Some(dqkv), Some(dgate)))
    }
}

impl CustomOp2 for CrossAttention {
    fn name(&self) -> &'static str {
        "fused-cross-attention"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let q = f32_slice(self.name(), s1, l1)?;
        let kv = f32_slice(self.name(), s2, l2)?;
        let (nq, d) = l1.shape().dims2()?;
        let (b, tk, d2) = l2.shape().dims3()?;
        let h = self.heads;
        let dh = check_heads(self.name(), d, h, self.q_rope.pairs)?;
        if d2 != 2 * d
            || self.query_scene.len() != nq
            || self.query_scene.iter().any(|&s| s as usize >= b)
            || self.key_bias.len() != b * tk
            || self.q_rope.cos.len() != nq * self.q_rope.pairs
            || self.k_rope.cos.len() != b * tk * self.k_rope.pairs
            || self.k_rope.pairs != self.q_rope.pairs
        {
            candle_core::bail!(
                "{}: q {:?}, kv {:?} and the held codes disagree",
                self.name(),
                l1.shape(),
                l2.shape()
            );
        }
        let src = KeySource {
            data: kv,
            stride: d2,
            k_off: 0,
            v_off: d,
            tk,
        };
        let keys: Vec<SceneKeys> =
            team::map_indices(b, 2, |s| scene_keys(src, s, h, dh, &self.k_rope));
        if tk >= LONG_KEYS
            && let Some(ranges) = scene_ranges(&self.query_scene, b)
        {
            let queries = LongQueries {
                q,
                stride: d,
                rope: &self.q_rope,
                ranges: &ranges,
                key_bias: &self.key_bias,
                gate: None,
            };
            let out = attend_long(&queries, h, d, &keys, tk);
            return Ok((CpuStorage::F32(out), Shape::from((nq, d))));
        }
        let out = run_rows(nq, d, h, &keys, tk, |r| {
            let s = self.query_scene[r] as usize;
            let (cos, sin) = self.q_rope.row(r);
            (
                s,
                QueryRow {
                    q: &q[r * d..(r + 1) * d],
                    cos,
                    sin,
                    bias: &self.key_bias[s * tk..(s + 1) * tk],
                    gate: None,
                },
            )
        });
        Ok((CpuStorage::F32(out), Shape::from((nq, d))))
    }

    fn bwd(
        &self,
        q: &Tensor,
        kv: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        let (dq, dkv) = cross_attention_grad(self, q, kv, grad)?;
        Ok((Some(dq), Some(dkv)))
    }
}

/// Applies [`SelfAttention`] (CPU tensors only): `qkv [B, T, 3D]`, `gate [B, T, H]` ->
/// `[B, T, D]`. No gradient: for inference.
pub fn self_attention(
    op: SelfAttention,
    qkv: &Tensor,
    gate: &Tensor,
) -> candle_core::Result<Tensor> {
    qkv.contiguous()?.apply_op2_no_bwd(&gate.contiguous()?, &op)
}

/// Applies [`SelfAttention`] with its gradient (CPU tensors only, for training): as
/// [`self_attention`], differentiable in `qkv` and `gate` by the one-pass backward of
/// [`super::attention_grad`].
pub fn self_attention_train(
    op: SelfAttention,
    qkv: &Tensor,
    gate: &Tensor,
) -> candle_core::Result<Tensor> {
    qkv.contiguous()?.apply_op2(&gate.contiguous()?, op)
}

/// Applies [`CrossAttention`] with its gradient (CPU tensors only, for training; query rows
/// grouped by scene in order): as [`cross_attention`], differentiable in `q` and `kv`.
pub fn cross_attention_train(
    op: CrossAttention,
    q: &Tensor,
    kv: &Tensor,
) -> candle_core::Result<Tensor> {
    q.contiguous()?.apply_op2(&kv.contiguous()?, op)
}

/// Applies [`CrossAttention`] (CPU tensors only): `q [Nq, D]`, `kv [B, Tk, 2D]` -> `[Nq, D]`.
/// No gradient: for inference.
pub fn cross_attention(op: CrossAttention, q: &Tensor, kv: &Tensor) -> candle_core::Result<Tensor> {
    q.contiguous()?.apply_op2_no_bwd(&kv.contiguous()?, &op)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use candle_core::{Device, Tensor};

    use super::*;
    use crate::kernels::test_data::{max_diff, uniform as random};
    use crate::layers::Mode;
    use crate::rigidformer::attention::multi_head;

    fn rotary(rows: usize, pairs: usize, seed: u64) -> RotaryRows {
        let angles = random(rows * pairs, seed, 6.0);
        RotaryRows {
            cos: angles.iter().map(|a| a.cos()).collect(),
            sin: angles.iter().map(|a| a.sin()).collect(),
            pairs,
        }
    }

    fn tensor(data: &[f32], shape: &[usize]) -> Tensor {
        Tensor::from_slice(data, shape, &Device::Cpu).unwrap()
    }

    /// Key bias with the last `padded[s]` keys of scene `s` masked.
    fn bias(b: usize, t: usize, padded: &[usize]) -> Vec<f32> {
        let mut v = vec![0f32; b * t];
        for s in 0..b {
            for j in t - padded[s]..t {
                v[s * t + j] = -1.0e9;
            }
        }
        v
    }

    #[test]
    fn self_attention_matches_the_composition() {
        for (b, t, heads, dh, pairs) in [
            (3, 18, 4, 32, 12),
            (1, 70, 2, 16, 6),
            (2, 5, 1, 8, 0),
            (2, LONG_KEYS + 22, 4, 32, 12),
        ] {
            let d = heads * dh;
            let qkv = tensor(&random(b * t * 3 * d, 1, 2.0), &[b, t, 3 * d]);
            let gate = tensor(&random(b * t * heads, 2, 4.0), &[b, t, heads]);
            let rope = rotary(b * t, pairs, 3);
            let key_bias = bias(b, t, &[2, 0, 3][..b]);
            let op = SelfAttention {
                heads,
                key_bias: Arc::new(key_bias.clone()),
                rope: Arc::new(rope.clone()),
            };
            let fused = self_attention(op, &qkv, &gate).unwrap();
            let cos = tensor(&rope.cos, &[b, 1, t, pairs]);
            let sin = tensor(&rope.sin, &[b, 1, t, pairs]);
            let mask = tensor(&key_bias, &[b, 1, 1, t]);
            let q = qkv.narrow(2, 0, d).unwrap();
            let k = qkv.narrow(2, d, d).unwrap();
            let v = qkv.narrow(2, 2 * d, d).unwrap();
            let rope = (pairs > 0).then_some((&cos, &sin));
            let o = multi_head(&q, &k, &v, &mask, rope, rope, heads, Mode::Inference).unwrap();
            let g = candle_nn::ops::sigmoid(&gate).unwrap();
            let g = g.transpose(1, 2).unwrap().unsqueeze(3).unwrap();
            let reference = o
                .broadcast_mul(&g)
                .unwrap()
                .transpose(1, 2)
                .unwrap()
                .reshape((b, t, d))
                .unwrap();
            let diff = max_diff(&fused, &reference);
            assert!(diff < 2e-5, "b{b} t{t} h{heads}: {diff}");
        }
    }

    #[test]
    fn self_attention_gradients_match_the_composition() {
        use candle_core::Var;
        for (b, t, heads, dh, pairs) in [(3, 18, 4, 32, 12), (2, 5, 1, 8, 0)] {
            let d = heads * dh;
            let qkv =
                Var::from_tensor(&tensor(&random(b * t * 3 * d, 11, 2.0), &[b, t, 3 * d])).unwrap();
            let gate =
                Var::from_tensor(&tensor(&random(b * t * heads, 12, 4.0), &[b, t, heads])).unwrap();
            let r = tensor(&random(b * t * d, 13, 2.0), &[b, t, d]);
            let rope = rotary(b * t, pairs, 14);
            let key_bias = bias(b, t, &[2, 0, 3][..b]);
            let (qt, gt) = (qkv.as_tensor(), gate.as_tensor());
            let op = SelfAttention {
                heads,
                key_bias: Arc::new(key_bias.clone()),
                rope: Arc::new(rope.clone()),
            };
            let fused = self_attention_train(op, qt, gt).unwrap();
            let cos = tensor(&rope.cos, &[b, 1, t, pairs]);
            let sin = tensor(&rope.sin, &[b, 1, t, pairs]);
            let mask = tensor(&key_bias, &[b, 1, 1, t]);
            let (q, k, v) = (
                qt.narrow(2, 0, d).unwrap(),
                qt.narrow(2, d, d).unwrap(),
                qt.narrow(2, 2 * d, d).unwrap(),
            );
            let rot = (pairs > 0).then_some((&cos, &sin));
            let o = multi_head(&q, &k, &v, &mask, rot, rot, heads, Mode::Training).unwrap();
            let g = candle_nn::ops::sigmoid(gt).unwrap();
            let g = g.transpose(1, 2).unwrap().unsqueeze(3).unwrap();
            let reference = o
                .broadcast_mul(&g)
                .unwrap()
                .transpose(1, 2)
                .unwrap()
                .reshape((b, t, d))
                .unwrap();
            assert!(max_diff(&fused, &reference) < 2e-5);
            let grads = |y: &Tensor| {
                let g = (y * &r).unwrap().sum_all().unwrap().backward().unwrap();
                (g.get(qt).unwrap().clone(), g.get(gt).unwrap().clone())
            };
            let (dq1, dg1) = grads(&fused);
            let (dq2, dg2) = grads(&reference);
            let (e1, e2) = (max_diff(&dq1, &dq2), max_diff(&dg1, &dg2));
            assert!(
                e1 < 1e-4 && e2 < 1e-4,
                "b{b} t{t} h{heads}: dqkv {e1}, dgate {e2}"
            );
        }
    }

    #[test]
    fn cross_attention_gradients_match_the_composition() {
        use candle_core::Var;
        let (b, tk, heads, dh, pairs) = (3usize, 21usize, 4usize, 32usize, 12usize);
        let d = heads * dh;
        let counts = [2usize, 0, 5];
        let nq: usize = counts.iter().sum();
        let q = Var::from_tensor(&tensor(&random(nq * d, 15, 2.0), &[nq, d])).unwrap();
        let kv =
            Var::from_tensor(&tensor(&random(b * tk * 2 * d, 16, 2.0), &[b, tk, 2 * d])).unwrap();
        let r = tensor(&random(nq * d, 17, 2.0), &[nq, d]);
        let q_rope = rotary(nq, pairs, 18);
        let k_rope = rotary(b * tk, pairs, 19);
        let key_bias = bias(b, tk, &[4, 0, 1]);
        let query_scene: Vec<u32> = counts
            .iter()
            .enumerate()
            .flat_map(|(s, &c)| std::iter::repeat_n(s as u32, c))
            .collect();
        let op = CrossAttention {
            heads,
            query_scene: Arc::new(query_scene),
            key_bias: Arc::new(key_bias.clone()),
            q_rope: Arc::new(q_rope.clone()),
            k_rope: Arc::new(k_rope.clone()),
        };
        let (qt, kvt) = (q.as_tensor(), kv.as_tensor());
        let fused = cross_attention_train(op, qt, kvt).unwrap();
        let mut parts = Vec::new();
        let mut row = 0;
        for (s, &c) in counts.iter().enumerate() {
            if c == 0 {
                continue;
            }
            let rows = |v: &[f32], first: usize, n: usize| {
                tensor(&v[first * pairs..(first + n) * pairs], &[1, 1, n, pairs])
            };
            let (qc, qs) = (rows(&q_rope.cos, row, c), rows(&q_rope.sin, row, c));
            let (kc, ks) = (rows(&k_rope.cos, s * tk, tk), rows(&k_rope.sin, s * tk, tk));
            let mask = tensor(&key_bias[s * tk..(s + 1) * tk], &[1, 1, 1, tk]);
            let kvs = kvt.narrow(0, s, 1).unwrap();
            let o = multi_head(
                &qt.narrow(0, row, c).unwrap().unsqueeze(0).unwrap(),
                &kvs.narrow(2, 0, d).unwrap(),
                &kvs.narrow(2, d, d).unwrap(),
                &mask,
                Some((&qc, &qs)),
                Some((&kc, &ks)),
                heads,
                Mode::Training,
            )
            .unwrap();
            parts.push(o.transpose(1, 2).unwrap().reshape((c, d)).unwrap());
            row += c;
        }
        let reference = Tensor::cat(&parts, 0).unwrap();
        assert!(max_diff(&fused, &reference) < 2e-5);
        let grads = |y: &Tensor| {
            let g = (y * &r).unwrap().sum_all().unwrap().backward().unwrap();
            (g.get(qt).unwrap().clone(), g.get(kvt).unwrap().clone())
        };
        let (dq1, dkv1) = grads(&fused);
        let (dq2, dkv2) = grads(&reference);
        let (e1, e2) = (max_diff(&dq1, &dq2), max_diff(&dkv1, &dkv2));
        assert!(e1 < 1e-4 && e2 < 1e-4, "dq {e1}, dkv {e2}");
    }

    #[test]
    fn cross_attention_matches_the_composition() {
        // Short key lists (the row kernel) and long ones (the blocked path, several row blocks
        // per scene); scenes with ragged query counts, one empty.
        for (tk, counts) in [(21usize, [2usize, 0, 5]), (LONG_KEYS + 22, [70, 0, 131])] {
            cross_attention_case(tk, counts);
        }
    }

    fn cross_attention_case(tk: usize, counts: [usize; 3]) {
        let (b, heads, dh, pairs) = (3usize, 4usize, 32usize, 12usize);
        let d = heads * dh;
        let nq: usize = counts.iter().sum();
        let q = tensor(&random(nq * d, 5, 2.0), &[nq, d]);
        let kv = tensor(&random(b * tk * 2 * d, 6, 2.0), &[b, tk, 2 * d]);
        let q_rope = rotary(nq, pairs, 7);
        let k_rope = rotary(b * tk, pairs, 8);
        let key_bias = bias(b, tk, &[4, 0, 1]);
        let query_scene: Vec<u32> = counts
            .iter()
            .enumerate()
            .flat_map(|(s, &c)| std::iter::repeat_n(s as u32, c))
            .collect();
        let op = CrossAttention {
            heads,
            query_scene: Arc::new(query_scene),
            key_bias: Arc::new(key_bias.clone()),
            q_rope: Arc::new(q_rope.clone()),
            k_rope: Arc::new(k_rope.clone()),
        };
        let fused = cross_attention(op, &q, &kv).unwrap();
        let mut row = 0;
        for (s, &c) in counts.iter().enumerate() {
            if c == 0 {
                continue;
            }
            let qs = q.narrow(0, row, c).unwrap().unsqueeze(0).unwrap();
            let kvs = kv.narrow(0, s, 1).unwrap();
            let qcos = tensor(
                &q_rope.cos[row * pairs..(row + c) * pairs],
                &[1, 1, c, pairs],
            );
            let qsin = tensor(
                &q_rope.sin[row * pairs..(row + c) * pairs],
                &[1, 1, c, pairs],
            );
            let kcos = tensor(
                &k_rope.cos[s * tk * pairs..(s + 1) * tk * pairs],
                &[1, 1, tk, pairs],
            );
            let ksin = tensor(
                &k_rope.sin[s * tk * pairs..(s + 1) * tk * pairs],
                &[1, 1, tk, pairs],
            );
            let mask = tensor(&key_bias[s * tk..(s + 1) * tk], &[1, 1, 1, tk]);
            let o = multi_head(
                &qs,
                &kvs.narrow(2, 0, d).unwrap(),
                &kvs.narrow(2, d, d).unwrap(),
                &mask,
                Some((&qcos, &qsin)),
                Some((&kcos, &ksin)),
                heads,
                Mode::Inference,
            )
            .unwrap();
            let reference = o.transpose(1, 2).unwrap().reshape((c, d)).unwrap();
            let diff = max_diff(&fused.narrow(0, row, c).unwrap(), &reference);
            assert!(diff < 2e-5, "scene {s}: {diff}");
            row += c;
        }
    }
}
