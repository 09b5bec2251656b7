//! Backward passes of the fused self- and cross-attention ([`super::attention`]) for
//! training on the CPU: per scene and head, the rotated queries and keys, the softmax and the
//! gated output are recomputed from `qkv` and the gate logits (nothing of the forward pass is
//! kept), then the gradients of values, scores, rotated queries and keys and the gate logits
//! follow in one sweep over the query rows, and the rotary code is undone on the query and key
//! gradients. Scenes run in parallel over rayon's pool.

use candle_core::{CpuStorage, CustomOp3, Layout, Shape, Tensor};
use rayon::prelude::*;

use super::attention_ops::{CrossAttention, RotaryRows, SelfAttention, exp_shifted, rotate};
use super::simd::axpy;
use super::storage::f32_slice;

/// Undoes [`rotate`] (the rotation's transpose) on a gradient.
fn unrotate(x: &mut [f32], cos: &[f32], sin: &[f32]) {
    for (i, (c, s)) in cos.iter().zip(sin).enumerate() {
        let (e, o) = (x[2 * i], x[2 * i + 1]);
        x[2 * i] = e * c + o * s;
        x[2 * i + 1] = o * c - e * s;
    }
}

/// Sizes of one self-attention pass.
#[derive(Clone, Copy)]
struct Dims {
    t: usize,
    d: usize,
    heads: usize,
}

/// One head of one scene: rotated queries `q [Tq, dh]`, rotated keys `k [Tk, dh]`, values
/// `v [Tk, dh]`, key bias `[Tk]`, gate logits `[Tq]` (if gated) and the output gradient
/// `dout [Tq, dh]` -> gradients of the rotated queries, rotated keys, values (`dq`, `dk`,
/// `dv`, overwritten) and the gate logits (`dgate [Tq]`).
#[allow(clippy::too_many_arguments)]
fn head_grad(
    dh: usize,
    (q, k, v): (&[f32], &[f32], &[f32]),
    bias: &[f32],
    gate: Option<&[f32]>,
    dout: &[f32],
    (dq, dk, dv): (&mut [f32], &mut [f32], &mut [f32]),
    dgate: &mut [f32],
) {
    let (tq, tk) = (q.len() / dh, bias.len());
    let scale = 1.0 / (dh as f32).sqrt();
    let (mut p, mut dp, mut o, mut d_o) = (
        vec![0f32; tk],
        vec![0f32; tk],
        vec![0f32; dh],
        vec![0f32; dh],
    );
    dk.fill(0.0);
    dv.fill(0.0);
    for i in 0..tq {
        let qi = &q[i * dh..(i + 1) * dh];
        for (j, pj) in p.iter_mut().enumerate() {
            let kj = &k[j * dh..(j + 1) * dh];
            *pj = scale * qi.iter().zip(kj).map(|(a, b)| a * b).sum::<f32>() + bias[j];
        }
        let inv: f32 = 1.0 / exp_shifted(&mut p);
        // Masked keys come out of the clamped `exp` as ~1e-38, not 0: flushed, so that their
        // gradients hold no subnormal numbers (which slow every later product down).
        p.iter_mut()
            .for_each(|x| *x = if *x < 1e-30 { 0.0 } else { *x * inv });
        d_o.copy_from_slice(&dout[i * dh..(i + 1) * dh]);
        if let Some(gate) = gate {
            o.fill(0.0);
            for (j, &pj) in p.iter().enumerate() {
                axpy(&mut o, pj, &v[j * dh..(j + 1) * dh]);
            }
            let sg = 1.0 / (1.0 + (-gate[i]).exp());
            let dsg: f32 = d_o.iter().zip(&o).map(|(a, b)| a * b).sum();
            dgate[i] = dsg * sg * (1.0 - sg);
            d_o.iter_mut().for_each(|x| *x *= sg); // gradient of the attention output
        }
        for (j, dpj) in dp.iter_mut().enumerate() {
            let vj = &v[j * dh..(j + 1) * dh];
            *dpj = d_o.iter().zip(vj).map(|(a, b)| a * b).sum();
            axpy(&mut dv[j * dh..(j + 1) * dh], p[j], &d_o);
        }
        let c: f32 = p.iter().zip(&dp).map(|(a, b)| a * b).sum();
        let dqi = &mut dq[i * dh..(i + 1) * dh];
        dqi.fill(0.0);
        for j in 0..tk {
            let ds = p[j] * (dp[j] - c) * scale;
            axpy(dqi, ds, &k[j * dh..(j + 1) * dh]);
            axpy(&mut dk[j * dh..(j + 1) * dh], ds, qi);
        }
    }
}

