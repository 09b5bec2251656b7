//! RigidFormer's [`WorldModel::path_gradients`](crate::WorldModel::path_gradients): every
//! candidate path rolled out as a driven Predict rolls it out, all candidates of all items in
//! one pass per step, with the poses kept in an autograd graph from the kinematic poses
//! through the network ([`super::pose_inputs`]), the Verlet base and the Kabsch fit to the
//! cost, then one backward pass (`docs/gradients.md`).

use candle_core::{Device, Tensor, Var};

use super::RigidFormer;
use super::batch::SceneRequest;
use super::features::rotation_translation;
use super::inputs::build_inputs_and_points;
use super::pose_inputs::{PoseTensors, check_differentiable, pose_inputs, straight_through};
use super::projection::{base_shift, project_poses};
use super::{host_tensor, prepared_for};
use crate::api::{Pose, SceneState};
use crate::gradient::{GradientItem, PathGradient, path_cost};
use crate::layers::{Exec, Mode};
use crate::prepare::{PreparedScene, normalise_pose, validate_state};
use crate::{ModelError, PathCost};

/// Added under the square root of a distance term, m^2, so that its gradient is finite at
/// the target itself.
const DISTANCE_EPS_M2: f64 = 1e-12;

/// One candidate's rollout: its host state, its graph state and its leaves.
struct Candidate<'a> {
    scene: &'a PreparedScene,
    dt_steps: u32,
    cost: &'a PathCost,
    kinematic: &'a [bool],
    /// Kinematic object indices, in order.
    driven: Vec<usize>,
    /// The path `[steps][driven]`, normalised.
    path: Vec<Vec<Pose>>,
    start: SceneState,
    host: SceneState,
    now: PoseTensors,
    before: PoseTensors,
    /// Leaves `[steps, driven, 3]`: the small rotation (rad) and the translation (m) added to
    /// every kinematic pose of the path.
    turn: Var,
    shift: Var,
    /// The graph's kinematic translations after each step, `[driven, 3]` each.
    driven_track: Vec<Tensor>,
    /// The cost terms met so far (scalars).
    terms: Vec<Tensor>,
    /// The host poses after every step, `[steps][objects]`.
    poses: Vec<Vec<Pose>>,
}

/// Rotation matrices `[n, 3, 3]` and translations `[n, 3]` of `poses` on `device`.
fn pose_tensors(poses: &[Pose], device: &Device) -> candle_core::Result<PoseTensors> {
    let mut rot = Vec::with_capacity(9 * poses.len());
    let mut trans = Vec::with_capacity(3 * poses.len());
    for p in poses {
        let (r, t) = rotation_translation(p);
        for i in 0..3 {
            for j in 0..3 {
                rot.push(r[(i, j)]);
            }
        }
        trans.extend([t.x, t.y, t.z]);
    }
    Ok(PoseTensors {
        rot: host_tensor(device, &rot, &[poses.len(), 3, 3])?,
        trans: host_tensor(device, &trans, &[poses.len(), 3])?,
    })
}

/// `[w]x [n, 3, 3]` of `w [n, 3]`.
fn skew(w: &Tensor) -> candle_core::Result<Tensor> {
    let n = w.dim(0)?;
    // Row-major generators: x -> e_x, y -> e_y, z -> e_z of the cross product matrix.
    #[rustfmt::skip]
    let basis: [f32; 27] = [
        0., 0., 0., 0., 0., -1., 0., 1., 0.,
        0., 0., 1., 0., 0., 0., -1., 0., 0.,
        0., -1., 0., 1., 0., 0., 0., 0., 0.,
    ];
    let basis = Tensor::from_slice(&basis, (3, 9), &Device::Cpu)?.to_device(w.device())?;
    w.matmul(&basis)?.reshape((n, 3, 3))
}

/// Object indices as index rows.
fn as_rows(objects: &[usize]) -> Vec<u32> {
    objects.iter().map(|&j| j as u32).collect()
}

/// Rows `rows` of `[O, ...]`-shaped `x` (u32 on `device`).
fn rows(x: &Tensor, rows: &[u32], device: &Device) -> candle_core::Result<Tensor> {
    x.index_select(&super::host_index(device, rows)?, 0)
}

