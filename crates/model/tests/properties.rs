//! Structural properties of a randomly initialised RigidFormer: symmetries, rigidity, batch
//! independence, robustness to point counts.
mod common;

use common::{max_pose_diff, random_scene};
use dynaserve_model::{
    Device, Mode, ModelConfig, ModelUnit, ObjectInput, Pose, RigidFormer, SceneState, StepItem,
    WorldModel, rollout,
};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn tiny() -> RigidFormer {
    RigidFormer::new(ModelConfig::tiny(), 7, &Device::Cpu).unwrap()
}

fn step1(model: &RigidFormer, objects: Vec<ObjectInput>, state: &SceneState, dt: u32) -> Vec<Pose> {
    let scene = model.prepare(objects).unwrap();
    model
        .step(&[StepItem {
            scene: &scene,
            state,
            dt_steps: dt,
        }])
        .unwrap()
        .pop()
        .unwrap()
}

/// Objects close together so contact features and attention both matter.
fn close_scene(seed: u64, m: usize, n: usize) -> (Vec<ObjectInput>, SceneState) {
    let (objects, mut state) = random_scene(seed, m, n);
    for (j, (c, p)) in state
        .current
        .iter_mut()
        .zip(state.previous.iter_mut())
        .enumerate()
    {
        let off = [0.7 * j as f32, 0.0, 0.4 + 0.3 * (j % 2) as f32];
        let d: [f32; 3] = std::array::from_fn(|i| off[i] - c.translation[i]);
        c.translation = std::array::from_fn(|i| c.translation[i] + d[i]);
        p.translation = std::array::from_fn(|i| p.translation[i] + d[i]);
    }
    (objects, state)
}

#[test]
fn object_permutation_equivariance() {
    let model = tiny();
    let (objects, state) = close_scene(1, 6, 96);
    let base = step1(&model, objects.clone(), &state, 1);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut perm: Vec<usize> = (0..objects.len()).collect();
    perm.shuffle(&mut rng);
    let objects_p: Vec<ObjectInput> = perm.iter().map(|&i| objects[i].clone()).collect();
    let state_p = SceneState {
        previous: perm.iter().map(|&i| state.previous[i]).collect(),
        current: perm.iter().map(|&i| state.current[i]).collect(),
        earlier: None,
        carry: Default::default(),
    };
    let out_p = step1(&model, objects_p, &state_p, 1);
    let expected: Vec<Pose> = perm.iter().map(|&i| base[i]).collect();
    let diff = max_pose_diff(&out_p, &expected);
    assert!(diff < 1e-5, "permuted output differs by {diff}");
    // The step actually moved things (a non-trivial check).
    assert!(max_pose_diff(&base, &state.current) > 1e-3);
}

#[test]
fn point_order_invariance() {
    let model = tiny();
    let (objects, state) = close_scene(2, 4, 128);
    let base = step1(&model, objects.clone(), &state, 2);
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let shuffled: Vec<ObjectInput> = objects
        .into_iter()
        .map(|mut o| {
            o.reference.shuffle(&mut rng);
            o
        })
        .collect();
    let out = step1(&model, shuffled, &state, 2);
    let diff = max_pose_diff(&base, &out);
    assert!(diff < 1e-5, "shuffled points change the output by {diff}");
}

#[test]
fn anchor_order_invariance() {
    let model = tiny();
    let (objects, state) = close_scene(3, 4, 128);
    let mut scene = model.prepare(objects).unwrap();
    let base = model
        .step(&[StepItem {
            scene: &scene,
            state: &state,
            dt_steps: 1,
        }])
        .unwrap();
    let k = model.config().anchors;
    let before: Vec<usize> = scene.anchor_indices(0).unwrap().to_vec();
    for j in 0..scene.len() {
        let perm: Vec<usize> = (0..k).rev().collect();
        scene.permute_anchors(j, &perm).unwrap();
    }
    assert_ne!(before, scene.anchor_indices(0).unwrap());
    let out = model
        .step(&[StepItem {
            scene: &scene,
            state: &state,
            dt_steps: 1,
        }])
        .unwrap();
    let diff = max_pose_diff(&base[0], &out[0]);
    assert!(diff < 1e-5, "anchor order changes the output by {diff}");
}

