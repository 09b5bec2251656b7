//! Anchor head: each anchor's query (its point feature, offset from the object's centroid,
//! Gaussian anchor-vertex pooling of nearby point features with a learned bandwidth, its
//! rotary code, plus the object's final token) cross-attends to the decoder tokens of several
//! depths; an MLP turns it into an acceleration.

use std::sync::{Arc, OnceLock};

use candle_core::{Device, Tensor};

use super::attention::multi_head;
use super::batch::BatchInputs;
use super::decoder::Decoded;
use super::wrench::ContactWrench;
use super::{host_index, host_tensor};
use crate::kernels::attention::{
    CrossAttention, RotaryRows, cross_attention, cross_attention_train,
};
use crate::kernels::avp::{AnchorPooling, anchor_pooling, anchor_pooling_composed};
use crate::layers::{Exec, Init, Linear, Mlp, Mode, ParamStore, RmsNorm, gather_padded};
use crate::{ModelConfig, ModelError};

/// Widths of the anchor query's input segments in the order [`AnchorHead`] concatenates them
/// before `anchors.query_in`: the anchor's own point feature (`point_dim`), its offset from the
/// object's centroid (3, metres), the pooled point feature (`point_dim`) and its rotary code
/// (`rope_dim`). Code that remaps `query_in`'s columns reads the layout from here.
pub(crate) fn query_segments(c: &ModelConfig) -> [usize; 4] {
    [c.point_dim, 3, c.point_dim, c.rope_dim]
}

/// The anchor head's layers (`anchors.*` parameters).
pub(crate) struct AnchorHead {
    query_in: Linear,
    own_token: Linear,
    own_norm: RmsNorm,
    tap_norms: Vec<RmsNorm>,
    depth_embedding: Tensor,
    log_sigma: Tensor,
    /// `exp(-2 log_sigma)` on the host, kept when `log_sigma` is a constant (inference).
    inv_sigma2: OnceLock<f32>,
    q_norm: RmsNorm,
    q: Linear,
    kv: Linear,
    out: Linear,
    head_norm: RmsNorm,
    head: Mlp,
    /// The coarse output MLP (`anchors.coarse.*`, D -> D -> 3, last layer initialised to
    /// zero) when the configuration has a coarse unit.
    coarse: Option<Mlp>,
    /// The contact wrench (`anchors.wrench.*`) when the configuration has one.
    wrench: Option<ContactWrench>,
    device: Device,
}

impl AnchorHead {
    /// Creates or loads the anchor head's parameters for configuration `c`.
    pub fn new(
        p: &mut ParamStore,
        c: &ModelConfig,
        device: &Device,
    ) -> Result<AnchorHead, ModelError> {
        let (d, eps) = (c.width, c.norm_eps);
        let taps = c.anchor_taps.len();
        let q_in = query_segments(c).iter().sum();
        Ok(AnchorHead {
            query_in: p.linear("anchors.query_in", q_in, d, true)?,
            own_token: p.linear("anchors.own_token", d, d, false)?,
            own_norm: p.rms_norm("anchors.own_norm", d, eps)?,
            tap_norms: (0..taps)
                .map(|t| p.rms_norm(&format!("anchors.tap_norm.{t}"), d, eps))
                .collect::<Result<_, _>>()?,
            depth_embedding: p.get("anchors.depth_embedding", &[taps, d], Init::Uniform(0.1))?,
            log_sigma: p.get("anchors.avp.log_sigma", &[1], Init::Const(c.avp_sigma.ln()))?,
            inv_sigma2: OnceLock::new(),
            q_norm: p.rms_norm("anchors.q_norm", d, eps)?,
            q: p.linear("anchors.cross.q", d, d, false)?,
            kv: p.linear("anchors.cross.kv", d, 2 * d, false)?,
            out: p.linear("anchors.cross.out", d, d, false)?,
            head_norm: p.rms_norm("anchors.head_norm", d, eps)?,
            head: Mlp::new(p, "anchors.head", d, d, 3)?,
            coarse: match c.accel_coarse_scale {
                Some(_) => Some(Mlp::with_zero_output(p, "anchors.coarse", d, d, 3)?),
                None => None,
            },
            wrench: match c.dynamics.contact_wrench {
                true => Some(ContactWrench::new(p, c, device)?),
                false => None,
            },
            device: device.clone(),
        })
    }

