//! The contact partner inputs: a point whose contact feature reaches another object reads that
//! object's mass relative to its own, its friction and its restitution; the floor and empty
//! space read zeros; through the model's own input path (scene-relative mass included) the
//! values land in the documented columns; a model widened with them computes the same steps and
//! its new weight columns receive gradients.
mod common;

use common::{assert_widened_inputs_start_at_zero_and_learn, first_layer_dims};
use dynaserve_geometry::ContactSource;
use dynaserve_model::{
    BASE_POINT_FEATURES, CONTACT_PARTNER_FEATURES, CONTACT_PARTNER_MAX_LN_RATIO,
    CONTACT_VELOCITY_FEATURES, Device, FeatureFrame, FeatureNormalization, InputGroup, ModelConfig,
    Pose, RigidFormer, ScenePoints, WorldModel, contact_partner_features, object_params,
};
use nalgebra::{UnitQuaternion, Vector3};

fn at(p: [f32; 3]) -> Pose {
    Pose::from_parts(Vector3::from(p), UnitQuaternion::identity())
}

#[test]
fn the_function_reads_the_partner_object_and_nothing_else() {
    // Object 0 owns points 0..2, object 1 points 2..5.
    let offsets = [0, 2, 5];
    let params = [object_params(2.0, 0.4, 0.3), object_params(0.5, 0.9, 0.1)];
    let ratio = (0.5f32 / 2.0).ln();
    let f = contact_partner_features(ContactSource::Point(3), 1, &offsets, &params);
    assert!(
        (f[0] - 1.0).abs() < 1e-6 && (f[1] - ratio).abs() < 1e-5,
        "{f:?}"
    );
    assert_eq!((f[2], f[3]), (0.9, 0.1));
    // Seen from the other side: the inverse ratio and the first object's material.
    let g = contact_partner_features(ContactSource::Point(0), 4, &offsets, &params);
    assert!(
        (g[1] + ratio).abs() < 1e-5 && g[2] == 0.4 && g[3] == 0.3,
        "{g:?}"
    );
    // A ratio beyond the clamp reads the clamp.
    let heavy = [object_params(1.0, 0.5, 0.5), object_params(1e4, 0.5, 0.5)];
    let h = contact_partner_features(ContactSource::Point(2), 0, &offsets, &heavy);
    assert_eq!(h[1], CONTACT_PARTNER_MAX_LN_RATIO);
    for source in [ContactSource::Ground, ContactSource::Free] {
        let z = contact_partner_features(source, 0, &offsets, &params);
        assert_eq!(z, [0.0; CONTACT_PARTNER_FEATURES]);
    }
    // Without the objects' parameters there is nothing to read.
    let none = contact_partner_features(ContactSource::Point(3), 1, &offsets, &[]);
    assert_eq!(none, [0.0; CONTACT_PARTNER_FEATURES]);
}

/// Two small clouds 4 cm apart high above the floor, and one resting on it far away: the
/// facing points read each other's parameters at the group's columns, the resting cloud reads
/// zeros (its nearest surface is the floor).
#[test]
fn scene_points_write_the_partner_at_the_groups_columns() {
    let mut cfg = ModelConfig::tiny();
    cfg.dynamics.contact_partner = true;
    cfg.normalization = FeatureNormalization::defaults_for(&cfg.dynamics);
    let cloud: Vec<[f32; 3]> = vec![[0.0, 0.0, 0.0], [0.0, 0.02, 0.0], [0.0, 0.0, 0.02]];
    let poses = [
        at([0.0, 0.0, 2.0]),
        at([0.04, 0.0, 2.0]),
        at([3.0, 0.0, cfg.ground_z.unwrap() + 0.01]),
    ];
    let references = [cloud.as_slice(), cloud.as_slice(), cloud.as_slice()];
    let params = [
        object_params(1.0, 0.2, 0.7),
        object_params(3.0, 0.6, 0.1),
        object_params(1.0, 0.5, 0.5),
    ];
    let points =
        ScenePoints::new(&cfg, references, &poses, &poses).with_object_params(params.to_vec());
    let col = InputGroup::ContactPartner.offset(&cfg.dynamics);
    assert_eq!(col, BASE_POINT_FEATURES + CONTACT_VELOCITY_FEATURES);
    assert_eq!(col + CONTACT_PARTNER_FEATURES, cfg.point_features());
    let mut raw = vec![0f32; cfg.point_features()];
    for q in 0..9 {
        let object = q / 3;
        let frame = FeatureFrame::new(&cfg.dynamics, 1, poses[object].translation);
        points.raw_features(
            q,
            cloud[q % 3],
            params[object],
            &frame,
            &cfg.dynamics,
            &mut raw,
        );
        let got = &raw[col..col + CONTACT_PARTNER_FEATURES];
        let want = match object {
            0 => [1.0, 3f32.ln(), 0.6, 0.1],
            1 => [1.0, -(3f32.ln()), 0.2, 0.7],
            _ => [0.0; CONTACT_PARTNER_FEATURES],
        };
        assert!(
            got.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-5),
            "point {q} reads {got:?}, expected {want:?}"
        );
    }
}

/// A model widened with the contact partner computes the same step (its new columns start at
/// zero), and the new columns receive gradients from objects near each other.
#[test]
fn widened_model_steps_the_same_and_learns_from_the_partner() {
    let old = RigidFormer::new(ModelConfig::tiny(), 12, &Device::Cpu).unwrap();
    let extra = FeatureNormalization {
        mean: vec![0.1, 0.0, 0.05, 0.05],
        std: vec![0.3, 0.5, 0.2, 0.2],
    };
    let wide = old
        .widened_with_inputs(InputGroup::ContactPartner, &extra, true)
        .unwrap();
    let width = BASE_POINT_FEATURES + CONTACT_VELOCITY_FEATURES + CONTACT_PARTNER_FEATURES;
    assert_eq!(first_layer_dims(&wide)[1], width);
    assert!(wide.config().dynamics.contact_partner);

    assert_widened_inputs_start_at_zero_and_learn(
        &old,
        &wide,
        CONTACT_PARTNER_FEATURES,
        "contact partner",
    );
}
