//! The surface normal inputs: between two sparsely sampled faces the point-to-plane height is
//! the true gap where the point-to-point distance is not; the ground and empty space read as
//! documented; a trained model widened with them computes the same steps, its new weight
//! columns receive gradients, and it saves and loads with them; the shipped checkpoint reads
//! with them, the contact velocity and the approach.
mod common;

use common::{
    FIRST_LAYER, constant_velocity_targets, first_layer_dims, max_pose_diff, one_step_gradient,
    random_scene, squared_norm, step_random_scene,
};
use dynaserve_model::{
    APPROACH_FEATURES, BASE_POINT_FEATURES, CONTACT_VELOCITY_FEATURES, Device, FeatureFrame,
    FeatureNormalization, InputGroup, ModelConfig, ObjectInput, Pose, RigidFormer,
    SURFACE_NORMAL_FEATURES, ScenePoints, SceneState, StepItem, WorldModel, body_normals,
    load_rigidformer,
};
use nalgebra::{UnitQuaternion, Vector3};

/// A cube of half-side 0.1 m sampled on a 4 x 4 grid per face (spacing 0.05 m), body frame.
fn cube() -> Vec<[f32; 3]> {
    let g = [-0.075f32, -0.025, 0.025, 0.075];
    let mut out = Vec::new();
    for axis in 0..3 {
        for side in [-0.1f32, 0.1] {
            for a in g {
                for b in g {
                    let mut p = [0.0; 3];
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

/// A point of `cube()` in the middle of its face (both in-face coordinates +-0.025 m), whose
/// nearest neighbours all lie on that face.
fn mid_face(p: &[f32; 3]) -> bool {
    p.iter().filter(|v| v.abs() < 0.05).count() == 2
}

fn close(a: &[f32], b: &[f32], tol: f32) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
}

fn pose(centre: [f32; 3], yaw: f32) -> Pose {
    Pose::from_parts(
        Vector3::from(centre),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

/// Cube A (turned half a turn about z, so its body -x face looks along world +x) faces cube B
/// across a 2 cm gap, B shifted sideways by half the point spacing; cube C hovers 5 cm above
/// the ground; cube D is far from everything.
#[test]
fn point_to_plane_height_is_the_gap_the_points_miss() {
    let mut cfg = ModelConfig::tiny();
    cfg.dynamics.surface_normals = true;
    cfg.normalization = FeatureNormalization::defaults_for(&cfg.dynamics);
    let nf = cfg.point_features();
    assert_eq!(
        nf,
        BASE_POINT_FEATURES + CONTACT_VELOCITY_FEATURES + SURFACE_NORMAL_FEATURES
    );
    let reference = cube();
    let normals = body_normals(&reference);
    let current = [
        pose([0.0, 0.0, 1.0], std::f32::consts::PI),
        pose([0.22, 0.025, 1.0], 0.0),
        pose([5.0, 0.0, 0.15], 0.0),
        pose([20.0, 0.0, 5.0], 0.0),
    ];
    let points = ScenePoints::new(
        &cfg,
        std::iter::repeat_n(reference.as_slice(), 4),
        &current,
        &current,
    )
    .with_normals(std::iter::repeat_n(normals.as_slice(), 4), &current);
    let at = BASE_POINT_FEATURES + CONTACT_VELOCITY_FEATURES;
    let mut raw = vec![0f32; nf];
    let mut checked = [0usize; 3];
    for (j, now) in current.iter().enumerate() {
        let frame = FeatureFrame::new(&cfg.dynamics, 1, now.translation);
        for (i, x) in reference.iter().enumerate() {
            let q = points.offsets[j] + i;
            points.raw_features(q, *x, [0.0, 0.5, 0.5], &frame, &cfg.dynamics, &mut raw);
            let own = &raw[at..at + 3];
            let (other, gap) = (&raw[at + 3..at + 6], raw[at + 6]);
            // Every normal is a unit vector; mid-face ones are the face's, turned by the pose.
            assert!((own.iter().map(|v| v * v).sum::<f32>() - 1.0).abs() < 1e-4);
            let world_x = points.world[q][0];
            if j == 0 && mid_face(x) && x[0] < -0.09 {
                // A's face towards B: the nearest point of B is 3.2 cm away, the plane 2 cm.
                assert!(close(own, &[1.0, 0.0, 0.0], 1e-4), "own normal {own:?}");
                assert!(
                    close(other, &[-1.0, 0.0, 0.0], 1e-4),
                    "B's normal {other:?}"
                );
                let distance = raw[..3].iter().map(|v| v * v).sum::<f32>().sqrt();
                assert!((distance - 0.032).abs() < 1e-3, "point distance {distance}");
                assert!((gap - 0.02).abs() < 1e-4, "A at x {world_x}: gap {gap}");
                checked[0] += 1;
            }
            if j == 2 && mid_face(x) && x[2] < -0.09 {
                // C's bottom: the ground's normal and the height above it.
                assert!(close(own, &[0.0, 0.0, -1.0], 1e-4), "own normal {own:?}");
                assert_eq!(other, &[0.0, 0.0, 1.0]);
                assert!((gap - 0.05).abs() < 1e-5, "C's bottom: gap {gap}");
                checked[1] += 1;
            }
            if j == 3 {
                assert_eq!(other, &[0.0; 3]);
                assert_eq!(gap, cfg.contact_radius);
                checked[2] += 1;
            }
        }
    }
    assert_eq!(checked, [4, 4, reference.len()]);
}

fn extra() -> FeatureNormalization {
    FeatureNormalization {
        mean: vec![0.0, 0.01, 0.02, 0.0, -0.01, 0.03, 0.1],
        std: vec![0.5, 0.6, 0.5, 0.4, 0.5, 0.6, 0.1],
    }
}

/// A trained-like model widened with the surface normals: same steps, the 7 new columns get
/// a gradient, the old constants are kept, the copy round-trips through a checkpoint, and
/// widening twice or with the wrong number of constants is refused.
#[test]
fn widened_model_steps_the_same_and_trains_its_new_columns() {
    let old = RigidFormer::new(ModelConfig::tiny(), 9, &Device::Cpu).unwrap();
    assert!(!old.config().dynamics.surface_normals);
    let wide = old.widened_with_surface_normals(&extra(), true).unwrap();
    assert_eq!(first_layer_dims(&wide)[1], 22);
    assert_eq!(wide.config().point_features(), 22);
    assert_eq!(
        wide.config().normalization.mean[..15],
        old.config().normalization.mean[..]
    );
    assert_eq!(wide.config().normalization.std[15..], extra().std[..]);
    for (seed, k) in [(1, 1), (2, 4)] {
        let diff = max_pose_diff(
            &step_random_scene(&old, seed, k),
            &step_random_scene(&wide, seed, k),
        );
        assert!(
            diff < 1e-5,
            "seed {seed}, k {k}: widened model differs by {diff}"
        );
    }

    let (objects, state) = random_scene(4, 5, 64);
    let target = constant_velocity_targets(&state, 0.0);
    let (g, _) = one_step_gradient(&wide, objects, &state, &target, 2, FIRST_LAYER);
    let norm = squared_norm(&g.narrow(1, 15, 7).unwrap());
    assert!(
        norm > 0.0 && norm.is_finite(),
        "new columns' gradient {norm}"
    );

    let dir = std::env::temp_dir().join(format!("dynaserve-normals-{}", std::process::id()));
    wide.save(&dir).unwrap();
    let back = load_rigidformer(&dir, &Device::Cpu, false).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(back.config(), wide.config());
    let diff = max_pose_diff(
        &step_random_scene(&wide, 5, 1),
        &step_random_scene(&back, 5, 1),
    );
    assert!(diff < 1e-6, "reloaded model differs by {diff}");

    let twice = wide.widened_with_surface_normals(&extra(), false);
    assert!(twice.err().unwrap().to_string().contains("already"));
    let short = FeatureNormalization {
        mean: vec![0.0; 3],
        std: vec![1.0; 3],
    };
    let bad = old.widened_with_surface_normals(&short, false);
    assert!(bad.err().unwrap().to_string().contains("needs 7"));
}

/// A model with surface normals but no contact velocity, widened with the contact velocity:
/// its new columns go between the base features and the normals, and it steps the same.
#[test]
fn contact_velocity_columns_go_before_the_normals() {
    let mut cfg = ModelConfig::tiny();
    cfg.dynamics.contact_velocity = false;
    cfg.dynamics.surface_normals = true;
    cfg.normalization = FeatureNormalization::defaults_for(&cfg.dynamics);
    let old = RigidFormer::new(cfg, 3, &Device::Cpu).unwrap();
    assert_eq!(first_layer_dims(&old)[1], 19);
    let cv = FeatureNormalization {
        mean: vec![0.0; 3],
        std: vec![0.05; 3],
    };
    let wide = old.widened_with_contact_velocity(&cv, false).unwrap();
    assert_eq!(first_layer_dims(&wide)[1], 22);
    let n = &wide.config().normalization;
    assert_eq!(n.std[12..15], [0.05; 3]);
    assert_eq!(n.std[15..], old.config().normalization.std[12..]);
    let diff = max_pose_diff(
        &step_random_scene(&old, 7, 2),
        &step_random_scene(&wide, 7, 2),
    );
    assert!(diff < 1e-5, "widened model differs by {diff}");
}

/// The shipped checkpoint was trained with three optional input groups: it reads as 25
/// features (the contact velocity's 3 after the base 12, the normals' 7 after them, the
/// approach's 3 last) with 25 normalisation constants, widening it again for any of them is
/// refused, and it steps a scene whose clouds are too small for a fitted plane (the normals
/// fall back to the radial direction) to finite poses.
#[test]
fn shipped_checkpoint_takes_the_contact_velocity_the_normals_and_the_approach() {
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rigidformer-small");
    let shipped = load_rigidformer(&dir, &Device::Cpu, false).unwrap();
    let dynamics = &shipped.config().dynamics;
    assert!(dynamics.contact_velocity && dynamics.surface_normals && dynamics.approach);
    assert!(!dynamics.history);
    let width = BASE_POINT_FEATURES
        + CONTACT_VELOCITY_FEATURES
        + SURFACE_NORMAL_FEATURES
        + APPROACH_FEATURES;
    assert_eq!(width, 25);
    assert_eq!(shipped.config().point_features(), width);
    assert_eq!(first_layer_dims(&shipped)[1], width);
    assert_eq!(shipped.config().normalization.mean.len(), width);
    let again = shipped.widened_with_surface_normals(&extra(), false);
    assert!(again.err().unwrap().to_string().contains("already"));
    let cv = FeatureNormalization {
        mean: vec![0.0; CONTACT_VELOCITY_FEATURES],
        std: vec![1.0; CONTACT_VELOCITY_FEATURES],
    };
    let again = shipped.widened_with_contact_velocity(&cv, false);
    assert!(again.err().unwrap().to_string().contains("already"));
    let approach = FeatureNormalization {
        mean: vec![0.0; APPROACH_FEATURES],
        std: vec![1.0; APPROACH_FEATURES],
    };
    let again = shipped.widened_with_inputs(InputGroup::Approach, &approach, false);
    assert!(again.err().unwrap().to_string().contains("already"));
    // Two objects of two points each: no plane fits, the estimator's fallback is used.
    let tiny = || ObjectInput {
        reference: vec![[-0.05, 0.0, 0.0], [0.05, 0.0, 0.0]],
        mass: 1.0,
        friction: 0.5,
        restitution: 0.2,
        kinematic: false,
    };
    let prepared = shipped.prepare(vec![tiny(), tiny()]).unwrap();
    let at = |x: f32, z: f32| Pose::from_parts(Vector3::new(x, 0.0, z), UnitQuaternion::identity());
    let state = SceneState {
        previous: vec![at(0.0, 0.3), at(0.5, 0.3)],
        current: vec![at(0.0, 0.29), at(0.5, 0.29)],
        earlier: None,
        carry: Default::default(),
    };
    let next = shipped
        .step(&[StepItem {
            scene: &prepared,
            state: &state,
            dt_steps: 1,
        }])
        .unwrap()
        .remove(0);
    for pose in &next {
        assert!(pose.translation.iter().all(|v| v.is_finite()), "{pose:?}");
    }
}
