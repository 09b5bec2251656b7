//! Lays a pass out: many scenes, each with its own vertex count, frame count and flow time,
//! padded to the largest vertex count V and frame count T of the pass, with the masks and
//! rotary codes of the three attention kinds.
//!
//! What does not change between the denoising steps of a sample (frame-0 inputs, prior,
//! per-object masks, and the embedding of the frame-0 condition) can be laid out once
//! ([`PreparedScene`]); a pass of prepared scenes ([`PreparedItem`]) then only writes in the
//! noisy positions, their rotary code and the flow times.
//!
//! Token groups: spatial and per-object attention see one frame of one scene (`[B * T]`
//! groups of `R + V` tokens, registers first); temporal attention sees one vertex across
//! frames (`[B * V]` groups of `R + T` tokens).

use candle_core::{Device, Tensor};

use super::config::{PhysiConfig, TrajectoryPrior};
use super::official::OfficialScene;
use super::scene::MeshScene;
use crate::ModelError;

/// Additive attention bias of a masked key (large and finite, so a fully masked row of a
/// padded group stays finite).
pub(crate) const MASKED: f32 = -1e9;

/// One scene of a network evaluation: its condition, its current noisy trajectory and its own
/// flow time.
#[derive(Clone, Copy, Debug)]
pub struct DenoiseItem<'a> {
    /// The scene's condition.
    pub scene: &'a MeshScene,
    /// Noisy trajectory `[frames, V, 3]` flattened, metres.
    pub z: &'a [f32],
    /// Frames of this trajectory (frame 0 included).
    pub frames: usize,
    /// Flow time in `[0, 1]` (0 noise, 1 data).
    pub t: f32,
}

/// Tensors of one pass (see the module docs for the group layout).
pub(crate) struct PassInputs {
    pub b: usize,
    pub t: usize,
    pub v: usize,
    /// Noisy positions `[B, T, V, 3]`.
    pub z: Tensor,
    /// The trajectory the network output is added to (`TrajectoryPrior`): `[B, 1, V, 3]` for
    /// the static prior (frame-0 positions), `[B, T, V, 3]` for either ballistic prior, metres.
    pub prior: Tensor,
    /// The scenes' frame-0 condition, raw or embedded.
    pub condition: Condition,
    /// Flow time per scene `[B]`.
    pub time: Tensor,
    /// Valid frames `[B, T, 1, 1]` (1 or 0) and their count `[B, 1, 1]`.
    pub frame_mask: Tensor,
    pub frame_count: Tensor,
    /// Valid vertices `[B, V, 1, 1]` and their count `[B, 1, 1]`.
    pub vertex_mask: Tensor,
    pub vertex_count: Tensor,
    /// Valid `(frame, vertex)` tokens `[B, T, V, 1]` for the loss.
    pub token_mask: Tensor,
    /// Key biases: spatial `[B * T, 1, 1, R + V]`, per-object `[B * T, 1, R + V, R + V]`,
    /// temporal `[B * V, 1, 1, R + T]`.
    pub spatial_bias: Tensor,
    pub object_bias: Tensor,
    pub temporal_bias: Tensor,
    /// Coordinate rotary code of the spatial groups, `(cos, sin)` `[B * T, 1, R + V, 3 f]`.
    pub spatial_rope: (Tensor, Tensor),
    /// Frame-index rotary code of the temporal groups `[1, 1, R + T, head_dim / 2]`.
    pub temporal_rope: (Tensor, Tensor),
}

fn tensor(data: Vec<f32>, shape: &[usize], device: &Device) -> Result<Tensor, ModelError> {
    Ok(Tensor::from_vec(data, shape, &Device::Cpu)?.to_device(device)?)
}

/// Coordinate rotary phases of one position: `[x f_0.., y f_0.., z f_0..]` with
/// `f_k = 2^k` radians per metre.
fn coord_phases(p: [f32; 3], freqs: usize, out: &mut Vec<f32>) {
    for c in p {
        for k in 0..freqs {
            out.push(c * (1u32 << k) as f32);
        }
    }
}

