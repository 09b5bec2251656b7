//! The pose-dependent network inputs of one pass rebuilt as functions of pose tensors, so
//! that a gradient pass can differentiate the network's output with respect to the poses
//! ([`PoseInputs`], `docs/gradients.md`).
//!
//! Every discrete choice is the host's ([`super::inputs`]): which surface each point's contact
//! feature reaches (another object's point, the floor or nothing) and that point's index, the
//! branch of every clamp, the lowest point of each object. Given those choices each input is a
//! smooth function of the poses and is written here with tensor operations. The values the
//! network reads stay exactly the host's (`host + (graph - detach(graph))`): the graph
//! contributes only the derivative, so a gradient pass forecasts what inference forecasts.

use candle_core::{D, Device, Tensor};

use super::batch::{BatchInputs, PoseInputs, SceneRequest};
use super::features::ScenePoints;
use super::features::{
    FeatureFrame, SUMMARY_HEIGHT_MAX, SUMMARY_HEIGHT_SCALE, SUMMARY_INCREMENT_SCALE,
    SUMMARY_LEVER_SCALE, SUMMARY_ROTATION_SCALE,
};
use super::inputs::rope_frequencies;
use super::{host_index, host_tensor};
use crate::config::APPROACH_FEATURES;
use crate::{ModelConfig, ModelError};
use dynaserve_geometry::ContactSource;

/// Poses of every object of a pass as tensors: rotations `[O, 3, 3]` (body to world) and
/// translations `[O, 3]` (metres).
#[derive(Clone)]
pub(crate) struct PoseTensors {
    /// `[O, 3, 3]`.
    pub rot: Tensor,
    /// `[O, 3]`, metres.
    pub trans: Tensor,
}

impl PoseTensors {
    /// Body-frame points `x [L, 3]` of objects `rows [L]` (u32) placed in the world, `[L, 3]`.
    fn place(&self, rows: &Tensor, x: &Tensor) -> candle_core::Result<Tensor> {
        let r = self.rot.index_select(rows, 0)?;
        r.matmul(&x.unsqueeze(2)?)?
            .squeeze(2)?
            .add(&self.trans.index_select(rows, 0)?)
    }
}

/// The network's value `host` with the derivative of `graph` (same shape, same value up to
/// rounding or a constant).
pub(crate) fn straight_through(host: &Tensor, graph: &Tensor) -> candle_core::Result<Tensor> {
    host + (graph - graph.detach())?
}

/// Which dynamics switches a gradient pass can differentiate: `Err` names the first one it
/// cannot (their inputs are not rebuilt here).
pub(crate) fn check_differentiable(cfg: &ModelConfig) -> Result<(), ModelError> {
    let d = &cfg.dynamics;
    let unsupported = [
        (d.history, "history inputs"),
        (d.contact_partner, "contact partner inputs"),
        (d.contact_summary, "the contact summary"),
        (d.floor_base, "the floor base"),
        (d.free_flight_gate, "the free-flight gate"),
        (d.kinematic_lead, "the kinematic lead"),
        (d.contact_wrench, "the contact wrench"),
        (d.contact_messages, "contact messages"),
        (cfg.floor_projection.is_some(), "the floor projection"),
    ];
    match unsupported.iter().find(|(on, _)| *on) {
        Some((_, what)) => Err(ModelError::Unsupported(format!(
            "gradients are not available for a model that reads {what}"
        ))),
        None => Ok(()),
    }
}

/// Host layout of one pass's points and the discrete choices the graph follows.
struct Layout {
    /// Object row of every packed point, `[P]`.
    object: Vec<u32>,
    /// Body-frame position `[P, 3]` and normal `[P, 3]` of every point.
    reference: Vec<f32>,
    normal: Vec<f32>,
    /// Its object's parameters as the model reads them, `[P, 3]`.
    params: Vec<f32>,
    /// Per point: 1 when the contact reaches another object's point, 1 when the floor.
    is_point: Vec<f32>,
    is_ground: Vec<f32>,
    /// The packed row of the point reached (the point itself otherwise), `[P]`.
    partner: Vec<u32>,
    /// The host's contact displacement where it does not depend on the poses (the floor's
    /// height, the free fallback), `[P, 3]`.
    disp_const: Vec<f32>,
    /// Per point: `1 / increment divisor` `[P]` and the divisor itself.
    inv_div: Vec<f32>,
    div: Vec<f32>,
    /// Lowest point row of every object at t, `[O]`.
    lowest: Vec<u32>,
}

