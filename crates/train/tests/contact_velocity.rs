//! A 12-feature model (one that predates the contact velocity inputs, with fitted-looking
//! normalisation constants) widened for those inputs steps a real simulated scene with
//! object-object contact exactly as before widening (the new inputs start with zero weights),
//! at several frames and step sizes. The shipped checkpoint already takes the contact velocity,
//! so the 12-feature model is built here.

use dynaserve_geometry::{ContactConfig, ContactSource, contact_hits};
use dynaserve_model::{
    Device, FeatureNormalization, ModelConfig, ObjectInput, RigidFormer, StepItem, WorldModel,
};
use dynaserve_sim::generators::generate_scene;
use dynaserve_sim::{GenerateOptions, Generator, Scenario};
use dynaserve_train::eval::observed_state;

#[test]
fn widened_model_steps_a_collision_scene_identically() {
    let mut cfg = ModelConfig::small();
    cfg.dynamics.contact_velocity = false;
    cfg.normalization = FeatureNormalization {
        mean: (0..12).map(|i| 0.01 * i as f32 - 0.05).collect(),
        std: (0..12).map(|i| 0.2 + 0.05 * i as f32).collect(),
    };
    let old = RigidFormer::new(cfg, 11, &Device::Cpu).unwrap();
    // Constants as a fit would give (non-zero means: the new inputs are not zero either).
    let extra = FeatureNormalization {
        mean: vec![0.001, -0.002, 0.02],
        std: vec![0.03, 0.03, 0.04],
    };
    let wide = old.widened_with_contact_velocity(&extra, false).unwrap();
    let opts = GenerateOptions::new(Generator::scenario(Scenario::Collide), 5, "test", 1);
    let record = generate_scene(&opts, 0).unwrap().record;
    let objects: Vec<ObjectInput> = record
        .objects
        .iter()
        .map(|o| ObjectInput {
            reference: o.reference_points.clone(),
            mass: o.mass,
            friction: o.friction,
            restitution: o.restitution,
            kinematic: o.kinematic,
        })
        .collect();
    let frames = record.objects[0].positions.len();
    let contact_cfg = ContactConfig {
        radius: old.config().contact_radius,
        ground_z: old.config().ground_z,
    };
    let (sa, sb) = (
        old.prepare(objects.clone()).unwrap(),
        wide.prepare(objects).unwrap(),
    );
    let mut worst = 0f32;
    let mut object_contacts = 0;
    let mut steps = 0;
    for start in (4..frames).step_by(4) {
        for k in [1u32, 2] {
            let state = observed_state(&record, start, k).unwrap();
            // Count the points touching another object at this frame.
            let mut world = Vec::new();
            let mut offsets = vec![0];
            for (o, p) in record.objects.iter().zip(&state.current) {
                world.extend(o.reference_points.iter().map(|x| p.transform_point(*x)));
                offsets.push(world.len());
            }
            object_contacts += contact_hits(&world, &offsets, &contact_cfg)
                .iter()
                .filter(|h| matches!(h.source, ContactSource::Point(_)))
                .count();
            let a = old
                .step(&[StepItem {
                    scene: &sa,
                    state: &state,
                    dt_steps: k,
                }])
                .unwrap();
            let b = wide
                .step(&[StepItem {
                    scene: &sb,
                    state: &state,
                    dt_steps: k,
                }])
                .unwrap();
            for (p, q) in a[0].iter().zip(&b[0]) {
                for d in 0..3 {
                    worst = worst.max((p.translation[d] - q.translation[d]).abs());
                }
                for d in 0..4 {
                    worst = worst.max((p.rotation[d] - q.rotation[d]).abs());
                }
            }
            steps += 1;
        }
    }
    eprintln!(
        "{steps} steps, {object_contacts} point-object contacts, max abs difference {worst:e}"
    );
    assert!(steps >= 10);
    assert!(
        object_contacts > 0,
        "the scene has no object-object contact"
    );
    assert!(worst < 1e-5, "widened model differs by {worst}");
}
