//! Object decoder: the object tokens of each scene plus learned registers, laid out
//! `[B, T = M + R, D]` with a key mask for padded slots, through pre-norm blocks (RMSNorm,
//! gated multi-head self-attention with ARoPE, FiLM on `tau = log2(dt_steps)`, SwiGLU).

use std::collections::HashMap;
use std::collections::hash_map::Entry;
use std::sync::{Arc, Mutex};

use candle_core::{Device, Tensor};

use super::attention::multi_head;
use super::batch::BatchInputs;
use super::host_tensor;
use crate::kernels::attention::{RotaryRows, SelfAttention, self_attention, self_attention_train};
use crate::layers::{Exec, Init, Linear, Mode, ParamStore, RmsNorm, SwiGlu, gather_padded};
use crate::{ModelConfig, ModelError};

/// Additive attention bias of a padded key.
pub(crate) const MASKED: f32 = -1.0e9;

/// Decoder output: final tokens `[B, T, D]`, the tapped depths (each `[B, T, D]`), the key
/// mask `[B, 1, 1, T]` and the token rotary code `(cos, sin)`, each `[B, 1, T, P]`, with the
/// same mask and code as host rows (`[B, T]` and `[B * T, P]`) for the fused kernels.
pub(crate) struct Decoded {
    pub last: Tensor,
    pub taps: Vec<Tensor>,
    pub mask: Tensor,
    pub rope: (Tensor, Tensor),
    pub key_bias: Arc<Vec<f32>>,
    pub rope_rows: Arc<RotaryRows>,
}

/// What every block of one pass shares: key mask `[B, 1, 1, T]`, rotary code `[B, 1, T, P]`,
/// `tau = log2(dt_steps)` `[B, 1]`, and mask and code as host rows.
struct PassContext {
    mask: Tensor,
    cos: Tensor,
    sin: Tensor,
    /// `tau = log2(dt_steps)` per scene `[B]` (host).
    tau: Vec<f32>,
    key_bias: Arc<Vec<f32>>,
    rope_rows: Arc<RotaryRows>,
    /// The rotary codes depend on graph poses (a gradient pass): attention takes them as
    /// tensors (the composition), since the fused kernels read them from the host rows.
    rope_in_graph: bool,
}

/// One pre-norm block (`decoder.blocks.{l}.*`).
struct Block {
    norm1: RmsNorm,
    qkv: Linear,
    gate: Linear,
    out: Linear,
    film_a: Linear,
    film_b: Linear,
    norm2: RmsNorm,
    ffn: SwiGlu,
    heads: usize,
    /// FiLM `(gamma, beta)` `[2D]` (gamma with its 1 added) by the bits of `tau`, for constant
    /// CPU weights: a step size always gives the same modulation, so an inference model
    /// computes it once per value.
    film_cache: Mutex<HashMap<u32, Vec<f32>>>,
}

impl Block {
    fn new(p: &mut ParamStore, c: &ModelConfig, l: usize) -> Result<Block, ModelError> {
        let (d, eps) = (c.width, c.norm_eps);
        let n = format!("decoder.blocks.{l}");
        Ok(Block {
            norm1: p.rms_norm(&format!("{n}.norm1"), d, eps)?,
            qkv: p.linear(&format!("{n}.attn.qkv"), d, 3 * d, false)?,
            gate: p.linear(&format!("{n}.attn.gate"), d, c.heads, true)?,
            out: p.linear(&format!("{n}.attn.out"), d, d, false)?,
            film_a: p.linear(&format!("{n}.film.0"), 1, c.film_hidden, true)?,
            // Small final layer: gamma ~ 1, beta ~ 0 at initialisation.
            film_b: p.linear_init(&format!("{n}.film.1"), c.film_hidden, 2 * d, true, 1e-2)?,
            norm2: p.rms_norm(&format!("{n}.norm2"), d, eps)?,
            ffn: SwiGlu::new(p, &format!("{n}.ffn"), d, c.ffn_hidden)?,
            heads: c.heads,
            film_cache: Mutex::new(HashMap::new()),
        })
    }

    /// FiLM parameters `[B, 2D]` (`gamma - 1` then `beta`) of `tau` (`[B]`, host).
    fn film(&self, tau: &[f32]) -> candle_core::Result<Tensor> {
        let t = Tensor::from_slice(tau, (tau.len(), 1), self.film_a.w.device())?;
        self.film_b.forward(&self.film_a.forward(&t)?.silu()?)
    }

