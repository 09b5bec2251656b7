//! A gradient call against a driven rollout of the same size with the shipped RigidFormer
//! (`models/rigidformer-small`): the push planner's call, `candidates` pusher paths of `steps`
//! steps from a box resting on the floor with the pusher behind it. `predict` steps all
//! candidates together with the inference kernels (what a session Predict runs); `gradient`
//! is `WorldModel::path_gradients` on the same paths (the forward with the composed kernels,
//! the graph and one backward pass). The two are interleaved in one process and the medians
//! and their ratio printed, with the process's peak resident memory after each.
//!
//! `cargo bench -p dynaserve-model --bench gradient` (release). `GRADIENT_BENCH=48x10,8x10`
//! chooses the sizes (candidates x steps; default `48x10,8x10`).

use std::path::Path;
use std::time::{Duration, Instant};

use dynaserve_model::{
    CostTarget, Device, Drive, GradientItem, ObjectInput, PathCost, Pose, SceneState, StepItem,
    WorldModel, load_rigidformer,
};

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

const BOX: usize = 0;
const PUSHER: usize = 1;

/// `n` points on the faces of a cube of half extent `h`, on a regular spiral (deterministic).
fn cube(n: usize, h: f32) -> Vec<[f32; 3]> {
    (0..n)
        .map(|i| {
            let (a, b) = (
                (i as f32 * 0.618_034).fract(),
                (i as f32 * 0.414_214).fract(),
            );
            let (u, v) = (h * (2.0 * a - 1.0), h * (2.0 * b - 1.0));
            let s = if i % 2 == 0 { h } else { -h };
            match (i / 2) % 3 {
                0 => [s, u, v],
                1 => [u, s, v],
                _ => [u, v, s],
            }
        })
        .collect()
}

fn at(x: f32, y: f32, z: f32) -> Pose {
    Pose {
        translation: [x, y, z],
        rotation: [0.0, 0.0, 0.0, 1.0],
    }
}

/// Peak resident memory of the process so far, MiB (0 where `/proc` is missing).
fn peak_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(0.0, |kib| kib / 1024.0)
}

fn median(mut v: Vec<Duration>) -> f64 {
    v.sort();
    v[v.len() / 2].as_secs_f64() * 1e3
}

fn main() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rigidformer-small");
    let model = load_rigidformer(&dir, &Device::Cpu, false).expect("the shipped model loads");
    let objects = vec![
        ObjectInput {
            reference: cube(128, 0.1),
            mass: 1.0,
            friction: 0.5,
            restitution: 0.2,
            kinematic: false,
        },
        ObjectInput {
            reference: cube(96, 0.06),
            mass: 5.0,
            friction: 0.5,
            restitution: 0.2,
            kinematic: true,
        },
    ];
    let scene = model.prepare(objects).unwrap();
    let start = vec![at(0.0, 0.0, 0.1), at(-0.18, 0.0, 0.06)];
    let state = SceneState::new(start.clone(), start);
    let kinematic = [false, true];
    let cost = PathCost {
        targets: vec![],
        smoothness: 0.1,
    };
    let sizes = std::env::var("GRADIENT_BENCH").unwrap_or_else(|_| "48x10,8x10".into());
    for size in sizes.split(',') {
        let (c, s) = size.split_once('x').expect("sizes are CANDIDATESxSTEPS");
        let (candidates, steps): (usize, usize) = (c.parse().unwrap(), s.parse().unwrap());
        let paths: Vec<Vec<Vec<Pose>>> = (0..candidates)
            .map(|c| {
                let dy = (c as f32 / candidates as f32 - 0.5) * 0.02;
                (1..=steps)
                    .map(|s| vec![at(-0.18 + 0.03 * s as f32, dy * s as f32, 0.06)])
                    .collect()
            })
            .collect();
        let mut with_goal = cost.clone();
        with_goal.targets.push(CostTarget {
            object: BOX,
            step: steps,
            position: [0.35, 0.15, 0.1],
            position_weight: 1.0,
            rotation: None,
            rotation_weight: 0.0,
        });
        let predict = || {
            let mut states = vec![state.clone(); candidates];
            for s in 0..steps {
                let targets: Vec<Vec<(usize, Pose)>> =
                    paths.iter().map(|p| vec![(PUSHER, p[s][0])]).collect();
                let items: Vec<StepItem<'_>> = states
                    .iter()
                    .map(|st| StepItem {
                        scene: &scene,
                        state: st,
                        dt_steps: 1,
                    })
                    .collect();
                let out = model.step(&items).unwrap();
                for ((st, next), t) in states.iter_mut().zip(out).zip(&targets) {
                    Drive::new(&kinematic, t).finish(st, next);
                }
            }
            states
        };
        let gradient = || {
            model
                .path_gradients(&[GradientItem {
                    scene: &scene,
                    state: &state,
                    kinematic: &kinematic,
                    paths: &paths,
                    dt_steps: 1,
                    cost: &with_goal,
                    deadline: None,
                }])
                .unwrap()
        };
        let (mut tp, mut tg) = (Vec::new(), Vec::new());
        let (mut peak_p, mut peak_g) = (0.0, 0.0);
        predict();
        gradient();
        for _ in 0..5 {
            let t = Instant::now();
            std::hint::black_box(predict());
            tp.push(t.elapsed());
            peak_p = f64::max(peak_p, peak_mib());
            let t = Instant::now();
            std::hint::black_box(gradient());
            tg.push(t.elapsed());
            peak_g = f64::max(peak_g, peak_mib());
        }
        let (p, g) = (median(tp), median(tg));
        println!(
            "{candidates} candidates x {steps} steps: driven rollout (Predict) median {p:.0} ms, \
             gradient median {g:.0} ms, ratio {:.1}; peak resident memory {peak_p:.0} MiB after \
             the rollouts, {peak_g:.0} MiB after the gradients",
            g / p
        );
    }
}
