//! The approach inputs: a point nearing the ground or another body reads the speed at which
//! it closes on that surface, the fraction of the step before it gets there and how far behind
//! the surface the free step would end, in the documented units at every step size; empty
//! space and receding surfaces read as nothing to reach; a model widened with them computes
//! the same steps and its new weight columns receive gradients.
mod common;

use common::{assert_widened_inputs_start_at_zero_and_learn, first_layer_dims};
use dynaserve_model::{
    APPROACH_FEATURES, BASE_POINT_FEATURES, Body, CONTACT_VELOCITY_FEATURES, Device, FeatureFrame,
    FeatureNormalization, InputGroup, ModelConfig, Pose, RigidFormer, ScenePoints, WorldModel,
    approach_features,
};
use nalgebra::{UnitQuaternion, Vector3};

fn at(p: [f32; 3]) -> Pose {
    Pose::from_parts(Vector3::from(p), UnitQuaternion::identity())
}

fn approach_config() -> ModelConfig {
    let mut cfg = ModelConfig::tiny();
    cfg.dynamics.approach = true;
    cfg.normalization = FeatureNormalization::defaults_for(&cfg.dynamics);
    cfg
}

/// The approach features of every point of the objects `references` placed at `previous`
/// and `current`, step size `k` frames, object after object.
fn approach_of(
    cfg: &ModelConfig,
    references: &[&[[f32; 3]]],
    previous: &[Pose],
    current: &[Pose],
    k: u32,
) -> Vec<[f32; APPROACH_FEATURES]> {
    let normals = || {
        references
            .iter()
            .map(|r| dynaserve_model::body_normals(r))
            .collect::<Vec<_>>()
    };
    let bodies: Vec<Body<'_>> = references
        .iter()
        .map(|&reference| Body {
            reference,
            params: [0.0, 0.5, 0.5],
        })
        .collect();
    let points = ScenePoints::for_model(cfg, &bodies, normals, current, previous, None, k);
    let at = cfg.point_features() - APPROACH_FEATURES;
    let mut raw = vec![0f32; cfg.point_features()];
    let mut out = Vec::new();
    let mut q = 0;
    for (reference, pose) in references.iter().zip(current) {
        let frame = FeatureFrame::new(&cfg.dynamics, k, pose.translation);
        for x in reference.iter() {
            points.raw_features(q, *x, [0.0, 0.5, 0.5], &frame, &cfg.dynamics, &mut raw);
            out.push([raw[at], raw[at + 1], raw[at + 2]]);
            q += 1;
        }
    }
    out
}

fn close(a: [f32; 3], b: [f32; 3]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5)
}

#[test]
fn the_function_reads_closing_speed_reach_and_depth() {
    let cfg = approach_config();
    let frame = |k: u32| FeatureFrame::new(&cfg.dynamics, k, [0.0; 3]);
    // A surface facing +z 0.05 m below; the point closes on it at 0.1 m per frame.
    let normals = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.05];
    let r = cfg.contact_radius;
    assert!(close(
        approach_features([0.0, 0.0, 0.1], &normals, r, &frame(1)),
        [0.1, 0.5, 0.05]
    ));
    // Two frames per step: the step travels 0.2 m, reaches the surface a quarter in and ends
    // 0.15 m behind it, 0.075 m per frame.
    assert!(close(
        approach_features([0.0, 0.0, 0.1], &normals, r, &frame(2)),
        [0.1, 0.25, 0.075]
    ));
    // Too slow to get there within the step, or receding: nothing reached.
    assert!(close(
        approach_features([0.0, 0.0, 0.02], &normals, r, &frame(1)),
        [0.02, 1.0, 0.0]
    ));
    assert!(close(
        approach_features([0.3, 0.0, -0.1], &normals, r, &frame(1)),
        [-0.1, 1.0, 0.0]
    ));
    // Already touching (or behind the plane): reached at once.
    let touching = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, -0.01];
    assert!(close(
        approach_features([0.0, 0.0, 0.1], &touching, r, &frame(1)),
        [0.1, 0.0, 0.11]
    ));
    // Nothing within the contact radius (a zero normal).
    let free = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, r];
    assert_eq!(
        approach_features([0.0, 0.0, 5.0], &free, r, &frame(1)),
        [0.0, 1.0, 0.0]
    );
    // The depth is bounded by the contact radius (per frame).
    let deep = approach_features([0.0, 0.0, 3.0], &normals, r, &frame(1));
    assert!((deep[2] - r).abs() < 1e-6, "{deep:?}");
}

