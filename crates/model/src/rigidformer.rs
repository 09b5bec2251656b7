//! RigidFormer: hierarchical point encoder -> object decoder with registers, gated attention,
//! FiLM on log2(dt_steps) and ARoPE -> anchor queries cross-attending to several decoder
//! depths -> per-anchor accelerations -> Verlet -> Kabsch -> rigid poses.
//!
//! Shapes below: `B` scenes, `O` objects in the batch, `M` the largest object count, `T = M + R`
//! decoder tokens, `N` the largest point count, `K` anchors, `S` set-abstraction centres, `G`
//! neighbours per centre, `C1 = point_dim`, `C2 = sa_dim`, `D = width`, `H` heads, `P =
//! rope_dim / 2` rotary pairs.

use std::time::{Duration, Instant};

use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;
use nalgebra::{Matrix3, Rotation3, UnitQuaternion};
use rayon::prelude::*;

use crate::api::{Pose, StepItem, WorldModel};
use crate::config::POINT_FEATURES;
use crate::inputs::{BatchInputs, SceneRequest, build_inputs};
use crate::kabsch_op::KabschOp;
use crate::layers::{
    Init, Linear, Mlp, Mode, ParamStore, RmsNorm, SwiGlu, rotate_pairs, smooth_l1_mean,
    softmax_last,
};
use crate::prepare::{PreparedScene, normalise_pose, prepare_scene, validate_state};
use crate::{ModelConfig, ModelError, ObjectInput, SceneState};

/// Default object budget of one forward pass inside [`WorldModel::step`]: larger batches are
/// split into consecutive passes of whole scenes (measured: per-scene time grows again past
/// about 32 MOVi-like scenes per pass as intermediate tensors outgrow the caches).
pub const DEFAULT_MAX_PASS_OBJECTS: usize = 320;

/// Additive attention bias of a padded key.
const MASKED: f32 = -1.0e9;

/// Wall-clock time of each phase of one batched step (CPU; on an accelerator the phases are
/// not synchronised, so only the total is meaningful there).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepProfile {
    /// Validation, world points, contact features, feature and geometry assembly.
    pub features: Duration,
    /// Point MLP and both set-abstraction levels (one token per object).
    pub encoder: Duration,
    /// Object decoder blocks.
    pub decoder: Duration,
    /// AVP, anchor queries, multi-scale cross-attention, acceleration head.
    pub anchors: Duration,
    /// Verlet, Kabsch and pose assembly.
    pub projection: Duration,
}

impl StepProfile {
    /// Sum of all phases.
    pub fn total(&self) -> Duration {
        self.features + self.encoder + self.decoder + self.anchors + self.projection
    }
}

/// Decoder outputs: final tokens `[B, T, D]`, tapped depths, key mask `[B, 1, 1, T]` and
/// token rotary `(cos, sin)` `[B, 1, T, P]`.
type Decoded = (Tensor, Vec<Tensor>, Tensor, (Tensor, Tensor));

struct Block {
    norm1: RmsNorm,
    qkv: Linear,
    gate: Linear,
    out: Linear,
    film_a: Linear,
    film_b: Linear,
    norm2: RmsNorm,
    ffn: SwiGlu,
}

struct Encoder {
    point: Mlp,
    sa1: Mlp,
    sa2: Mlp,
    token: Linear,
}

struct AnchorHead {
    query_in: Linear,
    own_token: Linear,
    own_norm: RmsNorm,
    tap_norms: Vec<RmsNorm>,
    depth_embedding: Tensor,
    log_sigma: Tensor,
    q_norm: RmsNorm,
    q: Linear,
    kv: Linear,
    out: Linear,
    head_norm: RmsNorm,
    head: Mlp,
}

/// The RigidFormer world model (see the module docs). Thread-safe; implements [`WorldModel`].
pub struct RigidFormer {
    name: String,
    config: ModelConfig,
    device: Device,
    varmap: VarMap,
    encoder: Encoder,
    registers: Tensor,
    blocks: Vec<Block>,
    anchors: AnchorHead,
    max_pass_objects: usize,
}

/// One training sample: a scene at time t with its ground-truth pose `dt_steps` later.
#[derive(Clone, Copy, Debug)]
pub struct TrainItem<'a> {
    /// The prepared scene (reference clouds, parameters, anchors).
    pub scene: &'a PreparedScene,
    /// Ground-truth poses at t - dt_steps (`previous`) and t (`current`).
    pub state: &'a SceneState,
    /// Ground-truth poses at t + dt_steps, `[objects]`.
    pub target: &'a [Pose],
    /// Step size in frames, `>= 1`.
    pub dt_steps: u32,
}

