//! Ensembles of RigidFormer checkpoints: loading, the mean step and clear errors.
mod common;

use std::path::Path;

use common::{load_error, max_pose_diff, random_scene, step_one, step_random_scene, tmp_dir};
use dynaserve_model::ensemble::{MAX_MEMBERS, mean_pose, weighted_mean_pose};
use dynaserve_model::{
    Device, ModelConfig, Pose, RigidFormer, SceneState, WorldModel, load_model, load_rigidformer,
};
use nalgebra::{UnitQuaternion, Vector3};

/// Saves tiny members with the given seeds as `dir/m<seed>` and writes an ensemble
/// `config.json` listing `members`.
fn ensemble_dir(dir: &Path, seeds: &[u64], members: &[&str]) {
    ensemble_dir_with(dir, seeds, serde_json::json!({"members": members}));
}

/// [`ensemble_dir`] with the fields of `fields` (an object: `members`, `weights`, ...) in the
/// `config.json`.
fn ensemble_dir_with(dir: &Path, seeds: &[u64], mut fields: serde_json::Value) {
    for &seed in seeds {
        RigidFormer::new(ModelConfig::tiny(), seed, &Device::Cpu)
            .unwrap()
            .save(&dir.join(format!("m{seed}")))
            .unwrap();
    }
    fields["architecture"] = "rigidformer-ensemble".into();
    std::fs::write(dir.join("config.json"), fields.to_string()).unwrap();
}

/// One step of a random four-object scene, the same for every model of a test.
fn step(model: &dyn WorldModel) -> Vec<Pose> {
    step_random_scene(model, 21, 2)
}

#[test]
fn an_ensemble_steps_to_the_mean_of_its_members() {
    let dir = tmp_dir("ensemble", "mean");
    ensemble_dir(&dir, &[1, 2], &["m1", "m2"]);
    let ensemble = load_model(&dir, &Device::Cpu).unwrap();
    assert_eq!(ensemble.name(), dir.file_name().unwrap().to_str().unwrap());
    let members: Vec<RigidFormer> = ["m1", "m2"]
        .iter()
        .map(|m| load_rigidformer(&dir.join(m), &Device::Cpu, false).unwrap())
        .collect();
    assert_eq!(ensemble.config(), members[0].config());
    let (a, b) = (step(&members[0]), step(&members[1]));
    // Two differently initialised networks disagree, so the test sees the averaging.
    assert!(max_pose_diff(&a, &b) > 1e-4, "members agree");
    let mean: Vec<Pose> = a
        .iter()
        .zip(&b)
        .map(|(p, q)| mean_pose(&[*p, *q]))
        .collect();
    let got = step(ensemble.as_ref());
    assert!(max_pose_diff(&got, &mean) < 1e-6, "{got:?} vs {mean:?}");
    // One member alone is that member.
    let single = dir.join("single");
    std::fs::create_dir_all(&single).unwrap();
    let config = serde_json::json!({"architecture": "rigidformer-ensemble", "members": ["../m2"]});
    std::fs::write(single.join("config.json"), config.to_string()).unwrap();
    let one = load_model(&single, &Device::Cpu).unwrap();
    assert!(max_pose_diff(&step(one.as_ref()), &b) < 1e-7);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_weighted_ensemble_steps_to_the_weighted_mean() {
    let dir = tmp_dir("ensemble", "weighted");
    ensemble_dir_with(
        &dir,
        &[5, 6],
        serde_json::json!({"members": ["m5", "m6"], "weights": [3.0, 1.0]}),
    );
    let members: Vec<RigidFormer> = ["m5", "m6"]
        .iter()
        .map(|m| load_rigidformer(&dir.join(m), &Device::Cpu, false).unwrap())
        .collect();
    let (a, b) = (step(&members[0]), step(&members[1]));
    let weighted: Vec<Pose> = a
        .iter()
        .zip(&b)
        .map(|(p, q)| weighted_mean_pose(&[*p, *q], &[0.75, 0.25]))
        .collect();
    let got = step(load_model(&dir, &Device::Cpu).unwrap().as_ref());
    assert!(
        max_pose_diff(&got, &weighted) < 1e-6,
        "{got:?} vs {weighted:?}"
    );
    // Three quarters of the way to the first member, not half.
    let equal: Vec<Pose> = a
        .iter()
        .zip(&b)
        .map(|(p, q)| mean_pose(&[*p, *q]))
        .collect();
    assert!(max_pose_diff(&got, &equal) > 1e-5);
    assert!(max_pose_diff(&got, &a) < max_pose_diff(&got, &b));
    // Weights near the largest float are scaled, not summed to infinity.
    ensemble_dir_with(
        &dir,
        &[],
        serde_json::json!({"members": ["m5", "m6"], "weights": [3e38, 3e38]}),
    );
    let huge = step(load_model(&dir, &Device::Cpu).unwrap().as_ref());
    assert!(max_pose_diff(&huge, &equal) < 1e-6, "{huge:?} vs {equal:?}");
    // One weight per member, each positive and finite.
    for (weights, needle) in [
        (serde_json::json!([1.0]), "1 weights for 2 members"),
        (serde_json::json!([1.0, 0.0]), "weight 1 is 0"),
        (serde_json::json!([-1.0, 1.0]), "weight 0 is -1"),
    ] {
        ensemble_dir_with(
            &dir,
            &[],
            serde_json::json!({"members": ["m5", "m6"], "weights": weights}),
        );
        let e = load_error(&dir);
        assert!(e.contains(needle), "{e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_mean_pose_averages_translations_and_rotations() {
    let yaw = |x: f32, angle: f32| {
        Pose::from_parts(
            Vector3::new(x, 1.0, 0.5),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), angle),
        )
    };
    let mean = mean_pose(&[yaw(0.0, 0.1), yaw(1.0, 0.3)]);
    assert!((mean.translation[0] - 0.5).abs() < 1e-6);
    let expected = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.2);
    assert!(mean.unit_quaternion().angle_to(&expected) < 1e-5);
    // `-q` is the same rotation as `q` and must not cancel it.
    let mut flipped = yaw(1.0, 0.3);
    flipped.rotation = flipped.rotation.map(|c| -c);
    let again = mean_pose(&[yaw(0.0, 0.1), flipped]);
    assert!(again.unit_quaternion().angle_to(&expected) < 1e-5);
    // Weights pull the mean towards the heavier pose; equal weights are the plain mean.
    let heavy = weighted_mean_pose(&[yaw(0.0, 0.1), yaw(1.0, 0.3)], &[1.0, 3.0]);
    assert!((heavy.translation[0] - 0.75).abs() < 1e-6);
    let at = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.25);
    assert!(heavy.unit_quaternion().angle_to(&at) < 1e-4);
    let even = weighted_mean_pose(&[yaw(0.0, 0.1), yaw(1.0, 0.3)], &[2.0, 2.0]);
    assert!(max_pose_diff(&[even], &[mean]) < 1e-6);
    // A single pose is itself.
    let one = mean_pose(&[yaw(0.2, 0.7)]);
    assert!(max_pose_diff(&[one], &[yaw(0.2, 0.7)]) < 1e-6);
}

