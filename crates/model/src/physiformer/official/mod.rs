//! The official PhysiFormer architecture (the authors' published code), so that their
//! checkpoints load and serve; `docs/physiformer.md` records where it differs from the paper.
//!
//! Tokens: one per vertex per frame, `x_embedder(z) + cond_x_embedder(X_0) + v_embedder(V_0) +
//! object_material_embed(material) + vert_token`, after a prefix of register tokens and scene
//! tokens (`scene_token_base + scene_cond_embed(scene condition)`). Conditioning
//! `c = t_embedder(t) + y_embedder(label)` modulates every block (adaLN). Blocks follow the
//! pattern (spatial, temporal, object, temporal by default); each factorised attention copies
//! the prefix into every group and averages it back over the groups afterwards. Spatial and
//! object attention rotate queries and keys by the vertex coordinate code of the noisy
//! positions (prefix tokens at the centre of all positions, or of the object in that frame),
//! temporal attention by the frame index. The final layer maps every token to 3 numbers: the
//! predicted clean trajectory in network coordinates ([`OfficialConfig`]), or, for a model
//! with a prior (this crate's options, off for published checkpoints), the prior plus that
//! output, ramped in over the first frames (`docs/physiformer.md`).
//!
//! Parameter names are the official state dict's without the denoiser's `net.` prefix
//! (`blocks.3.attn.qkv.weight`, ...), shapes as in PyTorch (`[out, in]`).
//!
//! Shapes: `F` frames, `V` vertices, `P` prefix tokens, `N = P + F V` tokens, `D` width, `H`
//! heads of `dh`, `O` objects of at most `n` vertices.

pub mod config;
pub mod import;
pub(crate) mod rope;

use candle_core::{D, DType, Device, IndexOp, Tensor};

use self::config::{Axis, NORM_EPS, OfficialConfig, TIME_FEATURES};
use super::config::PhysiConfig;
use super::prior::prior_trajectory;
use super::scene::{Material, MeshScene};
use crate::ModelError;
use crate::kernels::activation::swiglu_product;
use crate::layers::{Exec, Init, Linear, Mode, ParamStore, RmsNorm, softmax_last};

/// Largest attention score tensor of one chunk of groups, in elements (64 MiB of f32).
const SCORE_BUDGET: usize = 16 << 20;

/// One block's parameters.
struct Block {
    axis: Axis,
    norm1: RmsNorm,
    qkv: Linear,
    q_norm: RmsNorm,
    k_norm: RmsNorm,
    proj: Linear,
    norm2: RmsNorm,
    w12: Linear,
    w3: Linear,
    ada: Linear,
}

/// The official network's weights (see the module docs).
pub(crate) struct OfficialNet {
    cfg: OfficialConfig,
    x_embedder: Linear,
    cond_x_embedder: Linear,
    v_embedder: Linear,
    material: Option<(Linear, Linear)>,
    vert_token: Tensor,
    reg_tokens: Option<Tensor>,
    scene: Option<(Tensor, Linear, Linear)>,
    t_mlp: (Linear, Linear),
    label_row: Tensor,
    blocks: Vec<Block>,
    final_norm: RmsNorm,
    final_ada: Linear,
    final_linear: Linear,
    freqs: Vec<f32>,
}

/// A scene prepared for the official network: what every call on it shares.
#[derive(Clone, Debug)]
pub struct OfficialScene {
    pub(crate) frames: usize,
    pub(crate) vertices: usize,
    /// Object `o` owns vertices `offsets[o]..offsets[o + 1]`.
    offsets: Vec<usize>,
    /// Metres -> network coordinates: `(x - offset) / scale` per axis.
    pub(crate) scale: [f32; 3],
    pub(crate) offset: [f32; 3],
    /// The frame-0 condition plus the vertex token, `[V, D]`.
    cond: Tensor,
    /// Registers and scene tokens `[P, D]`.
    prefix: Tensor,
    /// Frame code `[1, 1, P + F, dh]`.
    time_rope: (Tensor, Tensor),
    /// Largest object's vertex count `n`.
    nmax: usize,
    /// Token of every object slot, `[F * O * n]` (frame-major, padding slots at token 0).
    gather: Tensor,
    /// Object slot of every token `[F * V]` in the `[F * O * n]` layout.
    scatter: Tensor,
    /// Key bias of the object groups `[F * O, 1, 1, P + n]` (0 or -1e9).
    object_bias: Tensor,
    /// The prior the output corrects, `[F V, 3]` network coordinates
    /// ([`super::config::TrajectoryPrior`]), and the correction's weight per token `[F V, 1]`
    /// (`correction_ramp_frames`).
    prior: Option<Tensor>,
    ramp: Option<Tensor>,
}

