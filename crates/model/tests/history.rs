//! The history inputs: each point's acceleration over the previous step beyond free fall is
//! zero for a body in free fall and for unknown earlier poses and measures a landing; a model
//! widened with them computes the same steps with or without earlier poses, its new weight
//! columns receive gradients, and earlier poses of the wrong count are refused.
mod common;

use common::{
    FIRST_LAYER, constant_velocity_targets, first_layer_dims, max_pose_diff, one_step_gradient,
    random_scene, squared_norm,
};
use dynaserve_model::{
    BASE_POINT_FEATURES, CONTACT_VELOCITY_FEATURES, Device, FeatureFrame, FeatureNormalization,
    HISTORY_FEATURES, InputGroup, ModelConfig, ModelError, Pose, RigidFormer, ScenePoints,
    SceneState, StepItem, WorldModel,
};
use nalgebra::{UnitQuaternion, Vector3};

/// Eight corners of a 0.2 m cube, body frame.
fn corners() -> Vec<[f32; 3]> {
    let s = [-0.1f32, 0.1];
    let mut out = Vec::with_capacity(8);
    for x in s {
        for y in s {
            for z in s {
                out.push([x, y, z]);
            }
        }
    }
    out
}

fn at(p: [f32; 3], yaw: f32) -> Pose {
    Pose::from_parts(
        Vector3::from(p),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

/// The history features of every point of one object placed at `earlier`, `previous`,
/// `current` (or without `earlier`), step size `k` frames.
fn history_of(
    cfg: &ModelConfig,
    poses: [Pose; 3],
    with_earlier: bool,
    k: u32,
) -> Vec<[f32; HISTORY_FEATURES]> {
    let reference = corners();
    let [earlier, previous, current] = poses;
    let mut points = ScenePoints::new(cfg, [reference.as_slice()], &[current], &[previous]);
    if with_earlier {
        points = points.with_history(cfg, [reference.as_slice()], &[earlier], k);
    }
    let frame = FeatureFrame::new(&cfg.dynamics, k, current.translation);
    let at = cfg.point_features() - HISTORY_FEATURES;
    let mut raw = vec![0f32; cfg.point_features()];
    reference
        .iter()
        .enumerate()
        .map(|(q, x)| {
            points.raw_features(q, *x, [0.0, 0.5, 0.5], &frame, &cfg.dynamics, &mut raw);
            [raw[at], raw[at + 1], raw[at + 2]]
        })
        .collect()
}

fn history_config() -> ModelConfig {
    let mut cfg = ModelConfig::tiny();
    cfg.dynamics.history = true;
    cfg.normalization = FeatureNormalization::defaults_for(&cfg.dynamics);
    cfg
}

#[test]
fn history_is_zero_in_free_fall_and_without_earlier_poses_and_measures_a_landing() {
    let cfg = history_config();
    assert_eq!(
        cfg.point_features(),
        BASE_POINT_FEATURES + CONTACT_VELOCITY_FEATURES + HISTORY_FEATURES
    );
    assert_eq!(
        InputGroup::History.offset(&cfg.dynamics),
        BASE_POINT_FEATURES + CONTACT_VELOCITY_FEATURES
    );
    let g = cfg.gravity[2];
    for k in [1u32, 2, 4] {
        // Free fall from 3 m at 1 m/s sideways, sampled every k frames: the second difference
        // is exactly g (k dt)^2, so the feature is zero.
        let h = k as f32 * cfg.dt_frame;
        let fall = |i: f32| at([i * h, 0.0, 3.0 + 0.5 * g * (i * h).powi(2)], 0.3);
        let free = history_of(&cfg, [fall(0.0), fall(1.0), fall(2.0)], true, k);
        for a in &free {
            assert!(
                a.iter().all(|v| v.abs() < 2e-4),
                "k {k}: free fall reads {a:?}"
            );
        }
        // Unknown earlier poses read as zero too, whatever the motion.
        let none = history_of(&cfg, [fall(0.0), at([0.0; 3], 1.0), fall(2.0)], false, k);
        assert!(none.iter().all(|a| *a == [0.0; 3]));
    }
    // A landing: falling at 2 m/s over the previous frame, at rest now. The second difference
    // is the frame's fall undone, +2 m/s * dt_frame in z, and the feature is that beyond free
    // fall: minus g dt_frame^2 (metres per frame^2).
    let dt = cfg.dt_frame;
    let landing = history_of(
        &cfg,
        [
            at([0.0, 0.0, 0.1 + 2.0 * dt], 0.0),
            at([0.0, 0.0, 0.1], 0.0),
            at([0.0, 0.0, 0.1], 0.0),
        ],
        true,
        1,
    );
    let expected = 2.0 * dt - g * dt * dt;
    for a in &landing {
        assert!(a[0].abs() < 1e-5 && a[1].abs() < 1e-5);
        assert!(
            (a[2] - expected).abs() < 1e-4,
            "landing reads {a:?}, expected {expected} m per frame^2 in z"
        );
    }
}

/// A model widened with the history computes the same step, with and without earlier
/// poses (its new columns start at zero), the earlier poses reach its new columns' gradient,
/// and a state with earlier poses for the wrong number of objects is refused by name.
#[test]
fn widened_model_steps_the_same_and_learns_from_earlier_poses() {
    let old = RigidFormer::new(ModelConfig::tiny(), 11, &Device::Cpu).unwrap();
    let extra = FeatureNormalization {
        mean: vec![0.0; HISTORY_FEATURES],
        std: vec![0.01; HISTORY_FEATURES],
    };
    let wide = old
        .widened_with_inputs(InputGroup::History, &extra, true)
        .unwrap();
    let width = BASE_POINT_FEATURES + CONTACT_VELOCITY_FEATURES + HISTORY_FEATURES;
    assert_eq!(first_layer_dims(&wide)[1], width);
    assert_eq!(wide.config().normalization.std[width - 3..], [0.01; 3]);

    let (objects, state) = random_scene(6, 4, 64);
    // Earlier poses off the constant-velocity line: every object was turned and shifted.
    let mut with_earlier = state.clone();
    with_earlier.earlier = Some(
        state
            .previous
            .iter()
            .map(|p| {
                let mut e = *p;
                e.translation[2] += 0.05;
                e
            })
            .collect(),
    );
    let step = |m: &RigidFormer, s: &SceneState| {
        let scene = m.prepare(objects.clone()).unwrap();
        m.step(&[StepItem {
            scene: &scene,
            state: s,
            dt_steps: 2,
        }])
        .unwrap()
        .remove(0)
    };
    let base = step(&old, &state);
    for s in [&state, &with_earlier] {
        let diff = max_pose_diff(&base, &step(&wide, s));
        assert!(diff < 1e-5, "widened model differs by {diff}");
    }

    let target = constant_velocity_targets(&state, 0.01);
    let columns = |s: &SceneState| {
        let (g, _) = one_step_gradient(&wide, objects.clone(), s, &target, 2, FIRST_LAYER);
        squared_norm(
            &g.narrow(1, width - HISTORY_FEATURES, HISTORY_FEATURES)
                .unwrap(),
        )
    };
    let (without, with) = (columns(&state), columns(&with_earlier));
    assert!(
        with > 0.0 && with.is_finite(),
        "history columns' gradient {with}"
    );
    // Without earlier poses the features are zero and so is their normalised value (mean 0
    // here): the columns get no gradient.
    assert_eq!(without, 0.0);

    let mut short = with_earlier.clone();
    short.earlier.as_mut().unwrap().pop();
    let scene = wide.prepare(objects.clone()).unwrap();
    let err = wide
        .step(&[StepItem {
            scene: &scene,
            state: &short,
            dt_steps: 2,
        }])
        .unwrap_err();
    assert!(matches!(err, ModelError::InvalidInput(_)));
    assert!(err.to_string().contains("3 earlier poses"), "{err}");
}

#[test]
fn advancing_a_state_keeps_the_step_before() {
    let p = |x: f32| at([x, 0.0, 1.0], 0.0);
    let mut s = SceneState::new(vec![p(0.0)], vec![p(1.0)]);
    assert_eq!(s.earlier, None);
    s.advance(vec![p(2.0)]);
    assert_eq!(s.earlier, Some(vec![p(0.0)]));
    assert_eq!((s.previous[0], s.current[0]), (p(1.0), p(2.0)));
    // Absent in JSON means none; present, it round-trips.
    let json = serde_json::to_string(&s).unwrap();
    assert_eq!(serde_json::from_str::<SceneState>(&json).unwrap(), s);
    let two = r#"{"previous":[],"current":[]}"#;
    assert_eq!(
        serde_json::from_str::<SceneState>(two).unwrap().earlier,
        None
    );
}