    /// `(gamma, beta)`, each `[B, 1, D]`, from the per-value cache when the FiLM weights are
    /// constants on the CPU; `None` otherwise.
    fn film_cached(
        &self,
        ctx: &PassContext,
        d: usize,
    ) -> candle_core::Result<Option<(Tensor, Tensor)>> {
        if !(self.film_a.is_constant_cpu() && self.film_b.is_constant_cpu()) {
            return Ok(None);
        }
        let b = ctx.tau.len();
        let (mut gamma, mut beta) = (Vec::with_capacity(b * d), Vec::with_capacity(b * d));
        let mut cache = self
            .film_cache
            .lock()
            .map_err(|_| candle_core::Error::Msg("FiLM cache lock poisoned".into()))?;
        for &tau in &ctx.tau {
            let gb = match cache.entry(tau.to_bits()) {
                Entry::Occupied(e) => e.into_mut(),
                Entry::Vacant(e) => {
                    let mut gb = self.film(&[tau])?.flatten_all()?.to_vec1::<f32>()?;
                    gb.iter_mut().take(d).for_each(|g| *g += 1.0);
                    e.insert(gb)
                }
            };
            if gb.len() != 2 * d {
                candle_core::bail!("FiLM of {} values for width {d}", gb.len());
            }
            gamma.extend_from_slice(&gb[..d]);
            beta.extend_from_slice(&gb[d..]);
        }
        let dev = self.film_a.w.device();
        Ok(Some((
            Tensor::from_vec(gamma, (b, 1, d), dev)?,
            Tensor::from_vec(beta, (b, 1, d), dev)?,
        )))
    }

    /// `[B, T, D]` -> `[B, T, D]`.
    fn forward(&self, x: &Tensor, ctx: &PassContext, exec: Exec) -> candle_core::Result<Tensor> {
        let d = x.dim(2)?;
        let xn = self.norm1.forward_exec(x, exec)?;
        let qkv = self.qkv.forward(&xn)?;
        let o = if exec.fused && !ctx.rope_in_graph {
            let op = SelfAttention {
                heads: self.heads,
                key_bias: ctx.key_bias.clone(),
                rope: ctx.rope_rows.clone(),
            };
            let gate = self.gate.forward(&xn)?;
            match exec.mode {
                Mode::Inference => self_attention(op, &qkv, &gate)?,
                Mode::Training => self_attention_train(op, &qkv, &gate)?,
            }
        } else {
            self.gated_attention(&xn, &qkv, ctx, exec)?
        };
        let x = (x + self.out.forward(&o)?)?;
        // FiLM on tau = log2(dt_steps): gamma = 1 + .., beta.
        let (gamma, beta) = match self.film_cached(ctx, d)? {
            Some(gb) => gb,
            None => {
                let fb = self.film(&ctx.tau)?; // [B, 2D]
                let gamma = (fb.narrow(1, 0, d)? + 1.0)?.unsqueeze(1)?;
                (gamma, fb.narrow(1, d, d)?.unsqueeze(1)?)
            }
        };
        let x = x.broadcast_mul(&gamma)?.broadcast_add(&beta)?;
        &x + self
            .ffn
            .forward(&self.norm2.forward_exec(&x, exec)?, exec.fused)?
    }

    /// The attention composition: `xn [B, T, D]` (normalised input), `qkv [B, T, 3D]` ->
    /// gated heads side by side `[B, T, D]`.
    fn gated_attention(
        &self,
        xn: &Tensor,
        qkv: &Tensor,
        ctx: &PassContext,
        exec: Exec,
    ) -> candle_core::Result<Tensor> {
        let (b, t, d) = xn.dims3()?;
        let q = qkv.narrow(2, 0, d)?;
        let k = qkv.narrow(2, d, d)?;
        let v = qkv.narrow(2, 2 * d, d)?;
        let rope = Some((&ctx.cos, &ctx.sin));
        let o = multi_head(&q, &k, &v, &ctx.mask, rope, rope, self.heads, exec.mode)?;
        // Per-head sigmoid gate from the block input.
        let gate = candle_nn::ops::sigmoid(&self.gate.forward(xn)?)?; // [B, T, H]
        let gate = gate.transpose(1, 2)?.unsqueeze(3)?; // [B, H, T, 1]
        o.broadcast_mul(&gate)?.transpose(1, 2)?.reshape((b, t, d))
    }
}

