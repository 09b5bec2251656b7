//! Scene generators shared by the integration tests.
#![allow(dead_code)]

use dynaserve_model::{
    ObjectInput, Pose, PreparedScene, RigidFormer, SceneState, StepItem, WorldModel,
};
use nalgebra::{UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `n` points on the surface of a box with half extents `h` (body frame, centred).
pub fn box_cloud(rng: &mut ChaCha8Rng, n: usize, h: [f32; 3]) -> Vec<[f32; 3]> {
    (0..n)
        .map(|_| {
            let face = rng.random_range(0..6);
            let axis = face / 2;
            let sign = if face % 2 == 0 { 1.0 } else { -1.0 };
            let mut p = [0f32; 3];
            for d in 0..3 {
                p[d] = if d == axis {
                    sign * h[d]
                } else {
                    rng.random_range(-h[d]..h[d])
                };
            }
            p
        })
        .collect()
}

/// A random object: a box of random size with `n` points and random parameters.
pub fn random_object(rng: &mut ChaCha8Rng, n: usize) -> ObjectInput {
    let h = [
        rng.random_range(0.2..0.6),
        rng.random_range(0.2..0.6),
        rng.random_range(0.2..0.6),
    ];
    ObjectInput {
        reference: box_cloud(rng, n, h),
        mass: rng.random_range(0.5..5.0),
        friction: rng.random_range(0.2..0.9),
        restitution: rng.random_range(0.1..0.8),
        kinematic: false,
    }
}

pub fn random_rotation(rng: &mut ChaCha8Rng) -> UnitQuaternion<f32> {
    UnitQuaternion::from_euler_angles(
        rng.random_range(-3.1..3.1),
        rng.random_range(-1.5..1.5),
        rng.random_range(-3.1..3.1),
    )
}

/// A random state: objects spread over a 6 m square, 0.3-3 m high, moving.
pub fn random_state(rng: &mut ChaCha8Rng, m: usize) -> SceneState {
    let current: Vec<Pose> = (0..m)
        .map(|_| {
            Pose::from_parts(
                Vector3::new(
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-3.0..3.0),
                    rng.random_range(0.3..3.0),
                ),
                random_rotation(rng),
            )
        })
        .collect();
    let lin: Vec<[f32; 3]> = (0..m)
        .map(|_| {
            [
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
                rng.random_range(-1.0..1.0),
            ]
        })
        .collect();
    let ang: Vec<[f32; 3]> = (0..m)
        .map(|_| {
            [
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
            ]
        })
        .collect();
    SceneState::from_velocities(current, &lin, &ang, 1.0 / 24.0).unwrap()
}

/// `m` random objects of `n` points each and a random state.
pub fn random_scene(seed: u64, m: usize, n: usize) -> (Vec<ObjectInput>, SceneState) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let objects = (0..m).map(|_| random_object(&mut rng, n)).collect();
    (objects, random_state(&mut rng, m))
}

pub fn max_pose_diff(a: &[Pose], b: &[Pose]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| {
            let t = (0..3)
                .map(|d| (x.translation[d] - y.translation[d]).abs())
                .fold(0.0, f32::max);
            let dot: f32 = (0..4).map(|d| x.rotation[d] * y.rotation[d]).sum();
            t.max(1.0 - dot.abs())
        })
        .fold(0.0, f32::max)
}

/// Names of the parameters in `vars` whose gradient in `grads` is missing, zero or not finite
/// (squared norm), in the order `vars` iterates.
pub fn params_without_gradient(
    grads: &candle_core::backprop::GradStore,
    vars: &std::collections::HashMap<String, candle_core::Var>,
) -> Vec<String> {
    vars.iter()
        .filter(|(_, var)| {
            let norm = grads.get(var.as_tensor()).map_or(0.0, squared_norm);
            !(norm > 0.0 && norm.is_finite())
        })
        .map(|(name, _)| name.clone())
        .collect()
}

/// Sum of the squares of a tensor's elements.
pub fn squared_norm(t: &candle_core::Tensor) -> f32 {
    t.sqr()
        .unwrap()
        .sum_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap()
}

/// Targets that continue each object's last increment (constant velocity), lowered by
/// `lower` metres: any such target gives every trainable parameter a gradient.
pub fn constant_velocity_targets(state: &SceneState, lower: f32) -> Vec<Pose> {
    state
        .previous
        .iter()
        .zip(&state.current)
        .map(|(p, c)| {
            let mut t = *c;
            for d in 0..3 {
                t.translation[d] = 2.0 * c.translation[d] - p.translation[d];
            }
            t.translation[2] -= lower;
            t
        })
        .collect()
}