/// Result of [`RigidFormer::train_forward`]. Every tensor is `[O, K, 3]` (objects of all
/// samples, scene-major, K anchors; metres or metres per step^2) unless noted; predictions carry
/// gradients.
pub struct TrainOutput {
    /// Scalar loss: weighted sum of the four Smooth L1 terms.
    pub loss: Tensor,
    /// The four terms `[pos_pre, acc_pre, pos_post, acc_post]`, each a scalar tensor.
    pub terms: [Tensor; 4],
    /// Predicted anchor accelerations `a` (m/step^2), before projection.
    pub accel_pre: Tensor,
    /// Anchor positions after Verlet, before projection: `2A_t - A_{t-1} + a`.
    pub positions_pre: Tensor,
    /// Anchor positions after Kabsch projection: `R A_ref + p`.
    pub positions_post: Tensor,
    /// Implied accelerations after projection: `positions_post - 2A_t + A_{t-1}`.
    pub accel_post: Tensor,
    /// Rigid transforms `[O, 12]`: row-major R then p (metres).
    pub transforms: Tensor,
    /// Ground-truth anchor positions at t + dt (no gradient).
    pub target_positions: Tensor,
    /// Ground-truth accelerations `A*_{t+1} - 2A*_t + A*_{t-1}` (no gradient).
    pub target_accel: Tensor,
}

impl RigidFormer {
    /// A randomly initialised model (deterministic for a given `seed`), trainable.
    pub fn new(config: ModelConfig, seed: u64, device: &Device) -> Result<RigidFormer, ModelError> {
        config.validate()?;
        let store = ParamStore::random(seed, device, true);
        Self::from_store("rigidformer".into(), config, store, device)
    }

    /// Builds the network from a parameter store (random or loaded).
    pub(crate) fn from_store(
        name: String,
        config: ModelConfig,
        mut p: ParamStore,
        device: &Device,
    ) -> Result<RigidFormer, ModelError> {
        config.validate()?;
        let mut m = Self::build(name, config, &mut p, device)?;
        m.varmap = p.finish()?;
        Ok(m)
    }

    fn build(
        name: String,
        config: ModelConfig,
        p: &mut ParamStore,
        device: &Device,
    ) -> Result<RigidFormer, ModelError> {
        let c = &config;
        let (c1, c2, d, eps) = (c.point_dim, c.sa_dim, c.width, c.norm_eps);
        let encoder = Encoder {
            point: Mlp::new(p, "encoder.point", POINT_FEATURES, c1, c1)?,
            sa1: Mlp::new(p, "encoder.sa1", c1 + 3, c2, c2)?,
            sa2: Mlp::new(p, "encoder.sa2", c2 + 3, d, d)?,
            token: p.linear("encoder.token", d, d, true)?,
        };
        let registers = p.get("decoder.registers", &[c.registers, d], Init::Uniform(0.5))?;
        let mut blocks = Vec::with_capacity(c.blocks);
        for l in 0..c.blocks {
            let n = format!("decoder.blocks.{l}");
            blocks.push(Block {
                norm1: p.rms_norm(&format!("{n}.norm1"), d, eps)?,
                qkv: p.linear(&format!("{n}.attn.qkv"), d, 3 * d, false)?,
                gate: p.linear(&format!("{n}.attn.gate"), d, c.heads, true)?,
                out: p.linear(&format!("{n}.attn.out"), d, d, false)?,
                film_a: p.linear(&format!("{n}.film.0"), 1, c.film_hidden, true)?,
                // Small final layer: gamma ~ 1, beta ~ 0 at initialisation.
                film_b: p.linear_init(&format!("{n}.film.1"), c.film_hidden, 2 * d, true, 1e-2)?,
                norm2: p.rms_norm(&format!("{n}.norm2"), d, eps)?,
                ffn: SwiGlu::new(p, &format!("{n}.ffn"), d, c.ffn_hidden)?,
            });
        }
        let taps = c.anchor_taps.len();
        let q_in = c1 + 3 + c1 + c.rope_dim;
        let anchors = AnchorHead {
            query_in: p.linear("anchors.query_in", q_in, d, true)?,
            own_token: p.linear("anchors.own_token", d, d, false)?,
            own_norm: p.rms_norm("anchors.own_norm", d, eps)?,
            tap_norms: (0..taps)
                .map(|t| p.rms_norm(&format!("anchors.tap_norm.{t}"), d, eps))
                .collect::<Result<_, _>>()?,
            depth_embedding: p.get("anchors.depth_embedding", &[taps, d], Init::Uniform(0.1))?,
            log_sigma: p.get("anchors.avp.log_sigma", &[1], Init::Const(c.avp_sigma.ln()))?,
            q_norm: p.rms_norm("anchors.q_norm", d, eps)?,
            q: p.linear("anchors.cross.q", d, d, false)?,
            kv: p.linear("anchors.cross.kv", d, 2 * d, false)?,
            out: p.linear("anchors.cross.out", d, d, false)?,
            head_norm: p.rms_norm("anchors.head_norm", d, eps)?,
            head: Mlp::new(p, "anchors.head", d, d, 3)?,
        };
        Ok(RigidFormer {
            name,
            config,
            device: device.clone(),
            varmap: VarMap::new(),
            encoder,
            registers,
            blocks,
            anchors,
            max_pass_objects: DEFAULT_MAX_PASS_OBJECTS,
        })
    }

