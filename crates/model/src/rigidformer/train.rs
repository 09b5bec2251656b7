//! Training forward: the network on ground-truth inputs with the differentiable kernels,
//! Verlet and the Kabsch custom op, and the loss of `docs/rigidformer.md`.

use candle_core::Tensor;

use super::RigidFormer;
use super::batch::SceneRequest;
use super::host_tensor;
use super::inputs::build_inputs;
use super::projection::{base_shift, pose_f64};
use crate::ModelError;
use crate::api::{Pose, SceneState};
use crate::config::{
    OBJECT_CONTACT_WEIGHT_DISTANCE_M, ROTATION_LEVER_ARM_M, ROTATION_MIN_RADIUS_M,
};
use crate::kernels::kabsch::KabschOp;
use crate::layers::{Mode, smooth_l1_mean};
use crate::prepare::{PreparedScene, normalise_pose, validate_state};

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
    /// Kinematic objects `[objects]` (driven along a given path, e.g. a pusher): they enter the
    /// inputs like any object but add nothing to the loss. Empty means none is kinematic.
    pub kinematic: &'a [bool],
}

/// Result of [`RigidFormer::train_forward`]. Every tensor is `[O, K, 3]` (objects of all
/// samples, scene-major, K anchors; metres or metres per step^2) unless noted; predictions carry
/// gradients.
pub struct TrainOutput {
    /// Scalar loss: weighted sum of the four Smooth L1 terms and the rotation term.
    pub loss: Tensor,
    /// The four terms `[pos_pre, acc_pre, pos_post, acc_post]`, each a scalar tensor.
    pub terms: [Tensor; 4],
    /// The rotation term (scalar, before its weight), or `None` when `loss.rotation_weight` is 0.
    pub rotation: Option<Tensor>,
    /// Predicted anchor accelerations `a` (m/step^2), before projection.
    pub accel_pre: Tensor,
    /// Anchor positions after Verlet, before projection: `base + b + a`.
    pub positions_pre: Tensor,
    /// Anchor positions after Kabsch projection: `R A_ref + p`.
    pub positions_post: Tensor,
    /// Implied accelerations after projection: `positions_post - (base + b)`.
    pub accel_post: Tensor,
    /// Rigid transforms `[O, 12]`: row-major R then p (metres).
    pub transforms: Tensor,
    /// Ground-truth anchor positions at t + dt (no gradient).
    pub target_positions: Tensor,
    /// Ground-truth accelerations `A*_{t+1} - 2A*_t + A*_{t-1}` (no gradient).
    pub target_accel: Tensor,
}