/// The gradient of parameter `name` of `model` after one training forward and backward pass
/// on `objects` in `state` toward `target` at step size `dt_steps`, and all the pass's
/// gradients (to check that another model's variables received none).
pub fn one_step_gradient(
    model: &dynaserve_model::RigidFormer,
    objects: Vec<ObjectInput>,
    state: &SceneState,
    target: &[Pose],
    dt_steps: u32,
    name: &str,
) -> (candle_core::Tensor, candle_core::backprop::GradStore) {
    use dynaserve_model::WorldModel;
    let scene = model.prepare(objects).unwrap();
    let out = model
        .train_forward(&[dynaserve_model::TrainItem {
            scene: &scene,
            state,
            target,
            dt_steps,
            kinematic: &[],
        }])
        .unwrap();
    let grads = out.loss.backward().unwrap();
    let vars = model.varmap().data().lock().unwrap().clone();
    let g = grads
        .get(vars[name].as_tensor())
        .unwrap_or_else(|| panic!("{name} received no gradient"))
        .clone();
    (g, grads)
}

/// One step of `dt_steps` frames of `random_scene(seed, 4, 96)` by `model`: the next poses.
pub fn step_random_scene(model: &dyn WorldModel, seed: u64, dt_steps: u32) -> Vec<Pose> {
    let (objects, state) = random_scene(seed, 4, 96);
    let scene = model.prepare(objects).unwrap();
    step_one(model, &scene, &state, dt_steps)
}

/// The poses after one step of `dt_steps` frames of one prepared scene from `state`.
pub fn step_one(
    model: &dyn WorldModel,
    scene: &PreparedScene,
    state: &SceneState,
    dt_steps: u32,
) -> Vec<Pose> {
    model
        .step(&[StepItem {
            scene,
            state,
            dt_steps,
        }])
        .unwrap()
        .remove(0)
}

/// Name of the encoder's first layer, whose input columns are the point features.
pub const FIRST_LAYER: &str = "encoder.point.0.weight";

/// Shape of `model`'s encoder first-layer weight, `[out, point features]`.
pub fn first_layer_dims(model: &RigidFormer) -> Vec<usize> {
    let vars = model.varmap().data().lock().unwrap();
    vars[FIRST_LAYER].as_tensor().dims().to_vec()
}

/// Checks a model widened with an input group, `wide`, against the model it came from, `old`:
/// one step of size 2 of `random_scene(6, 4, 64)` is the same (the new columns start at zero),
/// and the last `count` columns of the first layer, the group's, receive a finite non-zero
/// gradient. `what` names the group in messages.
pub fn assert_widened_inputs_start_at_zero_and_learn(
    old: &RigidFormer,
    wide: &RigidFormer,
    count: usize,
    what: &str,
) {
    let (objects, state) = random_scene(6, 4, 64);
    let step = |m: &RigidFormer| {
        let scene = m.prepare(objects.clone()).unwrap();
        step_one(m, &scene, &state, 2)
    };
    let diff = max_pose_diff(&step(old), &step(wide));
    assert!(
        diff < 1e-5,
        "model widened with the {what} differs by {diff}"
    );
    let width = first_layer_dims(wide)[1];
    let target = constant_velocity_targets(&state, 0.01);
    let (g, _) = one_step_gradient(wide, objects, &state, &target, 2, FIRST_LAYER);
    let columns = squared_norm(&g.narrow(1, width - count, count).unwrap());
    assert!(
        columns > 0.0 && columns.is_finite(),
        "{what} columns' gradient {columns}"
    );
}

/// A fresh (removed if present) directory path under the system temporary directory, unique to
/// this test process: `dynaserve-model-<tag>-<name>-<pid>`.
pub fn tmp_dir(tag: &str, name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!(
        "dynaserve-model-{tag}-{name}-{}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// `model` saved to a fresh directory (named by `tag`) and loaded back: the reloaded model,
/// after asserting that it steps a random scene (step size 2) to the same poses within 1e-6.
pub fn saved_and_reloaded(model: &RigidFormer, tag: &str) -> RigidFormer {
    let dir = tmp_dir(tag, "round-trip");
    model.save(&dir).unwrap();
    let back =
        dynaserve_model::load_rigidformer(&dir, &dynaserve_model::Device::Cpu, false).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let diff = max_pose_diff(
        &step_random_scene(model, 6, 2),
        &step_random_scene(&back, 6, 2),
    );
    assert!(diff < 1e-6, "reloaded model differs by {diff}");
    back
}

/// The message of the error `load_model` gives for `dir`; panics if it loads.
pub fn load_error(dir: &std::path::Path) -> String {
    match dynaserve_model::load_model(dir, &dynaserve_model::Device::Cpu) {
        Ok(_) => panic!("loading {} should fail", dir.display()),
        Err(e) => e.to_string(),
    }
}