/// Copies head `h` of `rows` rows (`row(r)` gives row `r`'s `[D]` channels) into `out [rows,
/// dh]`, rotated by rotary rows `first..` of `rope` when given.
fn gather_head<'a>(
    out: &mut [f32],
    h: usize,
    dh: usize,
    row: impl Fn(usize) -> &'a [f32],
    rope: Option<(&RotaryRows, usize)>,
) {
    for (r, o) in out.chunks_exact_mut(dh).enumerate() {
        o.copy_from_slice(&row(r)[h * dh..(h + 1) * dh]);
        if let Some((rope, first)) = rope {
            let (cos, sin) = rope.row(first + r);
            rotate(o, cos, sin);
        }
    }
}

/// Undoes the rotation of rotary rows `first..` on `x [rows, dh]` (a gradient).
fn unrotate_rows(x: &mut [f32], dh: usize, rope: &RotaryRows, first: usize) {
    for (r, o) in x.chunks_exact_mut(dh).enumerate() {
        let (cos, sin) = rope.row(first + r);
        unrotate(o, cos, sin);
    }
}

/// Gradients of one scene: `qkv [T, 3D]`, gate logits `[T, H]`, output gradient `[T, D]`,
/// key bias `[T]` and rotary rows `[T, P]` -> `dqkv [T, 3D]` and `dgate [T, H]`.
#[allow(clippy::too_many_arguments)]
fn scene_grad(
    n: Dims,
    qkv: &[f32],
    gate: &[f32],
    grad: &[f32],
    bias: &[f32],
    rope: &RotaryRows,
    first_row: usize,
    dqkv: &mut [f32],
    dgate: &mut [f32],
) {
    let Dims { t, d, heads } = n;
    let dh = d / heads;
    let mut bufs = vec![vec![0f32; t * dh]; 7];
    let (mut g, mut dg) = (vec![0f32; t], vec![0f32; t]);
    for h in 0..heads {
        let [q, k, v, dq, dk, dv, dout] = &mut bufs[..] else {
            unreachable!("seven buffers")
        };
        gather_head(
            q,
            h,
            dh,
            |r| &qkv[r * 3 * d..r * 3 * d + d],
            Some((rope, first_row)),
        );
        gather_head(
            k,
            h,
            dh,
            |r| &qkv[r * 3 * d + d..r * 3 * d + 2 * d],
            Some((rope, first_row)),
        );
        gather_head(v, h, dh, |r| &qkv[r * 3 * d + 2 * d..(r + 1) * 3 * d], None);
        gather_head(dout, h, dh, |r| &grad[r * d..(r + 1) * d], None);
        for (i, gi) in g.iter_mut().enumerate() {
            *gi = gate[i * heads + h];
        }
        head_grad(dh, (q, k, v), bias, Some(&g), dout, (dq, dk, dv), &mut dg);
        unrotate_rows(dq, dh, rope, first_row);
        unrotate_rows(dk, dh, rope, first_row);
        for j in 0..t {
            let row = &mut dqkv[j * 3 * d..(j + 1) * 3 * d];
            row[h * dh..(h + 1) * dh].copy_from_slice(&dq[j * dh..(j + 1) * dh]);
            row[d + h * dh..d + (h + 1) * dh].copy_from_slice(&dk[j * dh..(j + 1) * dh]);
            row[2 * d + h * dh..2 * d + (h + 1) * dh].copy_from_slice(&dv[j * dh..(j + 1) * dh]);
            dgate[j * heads + h] = dg[j];
        }
    }
}

/// `(qkv [B, T, 3D], gate [B, T, H], grad [B, T, D])` -> the gradients of `qkv` then of the
/// gate logits, flattened one after the other `[B * T * (3D + H)]`.
struct SelfAttentionGrad<'a>(&'a SelfAttention);