#[test]
fn rigid_by_construction_over_100_steps() {
    let model = tiny();
    let (objects, state) = close_scene(4, 5, 64);
    let scene = model.prepare(objects.clone()).unwrap();
    let traj = rollout(&model, &scene, state, 1, 100, |_, _| {}).unwrap();
    let last = traj.last().unwrap();
    let world = scene.world_points(last).unwrap();
    let mut worst = 0f32;
    for (o, pts) in objects.iter().zip(&world) {
        for i in 0..pts.len() {
            for j in (i + 1)..pts.len() {
                let d = |a: &[f32; 3], b: &[f32; 3]| {
                    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
                };
                worst =
                    worst.max((d(&pts[i], &pts[j]) - d(&o.reference[i], &o.reference[j])).abs());
            }
        }
    }
    assert!(worst < 1e-4, "pairwise distance drift {worst} m");
    // Objects did move over the rollout.
    assert!(
        traj.iter()
            .flatten()
            .all(|p| p.translation.iter().all(|v| v.is_finite()))
    );
}

#[test]
fn batch_invariance_with_31_other_scenes() {
    let model = tiny();
    let (objects, state) = close_scene(5, 5, 100);
    let scene = model.prepare(objects).unwrap();
    let alone = model
        .step(&[StepItem {
            scene: &scene,
            state: &state,
            dt_steps: 2,
        }])
        .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    let others: Vec<_> = (0..31)
        .map(|i| {
            let m = rng.random_range(1..12);
            let n = rng.random_range(16..200);
            let (o, s) = random_scene(100 + i, m, n);
            (model.prepare(o).unwrap(), s, rng.random_range(1..5u32))
        })
        .collect();
    let mut batch: Vec<StepItem<'_>> = others
        .iter()
        .map(|(sc, st, dt)| StepItem {
            scene: sc,
            state: st,
            dt_steps: *dt,
        })
        .collect();
    let pos = 13;
    batch.insert(
        pos,
        StepItem {
            scene: &scene,
            state: &state,
            dt_steps: 2,
        },
    );
    let out = model.step(&batch).unwrap();
    assert_eq!(out.len(), 32);
    let diff = max_pose_diff(&alone[0], &out[pos]);
    assert!(diff < 1e-5, "batched output differs by {diff}");
    // Splitting the batch into several passes (object budget) changes nothing.
    let split = tiny().with_max_pass_objects(9).step(&batch).unwrap();
    for (a, b) in out.iter().zip(&split) {
        assert!(max_pose_diff(a, b) < 1e-5);
    }
    // And a batch-mate alone equals itself in the batch too.
    let (sc, st, dt) = &others[0];
    let mate = model
        .step(&[StepItem {
            scene: sc,
            state: st,
            dt_steps: *dt,
        }])
        .unwrap();
    assert!(max_pose_diff(&mate[0], &out[0]) < 1e-5);
}

#[test]
fn training_kernels_match_inference_kernels() {
    let model = tiny();
    let (objects, state) = close_scene(6, 4, 64);
    let scene = model.prepare(objects).unwrap();
    let items = [StepItem {
        scene: &scene,
        state: &state,
        dt_steps: 4,
    }];
    let a = model.step_mode(&items, Mode::Inference, None).unwrap();
    let b = model.step_mode(&items, Mode::Training, None).unwrap();
    let diff = max_pose_diff(&a[0], &b[0]);
    assert!(diff < 1e-5, "modes differ by {diff}");
}

