//! The contact messages: a model that gains them computes the same steps as before (their
//! output layer starts at zero); they reach only objects in contact with another object; every
//! layer of the unit learns from one backward pass; the unit survives a checkpoint.
mod common;

use common::{box_cloud, max_pose_diff, one_step_gradient, squared_norm, step_one};
use dynaserve_model::{
    Device, ModelConfig, ModelUnit, ObjectInput, Pose, RigidFormer, SceneState, StepItem,
    WorldModel,
};
use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Two 0.4 m boxes stacked (the upper one's bottom face on the lower one's top face, both
/// drifting sideways), which touch each other, and, as a scene of its own, one such box falling
/// in the air, which touches nothing.
fn stack_and_loner() -> (
    (Vec<ObjectInput>, SceneState),
    (Vec<ObjectInput>, SceneState),
) {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut boxes = (0..3).map(|_| ObjectInput {
        reference: box_cloud(&mut rng, 128, [0.2, 0.2, 0.2]),
        mass: 1.0,
        friction: 0.5,
        restitution: 0.3,
        kinematic: false,
    });
    let place =
        |x: f32, z: f32| Pose::from_parts(Vector3::new(x, 0.0, z), UnitQuaternion::identity());
    let dt = 1.0 / 24.0;
    let stack = SceneState::from_velocities(
        vec![place(0.0, 0.2), place(0.01, 0.6)],
        &[[0.1, 0.0, 0.0], [0.3, 0.0, 0.0]],
        &[[0.0; 3]; 2],
        dt,
    )
    .unwrap();
    let alone =
        SceneState::from_velocities(vec![place(4.0, 1.5)], &[[0.0, 0.0, -1.0]], &[[0.0; 3]], dt)
            .unwrap();
    (
        (boxes.by_ref().take(2).collect(), stack),
        (boxes.collect(), alone),
    )
}

/// Sets parameter `name` of `model` to `value` everywhere (its shape kept).
fn fill(model: &RigidFormer, name: &str, value: f32) {
    let vars = model.varmap().data().lock().unwrap();
    let var = &vars[name];
    let t = candle_core::Tensor::ones(
        var.as_tensor().dims(),
        candle_core::DType::F32,
        &Device::Cpu,
    )
    .unwrap()
    .affine(f64::from(value), 0.0)
    .unwrap();
    var.set(&t).unwrap();
}

/// Widened with the unit, a model steps as before and has the unit's parameters (own layer
/// `C1 x 64 + 64`, partner layer `C1 x 64`, lever layer `6 x 64`, output `64 x C1 + C1`);
/// widening twice is refused.
#[test]
fn a_model_gains_contact_messages_as_the_same_function() {
    let plain = ModelConfig::small();
    let c1 = plain.point_dim;
    let a = RigidFormer::new_frozen(plain, 5, &Device::Cpu).unwrap();
    let wide = a
        .widened_with_unit(ModelUnit::ContactMessages, 7, false)
        .unwrap();
    assert!(wide.config().dynamics.contact_messages);
    assert_eq!(
        wide.parameter_count(),
        a.parameter_count() + c1 * 64 + 64 + c1 * 64 + 6 * 64 + 64 * c1 + c1
    );
    let ((objects, state), _) = stack_and_loner();
    let (sa, sw) = (
        a.prepare(objects.clone()).unwrap(),
        wide.prepare(objects).unwrap(),
    );
    for k in [1, 4] {
        let diff = max_pose_diff(
            &step_one(&a, &sa, &state, k),
            &step_one(&wide, &sw, &state, k),
        );
        assert!(diff < 1e-5, "k {k}: differs by {diff}");
    }
    let twice = wide.widened_with_unit(ModelUnit::ContactMessages, 7, false);
    assert!(twice.err().unwrap().to_string().contains("already"));
}

/// With a non-zero message, the stacked boxes step differently from the plain model and the
/// box in the air steps exactly as before; batched behind the lone box's scene (so that its
/// points' rows start later), the stack steps as it does alone.
#[test]
fn messages_reach_only_objects_in_contact() {
    let plain = ModelConfig::small();
    let a = RigidFormer::new_frozen(plain, 5, &Device::Cpu).unwrap();
    // Trainable, so that its parameters are variables that `fill` changes in place.
    let wide = a
        .widened_with_unit(ModelUnit::ContactMessages, 7, true)
        .unwrap();
    fill(&wide, "messages.out.weight", 0.05);
    fill(&wide, "messages.out.bias", 0.5);
    let ((stack, stack_state), (alone, alone_state)) = stack_and_loner();
    let step = |m: &RigidFormer| {
        let (s, l) = (
            m.prepare(stack.clone()).unwrap(),
            m.prepare(alone.clone()).unwrap(),
        );
        let batch = m
            .step(&[
                StepItem {
                    scene: &l,
                    state: &alone_state,
                    dt_steps: 1,
                },
                StepItem {
                    scene: &s,
                    state: &stack_state,
                    dt_steps: 1,
                },
            ])
            .unwrap();
        (batch, step_one(m, &s, &stack_state, 1))
    };
    let ((before, _), (after, stack_alone)) = (step(&a), step(&wide));
    for j in 0..2 {
        let moved = max_pose_diff(&before[1][j..j + 1], &after[1][j..j + 1]);
        assert!(
            moved > 1e-4,
            "box {j} in the stack: the message changed it by {moved}"
        );
    }
    let loner = max_pose_diff(&before[0], &after[0]);
    assert!(loner < 1e-6, "the lone box changed by {loner}");
    let batched = max_pose_diff(&after[1], &stack_alone);
    assert!(
        batched < 1e-5,
        "batched, the stack differs by {batched} from its own step"
    );
}

/// Every layer of the unit receives a gradient once its output layer is non-zero (the output
/// layer from the first pass), and a model with the unit round-trips through a checkpoint.
#[test]
fn the_messages_learn_and_save() {
    let mut cfg = ModelConfig::tiny();
    cfg.dynamics.contact_messages = true;
    let model = RigidFormer::new(cfg, 3, &Device::Cpu).unwrap();
    let ((objects, state), _) = stack_and_loner();
    let target = common::constant_velocity_targets(&state, 0.05);
    let gradient = |name: &str| {
        let (g, _) = one_step_gradient(&model, objects.clone(), &state, &target, 1, name);
        squared_norm(&g)
    };
    for name in ["messages.out.weight", "messages.out.bias"] {
        let norm = gradient(name);
        assert!(norm > 0.0 && norm.is_finite(), "{name} gradient {norm}");
    }
    fill(&model, "messages.out.weight", 0.05);
    for name in [
        "messages.own.weight",
        "messages.partner.weight",
        "messages.levers.weight",
    ] {
        let norm = gradient(name);
        assert!(norm > 0.0 && norm.is_finite(), "{name} gradient {norm}");
    }
    let back = common::saved_and_reloaded(&model, "messages");
    assert!(back.config().dynamics.contact_messages);
}