/// Writes the ballistic prior of `scene` for its first `frames` frames into `out` (`[T, v, 3]`
/// of the pass, `v` its padded vertex count; padded rows left at zero): each vertex moves from
/// its initial position with its initial velocity under gravity and is kept in the box, vertex
/// by vertex or, for `ObjectBallistic`, object by object; metres.
fn ballistic_prior(
    config: &PhysiConfig,
    scene: &MeshScene,
    frames: usize,
    v: usize,
    out: &mut [f32],
) {
    let e = config.box_half_extent;
    let per_object = config.prior == TrajectoryPrior::ObjectBallistic;
    for fr in 0..frames {
        let s = fr as f32 * config.dt_frame;
        let frame = &mut out[fr * v * 3..(fr * v + scene.vertices()) * 3];
        for (i, (p, u)) in scene.positions.iter().zip(&scene.velocities).enumerate() {
            for c in 0..3 {
                frame[i * 3 + c] = p[c] + u[c] * s + 0.5 * config.gravity[c] * s * s;
            }
        }
        if per_object {
            // Shift each object back inside the box as a whole, axis by axis.
            for w in scene.vertex_offsets.windows(2) {
                let rows = &mut frame[w[0] * 3..w[1] * 3];
                for c in 0..3 {
                    let (lo, hi) = rows
                        .chunks_exact(3)
                        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), r| {
                            (lo.min(r[c]), hi.max(r[c]))
                        });
                    let shift = (-e - lo).max(0.0) - (hi - e).max(0.0);
                    for r in rows.chunks_exact_mut(3) {
                        r[c] += shift;
                    }
                }
            }
        }
        for x in frame.iter_mut() {
            *x = x.clamp(-e, e);
        }
    }
}

/// The step-invariant layout of one scene over its frames, at its own size (no padding): what
/// a pass needs from the scene besides its noisy trajectory and flow time.
#[derive(Clone, Debug)]
pub(crate) struct SceneLayout {
    /// Frames laid out (frame 0 included).
    frames: usize,
    /// Vertices of the scene.
    vertices: usize,
    /// Frame-0 positions `[V, 3]`, metres.
    x0: Vec<f32>,
    /// Frame-0 velocities `[V, 3]`, m/s.
    v0: Vec<f32>,
    /// Material input of each vertex's object `[V, 2]`.
    material: Vec<f32>,
    /// Ballistic prior (either kind) `[frames, V, 3]`, metres; empty for the static prior.
    prior: Vec<f32>,
    /// Per-object key bias of one frame's group `[R + V, R + V]` (the same at every frame).
    object_bias: Vec<f32>,
}

impl SceneLayout {
    /// Lays out `scene` (already validated against `config`) over `frames` frames.
    pub(crate) fn new(
        config: &PhysiConfig,
        scene: &MeshScene,
        frames: usize,
    ) -> Result<SceneLayout, ModelError> {
        if frames < 2 || frames > config.frames {
            return Err(ModelError::InvalidInput(format!(
                "frames {frames} outside 2..={}",
                config.frames
            )));
        }
        let nv = scene.vertices();
        let r = config.registers;
        let objects = scene.object_of_vertex();
        let mut x0 = Vec::with_capacity(nv * 3);
        let mut v0 = Vec::with_capacity(nv * 3);
        let mut material = Vec::with_capacity(nv * 2);
        for (i, (p, u)) in scene.positions.iter().zip(&scene.velocities).enumerate() {
            x0.extend_from_slice(p);
            v0.extend_from_slice(u);
            material.extend_from_slice(&scene.materials[objects[i] as usize].features());
        }
        let prior = if config.prior.per_frame() {
            let mut p = vec![0f32; frames * nv * 3];
            ballistic_prior(config, scene, frames, nv, &mut p);
            p
        } else {
            Vec::new()
        };
        let lv = r + nv;
        let mut object_bias = vec![0f32; lv * lv];
        for qi in r..lv {
            for kj in r..lv {
                if objects[qi - r] != objects[kj - r] {
                    object_bias[qi * lv + kj] = MASKED;
                }
            }
        }
        Ok(SceneLayout {
            frames,
            vertices: nv,
            x0,
            v0,
            material,
            prior,
            object_bias,
        })
    }

    /// The raw condition of this scene alone on `device`: frame-0 positions and velocities
    /// `[1, 1, V, 3]` and material inputs `[1, 1, V, 2]`.
    pub(crate) fn raw_condition(&self, device: &Device) -> Result<Condition, ModelError> {
        let nv = self.vertices;
        Ok(Condition::Raw {
            x0: tensor(self.x0.clone(), &[1, 1, nv, 3], device)?,
            v0: tensor(self.v0.clone(), &[1, 1, nv, 3], device)?,
            material: tensor(self.material.clone(), &[1, 1, nv, 2], device)?,
        })
    }
}

