//! The fused CPU kernels give the same step, and the same training loss and gradients, as the
//! plain candle composition, on batches that mix object counts, point counts and step sizes
//! (padding in every layout).

mod common;

use common::random_scene;
use dynaserve_model::{Device, ModelConfig, Pose, RigidFormer, StepItem, TrainItem, WorldModel};

fn max_pose_diff(a: &[Pose], b: &[Pose]) -> f32 {
    a.iter()
        .zip(b)
        .flat_map(|(p, q)| {
            let t = p
                .translation
                .iter()
                .zip(&q.translation)
                .map(|(x, y)| (x - y).abs());
            let r = p
                .rotation
                .iter()
                .zip(&q.rotation)
                .map(|(x, y)| (x - y).abs());
            t.chain(r).collect::<Vec<_>>()
        })
        .fold(0.0, f32::max)
}

#[test]
fn fused_kernels_match_the_composition() {
    for config in [ModelConfig::tiny(), ModelConfig::small()] {
        let fused = RigidFormer::new(config.clone(), 11, &Device::Cpu).unwrap();
        let plain = RigidFormer::new(config, 11, &Device::Cpu)
            .unwrap()
            .with_fused_kernels(false);
        let scenes: Vec<_> = [(3, 40), (7, 150), (1, 9), (5, 64)]
            .iter()
            .enumerate()
            .map(|(i, &(m, n))| {
                let (objects, state) = random_scene(40 + i as u64, m, n);
                (fused.prepare(objects).unwrap(), state, 1 + i as u32)
            })
            .collect();
        let items: Vec<StepItem<'_>> = scenes
            .iter()
            .map(|(scene, state, dt)| StepItem {
                scene,
                state,
                dt_steps: *dt,
            })
            .collect();
        let a = fused.step(&items).unwrap();
        let b = plain.step(&items).unwrap();
        for (x, y) in a.iter().zip(&b) {
            let diff = max_pose_diff(x, y);
            assert!(diff < 1e-5, "fused and composed steps differ by {diff}");
        }
    }
}

#[test]
fn scene_groups_on_their_own_threads_match_one_pass() {
    // Two compute threads even where the machine has one, so the batch really splits.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    pool.install(|| {
        let grouped = RigidFormer::new(ModelConfig::small(), 12, &Device::Cpu).unwrap();
        let one_pass = RigidFormer::new(ModelConfig::small(), 12, &Device::Cpu)
            .unwrap()
            .with_scene_threads(false);
        let scenes: Vec<_> = [(3, 40), (7, 150), (1, 9), (5, 64), (2, 30)]
            .iter()
            .enumerate()
            .map(|(i, &(m, n))| {
                let (objects, state) = random_scene(60 + i as u64, m, n);
                (grouped.prepare(objects).unwrap(), state, 1 + (i % 3) as u32)
            })
            .collect();
        let items: Vec<StepItem<'_>> = scenes
            .iter()
            .map(|(scene, state, dt)| StepItem {
                scene,
                state,
                dt_steps: *dt,
            })
            .collect();
        let a = grouped.step(&items).unwrap();
        let b = one_pass.step(&items).unwrap();
        assert_eq!(a.len(), items.len());
        for (i, (x, y)) in a.iter().zip(&b).enumerate() {
            assert_eq!(x.len(), items[i].scene.len());
            let diff = max_pose_diff(x, y);
            assert!(
                diff < 1e-5,
                "scene {i}: grouped and one-pass steps differ by {diff}"
            );
        }
    });
}

/// Loss and the gradient of every parameter of a training batch (three scenes of different
/// object and point counts and step sizes), keyed by parameter name.
fn loss_and_gradients(
    model: &RigidFormer,
    scenes: &[(
        dynaserve_model::PreparedScene,
        dynaserve_model::SceneState,
        Vec<Pose>,
    )],
) -> (f32, Vec<(String, candle_core::Tensor)>) {
    let items: Vec<TrainItem<'_>> = scenes
        .iter()
        .enumerate()
        .map(|(i, (scene, state, target))| TrainItem {
            scene,
            state,
            target,
            dt_steps: [1, 2, 4][i % 3],
            kinematic: &[],
        })
        .collect();
    let out = model.train_forward(&items).unwrap();
    let grads = out.loss.backward().unwrap();
    let vars = model.varmap().data().lock().unwrap().clone();
    let mut g: Vec<(String, candle_core::Tensor)> = vars
        .iter()
        .map(|(name, v)| (name.clone(), grads.get(v.as_tensor()).unwrap().clone()))
        .collect();
    g.sort_by(|a, b| a.0.cmp(&b.0));
    (out.loss.to_scalar::<f32>().unwrap(), g)
}