    /// Sets the object budget of one forward pass (at least one scene always runs per pass).
    /// Results do not depend on it.
    pub fn with_max_pass_objects(mut self, objects: usize) -> RigidFormer {
        self.max_pass_objects = objects.max(1);
        self
    }

    /// Sets the model's name (normally its checkpoint directory name).
    pub fn with_name(mut self, name: impl Into<String>) -> RigidFormer {
        self.name = name.into();
        self
    }

    /// The trainable parameters, by name (for AdamW and for saving).
    pub fn varmap(&self) -> &VarMap {
        &self.varmap
    }

    /// The device the weights live on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Number of scalar parameters.
    pub fn parameter_count(&self) -> usize {
        self.varmap.all_vars().iter().map(|v| v.elem_count()).sum()
    }

    /// True for parameters that conventionally get no weight decay (norm scales, biases,
    /// registers, embeddings, the AVP bandwidth).
    pub fn is_no_decay(name: &str) -> bool {
        name.ends_with(".bias")
            || name.contains("norm")
            || name.contains("registers")
            || name.contains("embedding")
            || name.contains("log_sigma")
    }

    fn t(&self, data: &[f32], shape: &[usize]) -> Result<Tensor, ModelError> {
        Ok(Tensor::from_slice(data, shape, &Device::Cpu)?.to_device(&self.device)?)
    }

    fn idx(&self, data: &[u32]) -> Result<Tensor, ModelError> {
        Ok(Tensor::from_slice(data, data.len(), &Device::Cpu)?.to_device(&self.device)?)
    }

    /// Encoder: per-point features `[O * N, C1]` and object tokens `[O, D]`.
    fn encode(&self, inp: &BatchInputs, _mode: Mode) -> Result<(Tensor, Tensor), ModelError> {
        let c = &self.config;
        let (o, n, s, g) = (inp.o, inp.nmax, c.sa_centres, c.sa_neighbours);
        let feats = self.t(&inp.feats, &[o * n, POINT_FEATURES])?;
        let h = self.encoder.point.forward(&feats)?; // [O*N, C1]
        let grouped = h.index_select(&self.idx(&inp.group_idx)?, 0)?; // [O*S*G, C1]
        let rel = self.t(&inp.group_rel, &[o * s * g, 3])?;
        let x = Tensor::cat(&[rel, grouped], 1)?;
        let x = self
            .encoder
            .sa1
            .forward(&x)?
            .reshape((o * s, g, c.sa_dim))?
            .max(1)?; // [O*S, C2]
        let crel = self.t(&inp.centre_rel, &[o * s, 3])?;
        let x = Tensor::cat(&[crel, x], 1)?;
        let x = self
            .encoder
            .sa2
            .forward(&x)?
            .reshape((o, s, c.width))?
            .max(1)?; // [O, D]
        let tokens = self.encoder.token.forward(&x.silu()?)?;
        Ok((h, tokens))
    }

