//! One PhysiFormer block: adaLN-Zero modulation from the flow time, RMSNorm, multi-head
//! attention with QK-norm over one kind of token group, SwiGLU. Registers are copied into
//! every group and averaged back over the valid groups afterwards.

use candle_core::{D, Tensor};

use super::inputs::PassInputs;
use crate::ModelError;
use crate::layers::{Init, Linear, Mode, ParamStore, RmsNorm, SwiGlu};
use crate::rigidformer::attention::multi_head;

/// Which tokens attend to each other in a block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AttentionKind {
    /// All vertices of a scene at one frame (coordinate rotary code).
    Spatial,
    /// One vertex of a scene across its frames (frame-index rotary code).
    Temporal,
    /// The vertices of one object at one frame (coordinate rotary code).
    Object,
}

impl AttentionKind {
    /// The kind of block `index`: spatial, temporal, per-object, temporal, repeating.
    pub fn of_block(index: usize) -> AttentionKind {
        match index % 4 {
            0 => AttentionKind::Spatial,
            2 => AttentionKind::Object,
            _ => AttentionKind::Temporal,
        }
    }
}

/// Block parameters.
pub(crate) struct Block {
    kind: AttentionKind,
    heads: usize,
    norm1: RmsNorm,
    qkv: Linear,
    q_norm: RmsNorm,
    k_norm: RmsNorm,
    proj: Linear,
    norm2: RmsNorm,
    ffn: SwiGlu,
    /// Flow-time conditioning -> (shift, scale, gate) for attention and feed-forward; zero
    /// initialised so a new block is the identity.
    ada: Linear,
}

/// Modulation of one sub-layer, each `[B, D]`.
struct Modulation {
    shift: Tensor,
    scale: Tensor,
    gate: Tensor,
}

/// Reshapes a per-scene `[B, D]` to broadcast over `[B, ..., D]` of rank `rank`.
pub(crate) fn per_scene(x: &Tensor, rank: usize) -> candle_core::Result<Tensor> {
    let (b, d) = x.dims2()?;
    let mut shape = vec![b];
    shape.extend(std::iter::repeat_n(1, rank - 2));
    shape.push(d);
    x.reshape(shape)
}

/// `x * (1 + scale) + shift` with per-scene `[B, D]` modulation.
pub(crate) fn modulate(x: &Tensor, shift: &Tensor, scale: &Tensor) -> candle_core::Result<Tensor> {
    let r = x.rank();
    x.broadcast_mul(&(per_scene(scale, r)? + 1.0)?)?
        .broadcast_add(&per_scene(shift, r)?)
}

impl Block {
    pub fn new(
        p: &mut ParamStore,
        name: &str,
        kind: AttentionKind,
        width: usize,
        heads: usize,
        ffn_hidden: usize,
        eps: f32,
    ) -> Result<Block, ModelError> {
        let dh = width / heads;
        let ada_w = p.get(
            &format!("{name}.ada.weight"),
            &[6 * width, width],
            Init::Const(0.0),
        )?;
        let ada_b = p.get(&format!("{name}.ada.bias"), &[6 * width], Init::Const(0.0))?;
        Ok(Block {
            kind,
            heads,
            norm1: p.rms_norm(&format!("{name}.norm1"), width, eps)?,
            qkv: p.linear(&format!("{name}.qkv"), width, 3 * width, false)?,
            q_norm: p.rms_norm(&format!("{name}.q_norm"), dh, eps)?,
            k_norm: p.rms_norm(&format!("{name}.k_norm"), dh, eps)?,
            proj: p.linear(&format!("{name}.proj"), width, width, true)?,
            norm2: p.rms_norm(&format!("{name}.norm2"), width, eps)?,
            ffn: SwiGlu::new(p, &format!("{name}.ffn"), width, ffn_hidden)?,
            ada: Linear::new(ada_w, Some(ada_b)),
        })
    }