impl RigidFormer {
    /// [`WorldModel::path_gradients`](crate::WorldModel::path_gradients) (module docs).
    pub(crate) fn gradients(
        &self,
        items: &[GradientItem<'_>],
    ) -> Result<Vec<Vec<PathGradient>>, ModelError> {
        check_differentiable(&self.config)?;
        let device = self.device.clone();
        let mut cands = Vec::new();
        // The item each candidate answers.
        let mut owner = Vec::new();
        for (i, item) in items.iter().enumerate() {
            let what = format!("gradient[{i}]");
            item.validate(&what)?;
            let scene = prepared_for(&self.config, item.scene, &what)?;
            let start = validate_state(scene, item.state, item.dt_steps, &what)?;
            let driven: Vec<usize> = (0..scene.len()).filter(|&j| item.kinematic[j]).collect();
            // What every candidate of the item starts from (tensors share their storage).
            let now = pose_tensors(&start.current, &device)?;
            let before = pose_tensors(&start.previous, &device)?;
            let start_driven: Vec<Tensor> = [&before, &now]
                .iter()
                .map(|p| rows(&p.trans, &as_rows(&driven), &device))
                .collect::<Result<_, _>>()?;
            let host = SceneState {
                earlier: None,
                ..start.clone()
            };
            for (c, path) in item.paths.iter().enumerate() {
                let path = path
                    .iter()
                    .map(|step| {
                        step.iter()
                            .map(|p| {
                                normalise_pose(p).map_err(|e| {
                                    ModelError::InvalidInput(format!("{what}: candidate {c}: {e}"))
                                })
                            })
                            .collect::<Result<Vec<_>, _>>()
                    })
                    .collect::<Result<Vec<_>, _>>()?;
                let steps = path.len();
                cands.push(Candidate {
                    scene,
                    dt_steps: item.dt_steps,
                    cost: item.cost,
                    kinematic: item.kinematic,
                    driven: driven.clone(),
                    path,
                    now: now.clone(),
                    before: before.clone(),
                    host: host.clone(),
                    start: start.clone(),
                    turn: Var::zeros((steps, driven.len(), 3), candle_core::DType::F32, &device)?,
                    shift: Var::zeros((steps, driven.len(), 3), candle_core::DType::F32, &device)?,
                    driven_track: start_driven.clone(),
                    terms: Vec::new(),
                    poses: Vec::with_capacity(steps),
                });
                owner.push(i);
            }
        }
        let longest = cands.iter().map(|c| c.path.len()).max().unwrap_or(0);
        for step in 0..longest {
            let now = std::time::Instant::now();
            if let Some((i, item)) = items
                .iter()
                .enumerate()
                .find(|(_, item)| item.steps() > step && item.deadline.is_some_and(|d| d <= now))
            {
                return Err(ModelError::DeadlineExceeded(format!(
                    "gradient[{i}]: the deadline passed after {step} of {} steps",
                    item.steps()
                )));
            }
            let active: Vec<usize> = (0..cands.len())
                .filter(|&c| cands[c].path.len() > step)
                .collect();
            self.gradient_step(&mut cands, &active, step, &device)?;
        }
        // One backward pass for every candidate: their costs are independent, so the gradient
        // of the sum with respect to one candidate's leaves is that of its own cost.
        let mut total: Option<Tensor> = None;
        for c in &mut cands {
            let smooth = smoothness(c.cost, &c.driven_track)?;
            for term in c.terms.iter().chain(smooth.iter()) {
                total = Some(match total {
                    Some(t) => (t + term)?,
                    None => term.clone(),
                });
            }
        }
        let grads = match &total {
            Some(t) => Some(t.backward()?),
            None => None,
        };
        let read = |v: &Var| -> Result<Vec<Vec<[f32; 3]>>, ModelError> {
            let g = grads.as_ref().and_then(|g| g.get(v.as_tensor()).cloned());
            let g = match g {
                Some(g) => g,
                None => v.as_tensor().zeros_like()?,
            };
            let g: Vec<Vec<Vec<f32>>> = g.to_device(&Device::Cpu)?.to_vec3()?;
            Ok(g.into_iter()
                .map(|s| s.into_iter().map(|p| [p[0], p[1], p[2]]).collect())
                .collect())
        };
        let mut out: Vec<Vec<PathGradient>> = items.iter().map(|_| Vec::new()).collect();
        for (c, item) in cands.iter().zip(&owner) {
            out[*item].push(PathGradient {
                cost: path_cost(c.cost, &c.start, c.kinematic, &c.poses),
                translation: read(&c.shift)?,
                rotation: read(&c.turn)?,
                poses: c.poses.clone(),
            });
        }
        Ok(out)
    }

    /// Advances the candidates `active` by step `step` (0-based) in one pass.
    fn gradient_step(
        &self,
        cands: &mut [Candidate<'_>],
        active: &[usize],
        step: usize,
        device: &Device,
    ) -> Result<(), ModelError> {
        let cfg = &self.config;
        let k = cfg.anchors;
        let requests: Vec<SceneRequest<'_>> = active
            .iter()
            .map(|&c| SceneRequest {
                scene: cands[c].scene,
                previous: cands[c].host.previous.clone(),
                current: cands[c].host.current.clone(),
                earlier: None,
                dt_steps: cands[c].dt_steps,
            })
            .collect();
        let (mut inp, placed) = build_inputs_and_points(cfg, &requests)?;
        let cat = |now: bool| -> candle_core::Result<PoseTensors> {
            let parts: Vec<&PoseTensors> = active
                .iter()
                .map(|&c| if now { &cands[c].now } else { &cands[c].before })
                .collect();
            Ok(PoseTensors {
                rot: Tensor::cat(&parts.iter().map(|p| &p.rot).collect::<Vec<_>>(), 0)?,
                trans: Tensor::cat(&parts.iter().map(|p| &p.trans).collect::<Vec<_>>(), 0)?,
            })
        };
        let now = cat(true)?;
        let before = cat(false)?;
        inp.pose_inputs = Some(pose_inputs(
            cfg, &requests, &placed, &inp, &now, &before, device,
        )?);
        // The training kernels (with their backward passes) where the CPU has them; attention
        // is composed of tensor ops with graph poses (the decoder and anchor head see to it).
        let exec = Exec {
            mode: Mode::Training,
            fused: self.fused_kernels && device.is_cpu(),
        };
        let acc = self.network_exec(&inp, exec, None)?; // [O, K, 3]
        let acc_host: Vec<f32> = acc
            .detach()
            .flatten_all()?
            .to_device(&Device::Cpu)?
            .to_vec1()?;
        let projected = project_poses(cfg, &inp, &acc_host)?; // [scenes][objects]
        // The graph's Verlet base (the rigid or linear constant-velocity extrapolation plus
        // the free fall) and Kabsch fit.
        let o = inp.o;
        let refs: Vec<f32> = inp
            .anchors_ref
            .iter()
            .flatten()
            .flatten()
            .map(|v| *v as f32)
            .collect();
        let x = host_tensor(device, &refs, &[o, k, 3])?;
        let placed = |p: &PoseTensors, r: &Tensor| -> candle_core::Result<Tensor> {
            x.matmul(&r.transpose(1, 2)?)?
                .broadcast_add(&p.trans.unsqueeze(1)?)
        };
        let base = if cfg.dynamics.rigid_extrapolation {
            let turn = now
                .rot
                .matmul(&before.rot.transpose(1, 2)?)?
                .matmul(&now.rot)?;
            let ahead = PoseTensors {
                rot: turn.clone(),
                trans: ((&now.trans * 2.0)? - &before.trans)?,
            };
            placed(&ahead, &turn)?
        } else {
            ((placed(&now, &now.rot)? * 2.0)? - placed(&before, &before.rot)?)?
        };
        let fall: Vec<f32> = (0..o)
            .flat_map(|obj| base_shift(cfg, &inp, obj).map(|v| v as f32))
            .collect();
        let target = base
            .broadcast_add(&host_tensor(device, &fall, &[o, 1, 3])?)?
            .add(&acc)?;
        let fit = crate::KabschOp::new(inp.anchors_ref.clone()).apply(&target.contiguous()?)?;
        let fit_rot = fit.narrow(1, 0, 9)?.reshape((o, 3, 3))?;
        let fit_trans = fit.narrow(1, 9, 3)?;
        let mut first = 0usize;
        for (slot, &c) in active.iter().enumerate() {
            let cand = &mut cands[c];
            let m = cand.scene.len();
            let mut next = projected[slot].clone();
            for (i, &j) in cand.driven.iter().enumerate() {
                next[j] = cand.path[step][i];
            }
            // Dynamic objects: the host's poses with the graph's derivative; kinematic ones:
            // the path's poses moved by the leaves.
            let host = pose_tensors(&next, device)?;
            let rot = straight_through(&host.rot, &fit_rot.narrow(0, first, m)?)?;
            let trans = straight_through(&host.trans, &fit_trans.narrow(0, first, m)?)?;
            let driven = as_rows(&cand.driven);
            let turn = cand.turn.as_tensor().narrow(0, step, 1)?.squeeze(0)?;
            let shift = cand.shift.as_tensor().narrow(0, step, 1)?.squeeze(0)?;
            let path_rot = rows(&host.rot, &driven, device)?;
            let path_trans = rows(&host.trans, &driven, device)?;
            let driven_rot = (&path_rot + skew(&turn)?.matmul(&path_rot)?)?;
            let driven_trans = (&path_trans + &shift)?;
            // Object j reads row j of the dynamic rows, or row m + i of the driven ones.
            let mut pick: Vec<u32> = (0..m as u32).collect();
            for (i, &j) in cand.driven.iter().enumerate() {
                pick[j] = (m + i) as u32;
            }
            let rot = rows(&Tensor::cat(&[&rot, &driven_rot], 0)?, &pick, device)?;
            let trans = rows(&Tensor::cat(&[&trans, &driven_trans], 0)?, &pick, device)?;
            cand.driven_track.push(driven_trans);
            for t in cand.cost.targets.iter().filter(|t| t.step == step + 1) {
                cand.terms.extend(target_terms(t, &rot, &trans, device)?);
            }
            cand.before = std::mem::replace(&mut cand.now, PoseTensors { rot, trans });
            cand.host.advance(next.clone());
            cand.host.earlier = None;
            cand.poses.push(next);
            first += m;
        }
        Ok(())
    }
}

/// The cost terms of one target (scalars) from the graph's poses after its step, rotations
/// `[m, 3, 3]` and translations `[m, 3]`.
fn target_terms(
    t: &crate::CostTarget,
    rot: &Tensor,
    trans: &Tensor,
    device: &Device,
) -> Result<Vec<Tensor>, ModelError> {
    let mut out = Vec::new();
    if t.position_weight > 0.0 {
        let goal = Tensor::from_slice(&t.position, 3, &Device::Cpu)?.to_device(device)?;
        let d2 = (trans.get(t.object)? - goal)?.sqr()?.sum_all()?;
        out.push(((d2 + DISTANCE_EPS_M2)?.sqrt()? * f64::from(t.position_weight))?);
    }
    if let (Some(q), true) = (t.rotation, t.rotation_weight > 0.0) {
        let goal = Pose {
            translation: [0.0; 3],
            rotation: q,
        };
        let (r, _) = rotation_translation(&goal);
        let r: Vec<f32> = (0..9).map(|i| r[(i / 3, i % 3)]).collect();
        let r = host_tensor(device, &r, &[3, 3])?;
        // 1 - cos(angle) = (3 - tr(R*^T R)) / 2.
        let inner = (rot.get(t.object)? * r)?.sum_all()?;
        out.push(((inner.affine(-0.5, 1.5))? * f64::from(t.rotation_weight))?);
    }
    Ok(out)
}

/// The smoothness term (a scalar, or none when its weight is 0) of a candidate's kinematic
/// translations `track` (`[driven, 3]` each: the start's two poses, then one per step).
fn smoothness(cost: &PathCost, track: &[Tensor]) -> Result<Option<Tensor>, ModelError> {
    if cost.smoothness <= 0.0 || track.len() < 3 {
        return Ok(None);
    }
    let mut sum: Option<Tensor> = None;
    for w in track.windows(3) {
        let a = ((&w[2] - (&w[1] * 2.0)?)? + &w[0])?.sqr()?.sum_all()?;
        sum = Some(match sum {
            Some(s) => (s + a)?,
            None => a,
        });
    }
    Ok(sum.map(|s| s * f64::from(cost.smoothness)).transpose()?)
}