    /// Multi-head attention `q [B, Tq, D]` over `k, v [B, Tk, D]`, additive key mask
    /// `[B, 1, 1, Tk]`, optional rotary `(cos, sin)` for q `[B, 1, Tq, P]` and k `[B, 1, Tk, P]`.
    #[allow(clippy::too_many_arguments)]
    fn attention(
        &self,
        q: &Tensor,
        k: &Tensor,
        v: &Tensor,
        mask: &Tensor,
        rope_q: Option<(&Tensor, &Tensor)>,
        rope_k: Option<(&Tensor, &Tensor)>,
        mode: Mode,
    ) -> Result<Tensor, ModelError> {
        let (b, tq, d) = q.dims3()?;
        let tk = k.dim(1)?;
        let h = self.config.heads;
        let dh = d / h;
        let split = |x: &Tensor, t: usize| -> candle_core::Result<Tensor> {
            x.reshape((b, t, h, dh))?.transpose(1, 2)?.contiguous()
        };
        let mut q = split(q, tq)?;
        let mut k = split(k, tk)?;
        let v = split(v, tk)?;
        if let Some((cos, sin)) = rope_q {
            q = rotate_pairs(&q, cos, sin)?;
        }
        if let Some((cos, sin)) = rope_k {
            k = rotate_pairs(&k, cos, sin)?;
        }
        let scores = (q.matmul(&k.t()?.contiguous()?)? * (1.0 / (dh as f64).sqrt()))?;
        let scores = scores.broadcast_add(mask)?;
        let att = softmax_last(&scores, mode)?;
        Ok(att.matmul(&v)?) // [B, H, Tq, dh]
    }

    /// Decoder over `[B, T, D]`; returns the final tokens and the tapped depths.
    fn decode(
        &self,
        inp: &BatchInputs,
        tokens: &Tensor,
        mode: Mode,
    ) -> Result<Decoded, ModelError> {
        let c = &self.config;
        let (b, m, r, d) = (inp.b, inp.mmax, c.registers, c.width);
        let t = m + r;
        let p = c.rope_dim / 2;
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
        let padded = Tensor::cat(
            &[
                tokens.clone(),
                Tensor::zeros((1, d), DType::F32, &self.device)?,
            ],
            0,
        )?
        .index_select(&self.idx(&gather)?, 0)?
        .reshape((b, m, d))?;
        let regs = self.registers.unsqueeze(0)?.broadcast_as((b, r, d))?;
        let mut x = if r > 0 {
            Tensor::cat(&[padded, regs.contiguous()?], 1)?
        } else {
            padded
        };
        let mask = self.t(&mask, &[b, 1, 1, t])?;
        let cos = self.t(&cos, &[b, 1, t, p])?;
        let sin = self.t(&sin, &[b, 1, t, p])?;
        let tau = self.t(&inp.tau, &[b, 1])?;
        let mut taps = Vec::with_capacity(c.anchor_taps.len());
        for (l, blk) in self.blocks.iter().enumerate() {
            let xn = blk.norm1.forward(&x, mode)?;
            let qkv = blk.qkv.forward(&xn)?;
            let q = qkv.narrow(2, 0, d)?;
            let k = qkv.narrow(2, d, d)?;
            let v = qkv.narrow(2, 2 * d, d)?;
            let o = self.attention(
                &q,
                &k,
                &v,
                &mask,
                Some((&cos, &sin)),
                Some((&cos, &sin)),
                mode,
            )?;
            // Per-head sigmoid gate from the block input.
            let gate = candle_nn::ops::sigmoid(&blk.gate.forward(&xn)?)?; // [B, T, H]
            let gate = gate.transpose(1, 2)?.unsqueeze(3)?; // [B, H, T, 1]
            let o = o
                .broadcast_mul(&gate)?
                .transpose(1, 2)?
                .reshape((b, t, d))?;
            x = (x + blk.out.forward(&o)?)?;
            // FiLM on tau = log2(dt_steps): gamma = 1 + .., beta.
            let fb = blk.film_b.forward(&blk.film_a.forward(&tau)?.silu()?)?; // [B, 2D]
            let gamma = (fb.narrow(1, 0, d)? + 1.0)?.unsqueeze(1)?;
            let beta = fb.narrow(1, d, d)?.unsqueeze(1)?;
            x = x.broadcast_mul(&gamma)?.broadcast_add(&beta)?;
            x = (&x + blk.ffn.forward(&blk.norm2.forward(&x, mode)?)?)?;
            for _ in c.anchor_taps.iter().filter(|&&tap| tap == l) {
                taps.push(x.clone());
            }
        }
        Ok((x, taps, mask, (cos, sin)))
    }