impl OfficialScene {
    /// Frames the scene was prepared for.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Number of vertices V.
    pub fn vertices(&self) -> usize {
        self.vertices
    }

    /// Positions `[.., 3]` flattened, metres -> network coordinates.
    pub(crate) fn to_network(&self, x: &[f32]) -> Vec<f32> {
        x.iter()
            .enumerate()
            .map(|(i, x)| (x - self.offset[i % 3]) / self.scale[i % 3])
            .collect()
    }
}

fn linear(
    p: &mut ParamStore,
    name: &str,
    input: usize,
    output: usize,
) -> Result<Linear, ModelError> {
    p.linear(name, input, output, true)
}

/// A layer that starts at zero (adaLN modulations and the final projection, as the official
/// initialisation: a fresh block is the identity and a fresh network outputs zeros).
fn zero_linear(
    p: &mut ParamStore,
    name: &str,
    input: usize,
    output: usize,
) -> Result<Linear, ModelError> {
    Ok(Linear::new(
        p.get(
            &format!("{name}.weight"),
            &[output, input],
            Init::Const(0.0),
        )?,
        Some(p.get(&format!("{name}.bias"), &[output], Init::Const(0.0))?),
    ))
}

/// `x * (1 + scale) + shift` with `[1, D]` modulation.
fn modulate(x: &Tensor, shift: &Tensor, scale: &Tensor) -> candle_core::Result<Tensor> {
    x.broadcast_mul(&(scale + 1.0)?)?.broadcast_add(shift)
}

/// The kernels of a pass in `mode` on `device`.
fn exec(mode: Mode, device: &Device) -> Exec {
    Exec {
        mode,
        fused: device.is_cpu(),
    }
}

/// Sinusoidal features `[1, 256]` of flow time `t`: `[cos(t w), sin(t w)]`,
/// `w_i = 10000^(-i / 128)`.
fn time_features(t: f32, device: &Device) -> candle_core::Result<Tensor> {
    let half = TIME_FEATURES / 2;
    let mut f = vec![0f32; TIME_FEATURES];
    for i in 0..half {
        let w = (-(10_000f32).ln() * i as f32 / half as f32).exp();
        let a = t * w;
        f[i] = a.cos();
        f[half + i] = a.sin();
    }
    Tensor::from_vec(f, (1, TIME_FEATURES), device)
}

impl Block {
    fn new(p: &mut ParamStore, i: usize, cfg: &OfficialConfig) -> Result<Block, ModelError> {
        let (d, dh) = (cfg.hidden, cfg.head_dim());
        let n = |s: &str| format!("blocks.{i}.{s}");
        Ok(Block {
            axis: cfg.axis(i),
            norm1: p.rms_norm(&n("norm1"), d, NORM_EPS)?,
            qkv: linear(p, &n("attn.qkv"), d, 3 * d)?,
            q_norm: p.rms_norm(&n("attn.q_norm"), dh, NORM_EPS)?,
            k_norm: p.rms_norm(&n("attn.k_norm"), dh, NORM_EPS)?,
            proj: linear(p, &n("attn.proj"), d, d)?,
            norm2: p.rms_norm(&n("norm2"), d, NORM_EPS)?,
            w12: linear(p, &n("mlp.w12"), d, 2 * cfg.ffn_hidden)?,
            w3: linear(p, &n("mlp.w3"), cfg.ffn_hidden, d)?,
            ada: zero_linear(p, &n("adaLN_modulation.1"), d, 6 * d)?,
        })
    }

