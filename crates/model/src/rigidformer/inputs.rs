//! Per-scene input assembly: world points, the per-point features (contact displacement,
//! per-step increment, offset from the reference cloud, physical parameters, optionally the
//! contact velocity), encoder
//! grouping geometry, anchor kinematics and ARoPE descriptors, laid out for one batched pass.
//! Scenes are processed in parallel with rayon; objects are laid out scene-major, and the
//! per-point rows are packed without padding (the point MLP never sees a padding row).

use nalgebra::{Matrix3, Vector3};

use super::base_prediction::{floor_lift, verlet_base};
use super::batch::{BatchInputs, SceneRequest};
use super::features::{
    Body, FeatureFrame, ScenePoints, contact_summary, nearest_object_gap, object_summary,
    rotation_translation as rot,
};
use super::projection::free_fall;
use super::wrench::wrench_geometry;
use crate::{ModelConfig, ModelError, team};
use dynaserve_geometry::ContactSource;

/// ARoPE frequencies (radians per metre): `rope_dim / 6` per axis, log-spaced.
pub(crate) fn rope_frequencies(cfg: &ModelConfig) -> Vec<f32> {
    let f = cfg.rope_dim / 6;
    (0..f)
        .map(|i| {
            if f == 1 {
                cfg.rope_freq_min
            } else {
                let t = i as f32 / (f - 1) as f32;
                cfg.rope_freq_min * (cfg.rope_freq_max / cfg.rope_freq_min).powf(t)
            }
        })
        .collect()
}

/// Rotary angles of a position: `[x f.., y f.., z f..]`.
fn angles(p: &[f32; 3], freqs: &[f32], out: &mut Vec<f32>) {
    out.clear();
    for c in p {
        for f in freqs {
            out.push(c * f);
        }
    }
}

/// One scene's share of the per-point and per-object buffers that vary in length (the large
/// fixed-size ones, features, AVP distances and point mask, are written in place).
struct SceneChunk {
    group_idx: Vec<u32>,
    group_rel: Vec<f32>,
    centre_rel: Vec<f32>,
    anchor_idx: Vec<u32>,
    anchor_rel: Vec<f32>,
    anchor_rope: Vec<f32>,
    anchor_cos: Vec<f32>,
    anchor_sin: Vec<f32>,
    object_cos: Vec<f32>,
    object_sin: Vec<f32>,
    object_summary: Vec<f32>,
    contact_summary: Vec<f32>,
    point_lever: Vec<f32>,
    anchor_spin: Vec<f32>,
    contact_rows: Vec<u32>,
    partner_row: Vec<u32>,
    partner_levers: Vec<f32>,
    anchors_base: Vec<Vec<[f64; 3]>>,
    anchors_ref: Vec<Vec<[f64; 3]>>,
    floor_lift: Vec<f64>,
    object_gap: Vec<f32>,
}

/// A scene's rows of the batch's fixed-size buffers: features `[points, F]` and point mask
/// `[m, nmax]`.
struct SceneRows<'b> {
    feats: &'b mut [f32],
    point_mask: &'b mut [f32],
}

/// Builds the inputs of one batched pass. Checks that every scene was prepared for `cfg`.
pub(crate) fn build_inputs<'a>(
    cfg: &ModelConfig,
    requests: &[SceneRequest<'a>],
) -> Result<BatchInputs<'a>, ModelError> {
    Ok(build_inputs_and_points(cfg, requests)?.0)
}