    /// Attention over `seq [G, L, D]` with key bias `bias` and rotary code `rope`
    /// (`[G or 1, 1, L, P]`) -> `[G, L, D]`.
    fn attend(
        &self,
        seq: &Tensor,
        bias: &Tensor,
        rope: (&Tensor, &Tensor),
        mode: Mode,
    ) -> candle_core::Result<Tensor> {
        let (g, l, d) = seq.dims3()?;
        let dh = d / self.heads;
        let qkv = self.qkv.forward(seq)?;
        let head_norm = |x: Tensor, n: &RmsNorm| -> candle_core::Result<Tensor> {
            n.forward(&x.reshape((g, l, self.heads, dh))?, mode)?
                .reshape((g, l, d))
        };
        let q = head_norm(qkv.narrow(D::Minus1, 0, d)?, &self.q_norm)?;
        let k = head_norm(qkv.narrow(D::Minus1, d, d)?, &self.k_norm)?;
        let v = qkv.narrow(D::Minus1, 2 * d, d)?.contiguous()?;
        let o = multi_head(&q, &k, &v, bias, Some(rope), Some(rope), self.heads, mode)?;
        self.proj.forward(&o.transpose(1, 2)?.reshape((g, l, d))?)
    }

    /// Mixes `x` (vertex tokens `[B, T, V, D]`) and `reg` (registers `[B, R, D]`) through the
    /// block's attention kind -> the attention outputs of both, same shapes.
    fn mix(
        &self,
        x: &Tensor,
        reg: &Tensor,
        inp: &PassInputs,
        mode: Mode,
    ) -> candle_core::Result<(Tensor, Tensor)> {
        let (b, t, v, d) = x.dims4()?;
        let r = reg.dim(1)?;
        match self.kind {
            AttentionKind::Spatial | AttentionKind::Object => {
                let regs = reg.unsqueeze(1)?.broadcast_as((b, t, r, d))?;
                let seq = Tensor::cat(&[&regs, x], 2)?.reshape((b * t, r + v, d))?;
                let bias = if self.kind == AttentionKind::Spatial {
                    &inp.spatial_bias
                } else {
                    &inp.object_bias
                };
                let (c, s) = &inp.spatial_rope;
                let o = self
                    .attend(&seq, bias, (c, s), mode)?
                    .reshape((b, t, r + v, d))?;
                let o_reg = o
                    .narrow(2, 0, r)?
                    .broadcast_mul(&inp.frame_mask)?
                    .sum(1)?
                    .broadcast_div(&inp.frame_count)?;
                Ok((o.narrow(2, r, v)?, o_reg))
            }
            AttentionKind::Temporal => {
                let xt = x.transpose(1, 2)?; // [B, V, T, D]
                let regs = reg.unsqueeze(1)?.broadcast_as((b, v, r, d))?;
                let seq = Tensor::cat(&[&regs, &xt], 2)?.reshape((b * v, r + t, d))?;
                let (c, s) = &inp.temporal_rope;
                let o = self
                    .attend(&seq, &inp.temporal_bias, (c, s), mode)?
                    .reshape((b, v, r + t, d))?;
                let o_reg = o
                    .narrow(2, 0, r)?
                    .broadcast_mul(&inp.vertex_mask)?
                    .sum(1)?
                    .broadcast_div(&inp.vertex_count)?;
                Ok((o.narrow(2, r, t)?.transpose(1, 2)?, o_reg))
            }
        }
    }

