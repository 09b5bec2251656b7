//! Our side of the published-size PhysiFormer benchmark (`benches/physiformer-official/run.sh`
//! runs both sides in turn): one denoiser call of the official B network on a 49-frame,
//! 356-vertex, 10-object scene, or one whole Heun sample, on this machine's CPU. Prints one
//! JSON line: seconds per repetition and the process's peak resident memory.
//!
//! `PF_BENCH_DIR` names the folder `official.py make` wrote, with the checkpoint imported
//! into `PF_BENCH_DIR/models/physiformer-b`; `PF_BENCH_WHAT` is `call` (default, three
//! calls) or `sample:STEPS`. Without `PF_BENCH_DIR` the bench says so and exits.

use std::path::PathBuf;
use std::time::Instant;

use candle_core::Device;
use dynaserve_model::PhysiFormer;
use dynaserve_model::physiformer::inputs::PreparedItem;
use dynaserve_model::physiformer::scene::{Material, MeshScene};

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn peak_rss_mib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        })
        .map_or(0, |kb| kb / 1024)
}

fn main() {
    let Some(dir) = std::env::var_os("PF_BENCH_DIR").map(PathBuf::from) else {
        eprintln!("official_denoise: set PF_BENCH_DIR (see benches/physiformer-official/run.sh)");
        return;
    };
    let what = std::env::var("PF_BENCH_WHAT").unwrap_or_else(|_| "call".into());
    let model = PhysiFormer::load(&dir.join("models/physiformer-b"), &Device::Cpu, false)
        .expect("load the imported B checkpoint");
    let sc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("scene.json")).unwrap()).unwrap();
    let flat = |k: &str| -> Vec<[f32; 3]> {
        let v: Vec<f32> = sc[k]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|r| {
                r.as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap() as f32)
            })
            .collect();
        v.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
    };
    let mut offsets = vec![0];
    for c in sc["counts"].as_array().unwrap() {
        offsets.push(offsets.last().unwrap() + c.as_u64().unwrap() as usize);
    }
    let materials = sc["kinds"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| {
            if k == "rigid" {
                Material::Rigid
            } else {
                Material::Elastic
            }
        })
        .collect();
    let scene = MeshScene {
        positions: flat("positions"),
        velocities: flat("velocities"),
        vertex_offsets: offsets,
        materials,
    };
    let frames = sc["frames"].as_u64().unwrap() as usize;
    let mut seconds = Vec::new();
    if let Some(steps) = what.strip_prefix("sample:") {
        let steps: usize = steps.parse().expect("sample:STEPS");
        let t0 = Instant::now();
        model.sample(&[(&scene, frames)], steps, 0).unwrap();
        seconds.push(t0.elapsed().as_secs_f64());
    } else {
        let prepared = model.prepare(&scene, frames).unwrap();
        let z: Vec<f32> = (0..frames * scene.vertices() * 3)
            .map(|i| 0.1 * ((i as f32) * 0.37).sin())
            .collect();
        for _ in 0..3 {
            let t0 = Instant::now();
            model
                .denoise_prepared(&[PreparedItem {
                    scene: &prepared,
                    z: &z,
                    t: 0.5,
                }])
                .unwrap();
            seconds.push(t0.elapsed().as_secs_f64());
        }
    }
    println!(
        "{}",
        serde_json::json!({
            "impl": "dynaserve",
            "what": what,
            "amp": "none",
            "threads": rayon::current_num_threads(),
            "seconds": seconds,
            "peak_rss_mib": peak_rss_mib(),
        })
    );
}
