mod common;

use dynaserve_model::{
    Device, ModelConfig, RigidFormer, StepItem, WorldModel, load_model, rollout,
};

#[test]
fn random_model_steps_saves_and_loads() {
    let model = RigidFormer::new(ModelConfig::tiny(), 1, &Device::Cpu).unwrap();
    let (objects, state) = common::random_scene(3, 4, 64);
    let scene = model.prepare(objects).unwrap();
    let out = model
        .step(&[StepItem {
            scene: &scene,
            state: &state,
            dt_steps: 2,
        }])
        .unwrap();
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].len(), 4);
    let traj = rollout(&model, &scene, state.clone(), 1, 5, |_, _| {}).unwrap();
    assert_eq!(traj.len(), 5);
    let dir = std::env::temp_dir().join(format!("dynaserve-model-smoke-{}", std::process::id()));
    model.save(&dir).unwrap();
    let loaded = load_model(&dir, &Device::Cpu).unwrap();
    let scene2 = loaded.prepare(common::random_scene(3, 4, 64).0).unwrap();
    let out2 = loaded
        .step(&[StepItem {
            scene: &scene2,
            state: &state,
            dt_steps: 2,
        }])
        .unwrap();
    // An inference model's products sum in another order: equal within float rounding.
    assert_eq!(out.len(), out2.len());
    assert!(
        common::max_pose_diff(&out[0], &out2[0]) < 1e-5,
        "{out:?} vs {out2:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An inference model (constant weights: transposed weight copies, FiLM cached per step size)
/// steps a batch of mixed step sizes like the same weights as training variables, twice (the
/// second step reads the caches the first filled).
#[test]
fn frozen_model_matches_the_trainable_one_on_mixed_step_sizes() {
    let config = ModelConfig::tiny();
    let trainable = RigidFormer::new(config.clone(), 3, &Device::Cpu).unwrap();
    let frozen = RigidFormer::new_frozen(config, 3, &Device::Cpu).unwrap();
    let scenes: Vec<_> = (0..3)
        .map(|i| {
            let (objects, state) = common::random_scene(20 + i, 3 + i as usize, 48);
            (trainable.prepare(objects).unwrap(), state)
        })
        .collect();
    let batch: Vec<StepItem<'_>> = scenes
        .iter()
        .zip([1u32, 2, 4])
        .map(|((scene, state), dt_steps)| StepItem {
            scene,
            state,
            dt_steps,
        })
        .collect();
    let want = trainable.step(&batch).unwrap();
    for _ in 0..2 {
        let got = frozen.step(&batch).unwrap();
        assert_eq!(got.len(), want.len());
        for (g, w) in got.iter().zip(&want) {
            assert!(common::max_pose_diff(g, w) < 1e-5, "{g:?} vs {w:?}");
        }
    }
}

/// A one-scene step splits its products, point MLPs, attention rows and anchor pooling over
/// the compute team; the poses agree with the same step on one thread. Uses the `small` widths
/// so every split is above its size threshold.
#[test]
fn one_scene_split_over_the_team_matches_one_thread() {
    if dynaserve_model::team::parts() < 2 {
        eprintln!("one compute thread here: nothing to split");
        return;
    }
    let model = RigidFormer::new_frozen(ModelConfig::small(), 5, &Device::Cpu).unwrap();
    let (objects, state) = common::random_scene(31, 10, 256);
    let scene = model.prepare(objects).unwrap();
    let batch = [StepItem {
        scene: &scene,
        state: &state,
        dt_steps: 1,
    }];
    dynaserve_model::team::set_enabled(false);
    let alone = model.step(&batch);
    dynaserve_model::team::set_enabled(true);
    let alone = alone.unwrap();
    for _ in 0..3 {
        let split = model.step(&batch).unwrap();
        assert!(
            common::max_pose_diff(&split[0], &alone[0]) < 1e-5,
            "{split:?} vs {alone:?}"
        );
    }
}