    /// Multi-head attention over `seq [G, L, D]` with rotary code `rope` (`[G or 1, 1, L,
    /// dh]`) and key bias `bias` (`[G, 1, 1, L]`) -> `[G, L, D]`, in chunks of groups so that
    /// the score tensor stays within [`SCORE_BUDGET`].
    fn attend(
        &self,
        seq: &Tensor,
        heads: usize,
        rope: Option<&(Tensor, Tensor)>,
        bias: Option<&Tensor>,
        exec: Exec,
    ) -> candle_core::Result<Tensor> {
        let (g, l, d) = seq.dims3()?;
        let chunk = (SCORE_BUDGET / (heads * l * l).max(1)).clamp(1, g);
        let mut outs = Vec::with_capacity(g.div_ceil(chunk));
        let mut start = 0;
        while start < g {
            let n = chunk.min(g - start);
            let part = |t: &Tensor| -> candle_core::Result<Tensor> {
                if t.dim(0)? == 1 {
                    Ok(t.clone())
                } else {
                    t.narrow(0, start, n)
                }
            };
            let rope = match rope {
                Some((c, s)) => Some((part(c)?, part(s)?)),
                None => None,
            };
            let bias = bias.map(part).transpose()?;
            outs.push(self.attend_chunk(
                &seq.narrow(0, start, n)?,
                heads,
                rope.as_ref(),
                bias.as_ref(),
                exec,
            )?);
            start += n;
        }
        let o = if outs.len() == 1 {
            outs.pop().expect("one chunk")
        } else {
            Tensor::cat(&outs, 0)?
        };
        debug_assert_eq!(o.dims3()?, (g, l, d));
        self.proj.forward(&o)
    }

    /// Attention of one chunk of groups, before the output projection.
    fn attend_chunk(
        &self,
        seq: &Tensor,
        heads: usize,
        rope: Option<&(Tensor, Tensor)>,
        bias: Option<&Tensor>,
        exec: Exec,
    ) -> candle_core::Result<Tensor> {
        let (g, l, d) = seq.dims3()?;
        let dh = d / heads;
        let qkv = self.qkv.forward(seq)?.reshape((g, l, 3, heads, dh))?;
        let part = |i: usize| -> candle_core::Result<Tensor> {
            qkv.i((.., .., i))?.transpose(1, 2)?.contiguous()
        };
        let mut q = self.q_norm.forward_exec(&part(0)?, exec)?;
        let mut k = self.k_norm.forward_exec(&part(1)?, exec)?;
        let v = part(2)?;
        if let Some((c, s)) = rope {
            q = rope::apply(&q, c, s)?;
            k = rope::apply(&k, c, s)?;
        }
        let scale = 1.0 / (dh as f64).sqrt();
        let mut scores = (q.matmul(&k.t()?.contiguous()?)? * scale)?;
        if let Some(b) = bias {
            scores = scores.broadcast_add(b)?;
        }
        let w = softmax_last(&scores, exec.mode)?;
        w.matmul(&v)?.transpose(1, 2)?.reshape((g, l, d))
    }

    /// One block over all tokens `x [N, D]` (prefix first) with conditioning `c [1, D]`
    /// (after SiLU).
    fn forward(
        &self,
        x: &Tensor,
        c: &Tensor,
        ctx: &CallContext<'_>,
    ) -> candle_core::Result<Tensor> {
        let m = self.ada.forward(c)?.chunk(6, D::Minus1)?;
        let h = modulate(&self.norm1.forward_exec(x, ctx.exec)?, &m[0], &m[1])?;
        let a = self.mix(&h, ctx)?;
        let x = (x + a.broadcast_mul(&m[2])?)?;
        let h = modulate(&self.norm2.forward_exec(&x, ctx.exec)?, &m[3], &m[4])?;
        let f = self.w3.forward(&swiglu_product(&self.w12.forward(&h)?)?)?;
        x + f.broadcast_mul(&m[5])?
    }