    /// Anchor head: accelerations `[O, K, 3]` in metres per step^2.
    #[allow(clippy::too_many_arguments)]
    fn anchor_accelerations(
        &self,
        inp: &BatchInputs,
        point_features: &Tensor,
        last: &Tensor,
        taps: &[Tensor],
        mask: &Tensor,
        rope: &(Tensor, Tensor),
        mode: Mode,
    ) -> Result<Tensor, ModelError> {
        let c = &self.config;
        let a = &self.anchors;
        let (b, m, o, n, k, d) = (inp.b, inp.mmax, inp.o, inp.nmax, c.anchors, c.width);
        let (c1, p) = (c.point_dim, c.rope_dim / 2);
        let t = m + c.registers;
        // Anchor-vertex pooling with a learned bandwidth: w = exp(-d^2 / sigma^2), normalised.
        let d2 = self.t(&inp.avp_d2, &[o, k, n])?;
        let pmask = self.t(&inp.point_mask, &[o, 1, n])?;
        let inv_s2 = (a.log_sigma.clone() * -2.0)?.exp()?; // [1]
        let w = d2
            .broadcast_mul(&inv_s2)?
            .neg()?
            .exp()?
            .broadcast_mul(&pmask)?; // [O, K, N]
        let hp = point_features.reshape((o, n, c1))?;
        let num = w.matmul(&hp)?; // [O, K, C1]
        let den = w.sum_keepdim(2)?; // >= 1: the anchor itself has weight 1
        let avp = num.broadcast_div(&den)?;
        let own = point_features
            .index_select(&self.idx(&inp.anchor_idx)?, 0)?
            .reshape((o, k, c1))?;
        let rel = self.t(&inp.anchor_rel, &[o, k, 3])?;
        let rope_feat = self.t(&inp.anchor_rope, &[o, k, 2 * p])?;
        let q_in = Tensor::cat(&[own, rel, avp, rope_feat], 2)?;
        let mut query = a.query_in.forward(&q_in)?; // [O, K, D]
        // The anchor's own object token (final depth), an equivariant direct path.
        let mut rows = Vec::with_capacity(o);
        for s in 0..b {
            for (j, _) in (inp.scene_offsets[s]..inp.scene_offsets[s + 1]).enumerate() {
                rows.push((s * t + j) as u32);
            }
        }
        let own_tok = last
            .reshape((b * t, d))?
            .index_select(&self.idx(&rows)?, 0)?;
        let own_tok = a.own_token.forward(&a.own_norm.forward(&own_tok, mode)?)?;
        query = query.broadcast_add(&own_tok.unsqueeze(1)?)?;
        // Lay the anchor queries out per scene: [B, M*K, D] (zero rows for padding).
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
        let query = Tensor::cat(
            &[
                query.reshape((o * k, d))?,
                Tensor::zeros((1, d), DType::F32, &self.device)?,
            ],
            0,
        )?
        .index_select(&self.idx(&gather)?, 0)?
        .reshape((b, m * k, d))?;
        let qcos = self.t(&qcos, &[b, 1, m * k, p])?;
        let qsin = self.t(&qsin, &[b, 1, m * k, p])?;
        // Keys/values: tokens from several depths, each normalised, plus a depth embedding.
        let mut kv_in = Vec::with_capacity(taps.len());
        for (i, x) in taps.iter().enumerate() {
            let e = a.depth_embedding.narrow(0, i, 1)?.unsqueeze(0)?;
            kv_in.push(a.tap_norms[i].forward(x, mode)?.broadcast_add(&e)?);
        }
        let kv_in = Tensor::cat(&kv_in, 1)?; // [B, nT*T, D]
        let nt = taps.len();
        let kmask = Tensor::cat(&vec![mask.clone(); nt], 3)?;
        let kcos = Tensor::cat(&vec![rope.0.clone(); nt], 2)?;
        let ksin = Tensor::cat(&vec![rope.1.clone(); nt], 2)?;
        let kv = a.kv.forward(&kv_in)?;
        let kx = kv.narrow(2, 0, d)?;
        let vx = kv.narrow(2, d, d)?;
        let qx = a.q.forward(&a.q_norm.forward(&query, mode)?)?;
        let att = self.attention(
            &qx,
            &kx,
            &vx,
            &kmask,
            Some((&qcos, &qsin)),
            Some((&kcos, &ksin)),
            mode,
        )?;
        let att = att.transpose(1, 2)?.reshape((b, m * k, d))?;
        let y = (query + a.out.forward(&att)?)?;
        // The acceleration MLP (D -> D -> 3, SiLU).
        let acc = a.head.forward(&a.head_norm.forward(&y, mode)?)?; // [B, M*K, 3]
        let acc = acc
            .reshape((b * m * k, 3))?
            .index_select(&self.idx(&back)?, 0)?
            .reshape((o, k, 3))?;
        // Head units (accel_scale per frame^2 or per step^2) to metres per step^2.
        let factor: Vec<f32> = inp
            .object_dt
            .iter()
            .map(|&dt| c.accel_scale * c.dynamics.output_factor(dt))
            .collect();
        Ok(acc.broadcast_mul(&self.t(&factor, &[o, 1, 1])?)?)
    }