/// Objects of at least 40 points: with fewer points than set-abstraction centres or
/// neighbours, groups repeat points and the max-pool ties, where the composition gives every
/// tied row the whole gradient and the fused kernel gives it to one row.
#[test]
fn fused_training_kernels_give_the_composition_gradients() {
    for config in [ModelConfig::tiny(), ModelConfig::small()] {
        let fused = RigidFormer::new(config.clone(), 5, &Device::Cpu).unwrap();
        let plain = RigidFormer::new(config, 5, &Device::Cpu)
            .unwrap()
            .with_fused_kernels(false);
        let scenes: Vec<_> = [(3, 40), (6, 90), (1, 48)]
            .iter()
            .enumerate()
            .map(|(i, &(m, n))| {
                let (objects, state) = random_scene(60 + i as u64, m, n);
                let target = state
                    .previous
                    .iter()
                    .zip(&state.current)
                    .map(|(p, c)| Pose {
                        translation: std::array::from_fn(|d| {
                            2.0 * c.translation[d] - p.translation[d] - 0.01
                        }),
                        rotation: c.rotation,
                    })
                    .collect();
                (fused.prepare(objects).unwrap(), state, target)
            })
            .collect();
        let (la, ga) = loss_and_gradients(&fused, &scenes);
        let (lb, gb) = loss_and_gradients(&plain, &scenes);
        assert!(
            (la - lb).abs() <= 1e-5 * lb.abs().max(1.0),
            "loss {la} vs {lb}"
        );
        assert_eq!(ga.len(), gb.len());
        for ((name, a), (_, b)) in ga.iter().zip(&gb) {
            let scale = b.abs().unwrap().flatten_all().unwrap().max(0).unwrap();
            let scale = scale.to_scalar::<f32>().unwrap();
            let diff = (a - b).unwrap().abs().unwrap().flatten_all().unwrap();
            let diff = diff.max(0).unwrap().to_scalar::<f32>().unwrap();
            assert!(
                diff <= 1e-3 * scale + 1e-6,
                "{name}: gradients differ by {diff} (largest {scale})"
            );
        }
    }
}

/// Twenty AdamW steps on one batch from the same initial weights: the fused kernels and the
/// composition lower the loss along the same curve.
#[test]
fn fused_and_composed_training_follow_the_same_loss_curve() {
    use candle_nn::Optimizer;
    let scenes: Vec<_> = [(4, 64), (7, 48)]
        .iter()
        .enumerate()
        .map(|(i, &(m, n))| random_scene(80 + i as u64, m, n))
        .collect();
    let curve = |fused: bool| -> Vec<f32> {
        let model = RigidFormer::new(ModelConfig::small(), 9, &Device::Cpu)
            .unwrap()
            .with_fused_kernels(fused);
        let data: Vec<_> = scenes
            .iter()
            .map(|(objects, state)| {
                let target: Vec<Pose> = state
                    .previous
                    .iter()
                    .zip(&state.current)
                    .map(|(p, c)| Pose {
                        translation: std::array::from_fn(|d| {
                            2.0 * c.translation[d] - p.translation[d] - 0.02
                        }),
                        rotation: c.rotation,
                    })
                    .collect();
                (model.prepare(objects.clone()).unwrap(), state, target)
            })
            .collect();
        let items: Vec<TrainItem<'_>> = data
            .iter()
            .map(|(scene, state, target)| TrainItem {
                scene,
                state,
                target,
                dt_steps: 2,
                kinematic: &[],
            })
            .collect();
        let mut opt = candle_nn::AdamW::new(
            model.varmap().all_vars(),
            candle_nn::ParamsAdamW {
                lr: 1e-3,
                ..Default::default()
            },
        )
        .unwrap();
        (0..20)
            .map(|_| {
                let out = model.train_forward(&items).unwrap();
                opt.backward_step(&out.loss).unwrap();
                out.loss.to_scalar::<f32>().unwrap()
            })
            .collect()
    };
    let (a, b) = (curve(true), curve(false));
    assert!(a[19] < 0.7 * a[0], "the loss did not fall: {a:?}");
    for (i, (x, y)) in a.iter().zip(&b).enumerate() {
        assert!((x - y).abs() <= 2e-3 * y.abs(), "step {i}: {x} vs {y}");
    }
}