    /// The block's attention over `h [N, D]` -> `[N, D]`: prefix rows averaged over the
    /// groups, token rows in place.
    fn mix(&self, h: &Tensor, ctx: &CallContext<'_>) -> candle_core::Result<Tensor> {
        let s = ctx.scene;
        let (p, f, v) = (ctx.prefix, s.frames, s.vertices);
        let d = h.dim(1)?;
        let pre = h.narrow(0, 0, p)?;
        let tok = h.narrow(0, p, f * v)?;
        let heads = ctx.heads;
        let with_prefix = |groups: usize, body: &Tensor| -> candle_core::Result<Tensor> {
            if p == 0 {
                return Ok(body.clone());
            }
            let pre = pre.unsqueeze(0)?.broadcast_as((groups, p, d))?;
            Tensor::cat(&[&pre, body], 1)
        };
        let split = |out: &Tensor, body: usize| -> candle_core::Result<(Option<Tensor>, Tensor)> {
            let pre = if p == 0 {
                None
            } else {
                Some(out.narrow(1, 0, p)?.mean(0)?)
            };
            Ok((pre, out.narrow(1, p, body)?))
        };
        let (pre_out, tok_out) = match self.axis {
            Axis::Spatial => {
                let seq = with_prefix(f, &tok.reshape((f, v, d))?)?;
                let out = self.attend(&seq, heads, ctx.spatial_rope.as_ref(), None, ctx.exec)?;
                let (pre, body) = split(&out, v)?;
                (pre, body.reshape((f * v, d))?)
            }
            Axis::Temporal => {
                let seq = with_prefix(v, &tok.reshape((f, v, d))?.transpose(0, 1)?)?;
                let out = self.attend(&seq, heads, ctx.time_rope, None, ctx.exec)?;
                let (pre, body) = split(&out, f)?;
                (pre, body.transpose(0, 1)?.reshape((f * v, d))?)
            }
            Axis::Object => {
                let groups = s.gather.dim(0)? / s.nmax;
                let body = tok
                    .index_select(&s.gather, 0)?
                    .reshape((groups, s.nmax, d))?;
                let seq = with_prefix(groups, &body)?;
                let out = self.attend(
                    &seq,
                    heads,
                    ctx.object_rope.as_ref(),
                    Some(&s.object_bias),
                    ctx.exec,
                )?;
                let (pre, body) = split(&out, s.nmax)?;
                let body = body
                    .reshape((groups * s.nmax, d))?
                    .index_select(&s.scatter, 0)?;
                (pre, body)
            }
        };
        match pre_out {
            Some(pre) => Tensor::cat(&[&pre, &tok_out], 0),
            None => Ok(tok_out),
        }
    }
}

/// What one call's blocks share: the scene and the rotary codes of this noisy trajectory.
struct CallContext<'a> {
    scene: &'a OfficialScene,
    prefix: usize,
    heads: usize,
    spatial_rope: Option<(Tensor, Tensor)>,
    time_rope: Option<&'a (Tensor, Tensor)>,
    object_rope: Option<(Tensor, Tensor)>,
    exec: Exec,
}

