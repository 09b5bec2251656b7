//! PhysiFormer denoising passes of the shipped `physiformer-small` on the Generate example
//! scene (a rigid cube under an elastic one, 16 vertices, 49 frames), by pass width `B`: the
//! wall time per scene of one pass of `B` copies (each at its own flow time and noise) for
//! - the per-step path ([`PhysiFormer::denoise`]: lays every step out from the scene),
//! - the prepared one ([`PhysiFormer::denoise_prepared`]: the step-invariant part laid out
//!   once per sample), on the process pool (`RAYON_NUM_THREADS`),
//! - the prepared one inside a rayon pool of one thread (every kernel on that thread).
//!
//! Every path runs each scene of a pass as its own forward (`docs/physiformer.md`, Serving).
//!
//! Widths and paths run interleaved, round after round, so a machine that changes speed moves
//! all of them alike; medians print.
//!
//! `cargo bench -p dynaserve-model --bench denoise` (release). `ROUNDS=n` sets the rounds
//! (default 15); `WIDTHS=1,8` the pass widths (default 1,2,4,8).

use std::path::Path;
use std::time::Instant;

use dynaserve_model::PhysiFormer;
use dynaserve_model::physiformer::flow::standard_normal;
use dynaserve_model::physiformer::inputs::{DenoiseItem, PreparedItem};
use dynaserve_model::physiformer::scene::{Material, MeshScene};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn cube(c: [f32; 3], h: f32) -> Vec<[f32; 3]> {
    let mut v = Vec::new();
    for x in [-h, h] {
        for y in [-h, h] {
            for z in [-h, h] {
                v.push([c[0] + x, c[1] + y, c[2] + z]);
            }
        }
    }
    v
}

/// The scene of `examples/scenes/generate/elastic_drop.json`.
fn scene() -> MeshScene {
    let mut positions = cube([0.0, 0.0, -0.85], 0.15);
    positions.extend(cube([0.05, 0.0, 0.1], 0.15));
    let mut velocities = vec![[0.0; 3]; 8];
    velocities.extend(vec![[0.5, 0.0, -1.0]; 8]);
    MeshScene {
        positions,
        velocities,
        vertex_offsets: vec![0, 8, 16],
        materials: vec![Material::Rigid, Material::Elastic],
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn env_list(name: &str, default: &[usize]) -> Vec<usize> {
    std::env::var(name)
        .ok()
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .filter(|v: &Vec<usize>| !v.is_empty())
        .unwrap_or_else(|| default.to_vec())
}

fn main() {
    dynaserve_model::keep_freed_memory();
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/physiformer-small");
    let device = candle_core::Device::Cpu;
    let model = PhysiFormer::load(&dir, &device, false).expect("load physiformer-small");
    let cfg = model.config().clone();
    let sc = scene();
    let frames = cfg.frames;
    let widths = env_list("WIDTHS", &[1, 2, 4, 8]);
    let rounds = env_list("ROUNDS", &[15])[0];
    let widest = widths.iter().copied().max().unwrap_or(1);
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let zs: Vec<Vec<f32>> = (0..widest)
        .map(|_| {
            (0..frames * sc.vertices() * 3)
                .map(|_| cfg.noise_scale * standard_normal(&mut rng))
                .collect()
        })
        .collect();
    let prepared = model.prepare(&sc, frames).expect("prepare");
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("one-thread pool");
    // [width][path] -> per-scene ms of each round; paths: per-step, prepared, prepared on one
    // thread.
    let mut times = vec![[Vec::new(), Vec::new(), Vec::new()]; widths.len()];
    for round in 0..=rounds {
        for (wi, &w) in widths.iter().enumerate() {
            let items: Vec<DenoiseItem<'_>> = (0..w)
                .map(|i| DenoiseItem {
                    scene: &sc,
                    z: &zs[i],
                    frames,
                    t: (i as f32 + 0.5) / widest as f32,
                })
                .collect();
            let t0 = Instant::now();
            let a = model.denoise(&items).expect("denoise");
            let per_step = t0.elapsed().as_secs_f64() * 1e3 / w as f64;
            let pitems: Vec<PreparedItem<'_>> = items
                .iter()
                .map(|it| PreparedItem {
                    scene: &prepared,
                    z: it.z,
                    t: it.t,
                })
                .collect();
            let t0 = Instant::now();
            let b = model.denoise_prepared(&pitems).expect("denoise_prepared");
            let cached = t0.elapsed().as_secs_f64() * 1e3 / w as f64;
            let t0 = Instant::now();
            let c = one
                .install(|| model.denoise_prepared(&pitems))
                .expect("denoise_prepared");
            let single = t0.elapsed().as_secs_f64() * 1e3 / w as f64;
            assert_eq!(a, b, "preparing changed a result");
            assert_eq!(b, c, "the thread count changed a result");
            if round > 0 {
                times[wi][0].push(per_step);
                times[wi][1].push(cached);
                times[wi][2].push(single);
            }
        }
    }
    println!(
        "pass width | per-step | prepared | prepared, 1 thread \
         | (ms per scene) prepared / per-step | 1 thread / pool"
    );
    for (wi, &w) in widths.iter().enumerate() {
        let [a, b, c] = times[wi].clone().map(median);
        println!(
            "{w} | {a:.2} | {b:.2} | {c:.2} | {:.3} | {:.3}",
            b / a,
            c / b
        );
    }
}