/// The layout of the pass `inp`, built from `requests`, whose scenes' contact searches are
/// `placed` (as [`build_inputs_and_points`](super::inputs::build_inputs_and_points) returns
/// them).
fn layout(
    cfg: &ModelConfig,
    requests: &[SceneRequest<'_>],
    placed: &[ScenePoints],
    inp: &BatchInputs,
) -> Layout {
    let p = inp.points;
    let mut l = Layout {
        object: Vec::with_capacity(p),
        reference: Vec::with_capacity(3 * p),
        normal: Vec::with_capacity(3 * p),
        params: Vec::with_capacity(3 * p),
        is_point: vec![0.0; p],
        is_ground: vec![0.0; p],
        partner: Vec::with_capacity(p),
        disp_const: vec![0.0; 3 * p],
        inv_div: Vec::with_capacity(p),
        div: Vec::with_capacity(p),
        lowest: Vec::with_capacity(inp.o),
    };
    let mut first_point = 0usize;
    let mut first_object = 0u32;
    for (r, points) in requests.iter().zip(placed) {
        let scene = r.scene;
        for (j, obj) in scene.objects.iter().enumerate() {
            let frame = FeatureFrame::new(&cfg.dynamics, r.dt_steps, r.current[j].translation);
            let base = points.offsets[j];
            let n = obj.reference.len();
            for i in 0..n {
                let q = base + i;
                let row = first_point + q;
                l.object.push(first_object + j as u32);
                l.reference.extend(obj.reference[i]);
                l.params.extend(obj.params);
                l.normal
                    .extend(obj.normals.get(i).copied().unwrap_or([0.0; 3]));
                let hit = points.contact[q];
                l.partner.push(match hit.source {
                    ContactSource::Point(other) => {
                        l.is_point[row] = 1.0;
                        (first_point + other as usize) as u32
                    }
                    ContactSource::Ground => {
                        l.is_ground[row] = 1.0;
                        l.disp_const[row * 3 + 2] = cfg.ground_z.unwrap_or(0.0);
                        row as u32
                    }
                    ContactSource::Free => {
                        l.disp_const[row * 3..row * 3 + 3].copy_from_slice(&hit.displacement);
                        row as u32
                    }
                });
                l.div.push(frame.increment_divisor);
                l.inv_div.push(1.0 / frame.increment_divisor);
            }
            let low = (base..base + n)
                .min_by(|&a, &b| points.world[a][2].total_cmp(&points.world[b][2]))
                .unwrap_or(base);
            l.lowest.push((first_point + low) as u32);
        }
        first_point += scene.total_points();
        first_object += scene.len() as u32;
    }
    l
}

/// `x [L, 3] . y [L, 3]` -> `[L, 1]`.
fn dot(x: &Tensor, y: &Tensor) -> candle_core::Result<Tensor> {
    (x * y)?.sum_keepdim(1)
}

/// The pose-dependent inputs of the pass `inp` (built from `requests`, whose contact
/// searches are `placed`) as functions of the
/// poses at t (`now`) and one step before (`before`), every object of the pass in order,
/// with the host's discrete choices: their values equal the host's up to float rounding.
/// The model's switches must pass [`check_differentiable`].
pub(crate) fn graph_inputs(
    cfg: &ModelConfig,
    requests: &[SceneRequest<'_>],
    placed: &[ScenePoints],
    inp: &BatchInputs,
    now: &PoseTensors,
    before: &PoseTensors,
    device: &Device,
) -> Result<PoseInputs, ModelError> {
    let l = layout(cfg, requests, placed, inp);
    let (pts, o, nf) = (inp.points, inp.o, cfg.point_features());
    let (k, s, g) = (cfg.anchors, cfg.sa_centres, cfg.sa_neighbours);
    let pairs = cfg.rope_dim / 2;
    let radius = cfg.contact_radius;
    let t = |data: &[f32], shape: &[usize]| host_tensor(device, data, shape);
    let col = |data: &[f32]| host_tensor(device, data, &[data.len(), 1]);
    let object = host_index(device, &l.object)?;
    let reference = t(&l.reference, &[pts, 3])?;
    let x = now.place(&object, &reference)?; // [P, 3]
    let x_prev = before.place(&object, &reference)?;
    let inv_div = col(&l.inv_div)?;
    let inc = (&x - &x_prev)?.broadcast_mul(&inv_div)?;
    // Contact displacement: to the partner point, to the floor (its height is constant), or
    // the constant fallback.
    let partner = host_index(device, &l.partner)?;
    let (is_point, is_ground) = (col(&l.is_point)?, col(&l.is_ground)?);
    let down = Tensor::new(&[[0f32, 0.0, -1.0]], device)?;
    let disp = ((x.index_select(&partner, 0)? - &x)?.broadcast_mul(&is_point)?
        + x.broadcast_mul(&down)?.broadcast_mul(&is_ground)?)?
    .add(&t(&l.disp_const, &[pts, 3])?)?;
    let origin = if cfg.dynamics.translation_invariant {
        now.trans
            .index_select(&object, 0)?
            .broadcast_mul(&Tensor::new(&[[1f32, 1.0, 0.0]], device)?)?
    } else {
        Tensor::zeros((pts, 3), candle_core::DType::F32, device)?
    };
    let offset = ((&x - origin)? - &reference)?;
    let params = t(&l.params, &[pts, 3])?;
    let mut columns = vec![disp.clone(), inc.clone(), offset, params];
    let cv = (inc.index_select(&partner, 0)? - &inc)?
        .broadcast_mul(&is_point)?
        .sub(&inc.broadcast_mul(&is_ground)?)?;
    if cfg.dynamics.contact_velocity {
        columns.push(cv.clone());
    }
    if cfg.dynamics.reads_normals() {
        let normals = now.place(&object, &t(&l.normal, &[pts, 3])?)?;
        let normals = (normals - now.trans.index_select(&object, 0)?)?; // rotate only
        let up = Tensor::new(&[[0f32, 0.0, 1.0]], device)?;
        let m = (normals
            .index_select(&partner, 0)?
            .broadcast_mul(&is_point)?
            + up.broadcast_mul(&is_ground)?)?;
        // The height above the reached surface's tangent plane where it is inside the
        // clamp; elsewhere its clamped (constant) value, the radius when nothing is near.
        let height = dot(&disp, &m)?.neg()?;
        let heights: Vec<f32> = height.detach().flatten_all()?.to_vec1()?;
        let (mut host_gap, mut held) = (Vec::with_capacity(pts), Vec::with_capacity(pts));
        for (q, h) in heights.iter().enumerate() {
            let reached = l.is_point[q] + l.is_ground[q] > 0.0;
            let inside = reached && h.abs() < radius;
            held.push((!inside) as u8 as f32);
            host_gap.push(if reached {
                h.clamp(-radius, radius)
            } else {
                radius
            });
        }
        let held = col(&held)?;
        let gap =
            (height.broadcast_mul(&(1.0 - &held)?)? + col(&host_gap)?.broadcast_mul(&held)?)?;
        if cfg.dynamics.surface_normals {
            columns.extend([normals, m.clone(), gap.clone()]);
        }
        if cfg.dynamics.approach {
            columns.push(approach(&l, &cv, &m, &gap, &host_gap, radius, device)?);
        }
    }
    let raw = Tensor::cat(&columns, 1)?; // [P, F]
    if raw.dim(1)? != nf {
        return Err(ModelError::Internal(format!(
            "gradient inputs have {} columns, the model reads {nf}",
            raw.dim(1)?
        )));
    }
    let norm = &cfg.normalization;
    let inv_std: Vec<f32> = norm.std[..nf].iter().map(|v| 1.0 / v).collect();
    let feats = raw
        .broadcast_sub(&t(&norm.mean[..nf], &[1, nf])?)?
        .broadcast_mul(&t(&inv_std, &[1, nf])?)?;
    // Encoder grouping, anchors and rotary codes, relative to each object's world centroid.
    let inv_scale = 1.0 / cfg.position_scale as f64;
    let objects: Vec<u32> = (0..o as u32).collect();
    let objects = host_index(device, &objects)?;
    let centroids: Vec<f32> = requests
        .iter()
        .flat_map(|r| r.scene.objects.iter().flat_map(|ob| ob.centroid))
        .collect();
    let centroid = now.place(&objects, &t(&centroids, &[o, 3])?)?; // [O, 3]
    let mut centre_rows = Vec::with_capacity(o * s);
    let mut first = 0usize;
    for r in requests {
        for ob in &r.scene.objects {
            centre_rows.extend(ob.centres.iter().map(|&c| (first + c) as u32));
            first += ob.reference.len();
        }
    }
    let centre_of_neighbour: Vec<u32> = centre_rows
        .iter()
        .flat_map(|&c| std::iter::repeat_n(c, g))
        .collect();
    let per = |n: usize| -> candle_core::Result<Tensor> {
        let rows: Vec<u32> = (0..o as u32)
            .flat_map(|j| std::iter::repeat_n(j, n))
            .collect();
        centroid.index_select(&host_index(device, &rows)?, 0)
    };
    let group_rel = ((x.index_select(&host_index(device, &inp.group_idx)?, 0)?
        - x.index_select(&host_index(device, &centre_of_neighbour)?, 0)?)?
        * inv_scale)?;
    let centre_rel =
        ((x.index_select(&host_index(device, &centre_rows)?, 0)? - per(s)?)? * inv_scale)?;
    let anchor = x.index_select(&host_index(device, &inp.anchor_idx)?, 0)?; // [O*K, 3]
    let anchor_off = (&anchor - per(k)?)?;
    let freqs = rope_frequencies(cfg);
    let freqs = t(&freqs, &[1, 1, freqs.len()])?;
    let angles = |p: &Tensor| {
        p.unsqueeze(2)?
            .broadcast_mul(&freqs)?
            .reshape((o * k, pairs))
    };
    let ang = angles(&anchor)?;
    let rope = if cfg.dynamics.translation_invariant {
        let rel = angles(&anchor_off)?;
        Tensor::cat(&[rel.cos()?, rel.sin()?], 1)?
    } else {
        Tensor::cat(&[ang.cos()?, ang.sin()?], 1)?
    };
    let object_summary = if cfg.dynamics.object_summary {
        Some(object_summary(cfg, &l, &x, &x_prev, now, before, device)?)
    } else {
        None
    };
    Ok(PoseInputs {
        feats,
        group_rel,
        centre_rel,
        anchor_rel: (&anchor_off * inv_scale)?.reshape((o, k, 3))?,
        anchor_rope: rope.reshape((o, k, 2 * pairs))?,
        anchor_cos: ang.cos()?,
        anchor_sin: ang.sin()?,
        object_cos: ang.cos()?.reshape((o, k, pairs))?.mean(1)?,
        object_sin: ang.sin()?.reshape((o, k, pairs))?.mean(1)?,
        object_summary,
    })
}

/// The pose-dependent inputs of the pass `inp` with the values the host computed and the
/// derivatives of [`graph_inputs`] (see the module docs).
pub(crate) fn pose_inputs(
    cfg: &ModelConfig,
    requests: &[SceneRequest<'_>],
    placed: &[ScenePoints],
    inp: &BatchInputs,
    now: &PoseTensors,
    before: &PoseTensors,
    device: &Device,
) -> Result<PoseInputs, ModelError> {
    let g = graph_inputs(cfg, requests, placed, inp, now, before, device)?;
    let st = |host: &[f32], graph: &Tensor| -> candle_core::Result<Tensor> {
        straight_through(&host_tensor(device, host, graph.dims())?, graph)
    };
    Ok(PoseInputs {
        feats: st(&inp.feats, &g.feats)?,
        group_rel: st(&inp.group_rel, &g.group_rel)?,
        centre_rel: st(&inp.centre_rel, &g.centre_rel)?,
        anchor_rel: st(&inp.anchor_rel, &g.anchor_rel)?,
        anchor_rope: st(&inp.anchor_rope, &g.anchor_rope)?,
        anchor_cos: st(&inp.anchor_cos, &g.anchor_cos)?,
        anchor_sin: st(&inp.anchor_sin, &g.anchor_sin)?,
        object_cos: st(&inp.object_cos, &g.object_cos)?,
        object_sin: st(&inp.object_sin, &g.object_sin)?,
        object_summary: match &g.object_summary {
            Some(graph) => Some(st(&inp.object_summary, graph)?),
            None => None,
        },
    })
}

/// The approach features `[P, 3]` (`[closing, reach, depth]`, as
/// [`super::features::approach_features`]) from the contact velocity `cv [P, 3]`, the
/// reached surface's normal `m [P, 3]` and the height above it `gap [P, 1]`, with the host's
/// branches (`host_gap [P]`).
fn approach(
    l: &Layout,
    cv: &Tensor,
    m: &Tensor,
    gap: &Tensor,
    host_gap: &[f32],
    radius: f32,
    device: &Device,
) -> Result<Tensor, ModelError> {
    let pts = l.div.len();
    let div = host_tensor(device, &l.div, &[pts, 1])?;
    let closing = dot(cv, m)?; // [P, 1]
    let travel = (&closing * &div)?;
    let closing_host: Vec<f32> = closing.detach().flatten_all()?.to_vec1()?;
    let (mut ratio, mut one, mut deep, mut capped) = (
        vec![0f32; pts],
        vec![0f32; pts],
        vec![0f32; pts],
        vec![0f32; pts],
    );
    let mut reached = vec![0f32; pts];
    for q in 0..pts {
        if l.is_point[q] + l.is_ground[q] == 0.0 {
            one[q] = 1.0; // nothing near: [0, 1, 0]
            continue;
        }
        reached[q] = 1.0;
        let (h, tr) = (host_gap[q], closing_host[q] * l.div[q]);
        if h > 0.0 {
            if tr > h {
                ratio[q] = 1.0;
            } else {
                one[q] = 1.0;
            }
        }
        let depth = tr - h;
        if depth > 0.0 && depth < radius {
            deep[q] = 1.0;
        } else if depth >= radius {
            capped[q] = 1.0;
        }
    }
    let c = |v: &[f32]| host_tensor(device, v, &[pts, 1]);
    let ratio = c(&ratio)?;
    let safe = (&travel + (1.0 - &ratio)?)?;
    let reach = ((gap / safe)?.broadcast_mul(&ratio)? + c(&one)?)?;
    let depth = ((&travel - gap)? / &div)?.broadcast_mul(&c(&deep)?)?;
    let cap: Vec<f32> = (0..pts).map(|q| radius / l.div[q]).collect();
    let depth = (depth + (c(&cap)? * c(&capped)?)?)?;
    let closing = closing.broadcast_mul(&c(&reached)?)?;
    let out = Tensor::cat(&[closing, reach, depth], 1)?;
    debug_assert_eq!(out.dim(1)?, APPROACH_FEATURES);
    Ok(out)
}

/// The object state summary `[O, 14]` ([`super::features::object_summary`]) as a function of
/// the points `x`, `x_prev` (`[P, 3]`) and poses, the lowest point the host's. The rotation
/// term is the skew part of `R_t R_{t-k}^T` scaled by the host's `angle / sin(angle)`: exact
/// at zero turn, its derivative off by `O(angle^2)` otherwise.
fn object_summary(
    cfg: &ModelConfig,
    l: &Layout,
    x: &Tensor,
    x_prev: &Tensor,
    now: &PoseTensors,
    before: &PoseTensors,
    device: &Device,
) -> Result<Tensor, ModelError> {
    let o = l.lowest.len();
    let lowest = host_index(device, &l.lowest)?;
    let inv_div: Vec<f32> = l.lowest.iter().map(|&r| l.inv_div[r as usize]).collect();
    let inv_div = host_tensor(device, &inv_div, &[o, 1])?;
    let low = x.index_select(&lowest, 0)?;
    let low_prev = x_prev.index_select(&lowest, 0)?;
    let height = |z: &Tensor, host: &[f32]| -> candle_core::Result<Tensor> {
        match cfg.ground_z {
            Some(ground) => {
                let open: Vec<f32> = host
                    .iter()
                    .map(|h| ((h - ground) < SUMMARY_HEIGHT_MAX) as u8 as f32)
                    .collect();
                let open = host_tensor(device, &open, &[o, 1])?;
                (z - f64::from(ground))?.broadcast_mul(&open)? / f64::from(SUMMARY_HEIGHT_SCALE)
            }
            None => z.zeros_like(),
        }
    };
    let low_z: Vec<f32> = low.narrow(1, 2, 1)?.detach().flatten_all()?.to_vec1()?;
    let centre_z: Vec<f32> = now
        .trans
        .narrow(1, 2, 1)?
        .detach()
        .flatten_all()?
        .to_vec1()?;
    let inc_scale = 1.0 / f64::from(SUMMARY_INCREMENT_SCALE);
    let h_low = height(&low.narrow(1, 2, 1)?, &low_z)?;
    let inc_low = ((low - &low_prev)?.broadcast_mul(&inv_div)? * inc_scale)?;
    let h_centre = height(&now.trans.narrow(1, 2, 1)?, &centre_z)?;
    let inc_centre = ((&now.trans - &before.trans)?.broadcast_mul(&inv_div)? * inc_scale)?;
    // The turn over the last step: vee((M - M^T) / 2) = sin(angle) axis, M = R_t R_{t-k}^T.
    let turn = now.rot.matmul(&before.rot.transpose(1, 2)?)?;
    let skew = ((&turn - turn.transpose(1, 2)?)? * 0.5)?;
    let e = |r: usize, c: usize| skew.narrow(1, r, 1)?.narrow(2, c, 1)?.reshape((o, 1));
    let sin_axis = Tensor::cat(&[e(2, 1)?, e(0, 2)?, e(1, 0)?], 1)?; // [O, 3]
    let sin_host: Vec<f32> = sin_axis.detach().flatten_all()?.to_vec1()?;
    let trace: Vec<f32> = turn
        .detach()
        .to_vec3::<f32>()?
        .iter()
        .map(|m| m[0][0] + m[1][1] + m[2][2])
        .collect();
    let scale: Vec<f32> = (0..o)
        .map(|j| {
            let sin = sin_host[3 * j..3 * j + 3]
                .iter()
                .map(|v| v * v)
                .sum::<f32>()
                .sqrt();
            let angle = sin.atan2((trace[j] - 1.0) / 2.0);
            if sin > 1e-6 { angle / sin } else { 1.0 }
        })
        .collect();
    let rotation = sin_axis
        .broadcast_mul(&host_tensor(device, &scale, &[o, 1])?)?
        .broadcast_mul(&inv_div)?
        .affine(1.0 / f64::from(SUMMARY_ROTATION_SCALE), 0.0)?;
    let lever = ((x.index_select(&lowest, 0)? - &now.trans)? / f64::from(SUMMARY_LEVER_SCALE))?;
    let out = Tensor::cat(
        &[h_low, inc_low, h_centre, inc_centre, rotation, lever],
        D::Minus1,
    )?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use nalgebra::{UnitQuaternion, Vector3};

    use super::*;
    use crate::ObjectInput;
    use crate::api::Pose;
    use crate::prepare::prepare_scene;
    use crate::rigidformer::inputs::build_inputs_and_points;

    /// `n` points spread over the surface of a cube of half extent `h`, deterministic.
    fn cloud(n: usize, h: f32, salt: u32) -> Vec<[f32; 3]> {
        (0..n as u32)
            .map(|i| {
                let u = |k: u32| {
                    let v = (i.wrapping_mul(2654435761) ^ (k + salt).wrapping_mul(40503))
                        .wrapping_mul(2246822519);
                    (v >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0
                };
                let mut p = [u(1) * h, u(2) * h, u(3) * h];
                let axis = (i % 3) as usize;
                p[axis] = if i % 2 == 0 { h } else { -h };
                p
            })
            .collect()
    }

    fn pose(t: [f32; 3], angle: f32, axis: Vector3<f32>) -> Pose {
        Pose::from_parts(
            Vector3::from(t),
            UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle),
        )
    }

    /// Two moving, turning cubes 2 cm apart near the floor (every kind of contact: the other
    /// cube, the floor, nothing) and a third in the air: every input the graph rebuilds has the
    /// host's value, so its derivative is that of the host's function given the host's choices.
    #[test]
    fn the_graph_rebuilds_the_host_inputs() {
        let mut cfg = ModelConfig::tiny();
        let d = &mut cfg.dynamics;
        (d.contact_velocity, d.surface_normals, d.approach) = (true, true, true);
        (
            d.object_summary,
            d.translation_invariant,
            d.rigid_extrapolation,
        ) = (true, true, true);
        cfg.normalization = crate::FeatureNormalization::defaults_for(&cfg.dynamics);
        check_differentiable(&cfg).unwrap();
        let objects: Vec<ObjectInput> = (0..3)
            .map(|j| ObjectInput {
                reference: cloud(80 + 16 * j, 0.1, j as u32),
                mass: 1.0 + j as f32,
                friction: 0.5,
                restitution: 0.3,
                kinematic: j == 1,
            })
            .collect();
        let scene = prepare_scene(&cfg, objects).unwrap();
        let z = Vector3::z_axis().into_inner();
        let tilt = Vector3::new(0.3, -0.2, 1.0);
        let current = vec![
            pose([0.0, 0.0, 0.104], 0.05, z),
            pose([0.22, 0.03, 0.12], 0.3, tilt),
            pose([2.0, 1.0, 1.5], 1.0, tilt),
        ];
        let previous = vec![
            pose([-0.01, 0.002, 0.11], 0.02, z),
            pose([0.25, 0.03, 0.121], 0.27, tilt),
            pose([2.0, 1.0, 1.52], 0.9, tilt),
        ];
        let requests = [SceneRequest {
            scene: &scene,
            previous: previous.clone(),
            current: current.clone(),
            earlier: None,
            dt_steps: 2,
        }];
        let (inp, placed) = build_inputs_and_points(&cfg, &requests).unwrap();
        let device = Device::Cpu;
        let tensors = |poses: &[Pose]| {
            let (mut rot, mut trans) = (Vec::new(), Vec::new());
            for p in poses {
                let (r, t) = super::super::features::rotation_translation(p);
                rot.extend((0..9).map(|i| r[(i / 3, i % 3)]));
                trans.extend([t.x, t.y, t.z]);
            }
            PoseTensors {
                rot: host_tensor(&device, &rot, &[poses.len(), 3, 3]).unwrap(),
                trans: host_tensor(&device, &trans, &[poses.len(), 3]).unwrap(),
            }
        };
        let g = graph_inputs(
            &cfg,
            &requests,
            &placed,
            &inp,
            &tensors(&current),
            &tensors(&previous),
            &device,
        )
        .unwrap();
        let worst = |name: &str, host: &[f32], graph: &Tensor| {
            let graph: Vec<f32> = graph.flatten_all().unwrap().to_vec1().unwrap();
            assert_eq!(host.len(), graph.len(), "{name}");
            let (i, d) = host
                .iter()
                .zip(&graph)
                .map(|(a, b)| (a - b).abs())
                .enumerate()
                .fold((0, 0f32), |w, (i, d)| if d > w.1 { (i, d) } else { w });
            assert!(d < 2e-4, "{name}[{i}]: host {} graph {}", host[i], graph[i]);
        };
        worst("feats", &inp.feats, &g.feats);
        worst("group_rel", &inp.group_rel, &g.group_rel);
        worst("centre_rel", &inp.centre_rel, &g.centre_rel);
        worst("anchor_rel", &inp.anchor_rel, &g.anchor_rel);
        worst("anchor_rope", &inp.anchor_rope, &g.anchor_rope);
        worst("anchor_cos", &inp.anchor_cos, &g.anchor_cos);
        worst("anchor_sin", &inp.anchor_sin, &g.anchor_sin);
        worst("object_cos", &inp.object_cos, &g.object_cos);
        worst("object_sin", &inp.object_sin, &g.object_sin);
        worst(
            "object_summary",
            &inp.object_summary,
            g.object_summary.as_ref().unwrap(),
        );
        // Every kind of contact occurred.
        let l = layout(&cfg, &requests, &placed, &inp);
        let points = l.is_point.iter().sum::<f32>();
        let ground = l.is_ground.iter().sum::<f32>();
        assert!(points > 0.0 && ground > 0.0 && points + ground < l.div.len() as f32);
    }
}