impl OfficialNet {
    /// Builds the network from `p` (loaded official weights, or seeded random ones for
    /// tests).
    pub(crate) fn new(cfg: OfficialConfig, p: &mut ParamStore) -> Result<OfficialNet, ModelError> {
        cfg.validate()?;
        let d = cfg.hidden;
        let x_embedder = linear(p, "x_embedder", 3, d)?;
        let cond_x_embedder = linear(p, "cond_x_embedder", 3, d)?;
        let v_embedder = linear(p, "v_embedder", 3, d)?;
        let material = if cfg.material_dim > 0 {
            Some((
                linear(p, "object_material_embed.0", cfg.material_dim, d)?,
                linear(p, "object_material_embed.2", d, d)?,
            ))
        } else {
            None
        };
        // Kept for a one-to-one state dict; the official forward pass does not add it.
        p.get(
            "object_id_embed.weight",
            &[cfg.max_objects + 1, d],
            Init::Uniform(0.02),
        )?;
        let vert_token = p
            .get("vert_token", &[1, 1, d], Init::Uniform(0.02))?
            .reshape((1, d))?;
        let reg_tokens = if cfg.registers > 0 {
            Some(
                p.get("reg_tokens", &[1, cfg.registers, d], Init::Uniform(0.02))?
                    .reshape((cfg.registers, d))?,
            )
        } else {
            None
        };
        let scene = if cfg.scene_tokens > 0 {
            Some((
                p.get(
                    "scene_token_base",
                    &[1, cfg.scene_tokens, d],
                    Init::Uniform(0.02),
                )?
                .reshape((cfg.scene_tokens, d))?,
                linear(p, "scene_cond_embed.0", cfg.scene_cond_dim, d)?,
                linear(p, "scene_cond_embed.2", d, cfg.scene_cond_out_tokens * d)?,
            ))
        } else {
            None
        };
        let t_mlp = (
            linear(p, "t_embedder.mlp.0", TIME_FEATURES, d)?,
            linear(p, "t_embedder.mlp.2", d, d)?,
        );
        let table = p.get(
            "y_embedder.embedding_table.weight",
            &[cfg.classes + 1, d],
            Init::Uniform(0.02),
        )?;
        let label_row = table.narrow(0, cfg.label, 1)?;
        let blocks = (0..cfg.depth)
            .map(|i| Block::new(p, i, &cfg))
            .collect::<Result<Vec<_>, _>>()?;
        let final_norm = p.rms_norm("final_layer.norm_final", d, NORM_EPS)?;
        let final_linear = zero_linear(p, "final_layer.linear", d, 3)?;
        let final_ada = zero_linear(p, "final_layer.adaLN_modulation.1", d, 2 * d)?;
        let freqs = rope::vertex_freqs(cfg.coord_freqs());
        Ok(OfficialNet {
            cfg,
            x_embedder,
            cond_x_embedder,
            v_embedder,
            material,
            vert_token,
            reg_tokens,
            scene,
            t_mlp,
            label_row,
            blocks,
            final_norm,
            final_ada,
            final_linear,
            freqs,
        })
    }

    /// The scene condition vector of the model's box (centre at the origin, half extent `e`).
    fn scene_condition(&self, physi: &PhysiConfig) -> Vec<f32> {
        let e = physi.box_half_extent;
        let mut c = vec![
            0.0,
            0.0,
            0.0,
            2.0 * e,
            2.0 * e,
            2.0 * e,
            physi.gravity[2],
            0.0,
        ];
        if self.cfg.scene_cond_dim == 9 {
            // --env_and_mat: the ceiling height (the box is closed).
            c.push(e);
        } else {
            // The metadata form: a closed box has a ceiling (1), no boundary margin.
            c.extend([1.0, 0.0]);
        }
        c
    }