/// With `dynamics.relative_mass` only mass ratios reach the network: a common factor on every
/// mass leaves the step unchanged, a changed ratio does not; without it the factor shows.
#[test]
fn relative_mass_sees_ratios_only() {
    let (objects, state) = close_scene(9, 4, 64);
    let scaled = |k: &[f32]| -> Vec<ObjectInput> {
        objects
            .iter()
            .zip(k.iter().cycle())
            .map(|(o, f)| ObjectInput {
                mass: o.mass * f,
                ..o.clone()
            })
            .collect()
    };
    let absolute = tiny();
    let a = step1(&absolute, objects.clone(), &state, 1);
    let a37 = step1(&absolute, scaled(&[37.0]), &state, 1);
    assert!(
        max_pose_diff(&a, &a37) > 1e-6,
        "absolute masses had no effect"
    );
    let relative = tiny().with_settings(|d, _| d.relative_mass = true).unwrap();
    let r = step1(&relative, objects.clone(), &state, 1);
    for factor in [0.01, 37.0, 1.0e3] {
        let diff = max_pose_diff(&r, &step1(&relative, scaled(&[factor]), &state, 1));
        assert!(
            diff < 1e-5,
            "common factor {factor} changed the step by {diff}"
        );
    }
    let ratio = step1(&relative, scaled(&[4.0, 1.0]), &state, 1);
    assert!(
        max_pose_diff(&r, &ratio) > 1e-6,
        "a changed mass ratio had no effect"
    );
    // What the network sees: the scene's mean log mass at the feature's normalisation mean.
    let cfg = relative.config();
    let seen = dynaserve_model::model_masses(cfg, &scaled(&[37.0]));
    let mean_ln = seen.iter().map(|m| m.ln()).sum::<f32>() / seen.len() as f32;
    assert!((mean_ln - cfg.normalization.mean[dynaserve_model::LN_MASS_FEATURE]).abs() < 1e-4);
    // A kinematic object (a pusher) sets no scale and is seen at the reference: making it 50
    // times heavier changes nothing the network sees, where a dynamic one's mass would.
    let pushed = |kinematic: bool, factor: f32| -> Vec<f32> {
        let mut o = scaled(&[factor, 1.0, 1.0, 1.0]);
        o[0].kinematic = kinematic;
        dynaserve_model::model_masses(cfg, &o)
    };
    let (light, heavy) = (pushed(true, 1.0), pushed(true, 50.0));
    for j in 0..light.len() {
        assert!((light[j] - heavy[j]).abs() <= 1e-5 * light[j], "object {j}");
    }
    let reference = cfg.normalization.mean[dynaserve_model::LN_MASS_FEATURE];
    assert!((heavy[0].ln() - reference).abs() < 1e-5);
    assert!((pushed(false, 50.0)[1] - pushed(false, 1.0)[1]).abs() > 1e-3 * light[1]);
}

#[test]
fn step_size_conditions_the_output() {
    let model = tiny();
    let (objects, state) = close_scene(8, 3, 64);
    let one = step1(&model, objects.clone(), &state, 1);
    let four = step1(&model, objects, &state, 4);
    assert!(
        max_pose_diff(&one, &four) > 1e-6,
        "FiLM on log2(dt) has no effect"
    );
}

#[test]
fn unseen_point_counts_and_removed_points_still_run() {
    let model = tiny();
    let (objects, state) = close_scene(9, 4, 768);
    let full = step1(&model, objects.clone(), &state, 1);
    assert!(full.iter().all(|p| {
        p.translation
            .iter()
            .chain(&p.rotation)
            .all(|v| v.is_finite())
    }));
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let masked: Vec<ObjectInput> = objects
        .into_iter()
        .map(|mut o| {
            o.reference.shuffle(&mut rng);
            o.reference.truncate(o.reference.len() * 3 / 4);
            o
        })
        .collect();
    let part = step1(&model, masked, &state, 1);
    assert!(part.iter().all(|p| {
        p.translation
            .iter()
            .chain(&p.rotation)
            .all(|v| v.is_finite())
    }));
    // Fewer points than anchors or group size also work (FPS repeats).
    let (mut few, st) = close_scene(10, 2, 3);
    few[1].reference.truncate(1);
    let out = step1(&model, few, &st, 1);
    assert_eq!(out.len(), 2);
}

fn msg<T>(r: Result<T, dynaserve_model::ModelError>) -> String {
    r.err().map(|e| e.to_string()).unwrap_or_default()
}

