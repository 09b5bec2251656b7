//! One training window drawn from a recorded scene: its step size, frame, object order,
//! point subsets and augmentation (rotation, mirror image, noise, patch cut, pushforward and
//! history poses).

use dynaserve_model::{ObjectInput, Pose, SceneState};
use dynaserve_sim::SceneRecord;
use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::seed::{mix, rng_for};
use crate::train::TrainError;
use crate::train::config::DataConfig;

/// One raw training window (before model preparation).
#[derive(Clone, Debug)]
pub struct Window {
    /// Objects with their (sub-sampled) body-frame clouds and parameters.
    pub objects: Vec<ObjectInput>,
    /// Observed poses at `t - dt_steps` and `t` (possibly noised), and at `t - 2 dt_steps`
    /// with [`DataConfig::history`].
    pub state: SceneState,
    /// Ground-truth poses at `t + dt_steps`.
    pub target: Vec<Pose>,
    /// Step size in frames.
    pub dt_steps: u32,
    /// Kinematic objects `[objects]` (in `objects` order): inputs only, not learned.
    pub kinematic: Vec<bool>,
    /// For a pushforward sample (`DataConfig::pushforward`), the recorded (not noised) poses
    /// at `t - (n + 1) dt_steps, ..., t - dt_steps` (`n` = `pushforward_steps`), each
    /// `[objects]`: the trainer replaces the observed poses by the model's steps from them.
    pub pushforward: Option<Vec<Vec<Pose>>>,
}

/// Random unit quaternion of angle `~ N(0, sigma)` about a random axis.
fn small_rotation(rng: &mut impl Rng, sigma: f32) -> UnitQuaternion<f32> {
    let axis = Vector3::new(
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
    );
    let n: f32 = axis.norm();
    if n < 1e-6 || sigma == 0.0 {
        return UnitQuaternion::identity();
    }
    let angle: f32 = StandardNormal.sample(rng);
    UnitQuaternion::from_scaled_axis(axis / n * (angle * sigma))
}

/// The reflection x -> -x of a point or position `[3]`, metres.
pub fn mirror_point(p: [f32; 3]) -> [f32; 3] {
    [-p[0], p[1], p[2]]
}

/// The orientation `M R M` (M = diag(-1, 1, 1)) of a body whose reference cloud and position
/// are reflected by [`mirror_point`]: with it, the reflected body's world points are the
/// reflections of the original's. A proper rotation (the quaternion's y and z parts negated),
/// so the reflected scene is again a rigid scene.
pub fn mirror_rotation(q: UnitQuaternion<f32>) -> UnitQuaternion<f32> {
    let q = q.into_inner();
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q.w, q.i, -q.j, -q.k))
}

fn quat(q: [f32; 4]) -> UnitQuaternion<f32> {
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[3], q[0], q[1], q[2]))
}