#[test]
fn bad_ensembles_are_refused_with_the_reason() {
    let dir = tmp_dir("ensemble", "bad");
    ensemble_dir(&dir, &[3], &[]);
    let e = load_error(&dir);
    assert!(e.contains("1 to") && e.contains("members"), "{e}");
    let many = vec!["m3"; MAX_MEMBERS + 1];
    ensemble_dir(&dir, &[], &many);
    assert!(load_error(&dir).contains(&format!("this one {}", MAX_MEMBERS + 1)));
    // A member that is not there is named.
    ensemble_dir(&dir, &[], &["m3", "missing"]);
    let e = load_error(&dir);
    assert!(
        e.contains("ensemble member") && e.contains("missing"),
        "{e}"
    );
    // Members of other sizes serve alike and are accepted; a member on another frame
    // interval is refused by name.
    let save = |name: &str, config: ModelConfig| {
        RigidFormer::new(config, 4, &Device::Cpu)
            .unwrap()
            .save(&dir.join(name))
            .unwrap()
    };
    save(
        "wide",
        ModelConfig {
            width: 64,
            ..ModelConfig::tiny()
        },
    );
    ensemble_dir(&dir, &[], &["m3", "wide"]);
    let mixed = load_model(&dir, &Device::Cpu).unwrap();
    assert_eq!(step(mixed.as_ref()).len(), 4);
    save(
        "fast",
        ModelConfig {
            dt_frame: 1.0 / 60.0,
            ..ModelConfig::tiny()
        },
    );
    ensemble_dir(&dir, &[], &["m3", "fast"]);
    let e = load_error(&dir);
    assert!(e.contains("dt_frame") && e.contains("fast"), "{e}");
    // Unknown fields are refused rather than ignored.
    std::fs::write(
        dir.join("config.json"),
        r#"{"architecture": "rigidformer-ensemble", "members": ["m3"], "weight": [1]}"#,
    )
    .unwrap();
    assert!(load_error(&dir).contains("not a valid ensemble configuration"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn members_of_other_anchor_and_grouping_sizes_each_step_their_own_preparation() {
    let dir = tmp_dir("ensemble", "sizes");
    ensemble_dir(&dir, &[5], &["m5", "coarse", "fine", "coarse2"]);
    let tiny = ModelConfig::tiny();
    for (name, seed, config) in [
        (
            "coarse",
            6,
            ModelConfig {
                sa_centres: tiny.sa_centres * 2,
                anchors: tiny.anchors + 2,
                ..ModelConfig::tiny()
            },
        ),
        (
            "fine",
            7,
            ModelConfig {
                sa_neighbours: tiny.sa_neighbours / 2,
                ..ModelConfig::tiny()
            },
        ),
        // The same sizes as `coarse`: served by `coarse`'s preparation.
        (
            "coarse2",
            8,
            ModelConfig {
                sa_centres: tiny.sa_centres * 2,
                anchors: tiny.anchors + 2,
                ..ModelConfig::tiny()
            },
        ),
    ] {
        RigidFormer::new(config, seed, &Device::Cpu)
            .unwrap()
            .save(&dir.join(name))
            .unwrap();
    }
    let ensemble = load_model(&dir, &Device::Cpu).unwrap();
    let members: Vec<RigidFormer> = ["m5", "coarse", "fine", "coarse2"]
        .iter()
        .map(|m| load_rigidformer(&dir.join(m), &Device::Cpu, false).unwrap())
        .collect();
    // Each member alone, on a scene it prepared itself.
    let alone: Vec<Vec<Pose>> = members.iter().map(|m| step(m)).collect();
    let mean: Vec<Pose> = (0..alone[0].len())
        .map(|j| mean_pose(&alone.iter().map(|a| a[j]).collect::<Vec<_>>()))
        .collect();
    assert!(max_pose_diff(&alone[0], &alone[1]) > 1e-4, "members agree");
    let got = step(ensemble.as_ref());
    assert!(max_pose_diff(&got, &mean) < 1e-6, "{got:?} vs {mean:?}");
    // The ensemble's preparation serves each member; the first member's alone does not serve
    // a member of other sizes, and the refusal names both sizes.
    let (objects, state) = random_scene(21, 4, 96);
    let by_ensemble = ensemble.prepare(objects.clone()).unwrap();
    for (m, a) in members.iter().zip(&alone) {
        assert!(max_pose_diff(&step_one(m, &by_ensemble, &state, 2), a) < 1e-6);
    }
    let by_first = members[0].prepare(objects).unwrap();
    let refused = members[1]
        .step(&[dynaserve_model::StepItem {
            scene: &by_first,
            state: &state,
            dt_steps: 2,
        }])
        .unwrap_err()
        .to_string();
    assert!(
        refused.contains("prepared for a model with") && refused.contains("sa_centres: 16"),
        "{refused}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `poses` turned by `angle` radians about the vertical through `(cx, cy)`.
fn turned(poses: &[Pose], angle: f32, cx: f32, cy: f32) -> Vec<Pose> {
    let r = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), angle);
    let c = Vector3::new(cx, cy, 0.0);
    poses
        .iter()
        .map(|p| {
            Pose::from_parts(
                c + r * (Vector3::from(p.translation) - c),
                r * p.unit_quaternion(),
            )
        })
        .collect()
}

#[test]
fn yaw_copies_make_a_step_indifferent_to_turns_by_their_angle() {
    let dir = tmp_dir("ensemble", "yaw");
    ensemble_dir_with(
        &dir,
        &[8],
        serde_json::json!({"members": ["m8"], "yaw_copies": 4}),
    );
    let averaged = load_model(&dir, &Device::Cpu).unwrap();
    let plain = load_rigidformer(&dir.join("m8"), &Device::Cpu, false).unwrap();
    let (objects, state) = random_scene(31, 4, 96);
    // The turn is about the scene's centre, which the copies are also made about.
    let n = state.current.len() as f32;
    let cx = state.current.iter().map(|p| p.translation[0]).sum::<f32>() / n;
    let cy = state.current.iter().map(|p| p.translation[1]).sum::<f32>() / n;
    let quarter = std::f32::consts::FRAC_PI_2;
    let turned_state = SceneState {
        previous: turned(&state.previous, quarter, cx, cy),
        current: turned(&state.current, quarter, cx, cy),
        earlier: None,
        carry: Default::default(),
    };
    // How far stepping the turned scene is from turning the step.
    let miss = |model: &dyn WorldModel| {
        let scene = model.prepare(objects.clone()).unwrap();
        let then_turned = turned(&step_one(model, &scene, &state, 2), quarter, cx, cy);
        max_pose_diff(&step_one(model, &scene, &turned_state, 2), &then_turned)
    };
    // A network trained or not is not exactly indifferent to the turn; the mean over the
    // quarter turns is, to rounding.
    assert!(
        miss(&plain) > 1e-3,
        "the plain network is already indifferent"
    );
    assert!(
        miss(averaged.as_ref()) < 1e-5,
        "{}",
        miss(averaged.as_ref())
    );
    // Its one copy is the member itself.
    ensemble_dir_with(
        &dir,
        &[],
        serde_json::json!({"members": ["m8"], "yaw_copies": 1}),
    );
    let one = load_model(&dir, &Device::Cpu).unwrap();
    assert!(max_pose_diff(&step(one.as_ref()), &step(&plain)) < 1e-7);
    for bad in [0, 17] {
        ensemble_dir_with(
            &dir,
            &[],
            serde_json::json!({"members": ["m8"], "yaw_copies": bad}),
        );
        let e = load_error(&dir);
        assert!(e.contains("yaw_copies") && e.contains("1 to 16"), "{e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
