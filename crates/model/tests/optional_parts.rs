//! The optional parts of a RigidFormer that start as the zero function: the object state
//! summary and the contact summary (their numbers for a known motion; a model that gains one,
//! random or widened, computes the same steps as one without; their layers learn and save) and
//! the coarse output unit.
mod common;

use common::{
    constant_velocity_targets, max_pose_diff, one_step_gradient, random_scene, squared_norm,
    step_random_scene,
};
use dynaserve_model::{
    Device, DynamicsConfig, FeatureFrame, ModelConfig, ModelUnit, Pose, RigidFormer, ScenePoints,
    WorldModel, contact_summary, load_rigidformer, nearest_object_gap, object_summary,
};
use nalgebra::{UnitQuaternion, Vector3};

/// The eight corners of a cube of half extent 0.1 m placed at `pose`.
fn corners(pose: &Pose) -> Vec<[f32; 3]> {
    let [x, y, z, w] = pose.rotation;
    let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
    let t = Vector3::from(pose.translation);
    (0..8)
        .map(|i| {
            let c = Vector3::new(
                if i & 1 == 0 { -0.1 } else { 0.1 },
                if i & 2 == 0 { -0.1 } else { 0.1 },
                if i & 4 == 0 { -0.1 } else { 0.1 },
            );
            let p = q * c + t;
            [p.x, p.y, p.z]
        })
        .collect()
}

/// A cube 1 m up, turned 0.2 rad about z and moved by (0.02, 0, -0.04) m over a step of two
/// frames: heights of its lowest corner (0.9 m) and centre, per-frame increments, the
/// per-frame turn and the lowest corner's offset from the centre (0.1 m below it), each divided
/// by its documented scale; without a ground, or far above it,
/// both heights read as the 4 m maximum.
#[test]
fn summary_reads_heights_increments_and_the_turn() {
    let previous = Pose::from_parts(
        Vector3::new(0.5, -0.3, 1.04),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.1),
    );
    let current = Pose::from_parts(
        Vector3::new(0.52, -0.3, 1.0),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
    );
    let frame = FeatureFrame::new(&DynamicsConfig::residual(), 2, current.translation);
    let (world, world_prev) = (corners(&current), corners(&previous));
    let s = object_summary(&world, &world_prev, &current, &previous, Some(0.0), &frame);
    let want = [
        0.9 / 0.5,
        f32::NAN, // the lowest corner's horizontal increment includes the turn
        f32::NAN,
        -0.02 / 0.1,
        1.0 / 0.5,
        0.01 / 0.1,
        0.0,
        -0.02 / 0.1,
        0.0,
        0.0,
        0.1 / 0.2,
        f32::NAN, // the lowest corner's horizontal offset depends on the turn
        f32::NAN,
        -0.1 / 0.2,
    ];
    for (i, (got, want)) in s.iter().zip(want).enumerate() {
        if want.is_finite() {
            assert!(
                (got - want).abs() < 1e-4,
                "summary[{i}] = {got}, expected {want}"
            );
        }
    }
    let none = object_summary(&world, &world_prev, &current, &previous, None, &frame);
    assert_eq!((none[0], none[4]), (8.0, 8.0));
    let under = object_summary(&world, &world_prev, &current, &previous, Some(-9.0), &frame);
    assert_eq!((under[0], under[4]), (8.0, 8.0));
    assert_eq!(none[5..], s[5..]);
}

/// Two cubes (half extent 0.1 m) 1 m up, side by side along x with 1 cm between their facing
/// corners, the second closing on the first at 3 cm per frame, and a third cube far away:
/// each of the pair reads the 1 cm gap, the direction to the other, the facing side's offset
/// from its centre (0.1 m along x), the closing velocity and half its corners in the patch; the
/// lone cube reads no contact.
#[test]
fn contact_summary_reads_where_and_how_fast_objects_meet() {
    let cfg = ModelConfig::small();
    let at = |x: f32, y: f32| Pose::from_parts(Vector3::new(x, y, 1.0), UnitQuaternion::identity());
    let current = [at(0.0, 0.0), at(0.21, 0.0), at(0.0, 3.0)];
    let previous = [at(0.0, 0.0), at(0.24, 0.0), at(0.0, 3.0)];
    let reference = corners(&Pose::from_parts(
        Vector3::zeros(),
        UnitQuaternion::identity(),
    ));
    let points = ScenePoints::new(
        &cfg,
        std::iter::repeat_n(reference.as_slice(), 3),
        &current,
        &previous,
    );
    let r = cfg.contact_radius;
    let summary = |j: usize| {
        let frame = FeatureFrame::new(&cfg.dynamics, 1, current[j].translation);
        let range = points.offsets[j]..points.offsets[j + 1];
        let nearest = nearest_object_gap(&points.contact, range.clone());
        contact_summary(
            &points.contact,
            &points.world,
            &points.world_prev,
            range,
            current[j].translation,
            nearest,
            r,
            &frame,
        )
    };
    let gap = 0.01 / r;
    let first = [gap, 1.0, 0.0, 0.0, 0.5, 0.0, 0.0, -0.3, 0.0, 0.0, 0.5];
    let second = [gap, -1.0, 0.0, 0.0, -0.5, 0.0, 0.0, 0.3, 0.0, 0.0, 0.5];
    for (j, want) in [(0, first), (1, second)] {
        let got = summary(j);
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            assert!(
                (g - w).abs() < 1e-4,
                "object {j}: summary[{i}] = {g}, expected {w}"
            );
        }
    }
    let lone = summary(2);
    assert_eq!(lone[0], 1.0);
    assert!(lone[1..].iter().all(|&v| v == 0.0), "lone cube: {lone:?}");
}