    /// Prepares `scene` (validated against `physi`) for `frames` frames: its condition
    /// embedded, its prefix tokens, frame code and object layout.
    pub(crate) fn prepare(
        &self,
        scene: &MeshScene,
        frames: usize,
        physi: &PhysiConfig,
        device: &Device,
    ) -> Result<OfficialScene, ModelError> {
        if frames > self.cfg.max_frames {
            return Err(ModelError::InvalidInput(format!(
                "frames: {frames} exceed the network's {}",
                self.cfg.max_frames
            )));
        }
        let (v, d, p) = (scene.vertices(), self.cfg.hidden, self.cfg.prefix_tokens());
        let (scale, offset) = self.cfg.to_network(physi.box_half_extent);
        let mut x0 = Vec::with_capacity(v * 3);
        let mut v0 = Vec::with_capacity(v * 3);
        for (q, u) in scene.positions.iter().zip(&scene.velocities) {
            for a in 0..3 {
                x0.push((q[a] - offset[a]) / scale[a]);
                v0.push(u[a] / scale[a]);
            }
        }
        let x0 = Tensor::from_vec(x0, (v, 3), device)?;
        let v0 = Tensor::from_vec(v0, (v, 3), device)?;
        let mut cond = self.cond_x_embedder.forward(&x0)?;
        if self.cfg.velocity_condition {
            cond = (cond + self.v_embedder.forward(&v0)?)?;
        }
        if let Some((l0, l2)) = &self.material {
            let mut rows = Vec::with_capacity(v * 2);
            for (o, m) in scene.materials.iter().enumerate() {
                let row = match m {
                    Material::Rigid => self.cfg.rigid_material,
                    Material::Elastic => self.cfg.elastic_material,
                };
                for _ in scene.vertex_offsets[o]..scene.vertex_offsets[o + 1] {
                    rows.extend(row);
                }
            }
            let rows = Tensor::from_vec(rows, (v, 2), device)?;
            cond = (cond + l2.forward(&l0.forward(&rows)?.silu()?)?)?;
        }
        let cond = cond.broadcast_add(&self.vert_token)?.contiguous()?;
        let mut prefix = Vec::new();
        if let Some(r) = &self.reg_tokens {
            prefix.push(r.clone());
        }
        if let Some((base, l0, l2)) = &self.scene {
            let c = self.scene_condition(physi);
            let c = Tensor::from_vec(c, (1, self.cfg.scene_cond_dim), device)?;
            let delta = l2
                .forward(&l0.forward(&c)?.silu()?)?
                .reshape((self.cfg.scene_cond_out_tokens, d))?;
            prefix.push(base.broadcast_add(&delta)?);
        }
        let prefix = if prefix.is_empty() {
            Tensor::zeros((0, d), DType::F32, device)?
        } else {
            Tensor::cat(&prefix, 0)?
        };
        let dh = self.cfg.head_dim();
        let time_rope = rope::cos_sin(
            &rope::frame_phases(p, frames, dh),
            &[1, 1, p + frames],
            dh,
            device,
        )?;
        // Object groups, frame-major: group f * O + o holds object o's vertices at frame f.
        let objects = scene.objects();
        let nmax = (0..objects)
            .map(|o| scene.vertex_offsets[o + 1] - scene.vertex_offsets[o])
            .max()
            .unwrap_or(1);
        let mut gather = vec![0u32; frames * objects * nmax];
        let mut scatter = vec![0u32; frames * v];
        let mut bias = vec![0f32; frames * objects * (p + nmax)];
        for f in 0..frames {
            for o in 0..objects {
                let g = f * objects + o;
                let (s, e) = (scene.vertex_offsets[o], scene.vertex_offsets[o + 1]);
                for slot in 0..nmax {
                    if s + slot < e {
                        gather[g * nmax + slot] = (f * v + s + slot) as u32;
                        scatter[f * v + s + slot] = (g * nmax + slot) as u32;
                    } else {
                        bias[g * (p + nmax) + p + slot] = -1e9;
                    }
                }
            }
        }
        let groups = frames * objects;
        let prior = match prior_trajectory(physi, scene, frames) {
            Some(m) => {
                let n: Vec<f32> = m
                    .iter()
                    .enumerate()
                    .map(|(i, x)| (x - offset[i % 3]) / scale[i % 3])
                    .collect();
                Some(Tensor::from_vec(n, (frames * v, 3), device)?)
            }
            None => None,
        };
        let ramp = match physi.correction_ramp_frames {
            0 => None,
            n => {
                let w: Vec<f32> = (0..frames * v)
                    .map(|i| ((i / v) as f32 / n as f32).min(1.0))
                    .collect();
                Some(Tensor::from_vec(w, (frames * v, 1), device)?)
            }
        };
        Ok(OfficialScene {
            frames,
            vertices: v,
            offsets: scene.vertex_offsets.clone(),
            scale,
            offset,
            cond,
            prefix,
            time_rope,
            nmax,
            gather: Tensor::from_vec(gather, groups * nmax, device)?,
            scatter: Tensor::from_vec(scatter, frames * v, device)?,
            object_bias: Tensor::from_vec(bias, (groups, 1, 1, p + nmax), device)?,
            prior,
            ramp,
        })
    }