    /// The network from assembled inputs to accelerations `[O, K, 3]` (m/step^2).
    fn network(
        &self,
        inp: &BatchInputs,
        mode: Mode,
        profile: Option<&mut StepProfile>,
    ) -> Result<Tensor, ModelError> {
        let t0 = Instant::now();
        let (h, tokens) = self.encode(inp, mode)?;
        let t1 = Instant::now();
        let (last, taps, mask, rope) = self.decode(inp, &tokens, mode)?;
        let t2 = Instant::now();
        let acc = self.anchor_accelerations(inp, &h, &last, &taps, &mask, &rope, mode)?;
        if let Some(p) = profile {
            p.encoder += t1 - t0;
            p.decoder += t2 - t1;
            p.anchors += t2.elapsed();
        }
        Ok(acc)
    }

    fn requests<'a>(&self, batch: &[StepItem<'a>]) -> Result<Vec<SceneRequest<'a>>, ModelError> {
        batch
            .iter()
            .enumerate()
            .map(|(i, it)| {
                let what = format!("batch[{i}]");
                check_prepared_for(&self.config, it.scene, &what)?;
                let (previous, current) = validate_state(it.scene, it.state, it.dt_steps, &what)?;
                Ok(SceneRequest {
                    scene: it.scene,
                    previous,
                    current,
                    dt_steps: it.dt_steps,
                })
            })
            .collect()
    }

    /// [`WorldModel::step`] with per-phase wall-clock times added to `profile`.
    pub fn step_profiled(
        &self,
        batch: &[StepItem<'_>],
        profile: &mut StepProfile,
    ) -> Result<Vec<Vec<Pose>>, ModelError> {
        self.step_mode(batch, Mode::Inference, Some(profile))
    }

    /// One batched step with an explicit kernel [`Mode`] (the training kernels give the same
    /// result up to rounding; used to test that).
    pub fn step_mode(
        &self,
        batch: &[StepItem<'_>],
        mode: Mode,
        mut profile: Option<&mut StepProfile>,
    ) -> Result<Vec<Vec<Pose>>, ModelError> {
        if batch.is_empty() {
            return Ok(Vec::new());
        }
        let t0 = Instant::now();
        let requests = self.requests(batch)?;
        if let Some(p) = profile.as_deref_mut() {
            p.features += t0.elapsed();
        }
        // Split into passes of whole scenes under the object budget.
        let mut out = Vec::with_capacity(batch.len());
        let mut start = 0;
        while start < batch.len() {
            let mut end = start + 1;
            let mut objects = batch[start].scene.len();
            while end < batch.len() && objects + batch[end].scene.len() <= self.max_pass_objects {
                objects += batch[end].scene.len();
                end += 1;
            }
            out.extend(self.step_pass(&requests[start..end], mode, profile.as_deref_mut())?);
            start = end;
        }
        Ok(out)
    }

    fn step_pass(
        &self,
        requests: &[SceneRequest<'_>],
        mode: Mode,
        mut profile: Option<&mut StepProfile>,
    ) -> Result<Vec<Vec<Pose>>, ModelError> {
        let t0 = Instant::now();
        let inp = build_inputs(&self.config, requests)?;
        let t1 = Instant::now();
        let acc = self.network(&inp, mode, profile.as_deref_mut())?;
        let acc: Vec<f32> = acc.flatten_all()?.to_device(&Device::Cpu)?.to_vec1()?;
        let t2 = Instant::now();
        let k = self.config.anchors;
        let poses: Result<Vec<Pose>, ModelError> = (0..inp.o)
            .into_par_iter()
            .map(|obj| {
                let fall = self.free_fall(inp.object_dt[obj]);
                let target: Vec<[f64; 3]> = (0..k)
                    .map(|i| {
                        let (at, ap) = (inp.anchors_t[obj][i], inp.anchors_prev[obj][i]);
                        let a = &acc[(obj * k + i) * 3..(obj * k + i + 1) * 3];
                        [0, 1, 2].map(|d| 2.0 * at[d] - ap[d] + fall[d] + a[d] as f64)
                    })
                    .collect();
                let sol = dynaserve_geometry::kabsch(&inp.anchors_ref[obj], &target, None)
                    .map_err(|e| ModelError::Internal(format!("kabsch failed: {e}")))?;
                Ok(pose_from(
                    &sol.rotation,
                    &sol.translation,
                    inp.current_rot[obj],
                ))
            })
            .collect();
        let poses = poses?;
        let mut out = Vec::with_capacity(inp.b);
        for s in 0..inp.b {
            out.push(poses[inp.scene_offsets[s]..inp.scene_offsets[s + 1]].to_vec());
        }
        if let Some(p) = profile {
            let t3 = Instant::now();
            p.features += t1 - t0;
            p.projection += t3 - t2;
        }
        Ok(out)
    }

    /// Displacement of free fall over one step of `dt_steps` frames that the Verlet base adds
    /// (`g (k dt_frame)^2`, metres), zero unless `dynamics.gravity_residual`.
    fn free_fall(&self, dt_steps: u32) -> [f64; 3] {
        let c = &self.config;
        if !c.dynamics.gravity_residual {
            return [0.0; 3];
        }
        let h = dt_steps as f64 * c.dt_frame as f64;
        c.gravity.map(|g| g as f64 * h * h)
    }

    /// Batched training forward on ground-truth inputs (training kernels): predictions before
    /// and after projection at the anchors, their targets and the loss of `docs/rigidformer.md`
    /// (Smooth L1 on position and acceleration, before and after projection, weights from
    /// `config.loss`, step-size balanced with per-frame units).
    pub fn train_forward(&self, items: &[TrainItem<'_>]) -> Result<TrainOutput, ModelError> {
        if items.is_empty() {
            return Err(ModelError::InvalidInput("empty training batch".into()));
        }
        let mut requests = Vec::with_capacity(items.len());
        let mut targets = Vec::new();
        for (i, it) in items.iter().enumerate() {
            let what = format!("train[{i}]");
            check_prepared_for(&self.config, it.scene, &what)?;
            let (previous, current) = validate_state(it.scene, it.state, it.dt_steps, &what)?;
            if it.target.len() != it.scene.len() {
                return Err(ModelError::InvalidInput(format!(
                    "{what}: {} target poses for {} objects",
                    it.target.len(),
                    it.scene.len()
                )));
            }
            for (j, p) in it.target.iter().enumerate() {
                targets.push(
                    normalise_pose(p).map_err(|e| {
                        ModelError::InvalidInput(format!("{what}: target[{j}]: {e}"))
                    })?,
                );
            }
            requests.push(SceneRequest {
                scene: it.scene,
                previous,
                current,
                dt_steps: it.dt_steps,
            });
        }
        let inp = build_inputs(&self.config, &requests)?;
        let accel_pre = self.network(&inp, Mode::Training, None)?; // [O, K, 3]
        let (o, k) = (inp.o, self.config.anchors);
        let flat = |v: &Vec<Vec<[f64; 3]>>| -> Vec<f32> {
            v.iter().flatten().flatten().map(|x| *x as f32).collect()
        };
        let a_t = self.t(&flat(&inp.anchors_t), &[o, k, 3])?;
        let a_prev = self.t(&flat(&inp.anchors_prev), &[o, k, 3])?;
        let a_ref = self.t(&flat(&inp.anchors_ref), &[o, k, 3])?;
        let mut tgt = Vec::with_capacity(o * k * 3);
        for (obj, pose) in targets.iter().enumerate() {
            let (rm, tv) = pose_f64(pose);
            for a in &inp.anchors_ref[obj] {
                let y = rm * nalgebra::Vector3::new(a[0], a[1], a[2]) + tv;
                tgt.extend([y.x as f32, y.y as f32, y.z as f32]);
            }
        }
        let target_positions = self.t(&tgt, &[o, k, 3])?;
        // 2 A_t - A_{t-1} (+ free fall with a gravity residual), per object.
        let fall: Vec<f32> = inp
            .object_dt
            .iter()
            .flat_map(|&dt| self.free_fall(dt).map(|v| v as f32))
            .collect();
        let base = ((&a_t * 2.0)? - &a_prev)?.broadcast_add(&self.t(&fall, &[o, 1, 3])?)?;
        let target_accel = (&target_positions - &base)?;
        let positions_pre = (&base + &accel_pre)?;
        let op = KabschOp::new(inp.anchors_ref.clone());
        let transforms = op.apply(&positions_pre.contiguous()?)?; // [O, 12]
        let rmat = transforms.narrow(1, 0, 9)?.reshape((o, 3, 3))?;
        let trans = transforms.narrow(1, 9, 3)?.reshape((o, 1, 3))?;
        let positions_post = a_ref
            .matmul(&rmat.transpose(1, 2)?)?
            .broadcast_add(&trans)?;
        let accel_post = (&positions_post - &base)?;
        let lc = &self.config.loss;
        // Errors in loss units: divided by `scale`, and by k^2 with per-frame units so that
        // every step size weighs the same.
        let inv: Vec<f32> = inp
            .object_dt
            .iter()
            .map(|&dt| 1.0 / (lc.scale * self.config.dynamics.output_factor(dt)))
            .collect();
        let inv = self.t(&inv, &[o, 1, 1])?;
        let scaled = |a: &Tensor, b: &Tensor| -> candle_core::Result<Tensor> {
            (a - b)?.broadcast_mul(&inv)
        };
        let terms = [
            smooth_l1_mean(&scaled(&positions_pre, &target_positions)?, lc.beta)?,
            smooth_l1_mean(&scaled(&accel_pre, &target_accel)?, lc.beta)?,
            smooth_l1_mean(&scaled(&positions_post, &target_positions)?, lc.beta)?,
            smooth_l1_mean(&scaled(&accel_post, &target_accel)?, lc.beta)?,
        ];
        let mut loss = (&terms[0] * lc.weights[0] as f64)?;
        for (term, w) in terms.iter().zip(lc.weights).skip(1) {
            loss = (loss + (term * w as f64)?)?;
        }
        Ok(TrainOutput {
            loss,
            terms,
            accel_pre,
            positions_pre,
            positions_post,
            accel_post,
            transforms,
            target_positions,
            target_accel,
        })
    }
}

/// Fails if `scene` was prepared by a model with other anchor or grouping sizes.
fn check_prepared_for(
    cfg: &ModelConfig,
    scene: &PreparedScene,
    what: &str,
) -> Result<(), ModelError> {
    let key = (cfg.anchors, cfg.sa_centres, cfg.sa_neighbours);
    if scene.key != key {
        return Err(ModelError::InvalidInput(format!(
            "{what}: the scene was prepared for a model with (anchors, centres, neighbours) = {:?}, this model uses {key:?}",
            scene.key
        )));
    }
    Ok(())
}

/// Rotation matrix and translation of a pose, in f64.
fn pose_f64(p: &Pose) -> (Matrix3<f64>, nalgebra::Vector3<f64>) {
    let [x, y, z, w] = p.rotation.map(|v| v as f64);
    let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
    let t = p.translation.map(|v| v as f64);
    (
        q.to_rotation_matrix().into_inner(),
        nalgebra::Vector3::new(t[0], t[1], t[2]),
    )
}

/// Pose from a rotation matrix and translation, with the quaternion sign nearest `near`.
fn pose_from(r: &Matrix3<f64>, p: &nalgebra::Vector3<f64>, near: [f32; 4]) -> Pose {
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*r));
    let c = q.coords;
    let mut rotation = [c.x as f32, c.y as f32, c.z as f32, c.w as f32];
    let dot: f32 = rotation.iter().zip(near).map(|(a, b)| a * b).sum();
    if dot < 0.0 {
        rotation = rotation.map(|v| -v);
    }
    Pose {
        translation: [p.x as f32, p.y as f32, p.z as f32],
        rotation,
    }
}

impl WorldModel for RigidFormer {
    fn name(&self) -> &str {
        &self.name
    }

    fn config(&self) -> &ModelConfig {
        &self.config
    }

    fn prepare(&self, objects: Vec<ObjectInput>) -> Result<PreparedScene, ModelError> {
        prepare_scene(&self.config, objects)
    }

    fn step(&self, batch: &[StepItem<'_>]) -> Result<Vec<Vec<Pose>>, ModelError> {
        self.step_mode(batch, Mode::Inference, None)
    }
}