/// Each unit's parameters (the summaries' MLPs, the wrench, the messages) are created after the
/// rest and its last layer starts at zero: a random model with it steps exactly as the one
/// without from the same seed, and so does a model widened with it; widening twice is refused.
#[test]
fn a_model_gains_a_unit_as_the_same_function() {
    for kind in ModelUnit::ALL {
        let plain = ModelConfig::small();
        assert!(!kind.enabled(&plain.dynamics));
        let mut with = plain.clone();
        kind.set(&mut with.dynamics, true);
        let a = RigidFormer::new_frozen(plain, 5, &Device::Cpu).unwrap();
        let b = RigidFormer::new_frozen(with, 5, &Device::Cpu).unwrap();
        let wide = a.widened_with_unit(kind, 7, false).unwrap();
        assert!(kind.enabled(&wide.config().dynamics));
        assert_eq!(
            wide.parameter_count(),
            b.parameter_count(),
            "{kind:?}: the widened model has the unit's parameters"
        );
        for (seed, k) in [(1, 1), (2, 4)] {
            let reference = step_random_scene(&a, seed, k);
            for (name, model) in [("random", &b), ("widened", &wide)] {
                let diff = max_pose_diff(&reference, &step_random_scene(model, seed, k));
                assert!(
                    diff < 1e-5,
                    "{kind:?}, {name}, seed {seed}, k {k}: differs by {diff}"
                );
            }
        }
        let twice = wide.widened_with_unit(kind, 7, false);
        assert!(twice.err().unwrap().to_string().contains("already"));
    }
}

/// A trainable model with both summaries: each summary's last layer receives a gradient from
/// the first backward pass, and the model round-trips through a checkpoint with them on.
#[test]
fn summary_layers_learn_and_save() {
    let mut cfg = ModelConfig::tiny();
    cfg.dynamics.object_summary = true;
    cfg.dynamics.contact_summary = true;
    let model = RigidFormer::new(cfg, 3, &Device::Cpu).unwrap();
    let (objects, state) = random_scene(4, 3, 64);
    // Targets 5 cm below constant velocity (any target gives a gradient).
    let target = constant_velocity_targets(&state, 0.05);
    for name in ["summary.1.weight", "contact_summary.1.weight"] {
        let (g, _) = one_step_gradient(&model, objects.clone(), &state, &target, 1, name);
        let norm = squared_norm(&g);
        assert!(norm > 0.0 && norm.is_finite(), "{name} gradient {norm}");
    }

    let back = common::saved_and_reloaded(&model, "summary");
    assert!(back.config().dynamics.object_summary);
    assert!(back.config().dynamics.contact_summary);
}

/// `a` and `b` step two random scenes (step sizes 1 and 3) to the same poses within 1e-5.
fn assert_same_steps(a: &RigidFormer, b: &RigidFormer) {
    for (seed, k) in [(1, 1), (2, 3)] {
        let diff = max_pose_diff(
            &step_random_scene(a, seed, k),
            &step_random_scene(b, seed, k),
        );
        assert!(diff < 1e-5, "seed {seed}, k {k}: differs by {diff}");
    }
}

/// A coarse output unit starts at zero (its MLP's last layer), so a random model with one
/// steps exactly as the one without from the same seed; its last layer receives a gradient; the
/// unit survives a checkpoint; a non-positive unit is refused.
#[test]
fn a_coarse_output_unit_starts_at_zero_and_learns() {
    let plain = ModelConfig::tiny();
    let mut with = plain.clone();
    with.accel_coarse_scale = Some(0.2);
    let a = RigidFormer::new_frozen(plain, 8, &Device::Cpu).unwrap();
    let b = RigidFormer::new(with.clone(), 8, &Device::Cpu).unwrap();
    assert_same_steps(&a, &b);
    let (objects, state) = random_scene(4, 3, 64);
    let target: Vec<Pose> = state.current.clone();
    let (g, _) = one_step_gradient(&b, objects, &state, &target, 1, "anchors.coarse.1.weight");
    let norm = squared_norm(&g);
    assert!(norm > 0.0 && norm.is_finite(), "coarse gradient {norm}");

    let dir = std::env::temp_dir().join(format!("dynaserve-coarse-{}", std::process::id()));
    b.save(&dir).unwrap();
    let back = load_rigidformer(&dir, &Device::Cpu, false).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(back.config().accel_coarse_scale, Some(0.2));

    with.accel_coarse_scale = Some(0.0);
    let err = RigidFormer::new(with, 8, &Device::Cpu).err().unwrap();
    assert!(err.to_string().contains("accel_coarse_scale"), "{err}");
}

