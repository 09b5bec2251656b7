//! The contact wrench: a model that gains one computes the same steps as before (its output
//! layer starts at zero); its output layer learns and the unit survives a checkpoint; a force
//! that is the same at every point moves every object by it without turning any, and a force
//! that varies over the cloud turns them.
mod common;

use common::{max_pose_diff, one_step_gradient, random_scene, squared_norm, step_random_scene};
use dynaserve_model::{Device, ModelConfig, ModelUnit, Pose, RigidFormer, WorldModel};
use nalgebra::{Quaternion, UnitQuaternion};

/// Sets parameter `name` of `model` to `values` (its shape kept).
fn set(model: &RigidFormer, name: &str, values: &[f32]) {
    let vars = model.varmap().data().lock().unwrap();
    let var = &vars[name];
    let t =
        candle_core::Tensor::from_slice(values, var.as_tensor().dims(), &candle_core::Device::Cpu)
            .unwrap();
    var.set(&t).unwrap();
}

/// The angle between two poses' rotations, radians.
fn turn_between(a: &Pose, b: &Pose) -> f32 {
    let q = |p: &Pose| {
        let [x, y, z, w] = p.rotation;
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
    };
    q(a).angle_to(&q(b))
}

/// Widened with the unit, a model steps as before and has the unit's parameters (point layer
/// `C1 x 64 + 64`, object layer `D x 64`, output `64 x 3 + 3`); widening twice is refused.
#[test]
fn a_model_gains_a_contact_wrench_as_the_same_function() {
    let plain = ModelConfig::small();
    let (c1, d) = (plain.point_dim, plain.width);
    let a = RigidFormer::new_frozen(plain, 5, &Device::Cpu).unwrap();
    let wide = a
        .widened_with_unit(ModelUnit::ContactWrench, 7, false)
        .unwrap();
    assert!(wide.config().dynamics.contact_wrench);
    assert_eq!(
        wide.parameter_count(),
        a.parameter_count() + c1 * 64 + 64 + d * 64 + 64 * 3 + 3
    );
    for (seed, k) in [(1, 1), (2, 4)] {
        let diff = max_pose_diff(
            &step_random_scene(&a, seed, k),
            &step_random_scene(&wide, seed, k),
        );
        assert!(diff < 1e-5, "seed {seed}, k {k}: differs by {diff}");
    }
    let twice = wide.widened_with_unit(ModelUnit::ContactWrench, 7, false);
    assert!(twice.err().unwrap().to_string().contains("already"));
}

/// The output layer (zero at the start) receives a gradient from the first backward pass, and a
/// model with the unit round-trips through a checkpoint.
#[test]
fn the_wrench_learns_and_saves() {
    let mut cfg = ModelConfig::tiny();
    cfg.dynamics.contact_wrench = true;
    let model = RigidFormer::new(cfg, 3, &Device::Cpu).unwrap();
    let (objects, state) = random_scene(4, 3, 64);
    let target = common::constant_velocity_targets(&state, 0.05);
    for name in ["anchors.wrench.out.weight", "anchors.wrench.out.bias"] {
        let (g, _) = one_step_gradient(&model, objects.clone(), &state, &target, 1, name);
        let norm = squared_norm(&g);
        assert!(norm > 0.0 && norm.is_finite(), "{name} gradient {norm}");
    }
    let back = common::saved_and_reloaded(&model, "wrench");
    assert!(back.config().dynamics.contact_wrench);
}

/// With the output layer's weights zero and its bias a force `f`, every point of every object
/// pushes alike: the moment about each cloud's centroid is zero, so each object keeps the
/// plain model's rotation and moves `f` (in the head's unit, times `accel_scale` and the step
/// size's output factor) further; the same bias with weights that make the force differ
/// between points turns them.
#[test]
fn a_uniform_force_moves_and_a_varying_one_turns() {
    let plain = ModelConfig::small();
    let a = RigidFormer::new_frozen(plain.clone(), 5, &Device::Cpu).unwrap();
    // Trainable, so that its parameters are variables that `set` changes in place.
    let wide = a
        .widened_with_unit(ModelUnit::ContactWrench, 7, true)
        .unwrap();
    let f = [0.4f32, -0.2, 0.3];
    set(&wide, "anchors.wrench.out.bias", &f);
    for k in [1u32, 2] {
        let (before, after) = (step_random_scene(&a, 3, k), step_random_scene(&wide, 3, k));
        let scale = plain.accel_scale * plain.dynamics.output_factor(k);
        for (j, (b, w)) in before.iter().zip(&after).enumerate() {
            let turn = turn_between(b, w);
            assert!(turn < 1e-5, "k {k}, object {j}: turned by {turn} rad");
            for (d, force) in f.iter().enumerate() {
                let moved = w.translation[d] - b.translation[d];
                assert!(
                    (moved - force * scale).abs() < 1e-4 * scale.max(1.0),
                    "k {k}, object {j}, axis {d}: moved {moved}, expected {}",
                    force * scale
                );
            }
        }
    }
    let weights: Vec<f32> = (0..3 * 64)
        .map(|i| ((i * 37 % 17) as f32 - 8.0) * 0.2)
        .collect();
    set(&wide, "anchors.wrench.out.weight", &weights);
    let (before, after) = (step_random_scene(&a, 3, 1), step_random_scene(&wide, 3, 1));
    let largest = before
        .iter()
        .zip(&after)
        .map(|(b, w)| turn_between(b, w))
        .fold(0.0f32, f32::max);
    assert!(
        largest > 1e-3,
        "a varying force turned no object ({largest} rad)"
    );
}