impl CustomOp3 for SelfAttentionGrad<'_> {
    fn name(&self) -> &'static str {
        "fused-self-attention-grad"
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
        let qkv = f32_slice(self.name(), s1, l1)?;
        let gate = f32_slice(self.name(), s2, l2)?;
        let grad = f32_slice(self.name(), s3, l3)?;
        let (b, t, d3) = l1.shape().dims3()?;
        let (d, heads) = (d3 / 3, self.0.heads);
        if l2.shape().dims3()? != (b, t, heads) || l3.shape().dims3()? != (b, t, d) {
            candle_core::bail!(
                "{}: qkv {:?}, gate {:?}, grad {:?}",
                self.name(),
                l1.shape(),
                l2.shape(),
                l3.shape()
            );
        }
        let n = Dims { t, d, heads };
        let mut out = vec![0f32; b * t * (d3 + heads)];
        let (dqkv, dgate) = out.split_at_mut(b * t * d3);
        let (bias, rope) = (&self.0.key_bias, &self.0.rope);
        dqkv.par_chunks_mut(t * d3)
            .zip(dgate.par_chunks_mut(t * heads))
            .enumerate()
            .for_each(|(s, (dqkv, dgate))| {
                scene_grad(
                    n,
                    &qkv[s * t * d3..(s + 1) * t * d3],
                    &gate[s * t * heads..(s + 1) * t * heads],
                    &grad[s * t * d..(s + 1) * t * d],
                    &bias[s * t..(s + 1) * t],
                    rope,
                    s * t,
                    dqkv,
                    dgate,
                )
            });
        Ok((CpuStorage::F32(out), Shape::from(b * t * (d3 + heads))))
    }
}

/// Gradients `(of qkv [B, T, 3D], of gate [B, T, H])` of the fused self-attention `op` given
/// the gradient of its output `grad [B, T, D]` (CPU tensors; checks the shapes against the
/// held key bias and rotary code as the forward pass does).
pub fn self_attention_grad(
    op: &SelfAttention,
    qkv: &Tensor,
    gate: &Tensor,
    grad: &Tensor,
) -> candle_core::Result<(Tensor, Tensor)> {
    let (b, t, d3) = qkv.dims3()?;
    if op.key_bias.len() != b * t || op.rope.cos.len() != b * t * op.rope.pairs {
        candle_core::bail!("fused-self-attention-grad: the held codes do not match {b}x{t}");
    }
    let flat = qkv.contiguous()?.apply_op3_no_bwd(
        &gate.contiguous()?,
        &grad.contiguous()?,
        &SelfAttentionGrad(op),
    )?;
    let dqkv = flat.narrow(0, 0, b * t * d3)?.reshape((b, t, d3))?;
    let h = op.heads;
    let dgate = flat.narrow(0, b * t * d3, b * t * h)?.reshape((b, t, h))?;
    Ok((dqkv, dgate))
}

/// `(q [Nq, D], kv [B, Tk, 2D], grad [Nq, D])` -> the gradients of `q` then of `kv`,
/// flattened one after the other `[Nq * D + B * Tk * 2D]`. Query rows must be grouped by scene
/// in scene order (as the anchor head lays them out).
struct CrossAttentionGrad<'a>(&'a CrossAttention);

