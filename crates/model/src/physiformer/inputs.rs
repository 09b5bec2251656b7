//! Lays a pass out: many scenes, each with its own vertex count, frame count and flow time,
//! padded to the largest vertex count V and frame count T of the pass, with the masks and
//! rotary codes of the three attention kinds.
//!
//! Token groups: spatial and per-object attention see one frame of one scene (`[B * T]`
//! groups of `R + V` tokens, registers first); temporal attention sees one vertex across
//! frames (`[B * V]` groups of `R + T` tokens).

use candle_core::{Device, Tensor};

use super::config::{PhysiConfig, TrajectoryPrior};
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
    /// Frame-0 positions `[B, 1, V, 3]`.
    pub x0: Tensor,
    /// Frame-0 velocities `[B, 1, V, 3]`.
    pub v0: Tensor,
    /// The trajectory the network output is added to (`TrajectoryPrior`): `[B, 1, V, 3]` for
    /// the static prior (frame-0 positions), `[B, T, V, 3]` for the ballistic one, metres.
    pub prior: Tensor,
    /// Material input of each vertex's object `[B, 1, V, 2]`.
    pub material: Tensor,
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

/// Writes the ballistic prior of `scene` for its first `frames` frames into `out`
/// (`[T, v, 3]` of the pass, `v` its padded vertex count; padded rows left at zero): each
/// vertex moves from its initial position with its initial velocity under gravity, clamped to
/// the box, metres.
fn ballistic_prior(
    config: &PhysiConfig,
    scene: &MeshScene,
    frames: usize,
    v: usize,
    out: &mut [f32],
) {
    let e = config.box_half_extent;
    for fr in 0..frames {
        let s = fr as f32 * config.dt_frame;
        for (i, (p, u)) in scene.positions.iter().zip(&scene.velocities).enumerate() {
            for c in 0..3 {
                let x = p[c] + u[c] * s + 0.5 * config.gravity[c] * s * s;
                out[(fr * v + i) * 3 + c] = x.clamp(-e, e);
            }
        }
    }
}

/// Lays out `items` for one pass on `device` (see [`PassInputs`]). Every item must have been
/// validated against `config`; this checks only the sizes of `z`.
pub(crate) fn build(
    config: &PhysiConfig,
    items: &[DenoiseItem<'_>],
    device: &Device,
) -> Result<PassInputs, ModelError> {
    if items.is_empty() {
        return Err(ModelError::InvalidInput(
            "a pass needs at least one scene".into(),
        ));
    }
    let b = items.len();
    let v = items.iter().map(|i| i.scene.vertices()).max().unwrap_or(0);
    let t = items.iter().map(|i| i.frames).max().unwrap_or(0);
    let r = config.registers;
    let f = config.coord_freqs();
    for (s, it) in items.iter().enumerate() {
        let need = it.frames * it.scene.vertices() * 3;
        if it.z.len() != need {
            return Err(ModelError::InvalidInput(format!(
                "scene {s}: noisy trajectory holds {} values, expected {need} (frames x vertices x 3)",
                it.z.len()
            )));
        }
        if !(0.0..=1.0).contains(&it.t) {
            return Err(ModelError::InvalidInput(format!(
                "scene {s}: flow time {} outside [0, 1]",
                it.t
            )));
        }
        if it.frames < 2 || it.frames > config.frames {
            return Err(ModelError::InvalidInput(format!(
                "scene {s}: frames {} outside 2..={}",
                it.frames, config.frames
            )));
        }
    }

    let mut z = vec![0f32; b * t * v * 3];
    let mut x0 = vec![0f32; b * v * 3];
    let mut v0 = vec![0f32; b * v * 3];
    let ballistic = config.prior == TrajectoryPrior::Ballistic;
    let mut prior = if ballistic {
        vec![0f32; b * t * v * 3]
    } else {
        Vec::new()
    };
    let mut material = vec![0f32; b * v * 2];
    let mut frame_mask = vec![0f32; b * t];
    let mut vertex_mask = vec![0f32; b * v];
    let mut token_mask = vec![0f32; b * t * v];
    let (lv, lt) = (r + v, r + t);
    let mut spatial_bias = vec![0f32; b * t * lv];
    let mut object_bias = vec![0f32; b * t * lv * lv];
    let mut temporal_bias = vec![0f32; b * v * lt];
    let mut phases = Vec::with_capacity(b * t * lv * 3 * f);
    let mut times = Vec::with_capacity(b);
    let mut frame_count = Vec::with_capacity(b);
    let mut vertex_count = Vec::with_capacity(b);

    for (s, it) in items.iter().enumerate() {
        let sc = it.scene;
        let nv = sc.vertices();
        let objects = sc.object_of_vertex();
        times.push(it.t);
        frame_count.push(it.frames as f32);
        vertex_count.push(nv as f32);
        for (i, (p, u)) in sc.positions.iter().zip(&sc.velocities).enumerate() {
            let at = (s * v + i) * 3;
            x0[at..at + 3].copy_from_slice(p);
            v0[at..at + 3].copy_from_slice(u);
            let m = sc.materials[objects[i] as usize].features();
            material[(s * v + i) * 2..][..2].copy_from_slice(&m);
            vertex_mask[s * v + i] = 1.0;
        }
        if ballistic {
            ballistic_prior(
                config,
                sc,
                it.frames,
                v,
                &mut prior[s * t * v * 3..][..t * v * 3],
            );
        }
        for fr in 0..it.frames {
            frame_mask[s * t + fr] = 1.0;
            let src = &it.z[fr * nv * 3..(fr + 1) * nv * 3];
            z[((s * t + fr) * v) * 3..][..nv * 3].copy_from_slice(src);
            for i in 0..nv {
                token_mask[(s * t + fr) * v + i] = 1.0;
            }
        }
        // Spatial and per-object groups: one per (scene, frame).
        for fr in 0..t {
            let g = s * t + fr;
            let group = &mut spatial_bias[g * lv..(g + 1) * lv];
            for (j, slot) in group.iter_mut().enumerate().skip(r) {
                if j - r >= nv {
                    *slot = MASKED;
                }
            }
            let ob = &mut object_bias[g * lv * lv..(g + 1) * lv * lv];
            for qi in 0..lv {
                for kj in 0..lv {
                    let key_valid = kj < r || kj - r < nv;
                    let same = qi < r
                        || kj < r
                        || (qi - r < nv && kj - r < nv && objects[qi - r] == objects[kj - r]);
                    if !(key_valid && same) {
                        ob[qi * lv + kj] = MASKED;
                    }
                }
            }
            // Registers sit at the mean position of the frame's vertices.
            let frame_z = if fr < it.frames {
                &it.z[fr * nv * 3..(fr + 1) * nv * 3]
            } else {
                &[][..]
            };
            let mut mean = [0f32; 3];
            if !frame_z.is_empty() {
                for p in frame_z.chunks_exact(3) {
                    for c in 0..3 {
                        mean[c] += p[c] / nv as f32;
                    }
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
            for j in 0..t {
                if j >= it.frames {
                    temporal_bias[g * lt + r + j] = MASKED;
                }
            }
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
    Ok(PassInputs {
        b,
        t,
        v,
        z: tensor(z, &[b, t, v, 3], device)?,
        prior: if ballistic {
            tensor(prior, &[b, t, v, 3], device)?
        } else {
            x0.clone()
        },
        x0,
        v0: tensor(v0, &[b, 1, v, 3], device)?,
        material: tensor(material, &[b, 1, v, 2], device)?,
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
