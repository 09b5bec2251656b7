//! Backward pass of the fused self-attention ([`super::attention::SelfAttention`]) for
//! training on the CPU: per scene and head, the rotated queries and keys, the softmax and the
//! gated output are recomputed from `qkv` and the gate logits (nothing of the forward pass is
//! kept), then the gradients of values, scores, rotated queries and keys and the gate logits
//! follow in one sweep over the query rows, and the rotary code is undone on the query and key
//! gradients. Scenes run in parallel over rayon's pool.

use candle_core::{CpuStorage, CustomOp3, Layout, Shape, Tensor};
use rayon::prelude::*;

use super::activation::f32_slice;
use super::attention::{RotaryRows, SelfAttention, rotate};
use super::simd::{axpy, exp_slice};

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
    let scale = 1.0 / (dh as f32).sqrt();
    let (mut q, mut k, mut v) = (vec![0f32; t * dh], vec![0f32; t * dh], vec![0f32; t * dh]);
    let (mut dq, mut dk, mut dv) = (vec![0f32; t * dh], vec![0f32; t * dh], vec![0f32; t * dh]);
    let (mut p, mut dp, mut o) = (vec![0f32; t], vec![0f32; t], vec![0f32; dh]);
    let mut dout = vec![0f32; dh];
    for h in 0..heads {
        for j in 0..t {
            let (cos, sin) = rope.row(first_row + j);
            let row = &qkv[j * 3 * d..(j + 1) * 3 * d];
            q[j * dh..(j + 1) * dh].copy_from_slice(&row[h * dh..(h + 1) * dh]);
            rotate(&mut q[j * dh..(j + 1) * dh], cos, sin);
            k[j * dh..(j + 1) * dh].copy_from_slice(&row[d + h * dh..d + (h + 1) * dh]);
            rotate(&mut k[j * dh..(j + 1) * dh], cos, sin);
            v[j * dh..(j + 1) * dh].copy_from_slice(&row[2 * d + h * dh..2 * d + (h + 1) * dh]);
        }
        dk.fill(0.0);
        dv.fill(0.0);
        for i in 0..t {
            let qi = &q[i * dh..(i + 1) * dh];
            for (j, pj) in p.iter_mut().enumerate() {
                let kj = &k[j * dh..(j + 1) * dh];
                *pj = scale * qi.iter().zip(kj).map(|(a, b)| a * b).sum::<f32>() + bias[j];
            }
            let max = p.iter().fold(f32::NEG_INFINITY, |m, &x| m.max(x));
            p.iter_mut().for_each(|x| *x -= max);
            exp_slice(&mut p);
            let inv: f32 = 1.0 / p.iter().sum::<f32>();
            // Masked keys come out of the clamped `exp` as ~1e-38, not 0: flushed, so that their
            // gradients hold no subnormal numbers (which slow every later product down).
            p.iter_mut()
                .for_each(|x| *x = if *x < 1e-30 { 0.0 } else { *x * inv });
            o.fill(0.0);
            for (j, &pj) in p.iter().enumerate() {
                axpy(&mut o, pj, &v[j * dh..(j + 1) * dh]);
            }
            let sg = 1.0 / (1.0 + (-gate[i * heads + h]).exp());
            dout.copy_from_slice(&grad[i * d + h * dh..i * d + (h + 1) * dh]);
            let dsg: f32 = dout.iter().zip(&o).map(|(a, b)| a * b).sum();
            dgate[i * heads + h] = dsg * sg * (1.0 - sg);
            dout.iter_mut().for_each(|x| *x *= sg); // gradient of the attention output
            for (j, dpj) in dp.iter_mut().enumerate() {
                let vj = &v[j * dh..(j + 1) * dh];
                *dpj = dout.iter().zip(vj).map(|(a, b)| a * b).sum();
                axpy(&mut dv[j * dh..(j + 1) * dh], p[j], &dout);
            }
            let c: f32 = p.iter().zip(&dp).map(|(a, b)| a * b).sum();
            let dqi = &mut dq[i * dh..(i + 1) * dh];
            dqi.fill(0.0);
            for j in 0..t {
                let ds = p[j] * (dp[j] - c) * scale;
                axpy(dqi, ds, &k[j * dh..(j + 1) * dh]);
                axpy(&mut dk[j * dh..(j + 1) * dh], ds, qi);
            }
        }
        for j in 0..t {
            let (cos, sin) = rope.row(first_row + j);
            unrotate(&mut dq[j * dh..(j + 1) * dh], cos, sin);
            unrotate(&mut dk[j * dh..(j + 1) * dh], cos, sin);
            let row = &mut dqkv[j * 3 * d..(j + 1) * 3 * d];
            row[h * dh..(h + 1) * dh].copy_from_slice(&dq[j * dh..(j + 1) * dh]);
            row[d + h * dh..d + (h + 1) * dh].copy_from_slice(&dk[j * dh..(j + 1) * dh]);
            row[2 * d + h * dh..2 * d + (h + 1) * dh].copy_from_slice(&dv[j * dh..(j + 1) * dh]);
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
