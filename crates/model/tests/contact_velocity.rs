//! The contact velocity inputs: a 12-feature model (read from disk, or a random one) widened
//! to 15 features computes the same steps, the new weight columns receive gradients,
//! and a widened model saves and loads as a 15-feature checkpoint.
mod common;

use common::{
    FIRST_LAYER, constant_velocity_targets, first_layer_dims, max_pose_diff, one_step_gradient,
    random_scene, squared_norm, step_random_scene,
};
use dynaserve_model::{
    Device, FeatureNormalization, ModelConfig, RigidFormer, WorldModel, load_rigidformer,
};

fn extra() -> FeatureNormalization {
    FeatureNormalization {
        mean: vec![0.01, -0.02, 0.03],
        std: vec![0.05, 0.06, 0.07],
    }
}

/// A 12-feature checkpoint on disk (written as models were before the contact velocity, with
/// fitted normalisation constants) reads as a 12-feature model, and its widened copy steps the
/// same scenes to within float rounding and keeps the 12 old constants.
#[test]
fn twelve_feature_checkpoint_reads_as_such_and_widens_without_change() {
    let mut cfg = ModelConfig::small();
    cfg.dynamics.contact_velocity = false;
    cfg.normalization = FeatureNormalization {
        mean: (0..12).map(|i| 0.01 * i as f32).collect(),
        std: (0..12).map(|i| 0.5 + 0.1 * i as f32).collect(),
    };
    let dir = std::env::temp_dir().join(format!("dynaserve-cv-twelve-{}", std::process::id()));
    RigidFormer::new(cfg, 21, &Device::Cpu)
        .unwrap()
        .save(&dir)
        .unwrap();
    let old = load_rigidformer(&dir, &Device::Cpu, false).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(!old.config().dynamics.contact_velocity);
    assert_eq!(old.config().point_features(), 12);
    assert_eq!(first_layer_dims(&old)[1], 12);
    let wide = old.widened_with_contact_velocity(&extra(), false).unwrap();
    assert_eq!(wide.config().point_features(), 15);
    assert_eq!(first_layer_dims(&wide)[1], 15);
    assert_eq!(
        wide.config().normalization.mean[..12],
        old.config().normalization.mean[..]
    );
    for (seed, k) in [(1, 1), (2, 4)] {
        let (a, b) = (
            step_random_scene(&old, seed, k),
            step_random_scene(&wide, seed, k),
        );
        let diff = max_pose_diff(&a, &b);
        assert!(
            diff < 1e-5,
            "seed {seed}, k {k}: widened model differs by {diff}"
        );
    }
}

/// A random 12-feature model widened for training: same outputs, every parameter (the new
/// columns included) gets a gradient, and the result round-trips through a checkpoint.
#[test]
fn widened_model_trains_its_new_columns_and_saves_as_fifteen_features() {
    let mut cfg = ModelConfig::tiny();
    cfg.dynamics.contact_velocity = false;
    cfg.normalization = FeatureNormalization::default();
    let old = RigidFormer::new(cfg, 9, &Device::Cpu).unwrap();
    let wide = old.widened_with_contact_velocity(&extra(), true).unwrap();
    let diff = max_pose_diff(
        &step_random_scene(&old, 3, 2),
        &step_random_scene(&wide, 3, 2),
    );
    assert!(diff < 1e-5, "widened model differs by {diff}");

    let (objects, state) = random_scene(4, 5, 64);
    // Targets: constant velocity (any pose works for a gradient).
    let target = constant_velocity_targets(&state, 0.0);
    let (g, grads) = one_step_gradient(&wide, objects, &state, &target, 2, FIRST_LAYER);
    let norm = squared_norm(&g.narrow(1, 12, 3).unwrap());
    assert!(
        norm > 0.0 && norm.is_finite(),
        "new columns' gradient {norm}"
    );
    // The old model's weights are not shared with the widened one.
    let old_vars = old.varmap().data().lock().unwrap().clone();
    assert!(grads.get(old_vars[FIRST_LAYER].as_tensor()).is_none());

    let dir = std::env::temp_dir().join(format!("dynaserve-cv-widen-{}", std::process::id()));
    wide.save(&dir).unwrap();
    let back = load_rigidformer(&dir, &Device::Cpu, false).unwrap();
    assert_eq!(back.config(), wide.config());
    let diff = max_pose_diff(
        &step_random_scene(&wide, 5, 1),
        &step_random_scene(&back, 5, 1),
    );
    assert!(diff < 1e-6, "reloaded model differs by {diff}");
    std::fs::remove_dir_all(&dir).unwrap();

    // Widening twice or with the wrong number of constants is refused with a message.
    let twice = wide.widened_with_contact_velocity(&extra(), false);
    assert!(twice.err().unwrap().to_string().contains("already"));
    let short = FeatureNormalization {
        mean: vec![0.0; 2],
        std: vec![1.0; 2],
    };
    let bad = old.widened_with_contact_velocity(&short, false);
    assert!(bad.err().unwrap().to_string().contains("needs 3"));
}