    /// The vertex codes of one call: spatial `[F, 1, P + V, dh]` and per-object
    /// `[F * O, 1, P + n, dh]`, from the noisy positions `z` (network coordinates).
    fn vertex_ropes(
        &self,
        s: &OfficialScene,
        z: &[f32],
        device: &Device,
    ) -> candle_core::Result<(Tensor, Tensor, Tensor, Tensor)> {
        let (p, f, v, dh) = (
            self.cfg.prefix_tokens(),
            s.frames,
            s.vertices,
            self.cfg.head_dim(),
        );
        let at = |i: usize| [z[3 * i], z[3 * i + 1], z[3 * i + 2]];
        // The prefix of every frame sits at the centre of all positions, as the official
        // masked mean computes it (weights 1 / (count + 1e-5)).
        let mut centre = [0f32; 3];
        for i in 0..f * v {
            let q = at(i);
            for a in 0..3 {
                centre[a] += q[a];
            }
        }
        let w = (f * v) as f32 + 1e-5;
        let centre = centre.map(|c| c / w);
        let mut pos = Vec::with_capacity(f * (p + v));
        for fr in 0..f {
            pos.extend(std::iter::repeat_n(centre, p));
            pos.extend((0..v).map(|i| at(fr * v + i)));
        }
        let (sc, ss) = rope::cos_sin(
            &rope::vertex_phases(&pos, dh, &self.freqs),
            &[f, 1, p + v],
            dh,
            device,
        )?;
        let objects = s.offsets.len() - 1;
        let n = s.nmax;
        let mut pos = Vec::with_capacity(f * objects * (p + n));
        for fr in 0..f {
            for o in 0..objects {
                let (a, b) = (s.offsets[o], s.offsets[o + 1]);
                let mut c = [0f32; 3];
                for i in a..b {
                    let q = at(fr * v + i);
                    for k in 0..3 {
                        c[k] += q[k];
                    }
                }
                let c = c.map(|x| x / (b - a) as f32);
                pos.extend(std::iter::repeat_n(c, p));
                pos.extend((0..n).map(|slot| {
                    if a + slot < b {
                        at(fr * v + a + slot)
                    } else {
                        [0.0; 3]
                    }
                }));
            }
        }
        let (oc, os) = rope::cos_sin(
            &rope::vertex_phases(&pos, dh, &self.freqs),
            &[f * objects, 1, p + n],
            dh,
            device,
        )?;
        Ok((sc, ss, oc, os))
    }

    /// The predicted clean trajectory `[F V, 3]` (network coordinates) of noisy trajectory
    /// `z [F V * 3]` (network coordinates) at flow time `t`: the network's output, or the
    /// scene's prior plus the (ramped) output when the model has a prior. `mode` picks the
    /// kernels (training ones pass gradients to every parameter).
    pub(crate) fn forward(
        &self,
        s: &OfficialScene,
        z: &[f32],
        t: f32,
        mode: Mode,
    ) -> Result<Tensor, ModelError> {
        let device = s.cond.device();
        let (p, f, v, d) = (
            self.cfg.prefix_tokens(),
            s.frames,
            s.vertices,
            self.cfg.hidden,
        );
        if z.len() != f * v * 3 {
            return Err(ModelError::InvalidInput(format!(
                "z holds {} values, expected {}",
                z.len(),
                f * v * 3
            )));
        }
        let zt = Tensor::from_slice(z, (f * v, 3), device)?;
        let tok = self
            .x_embedder
            .forward(&zt)?
            .reshape((f, v, d))?
            .broadcast_add(&s.cond.unsqueeze(0)?)?
            .reshape((f * v, d))?;
        let mut x = if p > 0 {
            Tensor::cat(&[&s.prefix, &tok], 0)?
        } else {
            tok
        };
        let c = (self
            .t_mlp
            .1
            .forward(&self.t_mlp.0.forward(&time_features(t, device)?)?.silu()?)?
            + &self.label_row)?;
        let c = c.silu()?;
        let (spatial_rope, object_rope) = if self.cfg.rope {
            let (sc, ss, oc, os) = self.vertex_ropes(s, z, device)?;
            (Some((sc, ss)), Some((oc, os)))
        } else {
            (None, None)
        };
        let ctx = CallContext {
            scene: s,
            prefix: p,
            heads: self.cfg.heads,
            spatial_rope,
            time_rope: self.cfg.rope.then_some(&s.time_rope),
            object_rope,
            exec: exec(mode, device),
        };
        for b in &self.blocks {
            x = b.forward(&x, &c, &ctx)?;
        }
        let m = self.final_ada.forward(&c)?.chunk(2, D::Minus1)?;
        let y = modulate(&self.final_norm.forward_exec(&x, ctx.exec)?, &m[0], &m[1])?;
        let mut out = self.final_linear.forward(&y.narrow(0, p, f * v)?)?;
        if let Some(r) = &s.ramp {
            out = out.broadcast_mul(r)?;
        }
        if let Some(prior) = &s.prior {
            out = (out + prior)?;
        }
        Ok(out)
    }
}