    /// `1 / sigma^2` of the AVP bandwidth (1/m^2) on the host: read once for a constant
    /// bandwidth, on every call for a training variable.
    fn inv_sigma2_host(&self) -> candle_core::Result<f32> {
        if let Some(&v) = self.inv_sigma2.get() {
            return Ok(v);
        }
        let v = (self.log_sigma.clone() * -2.0)?.exp()?.to_vec1::<f32>()?[0];
        if !self.log_sigma.is_variable() {
            let _ = self.inv_sigma2.set(v);
        }
        Ok(v)
    }

    /// Accelerations `[O, K, 3]` in metres per step^2 from the packed point features `[P, C1]`
    /// and the decoder's output.
    pub fn forward(
        &self,
        config: &ModelConfig,
        inp: &BatchInputs,
        point_features: &Tensor,
        dec: &Decoded,
        exec: Exec,
    ) -> Result<Tensor, ModelError> {
        let (o, k) = (inp.o, config.anchors);
        let own_tok = self.own_tokens(config, inp, dec, exec)?; // [O, D]
        let query = self.queries(config, inp, point_features, &own_tok, exec)?; // [O, K, D]
        let kv = self.keys_values(dec, exec)?; // [B, nT*T, 2D]
        // With graph poses the rotary codes are tensors, which only the composition reads.
        let y = if exec.fused && inp.pose_inputs.is_none() {
            self.cross_fused(config, inp, dec, &query, &kv, exec)?
        } else {
            self.cross_composed(config, inp, dec, &query, &kv, exec)?
        };
        // The acceleration MLP (D -> D -> 3, SiLU), plus the coarse one in its own unit.
        let x = self.head_norm.forward_exec(&y, exec)?;
        let mut acc = self.head.forward(&x, exec.fused)?; // [O * K, 3]
        if let (Some(coarse), Some(unit)) = (&self.coarse, config.accel_coarse_scale) {
            let ratio = (unit / config.accel_scale) as f64;
            acc = (acc + (coarse.forward(&x, exec.fused)? * ratio)?)?;
        }
        let mut acc = acc.reshape((o, k, 3))?;
        if let Some(wrench) = &self.wrench {
            acc = (acc + wrench.forward(inp, k, point_features, &own_tok)?)?;
        }
        // Head units (accel_scale per frame^2 or per step^2) to metres per step^2.
        let factor: Vec<f32> = inp
            .object_dt
            .iter()
            .map(|&dt| config.accel_scale * config.dynamics.output_factor(dt))
            .collect();
        Ok(acc.broadcast_mul(&host_tensor(&self.device, &factor, &[o, 1, 1])?)?)
    }

    /// Anchor queries `[O, K, D]`: own point feature, offset, AVP pooling and rotary features
    /// through `query_in`, plus the object's projected final token `own_tok` (`[O, D]`,
    /// [`AnchorHead::own_tokens`]).
    fn queries(
        &self,
        c: &ModelConfig,
        inp: &BatchInputs,
        point_features: &Tensor,
        own_tok: &Tensor,
        exec: Exec,
    ) -> Result<Tensor, ModelError> {
        let device = &self.device;
        let (o, k) = (inp.o, c.anchors);
        let (c1, p) = (c.point_dim, c.rope_dim / 2);
        // Anchor-vertex pooling with a learned bandwidth: w = exp(-d^2 / sigma^2), normalised.
        let avp = if exec.fused_inference() && device.is_cpu() {
            let inv_sigma2 = self.inv_sigma2_host()?;
            let op = AnchorPooling {
                anchors: k,
                objects: &inp.object_points,
                d2: &inp.anchor_d2,
                inv_sigma2,
            };
            anchor_pooling(point_features, &op)?
        } else {
            self.avp_composed(c, inp, point_features, exec)?
        };
        let own = point_features
            .index_select(&host_index(device, &inp.anchor_idx)?, 0)?
            .reshape((o, k, c1))?;
        let (rel, rope_feat) = match &inp.pose_inputs {
            Some(g) => (g.anchor_rel.clone(), g.anchor_rope.clone()),
            None => (
                host_tensor(device, &inp.anchor_rel, &[o, k, 3])?,
                host_tensor(device, &inp.anchor_rope, &[o, k, 2 * p])?,
            ),
        };
        // The order of `query_segments`.
        let q_in = Tensor::cat(&[own, rel, avp, rope_feat], 2)?;
        let query = self.query_in.forward(&q_in)?; // [O, K, D]
        Ok(query.broadcast_add(&own_tok.unsqueeze(1)?)?)
    }

