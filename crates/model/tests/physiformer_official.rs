//! Parity with the official PhysiFormer code, from the fixture its own code wrote
//! (`tests/fixtures/physiformer-official/`, made by `make_fixture.py` there): a small network
//! with randomised parameters saved as the official training saves a checkpoint, one
//! denoiser call and one whole sampling run with its starting noise. The checkpoint is
//! imported from the `.pt` (no Python here) and must reproduce the call within 1e-4 and the
//! sample within 1e-3 (largest absolute difference over the largest absolute value, in the
//! network's coordinates); a single perturbed weight, or the raw weights instead of the EMA
//! ones, must not.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use dynaserve_model::PhysiFormer;
use dynaserve_model::physiformer::config::TrajectoryPrior;
use dynaserve_model::physiformer::flow::{Sampler, SamplerKind};
use dynaserve_model::physiformer::inputs::PreparedItem;
use dynaserve_model::physiformer::scene::{Material, MeshScene};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/physiformer-official")
}

fn temp(tag: &str) -> PathBuf {
    std::env::temp_dir().join(format!("dynaserve-official-{tag}-{}", std::process::id()))
}

struct Reference {
    tensors: HashMap<String, Tensor>,
    json: serde_json::Value,
}

impl Reference {
    fn load() -> Reference {
        let tensors =
            candle_core::safetensors::load(fixture().join("reference.safetensors"), &Device::Cpu)
                .unwrap();
        let json = serde_json::from_str(
            &std::fs::read_to_string(fixture().join("reference.json")).unwrap(),
        )
        .unwrap();
        Reference { tensors, json }
    }

    fn values(&self, name: &str) -> Vec<f32> {
        self.tensors[name].flatten_all().unwrap().to_vec1().unwrap()
    }

