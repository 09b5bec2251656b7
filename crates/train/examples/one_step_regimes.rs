//! One-step translation error of a model by a coarse regime, next to free-fall extrapolation:
//! the quick look used to diagnose the first release (its card's regime table).
//!
//! ```sh
//! cargo run --release -p dynaserve-train --example one_step_regimes -- \
//!     models/rigidformer-small data/movi-b/test 40 10,30,50,70,90
//! ```
//!
//! Arguments: model directory, dataset split, number of scenes, frames `t` (the model observes
//! `t - 1` and `t` and predicts `t + 1` with the first 512 stored points per object). Regime of
//! an object, from the ground truth: *resting* if its centre moves slower than 0.05 m/s before
//! and after `t`; else *object* if one of its points is within 8 cm of another object's at
//! `t + 1`; else *floor* if its lowest point is below 2 cm at `t + 1`; else *air* (this last one
//! still holds impacts that happen and end between two frames). `ballistic` is
//! `2 x_t - x_{t-1} + g dt^2` with the manifest's gravity and frame interval, and no floor.
use std::path::Path;

use dynaserve_model::{Device, ObjectInput, SceneState, StepItem, load_model};
use dynaserve_sim::DatasetReader;
use dynaserve_train::eval::poses_at;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let model = load_model(Path::new(&args[1]), &Device::Cpu).unwrap();
    let reader = DatasetReader::open(&args[2]).unwrap();
    let (gravity, dt) = (reader.manifest().gravity, reader.manifest().dt_frame);
    let scenes: usize = args[3].parse().unwrap();
    let frames: Vec<usize> = args[4].split(',').map(|s| s.parse().unwrap()).collect();
    // regime -> (count, sum sq err model, sum sq static, signed z model)
    let mut acc = std::collections::BTreeMap::<&str, (usize, f64, f64, f64)>::new();
    for i in 0..scenes {
        let rec = reader.get(i).unwrap();
        let objects: Vec<ObjectInput> = rec
            .objects
            .iter()
            .map(|o| ObjectInput {
                reference: o.reference_points[..512].to_vec(),
                mass: o.mass,
                friction: o.friction,
                restitution: o.restitution,
                kinematic: o.kinematic,
            })
            .collect();
        let scene = model.prepare(objects).unwrap();
        for &t in &frames {
            let pose = |f: usize| poses_at(&rec, f).unwrap();
            let state = SceneState {
                previous: pose(t - 1),
                current: pose(t),
                earlier: t.checked_sub(2).map(pose),
            };
            let out = model
                .step(&[StepItem {
                    scene: &scene,
                    state: &state,
                    dt_steps: 1,
                }])
                .unwrap();
            let truth = pose(t + 1);
            for (j, o) in rec.objects.iter().enumerate() {
                let v0: f32 = (0..3)
                    .map(|d| (o.positions[t][d] - o.positions[t - 1][d]).powi(2))
                    .sum::<f32>()
                    .sqrt()
                    / dt;
                let v1: f32 = (0..3)
                    .map(|d| (o.positions[t + 1][d] - o.positions[t][d]).powi(2))
                    .sum::<f32>()
                    .sqrt()
                    / dt;
                // lowest point height at t+1
                let low = o.reference_points[..512]
                    .iter()
                    .map(|x| truth[j].transform_point(*x)[2])
                    .fold(f32::INFINITY, f32::min);
                let wp = |k: usize, f: usize| -> Vec<[f32; 3]> {
                    let p = if f == 0 { &state.current[k] } else { &truth[k] };
                    rec.objects[k].reference_points[..512]
                        .iter()
                        .map(|x| p.transform_point(*x))
                        .collect()
                };
                let mine = wp(j, 1);
                let mut near = f32::INFINITY;
                for k in 0..rec.objects.len() {
                    if k == j {
                        continue;
                    }
                    let other = wp(k, 1);
                    for a in &mine {
                        for b in &other {
                            let d = (a[0] - b[0]).powi(2)
                                + (a[1] - b[1]).powi(2)
                                + (a[2] - b[2]).powi(2);
                            near = near.min(d);
                        }
                    }
                }
                let near = near.sqrt();
                let regime = if v0 < 0.05 && v1 < 0.05 {
                    "resting"
                } else if near < 0.08 {
                    "object"
                } else if low < 0.02 {
                    "floor"
                } else {
                    "air"
                };
                let e: f64 = (0..3)
                    .map(|d| (out[0][j].translation[d] - truth[j].translation[d]).powi(2) as f64)
                    .sum();
                let g = gravity.map(|a| a * dt * dt);
                let es: f64 = (0..3)
                    .map(|d| {
                        (2.0 * state.current[j].translation[d] - state.previous[j].translation[d]
                            + g[d]
                            - truth[j].translation[d])
                            .powi(2) as f64
                    })
                    .sum();
                let ez = (out[0][j].translation[2] - truth[j].translation[2]) as f64;
                let a = acc.entry(regime).or_default();
                a.0 += 1;
                a.1 += e;
                a.2 += es;
                a.3 += ez;
            }
        }
    }
    for (r, (n, e, es, ez)) in acc {
        println!(
            "{r:14} n={n:5} model rmse {:.5} m  ballistic {:.5} m  mean z err {:+.5} m",
            (e / n as f64).sqrt(),
            (es / n as f64).sqrt(),
            ez / n as f64
        );
    }
}