/// [`build_inputs`], also returning every scene's [`ScenePoints`] (world points and contact
/// search), in request order, for a caller that reads the contacts again (a gradient pass).
pub(crate) fn build_inputs_and_points<'a>(
    cfg: &ModelConfig,
    requests: &[SceneRequest<'a>],
) -> Result<(BatchInputs<'a>, Vec<ScenePoints>), ModelError> {
    let key = cfg.prepared_key();
    if requests.iter().any(|r| r.scene.key != key) {
        return Err(ModelError::Internal(
            "scene prepared for another model reached the network".into(),
        ));
    }
    let b = requests.len();
    let mmax = requests.iter().map(|r| r.scene.len()).max().unwrap_or(0);
    let nmax = requests
        .iter()
        .flat_map(|r| r.scene.objects.iter().map(|o| o.reference.len()))
        .max()
        .unwrap_or(0);
    let mut scene_offsets = Vec::with_capacity(b + 1);
    scene_offsets.push(0);
    for r in requests {
        scene_offsets.push(scene_offsets.last().copied().unwrap_or(0) + r.scene.len());
    }
    let o = scene_offsets[b];
    let mut point_offsets = Vec::with_capacity(o + 1);
    point_offsets.push(0usize);
    for r in requests {
        for obj in &r.scene.objects {
            point_offsets.push(point_offsets[point_offsets.len() - 1] + obj.reference.len());
        }
    }
    let points = point_offsets[o];
    let mut pad_idx = vec![points as u32; o * nmax];
    for (obj, slots) in pad_idx.chunks_mut(nmax.max(1)).enumerate().take(o) {
        let (first, last) = (point_offsets[obj], point_offsets[obj + 1]);
        for (slot, row) in slots.iter_mut().zip(first..last) {
            *slot = row as u32;
        }
    }
    let freqs = rope_frequencies(cfg);
    // The large fixed-size buffers are allocated once and each scene writes its own rows.
    let nf = cfg.point_features();
    let mut feats = vec![0f32; points * nf];
    let mut point_mask = vec![0f32; o * nmax];
    let mut rows = Vec::with_capacity(b);
    let (mut f, mut pm) = (&mut feats[..], &mut point_mask[..]);
    for r in requests {
        let m = r.scene.len();
        let (f0, f1) = std::mem::take(&mut f).split_at_mut(r.scene.total_points() * nf);
        let (p0, p1) = std::mem::take(&mut pm).split_at_mut(m * nmax);
        rows.push(SceneRows {
            feats: f0,
            point_mask: p0,
        });
        (f, pm) = (f1, p1);
    }
    // Scenes over rayon's pool; one scene runs here (`team::map_pooled`).
    let scenes: Vec<_> = requests.iter().zip(&scene_offsets).zip(rows).collect();
    let (chunks, placed): (Vec<_>, Vec<_>) = team::map_pooled(scenes, 2, |((r, &first), rows)| {
        let points = scene_points(cfg, r);
        let chunks = scene_chunk(cfg, r, &points, point_offsets[first], nmax, &freqs, rows);
        (chunks, points)
    })
    .into_iter()
    .unzip();
    let mut inp = BatchInputs {
        b,
        mmax,
        nmax,
        o,
        scene_offsets,
        points,
        feats,
        pad_idx,
        object_points: point_offsets
            .windows(2)
            .map(|w| (w[0], w[1] - w[0]))
            .collect(),
        group_idx: Vec::new(),
        group_rel: Vec::new(),
        centre_rel: Vec::new(),
        anchor_d2: requests
            .iter()
            .flat_map(|r| r.scene.objects.iter().map(|obj| obj.anchor_d2.as_slice()))
            .collect(),
        point_mask,
        anchor_idx: Vec::new(),
        anchor_rel: Vec::new(),
        anchor_rope: Vec::new(),
        anchor_cos: Vec::new(),
        anchor_sin: Vec::new(),
        object_cos: Vec::new(),
        object_sin: Vec::new(),
        tau: requests
            .iter()
            .map(|r| (r.dt_steps as f32).log2())
            .collect(),
        object_dt: requests
            .iter()
            .flat_map(|r| std::iter::repeat_n(r.dt_steps, r.scene.len()))
            .collect(),
        object_summary: Vec::new(),
        contact_summary: Vec::new(),
        point_lever: Vec::new(),
        anchor_spin: Vec::new(),
        contact_rows: Vec::new(),
        partner_row: Vec::new(),
        partner_levers: Vec::new(),
        anchors_base: Vec::with_capacity(o),
        anchors_ref: Vec::with_capacity(o),
        floor_lift: Vec::new(),
        free_flight: if cfg.dynamics.free_flight_gate {
            requests
                .iter()
                .flat_map(|r| super::free_flight::free_flight(cfg, r))
                .collect()
        } else {
            Vec::new()
        },
        floor_clouds: if cfg.floor_projection.is_some() && cfg.ground_z.is_some() {
            requests
                .iter()
                .flat_map(|r| r.scene.objects.iter())
                .map(|obj| (!obj.kinematic).then_some(obj.reference.as_slice()))
                .collect()
        } else {
            Vec::new()
        },
        current_rot: requests
            .iter()
            .flat_map(|r| r.current.iter().map(|p| p.rotation))
            .collect(),
        object_gap: Vec::with_capacity(o),
        pose_inputs: None,
    };
    for c in chunks.into_iter().flatten() {
        inp.group_idx.extend(c.group_idx);
        inp.group_rel.extend(c.group_rel);
        inp.centre_rel.extend(c.centre_rel);
        inp.anchor_idx.extend(c.anchor_idx);
        inp.anchor_rel.extend(c.anchor_rel);
        inp.anchor_rope.extend(c.anchor_rope);
        inp.anchor_cos.extend(c.anchor_cos);
        inp.anchor_sin.extend(c.anchor_sin);
        inp.object_cos.extend(c.object_cos);
        inp.object_sin.extend(c.object_sin);
        inp.object_summary.extend(c.object_summary);
        inp.contact_summary.extend(c.contact_summary);
        inp.point_lever.extend(c.point_lever);
        inp.anchor_spin.extend(c.anchor_spin);
        inp.contact_rows.extend(c.contact_rows);
        inp.partner_row.extend(c.partner_row);
        inp.partner_levers.extend(c.partner_levers);
        inp.anchors_base.extend(c.anchors_base);
        inp.anchors_ref.extend(c.anchors_ref);
        inp.floor_lift.extend(c.floor_lift);
        inp.object_gap.extend(c.object_gap);
    }
    Ok((inp, placed))
}