/// Registers and blocks (`decoder.*` parameters).
pub(crate) struct Decoder {
    registers: Tensor,
    blocks: Vec<Block>,
    taps: Vec<usize>,
    rope_pairs: usize,
}

impl Decoder {
    /// Creates or loads the decoder's parameters for configuration `c`.
    pub fn new(p: &mut ParamStore, c: &ModelConfig) -> Result<Decoder, ModelError> {
        let registers = p.get(
            "decoder.registers",
            &[c.registers, c.width],
            Init::Uniform(0.5),
        )?;
        let blocks = (0..c.blocks)
            .map(|l| Block::new(p, c, l))
            .collect::<Result<_, _>>()?;
        Ok(Decoder {
            registers,
            blocks,
            taps: c.anchor_taps.clone(),
            rope_pairs: c.rope_dim / 2,
        })
    }

    /// Object tokens `[O, D]` -> [`Decoded`].
    pub fn forward(
        &self,
        inp: &BatchInputs,
        tokens: &Tensor,
        exec: Exec,
        device: &Device,
    ) -> Result<Decoded, ModelError> {
        let (r, d) = self.registers.dims2()?;
        let (b, m) = (inp.b, inp.mmax);
        let t = m + r;
        let p = self.rope_pairs;
        // Scatter object tokens into [B, M] slots (zero rows for padding) by gathering.
        let mut gather = vec![inp.o as u32; b * m];
        let mut mask = vec![MASKED; b * t];
        let mut cos = vec![1f32; b * t * p];
        let mut sin = vec![0f32; b * t * p];
        for s in 0..b {
            let (first, last) = (inp.scene_offsets[s], inp.scene_offsets[s + 1]);
            for (j, obj) in (first..last).enumerate() {
                gather[s * m + j] = obj as u32;
                mask[s * t + j] = 0.0;
                let dst = (s * t + j) * p;
                cos[dst..dst + p].copy_from_slice(&inp.object_cos[obj * p..(obj + 1) * p]);
                sin[dst..dst + p].copy_from_slice(&inp.object_sin[obj * p..(obj + 1) * p]);
            }
            for j in m..t {
                mask[s * t + j] = 0.0;
            }
        }
        let padded =
            gather_padded(tokens, &super::host_index(device, &gather)?)?.reshape((b, m, d))?;
        let regs = self.registers.unsqueeze(0)?.broadcast_as((b, r, d))?;
        let mut x = if r > 0 {
            Tensor::cat(&[padded, regs.contiguous()?], 1)?
        } else {
            padded
        };
        let (cos_t, sin_t) = match &inp.pose_inputs {
            // The same layout gathered from the graph's rows: padding and registers read the
            // appended row of ones (cosines) or zeros (sines).
            Some(g) => {
                let mut slots = vec![inp.o as u32; b * t];
                for s in 0..b {
                    let first = inp.scene_offsets[s];
                    for j in 0..inp.scene_offsets[s + 1] - first {
                        slots[s * t + j] = (first + j) as u32;
                    }
                }
                let slots = super::host_index(device, &slots)?;
                let ones = Tensor::ones((1, p), g.object_cos.dtype(), device)?;
                let cos = Tensor::cat(&[&g.object_cos, &ones], 0)?.index_select(&slots, 0)?;
                let sin = gather_padded(&g.object_sin, &slots)?;
                (cos.reshape((b, 1, t, p))?, sin.reshape((b, 1, t, p))?)
            }
            None => (
                host_tensor(device, &cos, &[b, 1, t, p])?,
                host_tensor(device, &sin, &[b, 1, t, p])?,
            ),
        };
        let ctx = PassContext {
            mask: host_tensor(device, &mask, &[b, 1, 1, t])?,
            cos: cos_t,
            sin: sin_t,
            tau: inp.tau.clone(),
            key_bias: Arc::new(mask),
            rope_rows: Arc::new(RotaryRows { cos, sin, pairs: p }),
            rope_in_graph: inp.pose_inputs.is_some(),
        };
        let mut taps = Vec::with_capacity(self.taps.len());
        for (l, blk) in self.blocks.iter().enumerate() {
            x = blk.forward(&x, &ctx, exec)?;
            for _ in self.taps.iter().filter(|&&tap| tap == l) {
                taps.push(x.clone());
            }
        }
        Ok(Decoded {
            last: x,
            taps,
            mask: ctx.mask,
            rope: (ctx.cos, ctx.sin),
            key_bias: ctx.key_bias,
            rope_rows: ctx.rope_rows,
        })
    }
}