/// How a pass carries the scenes' frame-0 condition.
pub(crate) enum Condition {
    /// The raw inputs, embedded by the network: frame-0 positions and velocities
    /// `[B, 1, V, 3]` and material inputs `[B, 1, V, 2]`.
    Raw {
        x0: Tensor,
        v0: Tensor,
        material: Tensor,
    },
    /// Already embedded (the sum of the three embeddings) `[B, 1, V, D]`; zero at padded
    /// vertices.
    Embedded(Tensor),
}

/// One scene of a pass being laid out: its layout, noisy trajectory and flow time.
struct PassScene<'a> {
    layout: &'a SceneLayout,
    z: &'a [f32],
    t: f32,
}

/// Checks the noisy trajectory and flow time of scene `s` against its layout.
fn check_step(s: usize, layout: &SceneLayout, z: &[f32], t: f32) -> Result<(), ModelError> {
    let need = layout.frames * layout.vertices * 3;
    if z.len() != need {
        return Err(ModelError::InvalidInput(format!(
            "scene {s}: noisy trajectory holds {} values, expected {need} (frames x vertices x 3)",
            z.len()
        )));
    }
    if !(0.0..=1.0).contains(&t) {
        return Err(ModelError::InvalidInput(format!(
            "scene {s}: flow time {t} outside [0, 1]"
        )));
    }
    Ok(())
}