/// A scene's world points at t and t-1 (t-2 for history) and their contacts, as the model
/// with `cfg` reads them for the step `r`.
fn scene_points(cfg: &ModelConfig, r: &SceneRequest<'_>) -> ScenePoints {
    let scene = r.scene;
    let bodies: Vec<Body<'_>> = scene
        .objects
        .iter()
        .map(|o| Body {
            reference: &o.reference,
            params: o.params,
        })
        .collect();
    ScenePoints::for_model(
        cfg,
        &bodies,
        || scene.objects.iter().map(|o| o.normals.as_slice()).collect(),
        &r.current,
        &r.previous,
        r.earlier.as_deref(),
        r.dt_steps,
    )
}

/// Points of a scene from which its objects' rows are built in parts over the compute team
/// ([`team`]; a one-scene step).
const TEAM_MIN_POINTS: usize = 1024;

/// One scene's inputs from its world points and contacts (`points`): every object's rows,
/// objects split over the compute team for a large scene outside a scene group. Chunks in
/// object order.
fn scene_chunk(
    cfg: &ModelConfig,
    r: &SceneRequest<'_>,
    points: &ScenePoints,
    first_point: usize,
    nmax: usize,
    freqs: &[f32],
    rows: SceneRows<'_>,
) -> Vec<SceneChunk> {
    let scene = r.scene;
    let m = scene.len();
    let poses: Vec<_> = r.current.iter().map(rot).collect();
    let centroids = scene
        .objects
        .iter()
        .zip(&poses)
        .map(|(o, (rc, pc))| rc * Vector3::from(o.centroid) + pc)
        .collect();
    let ctx = ObjectContext {
        cfg,
        r,
        points,
        poses,
        centroids,
        poses_prev: r.previous.iter().map(rot).collect(),
        first_point,
        nmax,
        freqs,
    };
    if m < 2 || scene.total_points() < TEAM_MIN_POINTS || team::parts() < 2 {
        return vec![ctx.objects(0..m, rows.feats, rows.point_mask)];
    }
    // One run of objects per part of the team, each with its own rows of both buffers.
    let (nf, offsets, parts) = (cfg.point_features(), &points.offsets, team::parts());
    let mut pieces = Vec::with_capacity(parts);
    let (mut feats, mut mask) = (rows.feats, rows.point_mask);
    for part in 0..parts {
        let objs = team::part_range(m, part, parts, 1);
        let (f, f_rest) = feats.split_at_mut((offsets[objs.end] - offsets[objs.start]) * nf);
        let (pm, pm_rest) = mask.split_at_mut(objs.len() * nmax);
        pieces.push((objs, f, pm));
        (feats, mask) = (f_rest, pm_rest);
    }
    team::map_items(pieces, |(objs, f, pm)| ctx.objects(objs, f, pm))
}