/// A model deepened with new decoder blocks after blocks 1, 3 and 5 steps exactly as before
/// (the old blocks moved to their new places, the new ones the identity), has the new blocks'
/// parameters and its taps on the new blocks; bad indices are refused.
#[test]
fn a_deepened_model_computes_the_same_function() {
    let a = RigidFormer::new_frozen(ModelConfig::small(), 5, &Device::Cpu).unwrap();
    assert_eq!(
        (a.config().blocks, &a.config().anchor_taps[..]),
        (6, &[1, 3, 5][..])
    );
    let deep = a.deepened(&[1, 3, 5], 9, false).unwrap();
    assert_eq!(deep.config().blocks, 9);
    assert_eq!(deep.config().anchor_taps, vec![2, 5, 8]);
    let per_block = a.parameter_count()
        - RigidFormer::new_frozen(
            ModelConfig {
                blocks: 5,
                anchor_taps: vec![1, 3, 4],
                ..ModelConfig::small()
            },
            5,
            &Device::Cpu,
        )
        .unwrap()
        .parameter_count();
    assert_eq!(deep.parameter_count(), a.parameter_count() + 3 * per_block);
    for (seed, k) in [(1, 1), (2, 4)] {
        let diff = max_pose_diff(
            &step_random_scene(&a, seed, k),
            &step_random_scene(&deep, seed, k),
        );
        assert!(diff < 1e-5, "seed {seed}, k {k}: differs by {diff}");
    }
    for bad in [&[][..], &[6][..], &[2, 2][..]] {
        let err = a.deepened(bad, 9, false).err().unwrap().to_string();
        assert!(err.contains("distinct indices below 6"), "{bad:?}: {err}");
    }
}

/// The inserted block's zero output projection receives a gradient from the first backward
/// pass, so training moves it off the identity.
#[test]
fn an_inserted_block_learns() {
    let model = RigidFormer::new(ModelConfig::tiny(), 3, &Device::Cpu)
        .unwrap()
        .deepened(&[0], 4, true)
        .unwrap();
    assert_eq!(model.config().anchor_taps, vec![1, 2]);
    let (objects, state) = random_scene(4, 3, 64);
    let target = constant_velocity_targets(&state, 0.05);
    let name = "decoder.blocks.1.attn.out.weight";
    let (g, _) = one_step_gradient(&model, objects, &state, &target, 1, name);
    let norm = squared_norm(&g);
    assert!(norm > 0.0 && norm.is_finite(), "{name} gradient {norm}");
}

/// A model whose encoder is widened (per-point MLP 32 -> 64 channels, first set-abstraction
/// level 64 -> 96) steps exactly as before, in inference and in the trainable composition,
/// has the larger parameter count of its widths, and refuses a narrower or unchanged width.
#[test]
fn a_widened_encoder_computes_the_same_function() {
    let a = RigidFormer::new_frozen(ModelConfig::small(), 5, &Device::Cpu).unwrap();
    let wide = a.widened_encoder(64, 96, 9, false).unwrap();
    assert_eq!((wide.config().point_dim, wide.config().sa_dim), (64, 96));
    let fresh = RigidFormer::new_frozen(wide.config().clone(), 5, &Device::Cpu).unwrap();
    assert_eq!(wide.parameter_count(), fresh.parameter_count());
    assert!(wide.parameter_count() > a.parameter_count());
    let trainable = a.widened_encoder(64, 96, 9, true).unwrap();
    for (seed, k) in [(1, 1), (2, 4)] {
        let before = step_random_scene(&a, seed, k);
        for model in [&wide, &trainable] {
            let diff = max_pose_diff(&before, &step_random_scene(model, seed, k));
            assert!(diff < 1e-5, "seed {seed}, k {k}: differs by {diff}");
        }
        // A fresh model of the wide shape is a different function: the copy is not trivial.
        assert!(max_pose_diff(&before, &step_random_scene(&fresh, seed, k)) > 1e-4);
    }
    for (c1, c2) in [(16, 64), (32, 32), (32, 64)] {
        let err = a
            .widened_encoder(c1, c2, 9, false)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("must grow"), "({c1}, {c2}): {err}");
    }
}

/// The widened per-point MLP's new output rows start at zero and get a gradient from the first
/// backward pass, so training puts the new channels to use.
#[test]
fn a_widened_encoder_learns() {
    let model = RigidFormer::new(ModelConfig::tiny(), 3, &Device::Cpu)
        .unwrap()
        .widened_encoder(24, 24, 4, true)
        .unwrap();
    let (objects, state) = random_scene(4, 3, 64);
    let target = constant_velocity_targets(&state, 0.05);
    let name = "encoder.point.1.weight";
    let (g, _) = one_step_gradient(&model, objects, &state, &target, 1, name);
    let rows = g.narrow(0, 16, 8).unwrap();
    let norm = squared_norm(&rows);
    assert!(
        norm > 0.0 && norm.is_finite(),
        "{name} new rows' gradient {norm}"
    );
}