    /// One block: `x [B, T, V, D]`, `reg [B, R, D]`, conditioning `c [B, D]` (already passed
    /// through SiLU) -> updated `(x, reg)`.
    pub fn forward(
        &self,
        x: &Tensor,
        reg: &Tensor,
        c: &Tensor,
        inp: &PassInputs,
        mode: Mode,
    ) -> candle_core::Result<(Tensor, Tensor)> {
        let m = self.ada.forward(c)?.chunk(6, D::Minus1)?;
        let sub = |i: usize| Modulation {
            shift: m[3 * i].clone(),
            scale: m[3 * i + 1].clone(),
            gate: m[3 * i + 2].clone(),
        };
        let (att, ff) = (sub(0), sub(1));
        let xa = modulate(&self.norm1.forward(x, mode)?, &att.shift, &att.scale)?;
        let ra = modulate(&self.norm1.forward(reg, mode)?, &att.shift, &att.scale)?;
        let (ox, or) = self.mix(&xa, &ra, inp, mode)?;
        let x = (x + ox.broadcast_mul(&per_scene(&att.gate, 4)?)?)?;
        let reg = (reg + or.broadcast_mul(&per_scene(&att.gate, 3)?)?)?;
        let fx = self.ffn.forward(
            &modulate(&self.norm2.forward(&x, mode)?, &ff.shift, &ff.scale)?,
            false,
        )?;
        let fr = self.ffn.forward(
            &modulate(&self.norm2.forward(&reg, mode)?, &ff.shift, &ff.scale)?,
            false,
        )?;
        let x = (&x + fx.broadcast_mul(&per_scene(&ff.gate, 4)?)?)?;
        let reg = (&reg + fr.broadcast_mul(&per_scene(&ff.gate, 3)?)?)?;
        Ok((x, reg))
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{Device, Tensor};

    use super::*;
    use crate::physiformer::config::PhysiConfig;
    use crate::physiformer::inputs::{DenoiseItem, build};
    use crate::physiformer::scene::{Material, MeshScene};

    /// The coordinate rotary code makes spatial attention depend on vertex positions only
    /// through their differences: moving a whole frame rigidly by a translation leaves the
    /// attention output unchanged, while deforming it changes the output.
    #[test]
    fn spatial_attention_is_invariant_to_translating_a_frame() {
        let cfg = PhysiConfig::tiny();
        let mut p = ParamStore::random(1, &Device::Cpu, false);
        let blk = Block::new(&mut p, "b", AttentionKind::Spatial, 32, 2, 64, 1e-6).unwrap();
        let positions: Vec<[f32; 3]> = (0..6)
            .map(|i| {
                [
                    0.1 * i as f32,
                    0.05 * (i * i) as f32 - 0.3,
                    0.2 - 0.07 * i as f32,
                ]
            })
            .collect();
        let scene = MeshScene {
            velocities: vec![[0.0; 3]; 6],
            vertex_offsets: vec![0, 6],
            materials: vec![Material::Rigid],
            positions: positions.clone(),
        };
        let frame = |shift: [f32; 3], squash: f32| -> Vec<f32> {
            let mut z = Vec::new();
            for _ in 0..2 {
                for q in &positions {
                    z.extend([q[0] * squash + shift[0], q[1] + shift[1], q[2] + shift[2]]);
                }
            }
            z
        };
        let seq = Tensor::rand(-1f32, 1f32, (2, cfg.registers + 6, 32), &Device::Cpu).unwrap();
        let run = |z: &[f32]| -> Vec<f32> {
            let it = DenoiseItem {
                scene: &scene,
                z,
                frames: 2,
                t: 0.5,
            };
            let inp = build(&cfg, &[it], &Device::Cpu).unwrap();
            let (c, s) = &inp.spatial_rope;
            blk.attend(&seq, &inp.spatial_bias, (c, s), Mode::Inference)
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1()
                .unwrap()
        };
        let base = run(&frame([0.0; 3], 1.0));
        let moved = run(&frame([0.37, -0.21, 0.55], 1.0));
        let squashed = run(&frame([0.0; 3], 0.5));
        let diff = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max)
        };
        assert!(diff(&base, &moved) < 1e-4, "{}", diff(&base, &moved));
        assert!(diff(&base, &squashed) > 1e-3);
    }
}
