//! `dynaserve train average`: the written weights are the element-wise mean, the first
//! model's settings are kept, and models whose weights mean different things are refused.

use std::path::{Path, PathBuf};

use candle_core::{DType, Device};
use dynaserve_model::checkpoint::WEIGHTS_FILE;
use dynaserve_model::{ModelConfig, RigidFormer, load_rigidformer, read_config};
use dynaserve_train::train::{AverageOptions, average};

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("dynaserve-average-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn options(models: Vec<PathBuf>, out: PathBuf) -> AverageOptions {
    AverageOptions {
        models,
        out,
        dtype: DType::F32,
    }
}

/// A tiny random-weight model of `config` (weights from `seed`) saved in `dir`.
fn save_tiny(config: ModelConfig, seed: u64, dir: &Path) {
    RigidFormer::new(config, seed, &Device::Cpu)
        .unwrap()
        .save(dir)
        .unwrap();
}

#[test]
fn the_average_is_the_mean_of_the_weights_with_the_first_models_settings() {
    let dir = scratch("mean");
    let (a, b, out) = (dir.join("a"), dir.join("b"), dir.join("out"));
    save_tiny(ModelConfig::tiny(), 1, &a);
    let mut led = ModelConfig::tiny();
    led.dynamics.kinematic_lead = true;
    led.loss.rest_weight = 3.0;
    save_tiny(led, 2, &b);

    average(&options(vec![a.clone(), b.clone()], out.clone())).unwrap();

    let load = |d: &PathBuf| candle_core::safetensors::load(d.join(WEIGHTS_FILE), &Device::Cpu);
    let (wa, wb, wo) = (load(&a).unwrap(), load(&b).unwrap(), load(&out).unwrap());
    assert_eq!(wo.len(), wa.len());
    let max_abs = |t: candle_core::Tensor| {
        t.abs()
            .unwrap()
            .flatten_all()
            .unwrap()
            .max(0)
            .unwrap()
            .to_scalar::<f32>()
            .unwrap()
    };
    let mut spread = 0.0f32;
    for (name, o) in &wo {
        let mean = ((&wa[name] + &wb[name]).unwrap() / 2.0).unwrap();
        let gap = max_abs((o - &mean).unwrap());
        assert!(gap < 1e-6, "{name}: {gap}");
        spread = spread.max(max_abs((&wa[name] - &wb[name]).unwrap()));
    }
    assert!(spread > 1e-3, "the two seeds gave the same weights");
    let config = read_config(&out).unwrap();
    assert!(!config.dynamics.kinematic_lead);
    assert_eq!(
        config.loss.rest_weight,
        ModelConfig::tiny().loss.rest_weight
    );
    // The written directory is a model.
    load_rigidformer(&out, &Device::Cpu, false).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn models_whose_weights_mean_different_things_are_refused() {
    let dir = scratch("refuse");
    let (a, b, out) = (dir.join("a"), dir.join("b"), dir.join("out"));
    save_tiny(ModelConfig::tiny(), 1, &a);
    let mut other = ModelConfig::tiny();
    // The same shapes, but the outputs are read differently.
    other.dynamics.rigid_extrapolation = !other.dynamics.rigid_extrapolation;
    save_tiny(other, 2, &b);

    let err = average(&options(vec![a.clone(), b], out.clone())).unwrap_err();
    assert!(
        err.to_string().contains("dynamics.rigid_extrapolation"),
        "{err}"
    );
    assert!(!out.exists(), "nothing is written on refusal");
    let err = average(&options(vec![a], out.clone())).unwrap_err();
    assert!(err.to_string().contains("at least two"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
