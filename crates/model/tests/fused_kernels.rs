//! The fused CPU kernels give the same step as the plain candle composition, on a batch that
//! mixes object counts, point counts and step sizes (padding in every layout).

mod common;

use common::random_scene;
use dynaserve_model::{Device, ModelConfig, Pose, RigidFormer, StepItem, WorldModel};

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