    fn points(&self, name: &str) -> Vec<[f32; 3]> {
        self.values(name)
            .chunks(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect()
    }

    /// The scene `which` ("call" or "sample") from its frame-0 state (metres, m/s).
    fn scene(&self, which: &str) -> MeshScene {
        let counts: Vec<usize> = self.json[which]["counts"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c.as_u64().unwrap() as usize)
            .collect();
        let mut offsets = vec![0];
        for c in &counts {
            offsets.push(offsets.last().unwrap() + c);
        }
        let materials = self.json[which]["kinds"]
            .as_array()
            .unwrap()
            .iter()
            .map(|k| match k.as_str().unwrap() {
                "rigid" => Material::Rigid,
                _ => Material::Elastic,
            })
            .collect();
        MeshScene {
            positions: self.points(&format!("{which}.positions")),
            velocities: self.points(&format!("{which}.velocities")),
            vertex_offsets: offsets,
            materials,
        }
    }
}

fn import(tag: &str, use_ema: bool) -> (PhysiFormer, PathBuf) {
    let out = temp(tag);
    let _ = std::fs::remove_dir_all(&out);
    let model = PhysiFormer::import_official(
        &fixture().join("checkpoint.pt"),
        None,
        &out,
        use_ema,
        None,
        &Device::Cpu,
    )
    .unwrap();
    (model, out)
}

/// Largest absolute difference over the largest absolute reference value.
fn relative(got: &[f32], want: &[f32]) -> f32 {
    assert_eq!(got.len(), want.len());
    let diff = got
        .iter()
        .zip(want)
        .map(|(a, b)| (a - b).abs())
        .fold(0f32, f32::max);
    diff / want.iter().map(|x| x.abs()).fold(0f32, f32::max)
}

/// Metres -> the network's coordinates of `model`.
fn to_network(model: &PhysiFormer, x: &[f32]) -> Vec<f32> {
    let (scale, offset) = model.config().noise_frame();
    x.iter()
        .enumerate()
        .map(|(i, v)| (v - offset[i % 3]) / scale[i % 3])
        .collect()
}

fn from_network(model: &PhysiFormer, x: &[f32]) -> Vec<f32> {
    let (scale, offset) = model.config().noise_frame();
    x.iter()
        .enumerate()
        .map(|(i, v)| v * scale[i % 3] + offset[i % 3])
        .collect()
}

/// The denoiser call of the fixture: relative error in network coordinates.
fn call_error(model: &PhysiFormer, r: &Reference) -> f32 {
    let scene = r.scene("call");
    let frames = r.json["frames"].as_u64().unwrap() as usize;
    let prepared = model.prepare(&scene, frames).unwrap();
    let z = from_network(model, &r.values("call.z"));
    let t = r.values("call.t")[0];
    let out = model
        .denoise_prepared(&[PreparedItem {
            scene: &prepared,
            z: &z,
            t,
        }])
        .unwrap()
        .remove(0);
    relative(&to_network(model, &out), &r.values("call.out"))
}

/// The fixture's whole sampling run from its starting noise: the sample in metres.
fn sample(model: &PhysiFormer, r: &Reference) -> Vec<f32> {
    let scene = r.scene("sample");
    let frames = r.json["frames"].as_u64().unwrap() as usize;
    let steps = r.json["steps"].as_u64().unwrap() as usize;
    let eps: Vec<f32> = r
        .values("sample.z0")
        .iter()
        .map(|z| z / model.config().noise_scale)
        .collect();
    let mut sampler = Sampler::with_noise(
        model.config(),
        &scene,
        frames,
        steps,
        SamplerKind::Heun,
        &eps,
    )
    .unwrap();
    let prepared = model.prepare(&scene, frames).unwrap();
    let mut calls = 0;
    while !sampler.done() {
        let (z, t) = sampler.query();
        let x = model
            .denoise_prepared(&[PreparedItem {
                scene: &prepared,
                z,
                t,
            }])
            .unwrap()
            .remove(0);
        sampler.advance(&x).unwrap();
        calls += 1;
    }
    assert_eq!(calls, 2 * steps - 1, "Heun, the last step Euler");
    sampler.trajectory().to_vec()
}

#[test]
fn denoiser_call_and_sample_match_the_official_code() {
    let r = Reference::load();
    let (model, dir) = import("parity", true);
    assert_eq!(
        model.config().prior,
        TrajectoryPrior::None,
        "published weights: no prior"
    );
    let err = call_error(&model, &r);
    eprintln!("denoiser call: relative error {err:e}");
    assert!(err < 1e-4, "denoiser call: relative error {err:e}");
    let x = sample(&model, &r);
    let err = relative(&to_network(&model, &x), &r.values("sample.out"));
    eprintln!("sample: relative error {err:e}");
    assert!(err < 1e-3, "sample: relative error {err:e}");
    let err_m = relative(&x, &r.values("sample.out_metres"));
    assert!(err_m < 1e-3, "sample in metres: relative error {err_m:e}");

    // The written directory loads again and gives the same call.
    let again = PhysiFormer::load(&dir, &Device::Cpu, false).unwrap();
    assert!(call_error(&again, &r) < 1e-4);
    let card = std::fs::read_to_string(dir.join("card.md")).unwrap();
    assert!(card.contains("official PhysiFormer") && card.contains("ema.shadow"));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn one_perturbed_weight_or_the_raw_weights_break_parity() {
    let r = Reference::load();
    let (_, dir) = import("perturbed", true);
    // One weight of one block, nudged by 0.1.
    let path = dir.join("model.safetensors");
    let mut weights = candle_core::safetensors::load(&path, &Device::Cpu).unwrap();
    let w = &weights["blocks.2.attn.qkv.weight"];
    let mut v: Vec<f32> = w.flatten_all().unwrap().to_vec1().unwrap();
    v[7] += 0.1;
    let nudged = Tensor::from_vec(v, w.dims(), &Device::Cpu).unwrap();
    weights.insert("blocks.2.attn.qkv.weight".into(), nudged);
    candle_core::safetensors::save(&weights, &path).unwrap();
    let model = PhysiFormer::load(&dir, &Device::Cpu, false).unwrap();
    let err = call_error(&model, &r);
    eprintln!("perturbed weight: relative error {err:e}");
    assert!(err > 1e-4, "a perturbed weight still matched: {err:e}");
    std::fs::remove_dir_all(dir).unwrap();

    let (raw, dir) = import("raw", false);
    let err = call_error(&raw, &r);
    eprintln!("raw weights: relative error {err:e}");
    assert!(
        err > 1e-3,
        "the raw weights matched the EMA reference: {err:e}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}