/// Lays out `items` for one pass on `device` (see [`PassInputs`]), the condition raw. Every
/// item must have been validated against `config`; this checks the frames and the sizes of
/// `z`.
pub(crate) fn build(
    config: &PhysiConfig,
    items: &[DenoiseItem<'_>],
    device: &Device,
) -> Result<PassInputs, ModelError> {
    let layouts = items
        .iter()
        .enumerate()
        .map(|(s, it)| {
            SceneLayout::new(config, it.scene, it.frames).map_err(|e| match e {
                ModelError::InvalidInput(m) => ModelError::InvalidInput(format!("scene {s}: {m}")),
                other => other,
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let scenes: Vec<PassScene<'_>> = items
        .iter()
        .zip(&layouts)
        .map(|(it, layout)| PassScene {
            layout,
            z: it.z,
            t: it.t,
        })
        .collect();
    assemble(config, &scenes, None, device)
}

/// Assembles one pass from laid-out scenes, padding them to the largest vertex and frame
/// count. `embedded`, when given, holds each scene's embedded condition `[1, 1, V_s, D]`;
/// otherwise the pass carries the raw condition.
fn assemble(
    config: &PhysiConfig,
    scenes: &[PassScene<'_>],
    embedded: Option<&[&Tensor]>,
    device: &Device,
) -> Result<PassInputs, ModelError> {
    if scenes.is_empty() {
        return Err(ModelError::InvalidInput(
            "a pass needs at least one scene".into(),
        ));
    }
    for (s, sc) in scenes.iter().enumerate() {
        check_step(s, sc.layout, sc.z, sc.t)?;
    }
    let b = scenes.len();
    let v = scenes.iter().map(|s| s.layout.vertices).max().unwrap_or(0);
    let t = scenes.iter().map(|s| s.layout.frames).max().unwrap_or(0);
    let r = config.registers;
    let f = config.coord_freqs();
    let (lv, lt) = (r + v, r + t);
    let per_frame_prior = config.prior.per_frame();

    let mut z = vec![0f32; b * t * v * 3];
    let mut x0 = vec![0f32; b * v * 3];
    let mut prior = if per_frame_prior {
        vec![0f32; b * t * v * 3]
    } else {
        Vec::new()
    };
    let mut frame_mask = vec![0f32; b * t];
    let mut vertex_mask = vec![0f32; b * v];
    let mut token_mask = vec![0f32; b * t * v];
    let mut spatial_bias = vec![0f32; b * t * lv];
    let mut object_bias = vec![0f32; b * t * lv * lv];
    let mut temporal_bias = vec![0f32; b * v * lt];
    let mut phases = Vec::with_capacity(b * t * lv * 3 * f);
    let mut times = Vec::with_capacity(b);
    let mut frame_count = Vec::with_capacity(b);
    let mut vertex_count = Vec::with_capacity(b);

    for (s, sc) in scenes.iter().enumerate() {
        let lay = sc.layout;
        let (nv, frames) = (lay.vertices, lay.frames);
        times.push(sc.t);
        frame_count.push(frames as f32);
        vertex_count.push(nv as f32);
        x0[s * v * 3..][..nv * 3].copy_from_slice(&lay.x0);
        vertex_mask[s * v..][..nv].fill(1.0);
        for fr in 0..frames {
            frame_mask[s * t + fr] = 1.0;
            let at = ((s * t + fr) * v) * 3;
            z[at..at + nv * 3].copy_from_slice(&sc.z[fr * nv * 3..(fr + 1) * nv * 3]);
            if per_frame_prior {
                prior[at..at + nv * 3].copy_from_slice(&lay.prior[fr * nv * 3..(fr + 1) * nv * 3]);
            }
            token_mask[(s * t + fr) * v..][..nv].fill(1.0);
        }
        // The per-object bias of one frame at the pass's width: padded keys masked, padded
        // queries see the registers only.
        let own = r + nv;
        let mut frame_bias = vec![MASKED; lv * lv];
        for qi in 0..lv {
            let row = &mut frame_bias[qi * lv..(qi + 1) * lv];
            if qi < own {
                row[..own].copy_from_slice(&lay.object_bias[qi * own..(qi + 1) * own]);
            } else {
                row[..r].fill(0.0);
            }
        }
        // Spatial and per-object groups: one per (scene, frame).
        for fr in 0..t {
            let g = s * t + fr;
            spatial_bias[g * lv + own..(g + 1) * lv].fill(MASKED);
            object_bias[g * lv * lv..(g + 1) * lv * lv].copy_from_slice(&frame_bias);
            // Registers sit at the mean position of the frame's vertices.
            let frame_z = if fr < frames {
                &sc.z[fr * nv * 3..(fr + 1) * nv * 3]
            } else {
                &[][..]
            };
            let mut mean = [0f32; 3];
            for p in frame_z.chunks_exact(3) {
                for c in 0..3 {
                    mean[c] += p[c] / nv as f32;
                }
            }
            for _ in 0..r {
                coord_phases(mean, f, &mut phases);
            }
            for i in 0..v {
                let p = if i < nv && !frame_z.is_empty() {
                    [frame_z[i * 3], frame_z[i * 3 + 1], frame_z[i * 3 + 2]]
                } else {
                    [0.0; 3]
                };
                coord_phases(p, f, &mut phases);
            }
        }
        // Temporal groups: one per (scene, vertex).
        for i in 0..v {
            let g = s * v + i;
            temporal_bias[g * lt + r + frames..(g + 1) * lt].fill(MASKED);
        }
    }

    let half = config.head_dim() / 2;
    let mut tcos = Vec::with_capacity(lt * half);
    let mut tsin = Vec::with_capacity(lt * half);
    for j in 0..lt {
        let frame = if j < r { 0.0 } else { (j - r) as f32 };
        for i in 0..half {
            let w = config
                .temporal_rope_base
                .powf(-(2.0 * i as f32) / config.head_dim() as f32);
            let ph = frame * w;
            tcos.push(ph.cos());
            tsin.push(ph.sin());
        }
    }
    let scos: Vec<f32> = phases.iter().map(|p| p.cos()).collect();
    let ssin: Vec<f32> = phases.iter().map(|p| p.sin()).collect();

    let x0 = tensor(x0, &[b, 1, v, 3], device)?;
    let prior = if per_frame_prior {
        tensor(prior, &[b, t, v, 3], device)?
    } else {
        x0.clone()
    };
    let condition = match embedded {
        Some(parts) => Condition::Embedded(pad_and_stack(parts, v)?),
        None => {
            let mut v0 = vec![0f32; b * v * 3];
            let mut material = vec![0f32; b * v * 2];
            for (s, sc) in scenes.iter().enumerate() {
                let nv = sc.layout.vertices;
                v0[s * v * 3..][..nv * 3].copy_from_slice(&sc.layout.v0);
                material[s * v * 2..][..nv * 2].copy_from_slice(&sc.layout.material);
            }
            Condition::Raw {
                x0: x0.clone(),
                v0: tensor(v0, &[b, 1, v, 3], device)?,
                material: tensor(material, &[b, 1, v, 2], device)?,
            }
        }
    };
    Ok(PassInputs {
        b,
        t,
        v,
        z: tensor(z, &[b, t, v, 3], device)?,
        prior,
        condition,
        time: tensor(times, &[b], device)?,
        frame_mask: tensor(frame_mask, &[b, t, 1, 1], device)?,
        frame_count: tensor(frame_count, &[b, 1, 1], device)?,
        vertex_mask: tensor(vertex_mask, &[b, v, 1, 1], device)?,
        vertex_count: tensor(vertex_count, &[b, 1, 1], device)?,
        token_mask: tensor(token_mask, &[b, t, v, 1], device)?,
        spatial_bias: tensor(spatial_bias, &[b * t, 1, 1, lv], device)?,
        object_bias: tensor(object_bias, &[b * t, 1, lv, lv], device)?,
        temporal_bias: tensor(temporal_bias, &[b * v, 1, 1, lt], device)?,
        spatial_rope: (
            tensor(scos, &[b * t, 1, lv, 3 * f], device)?,
            tensor(ssin, &[b * t, 1, lv, 3 * f], device)?,
        ),
        temporal_rope: (
            tensor(tcos, &[1, 1, lt, half], device)?,
            tensor(tsin, &[1, 1, lt, half], device)?,
        ),
    })
}

/// Pads each `[1, 1, V_s, D]` with zero rows to `[1, 1, v, D]` and stacks them into
/// `[B, 1, v, D]` (no copy for a pass of one unpadded scene).
fn pad_and_stack(parts: &[&Tensor], v: usize) -> candle_core::Result<Tensor> {
    let padded = parts
        .iter()
        .map(|p| {
            let nv = p.dim(2)?;
            if nv == v {
                Ok((*p).clone())
            } else {
                p.pad_with_zeros(2, 0, v - nv)
            }
        })
        .collect::<candle_core::Result<Vec<_>>>()?;
    if padded.len() == 1 {
        return Ok(padded[0].clone());
    }
    Tensor::cat(&padded, 0)
}

/// A scene prepared for sampling (see [`super::PhysiFormer::prepare`]): everything a
/// denoising pass needs from the scene that does not change between its steps, built once
/// per sample and kept with it: the layout over its frames (prior, object masks) and the
/// embedding of its frame-0 positions, velocities and materials. Only the noisy trajectory
/// and the flow time change per step ([`PreparedItem`]).
#[derive(Clone, Debug)]
pub struct PreparedScene {
    pub(crate) kind: Prepared,
}

/// What a network keeps of a prepared scene.
#[derive(Clone, Debug)]
pub(crate) enum Prepared {
    /// This crate's network: the layout and the embedded condition `[1, 1, V, D]`.
    Native {
        layout: SceneLayout,
        embedded: Tensor,
    },
    /// The official network's prepared scene.
    Official(OfficialScene),
}

impl PreparedScene {
    /// Frames the scene was prepared for (frame 0 included).
    pub fn frames(&self) -> usize {
        match &self.kind {
            Prepared::Native { layout, .. } => layout.frames,
            Prepared::Official(s) => s.frames(),
        }
    }

    /// Number of vertices V.
    pub fn vertices(&self) -> usize {
        match &self.kind {
            Prepared::Native { layout, .. } => layout.vertices,
            Prepared::Official(s) => s.vertices(),
        }
    }
}

/// One prepared scene of a network evaluation: its current noisy trajectory and its own flow
/// time.
#[derive(Clone, Copy, Debug)]
pub struct PreparedItem<'a> {
    /// The prepared scene.
    pub scene: &'a PreparedScene,
    /// Noisy trajectory `[frames, V, 3]` flattened, metres (`frames` of the preparation).
    pub z: &'a [f32],
    /// Flow time in `[0, 1]` (0 noise, 1 data).
    pub t: f32,
}

/// Lays out a pass of prepared scenes on `device`: the cached parts padded and stacked, the
/// noisy positions and flow times written in.
pub(crate) fn assemble_prepared(
    config: &PhysiConfig,
    items: &[PreparedItem<'_>],
    device: &Device,
) -> Result<PassInputs, ModelError> {
    let mut scenes: Vec<PassScene<'_>> = Vec::with_capacity(items.len());
    let mut embedded: Vec<&Tensor> = Vec::with_capacity(items.len());
    for it in items {
        let Prepared::Native {
            layout,
            embedded: e,
        } = &it.scene.kind
        else {
            return Err(ModelError::InvalidInput(
                "the scene was prepared for another network".into(),
            ));
        };
        scenes.push(PassScene {
            layout,
            z: it.z,
            t: it.t,
        });
        embedded.push(e);
    }
    assemble(config, &scenes, Some(&embedded), device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physiformer::scene::Material;

    /// One scene of two single-vertex objects: one near the floor falling, one flying at a wall.
    fn scene() -> MeshScene {
        MeshScene {
            positions: vec![[0.0, 0.0, -0.9], [0.8, 0.0, 0.0]],
            velocities: vec![[0.0, 0.0, 0.0], [3.0, 0.0, 1.0]],
            vertex_offsets: vec![0, 1, 2],
            materials: vec![Material::Rigid, Material::Elastic],
        }
    }

    fn prior_of(config: &PhysiConfig, frames: usize) -> Vec<f32> {
        let sc = scene();
        let z = vec![0f32; frames * 2 * 3];
        let it = DenoiseItem {
            scene: &sc,
            z: &z,
            frames,
            t: 0.5,
        };
        let inp = build(config, &[it], &Device::Cpu).unwrap();
        let (b, t, v) = (inp.b, inp.t, inp.v);
        inp.prior
            .broadcast_as((b, t, v, 3))
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap()
    }

    #[test]
    fn ballistic_prior_follows_gravity_and_stays_in_the_box() {
        let cfg = PhysiConfig::tiny();
        assert_eq!(cfg.prior, TrajectoryPrior::Ballistic);
        let p = prior_of(&cfg, 5);
        let s = 2.0 * cfg.dt_frame;
        // Frame 2, vertex 0: free fall from rest.
        let want = -0.9 + 0.5 * cfg.gravity[2] * s * s;
        assert!(
            (p[(2 * 2) * 3 + 2] - want).abs() < 1e-6,
            "{}",
            p[(2 * 2) * 3 + 2]
        );
        // Frame 0 is the initial state.
        assert_eq!(&p[..6], &[0.0, 0.0, -0.9, 0.8, 0.0, 0.0]);
        // Vertex 1 reaches the wall x = 1 and stays on it.
        let last_x = p[(4 * 2 + 1) * 3];
        assert_eq!(last_x, cfg.box_half_extent);
        assert!(p.iter().all(|x| x.abs() <= cfg.box_half_extent));
    }

    /// The object-wise prior shifts a whole object back into the box: a resting box on the
    /// floor keeps its shape and height where the vertex clamp squashes it.
    #[test]
    fn object_ballistic_prior_keeps_a_resting_object_whole() {
        let e = 1.0;
        let sc = MeshScene {
            positions: vec![[0.0, 0.0, -e], [0.0, 0.0, -e + 0.2], [0.1, 0.0, -e]],
            velocities: vec![[0.5, 0.0, 0.0]; 3],
            vertex_offsets: vec![0, 3],
            materials: vec![Material::Rigid],
        };
        let run = |prior| {
            let cfg = PhysiConfig {
                prior,
                ..PhysiConfig::tiny()
            };
            let mut out = vec![0f32; 5 * 3 * 3];
            ballistic_prior(&cfg, &sc, 5, 3, &mut out);
            (cfg, out)
        };
        let (cfg, whole) = run(TrajectoryPrior::ObjectBallistic);
        let (_, clamped) = run(TrajectoryPrior::Ballistic);
        let s = 4.0 * cfg.dt_frame;
        for i in 0..3 {
            let at = (4 * 3 + i) * 3;
            let p = sc.positions[i];
            // Slides with its velocity and keeps its height.
            assert!((whole[at] - (p[0] + 0.5 * s)).abs() < 1e-6);
            assert!(
                (whole[at + 2] - p[2]).abs() < 1e-6,
                "vertex {i}: {}",
                whole[at + 2]
            );
        }
        // The vertex clamp lets the top vertex fall towards the floor.
        assert!(clamped[(4 * 3 + 1) * 3 + 2] < sc.positions[1][2] - 0.01);
    }

    #[test]
    fn static_prior_is_the_initial_state_at_every_frame() {
        let cfg = PhysiConfig {
            prior: TrajectoryPrior::Static,
            ..PhysiConfig::tiny()
        };
        let p = prior_of(&cfg, 4);
        for fr in 0..4 {
            assert_eq!(&p[fr * 6..fr * 6 + 6], &[0.0, 0.0, -0.9, 0.8, 0.0, 0.0]);
        }
    }
}