/// Draws one window from `scene` with the augmentation of `c` (input noise and pushforward
/// poses only if `noise`, i.e. for training batches). `scene_key` identifies the scene in its
/// dataset: with [`DataConfig::points_per_scene`] it seeds each object's point subset, so every
/// window of one scene shows the same clouds.
pub fn sample_window(
    scene: &SceneRecord,
    c: &DataConfig,
    rng: &mut ChaCha8Rng,
    noise: bool,
    scene_key: u64,
) -> Result<Window, TrainError> {
    let frames = scene
        .objects
        .first()
        .map(|o| o.positions.len())
        .unwrap_or(0);
    if scene.objects.is_empty() || frames < 3 {
        return Err(TrainError::Data(format!(
            "a scene with {} objects and {frames} frames cannot give a training window",
            scene.objects.len()
        )));
    }
    let valid: Vec<u32> = c
        .step_sizes
        .iter()
        .copied()
        .filter(|&k| 2 * (k as usize) < frames)
        .collect();
    let k = if valid.is_empty() {
        ((frames - 1) / 2) as u32
    } else {
        valid[rng.random_range(0..valid.len())]
    };
    let ku = k as usize;
    // The event draw happens only when enabled, so configurations without it keep their
    // sample streams.
    let weighted = noise && c.event_share > 0.0 && rng.random::<f32>() < c.event_share;
    // Likewise the stop draw, among the samples the event draw leaves.
    let stopping = noise && !weighted && c.stop_share > 0.0 && rng.random::<f32>() < c.stop_share;
    let drawn = if weighted {
        crate::train::events::draw_frame(scene, ku, rng)
    } else if stopping {
        crate::train::stops::draw_frame(scene, ku, rng)
    } else {
        None
    };
    let t = match drawn {
        Some(t) => t,
        None => rng.random_range(ku..=frames - 1 - ku),
    };
    let mut order: Vec<usize> = (0..scene.objects.len()).collect();
    if c.shuffle_objects {
        order.shuffle(rng);
    }
    let rz = if c.rotate_z {
        UnitQuaternion::from_axis_angle(
            &Vector3::z_axis(),
            rng.random_range(0.0..std::f32::consts::TAU),
        )
    } else {
        UnitQuaternion::identity()
    };
    // Drawn only with the option, so configurations without it keep their sample streams.
    let mirrored = c.mirror && rng.random::<bool>();
    let pose_at = |o: &dynaserve_sim::ObjectRecord, f: usize| -> Pose {
        let (p, q) = if mirrored {
            (
                mirror_point(o.positions[f]),
                mirror_rotation(quat(o.rotations[f])),
            )
        } else {
            (o.positions[f], quat(o.rotations[f]))
        };
        Pose::from_parts(rz * Vector3::from(p), rz * q)
    };
    let mut objects = Vec::with_capacity(order.len());
    let mut previous = Vec::with_capacity(order.len());
    let mut current = Vec::with_capacity(order.len());
    let mut earlier = Vec::with_capacity(order.len());
    // Drawn only with the option, so configurations without it keep their sample streams.
    let with_history = c.history
        && t >= 2 * ku
        && !(noise && c.history_drop > 0.0 && rng.random::<f32>() < c.history_drop);
    let mut target = Vec::with_capacity(order.len());
    let kinematic = order.iter().map(|&j| scene.objects[j].kinematic).collect();
    for &j in &order {
        let o = &scene.objects[j];
        if o.positions.len() != frames || o.rotations.len() != frames {
            return Err(TrainError::Data(format!(
                "object {j} has {} positions and {} rotations, expected {frames}",
                o.positions.len(),
                o.rotations.len()
            )));
        }
        let p = o.reference_points.len();
        if p == 0 {
            return Err(TrainError::Data(format!(
                "object {j} has no reference points"
            )));
        }
        // The subset's own generator when it is fixed per scene; the window's otherwise (so
        // configurations without the option keep their sample streams).
        let mut scene_rng = c
            .points_per_scene
            .then(|| rng_for(mix(scene_key), 5, j as u64));
        let prng: &mut ChaCha8Rng = scene_rng.as_mut().unwrap_or(rng);
        let n = prng.random_range(c.points_min..=c.points_max).min(p);
        // Partial Fisher-Yates: a uniform subset of n points.
        let mut idx: Vec<usize> = (0..p).collect();
        for i in 0..n {
            let r = prng.random_range(i..p);
            idx.swap(i, r);
        }
        idx.truncate(n);
        let mut reference: Vec<[f32; 3]> = idx
            .iter()
            .map(|&i| {
                let p = o.reference_points[i];
                if mirrored { mirror_point(p) } else { p }
            })
            .collect();
        if c.point_drop_prob > 0.0 && rng.random::<f32>() < c.point_drop_prob && n > 1 {
            // Remove the points farthest along a random direction (a contiguous patch).
            let u = small_rotation(rng, 10.0) * Vector3::z();
            let frac = rng.random_range(0.0..=c.point_drop_max);
            let drop = ((frac * n as f32) as usize).min(n - 1);
            reference.sort_by(|a, b| {
                let (da, db) = (Vector3::from(*a).dot(&u), Vector3::from(*b).dot(&u));
                da.total_cmp(&db)
            });
            reference.truncate(n - drop);
        }
        objects.push(ObjectInput {
            reference,
            mass: o.mass,
            friction: o.friction,
            restitution: o.restitution,
            kinematic: o.kinematic,
        });
        let mut prev = pose_at(o, t - ku);
        let mut cur = pose_at(o, t);
        let mut before = with_history.then(|| pose_at(o, t - 2 * ku));
        if noise && (c.noise_position > 0.0 || c.noise_rotation > 0.0) {
            for pose in [Some(&mut prev), Some(&mut cur), before.as_mut()]
                .into_iter()
                .flatten()
            {
                let mut p = Vector3::from(pose.translation);
                for d in 0..3 {
                    let e: f32 = StandardNormal.sample(rng);
                    p[d] += e * c.noise_position;
                }
                let q = small_rotation(rng, c.noise_rotation) * pose.unit_quaternion();
                *pose = Pose::from_parts(p, q);
            }
        }
        previous.push(prev);
        current.push(cur);
        earlier.extend(before);
        target.push(pose_at(o, t + ku));
    }
    // Drawn last and only when enabled, so configurations without it keep their streams.
    let n = c.pushforward_steps.max(1) as usize;
    let pushforward =
        (noise && c.pushforward > 0.0 && t >= (n + 1) * ku && rng.random::<f32>() < c.pushforward)
            .then(|| {
                (1..=n + 1)
                    .rev()
                    .map(|back| {
                        order
                            .iter()
                            .map(|&j| pose_at(&scene.objects[j], t - back * ku))
                            .collect()
                    })
                    .collect()
            });
    Ok(Window {
        objects,
        state: SceneState {
            previous,
            current,
            earlier: with_history.then_some(earlier),
            carry: Default::default(),
        },
        target,
        dt_steps: k,
        kinematic,
        pushforward,
    })
}