#[test]
fn points_nearing_the_ground_and_another_body_read_their_approach() {
    let cfg = approach_config();
    assert_eq!(
        InputGroup::Approach.offset(&cfg.dynamics),
        BASE_POINT_FEATURES + CONTACT_VELOCITY_FEATURES
    );
    let dt = cfg.dt_frame;
    // One point 0.06 m above the ground falling at 2 m/s, one step of one frame.
    let low = [[0.0f32, 0.0, 0.0]];
    let v = 2.0;
    let z = cfg.ground_z.unwrap() + 0.06;
    let landing = approach_of(
        &cfg,
        &[&low],
        &[at([0.0, 0.0, z + v * dt])],
        &[at([0.0, 0.0, z])],
        1,
    );
    let travel = v * dt;
    let expected = [travel, 0.06 / travel, travel - 0.06];
    assert!(
        close(landing[0], expected),
        "landing reads {:?}, expected {expected:?}",
        landing[0]
    );

    // Two flat 3 x 3 patches (a point behind each, so the estimated normals point out of the
    // faces), high above the ground: the left face at x = 0.05 flying right at 3 m/s, the
    // right face at x = 0.1, still. Their faces are 0.05 m apart and close by 0.125 m in the
    // frame: they meet 0.4 into it and the free step would end 0.075 m deep.
    let patch = |x: f32| -> Vec<[f32; 3]> {
        let mut out = Vec::new();
        for a in [-0.02f32, 0.0, 0.02] {
            for b in [-0.02f32, 0.0, 0.02] {
                out.push([x, a, b]);
            }
        }
        out.push([-x * 4.0, 0.0, 0.0]);
        out
    };
    let (left, right) = (patch(0.05), patch(-0.05));
    let v = 3.0;
    let h = 2.0;
    let meeting = approach_of(
        &cfg,
        &[&left, &right],
        &[at([-v * dt, 0.0, h]), at([0.15, 0.0, h])],
        &[at([0.0, 0.0, h]), at([0.15, 0.0, h])],
        1,
    );
    let travel = v * dt;
    let expected = [travel, 0.05 / travel, travel - 0.05];
    // The moving face closes on the still one, and the still face sees it come just as fast.
    for f in meeting[..9].iter().chain(&meeting[10..19]) {
        assert!(
            close(*f, expected),
            "face point reads {f:?}, expected {expected:?}"
        );
    }
    // The points behind the faces have nothing within the contact radius.
    assert_eq!(
        (meeting[9], meeting[19]),
        ([0.0, 1.0, 0.0], [0.0, 1.0, 0.0])
    );
    // Far apart in the air: nothing to reach.
    let apart = approach_of(
        &cfg,
        &[&left, &right],
        &[at([-v * dt, 0.0, h]), at([3.0, 0.0, h])],
        &[at([0.0, 0.0, h]), at([3.0, 0.0, h])],
        1,
    );
    assert!(apart.iter().all(|f| *f == [0.0, 1.0, 0.0]));
}

/// A model widened with the approach computes the same step (its new columns start at zero)
/// and the new columns receive gradients from objects near each other.
#[test]
fn widened_model_steps_the_same_and_learns_from_the_approach() {
    let old = RigidFormer::new(ModelConfig::tiny(), 12, &Device::Cpu).unwrap();
    let extra = FeatureNormalization {
        mean: vec![0.0, 1.0, 0.0],
        std: vec![0.05, 0.3, 0.05],
    };
    let wide = old
        .widened_with_inputs(InputGroup::Approach, &extra, true)
        .unwrap();
    let width = BASE_POINT_FEATURES + CONTACT_VELOCITY_FEATURES + APPROACH_FEATURES;
    assert_eq!(first_layer_dims(&wide)[1], width);
    assert!(wide.config().dynamics.approach && !wide.config().dynamics.surface_normals);

    assert_widened_inputs_start_at_zero_and_learn(&old, &wide, APPROACH_FEATURES, "approach");
}