    /// Every object's final decoder token through `own_norm` and `own_token`, `[O, D]`: the
    /// anchor queries' equivariant direct path (and the contact wrench's object input).
    fn own_tokens(
        &self,
        c: &ModelConfig,
        inp: &BatchInputs,
        dec: &Decoded,
        exec: Exec,
    ) -> Result<Tensor, ModelError> {
        let (b, d) = (inp.b, c.width);
        let t = inp.mmax + c.registers;
        let mut rows = Vec::with_capacity(inp.o);
        for s in 0..b {
            for (j, _) in (inp.scene_offsets[s]..inp.scene_offsets[s + 1]).enumerate() {
                rows.push((s * t + j) as u32);
            }
        }
        let own_tok = dec
            .last
            .reshape((b * t, d))?
            .index_select(&host_index(&self.device, &rows)?, 0)?;
        Ok(self
            .own_token
            .forward(&self.own_norm.forward_exec(&own_tok, exec)?)?)
    }

    /// Anchor-vertex pooling `[O, K, C1]` as a composition of candle ops (every device, and
    /// training, where the gradient reaches the bandwidth).
    fn avp_composed(
        &self,
        c: &ModelConfig,
        inp: &BatchInputs,
        point_features: &Tensor,
        exec: Exec,
    ) -> Result<Tensor, ModelError> {
        let device = &self.device;
        let (o, n, k) = (inp.o, inp.nmax, c.anchors);
        Ok(anchor_pooling_composed(
            point_features,
            &host_tensor(device, &inp.avp_d2_padded(k), &[o, k, n])?,
            &host_tensor(device, &inp.point_mask, &[o, 1, n])?,
            &host_index(device, &inp.pad_idx)?,
            &(self.log_sigma.clone() * -2.0)?.exp()?,
            exec.fused_inference(),
        )?)
    }

    /// Keys and values `[B, nT*T, 2D]`: the tapped depths, each normalised, plus a depth
    /// embedding, through `cross.kv`.
    fn keys_values(&self, dec: &Decoded, exec: Exec) -> Result<Tensor, ModelError> {
        let mut kv_in = Vec::with_capacity(dec.taps.len());
        for (i, x) in dec.taps.iter().enumerate() {
            let e = self.depth_embedding.narrow(0, i, 1)?.unsqueeze(0)?;
            kv_in.push(self.tap_norms[i].forward_exec(x, exec)?.broadcast_add(&e)?);
        }
        Ok(self.kv.forward(&Tensor::cat(&kv_in, 1)?)?)
    }

    /// Cross-attention with the fused kernel (with its gradient in training): queries stay
    /// packed `[O * K, D]`, each attending to its own scene's keys. Returns the updated queries
    /// `[O * K, D]` (the acceleration MLP's input before its norm).
    fn cross_fused(
        &self,
        c: &ModelConfig,
        inp: &BatchInputs,
        dec: &Decoded,
        query: &Tensor,
        kv: &Tensor,
        exec: Exec,
    ) -> Result<Tensor, ModelError> {
        let (b, o, k, d) = (inp.b, inp.o, c.anchors, c.width);
        let p = c.rope_dim / 2;
        let nt = dec.taps.len();
        let t = dec.key_bias.len() / b.max(1);
        let mut query_scene = Vec::with_capacity(o * k);
        for s in 0..b {
            let objects = inp.scene_offsets[s + 1] - inp.scene_offsets[s];
            query_scene.extend(std::iter::repeat_n(s as u32, objects * k));
        }
        // The same key mask and rotary code for every tapped depth.
        let mut key_bias = Vec::with_capacity(b * nt * t);
        let mut k_rope = RotaryRows {
            cos: Vec::with_capacity(b * nt * t * p),
            sin: Vec::with_capacity(b * nt * t * p),
            pairs: p,
        };
        for s in 0..b {
            for _ in 0..nt {
                key_bias.extend_from_slice(&dec.key_bias[s * t..(s + 1) * t]);
                let rows = s * t * p..(s + 1) * t * p;
                k_rope
                    .cos
                    .extend_from_slice(&dec.rope_rows.cos[rows.clone()]);
                k_rope.sin.extend_from_slice(&dec.rope_rows.sin[rows]);
            }
        }
        let op = CrossAttention {
            heads: c.heads,
            query_scene: Arc::new(query_scene),
            key_bias: Arc::new(key_bias),
            q_rope: Arc::new(RotaryRows {
                cos: inp.anchor_cos.clone(),
                sin: inp.anchor_sin.clone(),
                pairs: p,
            }),
            k_rope: Arc::new(k_rope),
        };
        let query = query.reshape((o * k, d))?;
        let qx = self.q.forward(&self.q_norm.forward_exec(&query, exec)?)?;
        let att = match exec.mode {
            Mode::Inference => cross_attention(op, &qx, kv)?,
            Mode::Training => cross_attention_train(op, &qx, kv)?,
        };
        Ok((query + self.out.forward(&att)?)?)
    }