#[test]
fn invalid_inputs_give_clear_errors() {
    let model = tiny();
    let (objects, state) = random_scene(11, 3, 32);
    assert!(msg(model.prepare(vec![])).contains("no objects"));
    let mut bad = objects.clone();
    bad[1].reference.clear();
    assert!(msg(model.prepare(bad)).contains("objects[1].reference is empty"));
    let mut bad = objects.clone();
    bad[2].reference[5][1] = f32::NAN;
    assert!(msg(model.prepare(bad)).contains("objects[2].reference[5]"));
    let mut bad = objects.clone();
    bad[0].mass = -1.0;
    assert!(msg(model.prepare(bad)).contains("mass"));
    let mut bad = objects.clone();
    bad[0].friction = f32::INFINITY;
    assert!(msg(model.prepare(bad)).contains("friction"));

    let scene = model.prepare(objects).unwrap();
    let step = |st: &SceneState, dt: u32| {
        model.step(&[StepItem {
            scene: &scene,
            state: st,
            dt_steps: dt,
        }])
    };
    assert!(msg(step(&state, 0)).contains("dt_steps"));
    let mut short = state.clone();
    short.current.pop();
    assert!(msg(step(&short, 1)).contains("3 objects"));
    let mut nan = state.clone();
    nan.previous[1].translation[0] = f32::NAN;
    assert!(msg(step(&nan, 1)).contains("previous[1]"));
    let mut zero_q = state.clone();
    zero_q.current[0].rotation = [0.0; 4];
    assert!(msg(step(&zero_q, 1)).contains("current[0]"));
    // A scene prepared by a model with other anchor/grouping sizes is refused.
    let other = RigidFormer::new(
        ModelConfig {
            anchors: 6,
            ..ModelConfig::tiny()
        },
        1,
        &Device::Cpu,
    )
    .unwrap();
    let foreign = other.prepare(random_scene(11, 3, 32).0).unwrap();
    let r = model.step(&[StepItem {
        scene: &foreign,
        state: &state,
        dt_steps: 1,
    }]);
    assert!(msg(r).contains("prepared for a model"));
    // Unnormalised quaternions are accepted and normalised.
    let mut scaled = state.clone();
    scaled.current[0].rotation = scaled.current[0].rotation.map(|v| v * 3.0);
    let a = step(&state, 1).unwrap();
    let b = step(&scaled, 1).unwrap();
    assert!(max_pose_diff(&a[0], &b[0]) < 1e-5);
}

/// `with_settings` changes the switches that leave the weights alone and refuses those that
/// change the network's inputs or parameters (an input group, any unit).
#[test]
fn settings_edits_may_not_switch_inputs_or_units() {
    let m = tiny()
        .with_settings(|d, l| {
            d.floor_base = !d.floor_base;
            l.rest_weight = 3.0;
        })
        .unwrap();
    assert_eq!(m.config().loss.rest_weight, 3.0);
    assert!(tiny().with_settings(|d, _| d.history = !d.history).is_err());
    for unit in ModelUnit::ALL {
        let flipped = tiny().with_settings(|d, _| unit.set(d, !unit.enabled(d)));
        assert!(flipped.is_err(), "{unit:?}");
    }
}

/// The encoder's grouping covers a cloud no larger than its slots and at most
/// `sa_centres * sa_neighbours` points of a larger one; more centres group more of it.
#[test]
fn grouped_points_are_bounded_by_the_grouping_slots() {
    let grouped = |centres: usize, n: usize| {
        let mut c = ModelConfig::tiny();
        c.sa_centres = centres;
        let model = RigidFormer::new(c, 7, &Device::Cpu).unwrap();
        let (objects, _) = random_scene(11, 1, n);
        let scene = model.prepare(objects).unwrap();
        assert_eq!(scene.grouped_points(1), None);
        scene.grouped_points(0).unwrap()
    };
    let g = ModelConfig::tiny().sa_neighbours;
    // Fewer points than one group: every point is grouped (groups repeat points).
    assert_eq!(grouped(4, g - 1), g - 1);
    let small = grouped(4, 4 * g * 8);
    assert!(small <= 4 * g, "{small} grouped by {} slots", 4 * g);
    let more = grouped(16, 4 * g * 8);
    assert!(
        more > small,
        "16 centres group {more} points, 4 group {small}"
    );
}