impl RigidFormer {
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
            let scene = super::prepared_for(&self.config, it.scene, &what)?;
            let state = validate_state(scene, it.state, it.dt_steps, &what)?;
            if it.target.len() != it.scene.len() {
                return Err(ModelError::InvalidInput(format!(
                    "{what}: {} target poses for {} objects",
                    it.target.len(),
                    it.scene.len()
                )));
            }
            if !it.kinematic.is_empty() && it.kinematic.len() != it.scene.len() {
                return Err(ModelError::InvalidInput(format!(
                    "{what}: {} kinematic flags for {} objects",
                    it.kinematic.len(),
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
                scene,
                previous: state.previous,
                current: state.current,
                earlier: state.earlier,
                dt_steps: it.dt_steps,
            });
        }
        let inp = build_inputs(&self.config, &requests)?;
        let accel_pre = self.network(&inp, Mode::Training, None)?; // [O, K, 3]
        let (o, k) = (inp.o, self.config.anchors);
        let flat = |v: &Vec<Vec<[f64; 3]>>| -> Vec<f32> {
            v.iter().flatten().flatten().map(|x| *x as f32).collect()
        };
        let a_base = host_tensor(&self.device, &flat(&inp.anchors_base), &[o, k, 3])?;
        let a_ref = host_tensor(&self.device, &flat(&inp.anchors_ref), &[o, k, 3])?;
        let mut tgt = Vec::with_capacity(o * k * 3);
        for (obj, pose) in targets.iter().enumerate() {
            let (rm, tv) = pose_f64(pose);
            for a in &inp.anchors_ref[obj] {
                let y = rm * nalgebra::Vector3::new(a[0], a[1], a[2]) + tv;
                tgt.extend([y.x as f32, y.y as f32, y.z as f32]);
            }
        }
        let target_positions = host_tensor(&self.device, &tgt, &[o, k, 3])?;
        // The Verlet base (+ free fall with a gravity residual, + the floor lift), per object.
        let fall: Vec<f32> = (0..o)
            .flat_map(|obj| base_shift(&self.config, &inp, obj).map(|v| v as f32))
            .collect();
        let base = a_base.broadcast_add(&host_tensor(&self.device, &fall, &[o, 1, 3])?)?;
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
        // every step size weighs the same; kinematic objects' errors are multiplied by zero.
        let learned = items.iter().flat_map(|it| {
            (0..it.scene.len()).map(|j| !it.kinematic.get(j).copied().unwrap_or(false))
        });
        // Objects at rest in the window weigh `rest_weight` times as much; moving objects
        // touching another object at t, `object_contact_weight` times.
        let resting = requests.iter().zip(items).flat_map(|(r, it)| {
            (0..it.scene.len())
                .map(move |j| at_rest([&r.previous[j], &r.current[j], &it.target[j]], it.dt_steps))
        });
        let inv: Vec<f32> = inp
            .object_dt
            .iter()
            .zip(learned)
            .zip(resting)
            .zip(&inp.object_gap)
            .map(|(((&dt, learn), rest), &gap)| {
                let w = if rest {
                    lc.rest_weight
                } else if gap <= OBJECT_CONTACT_WEIGHT_DISTANCE_M {
                    lc.object_contact_weight
                } else {
                    1.0
                };
                if learn {
                    w / (lc.scale * self.config.dynamics.output_factor(dt))
                } else {
                    0.0
                }
            })
            .collect();
        let inv = host_tensor(&self.device, &inv, &[o, 1, 1])?;
        let scaled = |a: &Tensor, b: &Tensor| -> candle_core::Result<Tensor> {
            (a - b)?.broadcast_mul(&inv)
        };
        let post_error = (&positions_post - &target_positions)?; // [O, K, 3], metres
        let terms = [
            smooth_l1_mean(&scaled(&positions_pre, &target_positions)?, lc.beta)?,
            smooth_l1_mean(&scaled(&accel_pre, &target_accel)?, lc.beta)?,
            smooth_l1_mean(&post_error.broadcast_mul(&inv)?, lc.beta)?,
            smooth_l1_mean(&scaled(&accel_post, &target_accel)?, lc.beta)?,
        ];
        let mut loss = (&terms[0] * lc.weights[0] as f64)?;
        for (term, w) in terms.iter().zip(lc.weights).skip(1) {
            loss = (loss + (term * w as f64)?)?;
        }
        let mut rotation_term = None;
        if lc.rotation_weight > 0.0 {
            // Each object's errors rescaled from its anchor radius to the common lever arm.
            let lever: Vec<f32> = inp
                .anchors_ref
                .iter()
                .map(|anchors| ROTATION_LEVER_ARM_M / anchor_radius(anchors))
                .collect();
            let lever = host_tensor(&self.device, &lever, &[o, 1, 1])?;
            let rotation = rotation_errors(&post_error)?
                .broadcast_mul(&inv)?
                .broadcast_mul(&lever)?;
            let term = smooth_l1_mean(&rotation, lc.beta)?;
            loss = (loss + (&term * lc.rotation_weight as f64)?)?;
            rotation_term = Some(term);
        }
        Ok(TrainOutput {
            loss,
            terms,
            rotation: rotation_term,
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

/// Anchor errors `[O, K, 3]` less their mean over each object's K anchors, `[O, K, 3]`: a rigid
/// error `(R - R*) a + (p - p*)` loses its translation and keeps the rotation error times each
/// anchor's offset from the anchors' centroid. Same units as the input.
pub(crate) fn rotation_errors(errors: &Tensor) -> candle_core::Result<Tensor> {
    errors.broadcast_sub(&errors.mean_keepdim(1)?)
}

/// Root-mean-square distance of one object's reference anchors from their centroid, metres,
/// at least [`ROTATION_MIN_RADIUS_M`].
pub(crate) fn anchor_radius(anchors: &[[f64; 3]]) -> f32 {
    let n = anchors.len().max(1) as f64;
    let c = (0..3).map(|i| anchors.iter().map(|a| a[i]).sum::<f64>() / n);
    let c: Vec<f64> = c.collect();
    let ms = anchors
        .iter()
        .map(|a| (0..3).map(|i| (a[i] - c[i]).powi(2)).sum::<f64>())
        .sum::<f64>()
        / n;
    (ms.sqrt() as f32).max(ROTATION_MIN_RADIUS_M)
}

/// True when the three poses `[t - k, t, t + k]` of one object lie within the resting
/// tolerances of [`crate::config::REST_TRANSLATION_PER_FRAME_M`] and
/// [`crate::config::REST_ROTATION_PER_FRAME_RAD`] per frame of each consecutive one.
pub(crate) fn at_rest(poses: [&Pose; 3], dt_steps: u32) -> bool {
    let k = dt_steps.max(1) as f32;
    poses.windows(2).all(|w| {
        let (a, b) = (w[0], w[1]);
        let d2: f32 = (0..3)
            .map(|i| (a.translation[i] - b.translation[i]).powi(2))
            .sum();
        // Angle between unit quaternions: 2 acos(|<a, b>|).
        let dot: f32 = (0..4).map(|i| a.rotation[i] * b.rotation[i]).sum();
        let angle = 2.0 * dot.abs().min(1.0).acos();
        d2.sqrt() <= crate::config::REST_TRANSLATION_PER_FRAME_M * k
            && angle <= crate::config::REST_ROTATION_PER_FRAME_RAD * k
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    /// A rigid error on two anchors `[1, 2, 3]`: a translation leaves nothing, a small rotation
    /// about z leaves `omega x (a - centroid)`.
    #[test]
    fn rotation_errors_keep_only_the_rotation() {
        let dev = Device::Cpu;
        let translation = Tensor::new(&[[[0.3f32, -0.2, 0.1], [0.3, -0.2, 0.1]]], &dev).unwrap();
        let left = rotation_errors(&translation)
            .unwrap()
            .flatten_all()
            .unwrap();
        assert!(
            left.to_vec1::<f32>()
                .unwrap()
                .iter()
                .all(|v| v.abs() < 1e-7)
        );
        // Anchors at x = +-0.1 m rotated by 0.01 rad about z move by -+0.001 m in y; a common
        // translation is added on top.
        let rotated = Tensor::new(&[[[0.5f32, 0.001, 0.0], [0.5, -0.001, 0.0]]], &dev).unwrap();
        let left = rotation_errors(&rotated).unwrap().flatten_all().unwrap();
        let v = left.to_vec1::<f32>().unwrap();
        let want = [0.0, 0.001, 0.0, 0.0, -0.001, 0.0];
        assert!(
            v.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6),
            "{v:?}"
        );
        assert!((anchor_radius(&[[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0]]) - 0.1).abs() < 1e-6);
        assert_eq!(anchor_radius(&[[0.0; 3], [0.0; 3]]), ROTATION_MIN_RADIUS_M);
    }
}