    /// Cross-attention as a composition of candle ops: queries laid out per scene
    /// `[B, M*K, D]` (zero rows for padding) and gathered back. Returns the updated queries
    /// `[O * K, D]`, as [`AnchorHead::cross_fused`].
    fn cross_composed(
        &self,
        c: &ModelConfig,
        inp: &BatchInputs,
        dec: &Decoded,
        query: &Tensor,
        kv: &Tensor,
        exec: Exec,
    ) -> Result<Tensor, ModelError> {
        let device = &self.device;
        let mode = exec.mode;
        let (b, m, o, k, d) = (inp.b, inp.mmax, inp.o, c.anchors, c.width);
        let p = c.rope_dim / 2;
        let mut gather = vec![(o * k) as u32; b * m * k];
        let mut qcos = vec![1f32; b * m * k * p];
        let mut qsin = vec![0f32; b * m * k * p];
        let mut back = Vec::with_capacity(o * k);
        for s in 0..b {
            for (j, obj) in (inp.scene_offsets[s]..inp.scene_offsets[s + 1]).enumerate() {
                for kk in 0..k {
                    let slot = (s * m + j) * k + kk;
                    gather[slot] = (obj * k + kk) as u32;
                    back.push(slot as u32);
                    let src = (obj * k + kk) * p;
                    qcos[slot * p..(slot + 1) * p].copy_from_slice(&inp.anchor_cos[src..src + p]);
                    qsin[slot * p..(slot + 1) * p].copy_from_slice(&inp.anchor_sin[src..src + p]);
                }
            }
        }
        let query = gather_padded(&query.reshape((o * k, d))?, &host_index(device, &gather)?)?
            .reshape((b, m * k, d))?;
        let (qcos, qsin) = match &inp.pose_inputs {
            // The same layout from the graph's rows (padding reads ones and zeros).
            Some(g) => {
                let slots = host_index(device, &gather)?;
                let ones = Tensor::ones((1, p), g.anchor_cos.dtype(), device)?;
                let cos = Tensor::cat(&[&g.anchor_cos, &ones], 0)?.index_select(&slots, 0)?;
                let sin = gather_padded(&g.anchor_sin, &slots)?;
                (
                    cos.reshape((b, 1, m * k, p))?,
                    sin.reshape((b, 1, m * k, p))?,
                )
            }
            None => (
                host_tensor(device, &qcos, &[b, 1, m * k, p])?,
                host_tensor(device, &qsin, &[b, 1, m * k, p])?,
            ),
        };
        let nt = dec.taps.len();
        let kmask = Tensor::cat(&vec![dec.mask.clone(); nt], 3)?;
        let kcos = Tensor::cat(&vec![dec.rope.0.clone(); nt], 2)?;
        let ksin = Tensor::cat(&vec![dec.rope.1.clone(); nt], 2)?;
        let kx = kv.narrow(2, 0, d)?;
        let vx = kv.narrow(2, d, d)?;
        let qx = self.q.forward(&self.q_norm.forward_exec(&query, exec)?)?;
        let att = multi_head(
            &qx,
            &kx,
            &vx,
            &kmask,
            Some((&qcos, &qsin)),
            Some((&kcos, &ksin)),
            c.heads,
            mode,
        )?;
        let att = att.transpose(1, 2)?.reshape((b, m * k, d))?;
        let y = (query + self.out.forward(&att)?)?; // [B, M*K, D]
        Ok(y.reshape((b * m * k, d))?
            .index_select(&host_index(device, &back)?, 0)?)
    }
}