impl CustomOp3 for CrossAttentionGrad<'_> {
    fn name(&self) -> &'static str {
        "fused-cross-attention-grad"
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
        let q = f32_slice(self.name(), s1, l1)?;
        let kv = f32_slice(self.name(), s2, l2)?;
        let grad = f32_slice(self.name(), s3, l3)?;
        let (nq, d) = l1.shape().dims2()?;
        let (b, tk, d2) = l2.shape().dims3()?;
        let op = self.0;
        let scenes = &op.query_scene;
        if l3.shape().dims2()? != (nq, d)
            || d2 != 2 * d
            || scenes.len() != nq
            || scenes.windows(2).any(|w| w[1] < w[0])
            || scenes.last().is_some_and(|&s| s as usize >= b)
        {
            candle_core::bail!(
                "{}: q {:?}, kv {:?}, grad {:?} (query rows grouped by scene in order)",
                self.name(),
                l1.shape(),
                l2.shape(),
                l3.shape()
            );
        }
        let (heads, dh) = (op.heads, d / op.heads);
        let mut out = vec![0f32; nq * d + b * tk * d2];
        let (dq_all, dkv_all) = out.split_at_mut(nq * d);
        // Each scene's query rows `first..first + count` and its slice of `dq`.
        let mut rest = dq_all;
        let mut parts = Vec::with_capacity(b);
        let mut first = 0;
        for s in 0..b {
            let count = scenes[first..]
                .iter()
                .take_while(|&&x| x as usize == s)
                .count();
            let (mine, tail) = std::mem::take(&mut rest).split_at_mut(count * d);
            parts.push((first, count, mine));
            rest = tail;
            first += count;
        }
        parts
            .into_par_iter()
            .zip(dkv_all.par_chunks_mut(tk * d2))
            .enumerate()
            .for_each(|(s, ((first, count, dq_out), dkv))| {
                let mut bufs = [
                    count * dh,
                    tk * dh,
                    tk * dh,
                    count * dh,
                    tk * dh,
                    tk * dh,
                    count * dh,
                ]
                .map(|n| vec![0f32; n]);
                let mut unused = vec![0f32; count];
                let bias = &op.key_bias[s * tk..(s + 1) * tk];
                for h in 0..heads {
                    let [qh, kh, vh, dq, dk, dv, dout] = &mut bufs;
                    let kv_row = |r: usize| &kv[(s * tk + r) * d2..(s * tk + r + 1) * d2];
                    gather_head(
                        qh,
                        h,
                        dh,
                        |r| &q[(first + r) * d..(first + r + 1) * d],
                        Some((&op.q_rope, first)),
                    );
                    gather_head(kh, h, dh, |r| &kv_row(r)[..d], Some((&op.k_rope, s * tk)));
                    gather_head(vh, h, dh, |r| &kv_row(r)[d..], None);
                    gather_head(
                        dout,
                        h,
                        dh,
                        |r| &grad[(first + r) * d..(first + r + 1) * d],
                        None,
                    );
                    head_grad(
                        dh,
                        (qh, kh, vh),
                        bias,
                        None,
                        dout,
                        (dq, dk, dv),
                        &mut unused,
                    );
                    unrotate_rows(dq, dh, &op.q_rope, first);
                    unrotate_rows(dk, dh, &op.k_rope, s * tk);
                    for r in 0..count {
                        dq_out[r * d + h * dh..r * d + (h + 1) * dh]
                            .copy_from_slice(&dq[r * dh..(r + 1) * dh]);
                    }
                    for j in 0..tk {
                        let row = &mut dkv[j * d2..(j + 1) * d2];
                        row[h * dh..(h + 1) * dh].copy_from_slice(&dk[j * dh..(j + 1) * dh]);
                        row[d + h * dh..d + (h + 1) * dh]
                            .copy_from_slice(&dv[j * dh..(j + 1) * dh]);
                    }
                }
            });
        Ok((CpuStorage::F32(out), Shape::from(nq * d + b * tk * d2)))
    }
}

/// Gradients `(of q [Nq, D], of kv [B, Tk, 2D])` of the fused cross-attention `op` given the
/// gradient of its output `grad [Nq, D]` (CPU tensors; query rows grouped by scene in order).
pub fn cross_attention_grad(
    op: &CrossAttention,
    q: &Tensor,
    kv: &Tensor,
    grad: &Tensor,
) -> candle_core::Result<(Tensor, Tensor)> {
    let (nq, d) = q.dims2()?;
    let (b, tk, d2) = kv.dims3()?;
    let flat = q.contiguous()?.apply_op3_no_bwd(
        &kv.contiguous()?,
        &grad.contiguous()?,
        &CrossAttentionGrad(op),
    )?;
    let dq = flat.narrow(0, 0, nq * d)?.reshape((nq, d))?;
    let dkv = flat.narrow(0, nq * d, b * tk * d2)?.reshape((b, tk, d2))?;
    Ok((dq, dkv))
}