/// What every object's rows of one scene read.
struct ObjectContext<'a> {
    cfg: &'a ModelConfig,
    r: &'a SceneRequest<'a>,
    points: &'a ScenePoints,
    poses: Vec<(Matrix3<f32>, Vector3<f32>)>,
    /// Every object's centroid in the world at t, metres.
    centroids: Vec<Vector3<f32>>,
    poses_prev: Vec<(Matrix3<f32>, Vector3<f32>)>,
    first_point: usize,
    nmax: usize,
    freqs: &'a [f32],
}

impl ObjectContext<'_> {
    /// Rows of objects `objs`: their features (`feats`, from the first object's first point)
    /// and point mask (`point_mask`, from the first object's row) written in place, the rest
    /// returned.
    fn objects(
        &self,
        objs: std::ops::Range<usize>,
        feats: &mut [f32],
        point_mask: &mut [f32],
    ) -> SceneChunk {
        let (cfg, r, freqs) = (self.cfg, self.r, self.freqs);
        let (first_point, nmax) = (self.first_point, self.nmax);
        let scene = r.scene;
        let m = objs.len();
        let (k, s, g) = (cfg.anchors, cfg.sa_centres, cfg.sa_neighbours);
        let p = cfg.rope_dim / 2;
        let inv_scale = 1.0 / cfg.position_scale;
        let norm = &cfg.normalization;
        let nf = cfg.point_features();
        let rigid = cfg.dynamics.rigid_extrapolation;
        let points = self.points;
        let (world, offsets) = (&points.world, &points.offsets);
        let (row0, mask0) = (offsets[objs.start], objs.start);
        let mut c = SceneChunk {
            group_idx: Vec::with_capacity(m * s * g),
            group_rel: Vec::with_capacity(m * s * g * 3),
            centre_rel: Vec::with_capacity(m * s * 3),
            anchor_idx: Vec::with_capacity(m * k),
            anchor_rel: Vec::with_capacity(m * k * 3),
            anchor_rope: Vec::with_capacity(m * k * 2 * p),
            anchor_cos: Vec::with_capacity(m * k * p),
            anchor_sin: Vec::with_capacity(m * k * p),
            object_cos: Vec::with_capacity(m * p),
            object_sin: Vec::with_capacity(m * p),
            object_summary: Vec::new(),
            contact_summary: Vec::new(),
            point_lever: Vec::new(),
            anchor_spin: Vec::new(),
            contact_rows: Vec::new(),
            partner_row: Vec::new(),
            partner_levers: Vec::new(),
            anchors_base: Vec::with_capacity(m),
            anchors_ref: Vec::with_capacity(m),
            floor_lift: Vec::new(),
            object_gap: Vec::with_capacity(m),
        };
        let mut ang = Vec::with_capacity(3 * freqs.len());
        // Normalisation as a multiply by the inverse deviation over fixed-length slices: the
        // compiler vectorises it (a division per feature was 2% of a batch-8 step).
        let (mean, inv_std): (&[f32], Vec<f32>) = (
            &norm.mean[..nf],
            norm.std[..nf].iter().map(|s| 1.0 / s).collect(),
        );
        for j in objs {
            let obj = &scene.objects[j];
            let n = obj.reference.len();
            let base = offsets[j];
            let (rc, pc) = self.poses[j];
            let wc = self.centroids[j];
            let frame = FeatureFrame::new(&cfg.dynamics, r.dt_steps, r.current[j].translation);
            if cfg.dynamics.object_summary {
                c.object_summary.extend(object_summary(
                    &world[base..base + n],
                    &points.world_prev[base..base + n],
                    &r.current[j],
                    &r.previous[j],
                    cfg.ground_z,
                    &frame,
                ));
            }
            let gap = nearest_object_gap(&points.contact, base..base + n);
            c.object_gap.push(gap);
            if cfg.dynamics.contact_summary {
                c.contact_summary.extend(contact_summary(
                    &points.contact,
                    world,
                    &points.world_prev,
                    base..base + n,
                    r.current[j].translation,
                    gap,
                    cfg.contact_radius,
                    &frame,
                ));
            }
            // Per-point features.
            for i in 0..n {
                let row = base + i - row0;
                let dst = &mut feats[row * nf..(row + 1) * nf];
                points.raw_features(
                    base + i,
                    obj.reference[i],
                    obj.params,
                    &frame,
                    &cfg.dynamics,
                    dst,
                );
                for ((v, m), is) in dst.iter_mut().zip(mean).zip(&inv_std) {
                    *v = (*v - m) * is;
                }
                point_mask[(j - mask0) * nmax + i] = 1.0;
            }
            if cfg.dynamics.contact_messages {
                self.partners(base..base + n, wc, &mut c);
            }
            // Encoder grouping.
            for (ci, &centre) in obj.centres.iter().enumerate() {
                let cw = world[base + centre];
                for d in 0..3 {
                    c.centre_rel.push((cw[d] - wc[d]) * inv_scale);
                }
                for &nb in &obj.neighbours[ci * g..(ci + 1) * g] {
                    c.group_idx.push((first_point + base + nb) as u32);
                    let nw = world[base + nb];
                    for d in 0..3 {
                        c.group_rel.push((nw[d] - cw[d]) * inv_scale);
                    }
                }
            }
            // Anchors.
            let (rp, pp) = self.poses_prev[j];
            let now64 = (rc.cast::<f64>(), pc.cast::<f64>());
            let before64 = (rp.cast::<f64>(), pp.cast::<f64>());
            let mut ab = Vec::with_capacity(k);
            let mut ar = Vec::with_capacity(k);
            let mut mean_cos = vec![0f32; p];
            let mut mean_sin = vec![0f32; p];
            for &a in &obj.anchors {
                c.anchor_idx.push((first_point + base + a) as u32);
                let w = world[base + a];
                for d in 0..3 {
                    c.anchor_rel.push((w[d] - wc[d]) * inv_scale);
                }
                angles(&w, freqs, &mut ang);
                let cos: Vec<f32> = ang.iter().map(|t| t.cos()).collect();
                let sin: Vec<f32> = ang.iter().map(|t| t.sin()).collect();
                for i in 0..p {
                    mean_cos[i] += cos[i] / k as f32;
                    mean_sin[i] += sin[i] / k as f32;
                }
                if cfg.dynamics.translation_invariant {
                    // The query's own positional features: relative to the object's centroid.
                    let rel = [w[0] - wc[0], w[1] - wc[1], w[2] - wc[2]];
                    angles(&rel, freqs, &mut ang);
                    c.anchor_rope.extend(ang.iter().map(|t| t.cos()));
                    c.anchor_rope.extend(ang.iter().map(|t| t.sin()));
                } else {
                    c.anchor_rope.extend_from_slice(&cos);
                    c.anchor_rope.extend_from_slice(&sin);
                }
                c.anchor_cos.extend_from_slice(&cos);
                c.anchor_sin.extend_from_slice(&sin);
                // Anchor kinematics in f64 for Verlet and Kabsch.
                let x = Vector3::from(obj.reference[a]).cast::<f64>();
                ab.push(verlet_base(
                    rigid,
                    &x,
                    (&now64.0, &now64.1),
                    (&before64.0, &before64.1),
                ));
                ar.push([x.x, x.y, x.z]);
            }
            if let (true, Some(ground)) = (cfg.dynamics.floor_base, cfg.ground_z) {
                let fall = free_fall(cfg, r.dt_steps);
                c.floor_lift.push(floor_lift(
                    &obj.reference,
                    (&now64.0, &now64.1),
                    (&before64.0, &before64.1),
                    fall[2] + f64::from(-ground),
                ));
            }
            c.object_cos.extend(mean_cos);
            c.object_sin.extend(mean_sin);
            c.anchors_base.push(ab);
            c.anchors_ref.push(ar);
            if cfg.dynamics.contact_wrench {
                // The anchor offsets just pushed, about the same world centroid.
                let rel = &c.anchor_rel[c.anchor_rel.len() - 3 * k..];
                let (levers, spin) = wrench_geometry(
                    &world[base..base + n],
                    wc,
                    rel,
                    &obj.inertia_inv,
                    &rc,
                    inv_scale,
                );
                c.point_lever.extend(levers);
                c.anchor_spin.extend(spin);
            }
        }
        c
    }

    /// Appends the contacts ([`BatchInputs::contact_rows`], partner rows and lever arms) of
    /// the scene's points `range`, all of one object whose world centroid is `centroid`.
    fn partners(&self, range: std::ops::Range<usize>, centroid: Vector3<f32>, c: &mut SceneChunk) {
        let (points, inv_scale) = (self.points, 1.0 / self.cfg.position_scale);
        let lever =
            |q: usize, centre: &Vector3<f32>| (Vector3::from(points.world[q]) - centre) * inv_scale;
        for q in range {
            if let ContactSource::Point(other) = points.contact[q].source {
                let other = other as usize;
                // The object holding point `other`: the last one starting at or before it.
                let obj = points.offsets.partition_point(|&start| start <= other) - 1;
                c.contact_rows.push((self.first_point + q) as u32);
                c.partner_row.push((self.first_point + other) as u32);
                c.partner_levers
                    .extend_from_slice(lever(q, &centroid).as_slice());
                c.partner_levers
                    .extend_from_slice(lever(other, &self.centroids[obj]).as_slice());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{UnitQuaternion, Vector3};

    use super::*;
    use crate::ObjectInput;
    use crate::api::Pose;
    use crate::config::BASE_POINT_FEATURES;
    use crate::prepare::prepare_scene;

    /// 96 points on the surface of a cube of half extent 0.1 m (a 4 x 4 grid on each face).
    fn cube() -> Vec<[f32; 3]> {
        let g = [-0.075f32, -0.025, 0.025, 0.075];
        let mut out = Vec::new();
        for axis in 0..3 {
            for side in [-0.1f32, 0.1] {
                for a in g {
                    for b in g {
                        let mut p = [a, b, a];
                        p[axis] = side;
                        p[(axis + 1) % 3] = a;
                        p[(axis + 2) % 3] = b;
                        out.push(p);
                    }
                }
            }
        }
        out
    }

    /// A body spinning at a constant rate about a tilted axis while its centre moves at a
    /// constant velocity: the rigid base puts every anchor exactly where the motion takes it;
    /// the linear base does not, and after a Kabsch fit it lags the turn by about
    /// `5/6 theta^3`.
    #[test]
    fn rigid_base_continues_a_spin_and_the_linear_base_lags_it() {
        let theta = 0.6f64; // radians per step
        let axis = nalgebra::Unit::new_normalize(Vector3::new(0.3, -0.2, 1.0));
        let turn = nalgebra::Rotation3::from_axis_angle(&axis, theta);
        let r_prev = nalgebra::Rotation3::from_euler_angles(0.1, 0.2, 0.3);
        let (r_now, r_next) = (turn * r_prev, turn * turn * r_prev);
        let (p_prev, p_now) = (Vector3::new(0.0, 0.0, 1.0), Vector3::new(0.1, -0.05, 1.02));
        let p_next = p_now * 2.0 - p_prev;
        let anchors: Vec<Vector3<f64>> = cube()
            .iter()
            .step_by(12)
            .map(|x| Vector3::from(*x).cast::<f64>())
            .collect();
        let base = |rigid: bool| -> Vec<[f64; 3]> {
            anchors
                .iter()
                .map(|x| {
                    verlet_base(
                        rigid,
                        x,
                        (r_now.matrix(), &p_now),
                        (r_prev.matrix(), &p_prev),
                    )
                })
                .collect()
        };
        let reference: Vec<[f64; 3]> = anchors.iter().map(|x| [x.x, x.y, x.z]).collect();
        for (x, b) in anchors.iter().zip(base(true)) {
            let exact = r_next * x + p_next;
            for d in 0..3 {
                assert!((b[d] - exact[d]).abs() < 1e-12, "{b:?} vs {exact:?}");
            }
        }
        let fit = dynaserve_geometry::kabsch(&reference, &base(false), None).unwrap();
        let r_fit = nalgebra::Rotation3::from_matrix_unchecked(fit.rotation);
        let lag = (r_next.inverse() * r_fit).angle();
        let expected = 5.0 / 6.0 * theta.powi(3);
        assert!(
            (lag - expected).abs() < 0.35 * expected,
            "lag {lag} rad, expected about {expected}"
        );
    }

    /// Two cubes 0.1 m apart of different masses and materials, and a third far away near the
    /// ground, through the model's input path with scene-relative mass: the points that reach
    /// the other cube read its parameters (the mass as a ratio, which the scene-wide factor
    /// leaves as is), every other point zeros.
    #[test]
    fn contact_partner_reads_the_other_cube_through_the_input_path() {
        let mut cfg = ModelConfig::tiny();
        cfg.dynamics.contact_partner = true;
        cfg.dynamics.relative_mass = true;
        cfg.normalization = crate::FeatureNormalization::defaults_for(&cfg.dynamics);
        let materials = [(2.0f32, 0.3f32, 0.6f32), (0.5, 0.9, 0.2), (1.0, 0.5, 0.5)];
        let objects: Vec<ObjectInput> = materials
            .iter()
            .map(|&(mass, friction, restitution)| ObjectInput {
                reference: cube(),
                mass,
                friction,
                restitution,
                kinematic: false,
            })
            .collect();
        let scene = prepare_scene(&cfg, objects).unwrap();
        let pose = |c: [f32; 3]| Pose::from_parts(Vector3::from(c), UnitQuaternion::identity());
        let current = vec![
            pose([0.0, 0.0, 1.0]),
            pose([0.3, 0.0, 1.0]),
            pose([5.0, 0.0, 0.15]),
        ];
        let inp = build_inputs(
            &cfg,
            &[SceneRequest {
                scene: &scene,
                previous: current.clone(),
                current,
                earlier: None,
                dt_steps: 1,
            }],
        )
        .unwrap();
        let (nf, norm) = (cfg.point_features(), &cfg.normalization);
        let col = crate::InputGroup::ContactPartner.offset(&cfg.dynamics);
        let n = cube().len();
        let mut touching = [0usize; 3];
        for row in 0..3 * n {
            let object = row / n;
            let raw: Vec<f32> = (col..col + crate::config::CONTACT_PARTNER_FEATURES)
                .map(|i| inp.feats[row * nf + i] * norm.std[i] + norm.mean[i])
                .collect();
            let want = match (object, raw[0] > 0.5) {
                (0, true) => [1.0, (0.5f32 / 2.0).ln(), 0.9, 0.2],
                (1, true) => [1.0, (2.0f32 / 0.5).ln(), 0.3, 0.6],
                _ => [0.0; 4],
            };
            touching[object] += (raw[0] > 0.5) as usize;
            assert!(
                raw.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-4),
                "object {object} row {row}: {raw:?}, expected {want:?}"
            );
        }
        assert!(
            touching[0] > 0 && touching[1] > 0 && touching[2] == 0,
            "{touching:?}"
        );
    }

    /// Two cubes 0.1 m apart closing in along x, and a third far away resting 0.05 m above the
    /// ground and sinking: points near the other cube see the closing velocity, points near
    /// the ground minus their own increment, every other point zero.
    #[test]
    fn contact_velocity_is_closing_velocity_ground_or_zero() {
        let cfg = ModelConfig::tiny();
        assert!(cfg.dynamics.contact_velocity && cfg.dynamics.per_frame_units);
        let centres = [[0.0f32, 0.0, 1.0], [0.3, 0.0, 1.0], [5.0, 0.0, 0.15]];
        // Increments over one step of k = 2 frames, metres.
        let steps = [[0.02f32, 0.0, 0.0], [-0.04, 0.0, 0.01], [0.0, 0.0, -0.03]];
        let k = 2u32;
        let objects: Vec<ObjectInput> = (0..3)
            .map(|_| ObjectInput {
                reference: cube(),
                mass: 1.0,
                friction: 0.5,
                restitution: 0.5,
                kinematic: false,
            })
            .collect();
        let scene = prepare_scene(&cfg, objects).unwrap();
        let pose = |c: [f32; 3]| Pose::from_parts(Vector3::from(c), UnitQuaternion::identity());
        let current: Vec<Pose> = centres.iter().map(|&c| pose(c)).collect();
        let previous: Vec<Pose> = (0..3)
            .map(|j| pose([0, 1, 2].map(|d| centres[j][d] - steps[j][d])))
            .collect();
        let inp = build_inputs(
            &cfg,
            &[SceneRequest {
                scene: &scene,
                previous,
                current: current.clone(),
                earlier: None,
                dt_steps: k,
            }],
        )
        .unwrap();
        let nf = cfg.point_features();
        assert_eq!(nf, 15);
        let norm = &cfg.normalization;
        // World points at t, by brute force, to classify each point's nearest surface.
        let world: Vec<Vec<[f32; 3]>> = (0..3)
            .map(|j| {
                let (r, t) = rot(&current[j]);
                scene.objects[j]
                    .reference
                    .iter()
                    .map(|x| {
                        let w = r * Vector3::from(*x) + t;
                        [w.x, w.y, w.z]
                    })
                    .collect()
            })
            .collect();
        let per_frame = |v: [f32; 3]| v.map(|c| c / k as f32);
        let mut counts = [0usize; 3];
        let mut row = 0;
        for j in 0..3 {
            for x in &world[j] {
                let nearest_other = (0..3)
                    .filter(|&o| o != j)
                    .flat_map(|o| world[o].iter().map(move |y| (o, y)))
                    .map(|(o, y)| {
                        let d2: f32 = (0..3).map(|d| (y[d] - x[d]).powi(2)).sum();
                        (d2, o)
                    })
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                let r2 = cfg.contact_radius.powi(2);
                let ground2 = x[2].powi(2);
                let expected = match nearest_other {
                    Some((d2, o)) if d2 < r2 && d2 < ground2 => {
                        counts[0] += 1;
                        let (a, b) = (per_frame(steps[o]), per_frame(steps[j]));
                        [0, 1, 2].map(|d| a[d] - b[d])
                    }
                    _ if ground2 < r2 => {
                        counts[1] += 1;
                        per_frame(steps[j]).map(|v| -v)
                    }
                    _ => {
                        counts[2] += 1;
                        [0.0; 3]
                    }
                };
                let f = &inp.feats[row * nf..(row + 1) * nf];
                for (d, want) in expected.iter().enumerate() {
                    let i = BASE_POINT_FEATURES + d;
                    let raw = f[i] * norm.std[i] + norm.mean[i];
                    assert!(
                        (raw - want).abs() < 1e-6,
                        "object {j} point {x:?}: contact velocity {d} is {raw}, expected {want}"
                    );
                }
                row += 1;
            }
        }
        assert_eq!(row, inp.points);
        assert!(
            counts.iter().all(|&c| c > 0),
            "every case occurs: {counts:?}"
        );
    }
}
