//! Checkpoint round trips and clear errors on corrupted or mismatched checkpoints.
mod common;

use common::{load_error, max_pose_diff, random_scene, tmp_dir};
use dynaserve_model::{
    DType, Device, ModelConfig, RigidFormer, StepItem, WorldModel, load_model, load_rigidformer,
};

fn outputs(model: &dyn WorldModel) -> Vec<Vec<dynaserve_model::Pose>> {
    let (o, s) = random_scene(12, 4, 80);
    let scene = model.prepare(o).unwrap();
    model
        .step(&[StepItem {
            scene: &scene,
            state: &s,
            dt_steps: 2,
        }])
        .unwrap()
}

#[test]
fn save_load_round_trip_is_identical() {
    let model = RigidFormer::new(ModelConfig::tiny(), 5, &Device::Cpu).unwrap();
    let dir = tmp_dir("ckpt", "roundtrip");
    model.save(&dir).unwrap();
    assert!(dir.join("card.md").exists());
    // Loaded as it was saved (trainable): the same network to the bit.
    let same = load_rigidformer(&dir, &Device::Cpu, true).unwrap();
    assert_eq!(outputs(&model), outputs(&same));
    // Loaded for inference: its products read transposed weight copies, so the sums run in
    // another order; the same poses within float rounding.
    let loaded = load_model(&dir, &Device::Cpu).unwrap();
    assert_eq!(loaded.config(), model.config());
    let (a, b) = (outputs(&model), outputs(loaded.as_ref()));
    assert_eq!(a.len(), b.len());
    for (pa, pb) in a.iter().zip(&b) {
        assert!(max_pose_diff(pa, pb) < 1e-5, "{pa:?} vs {pb:?}");
    }
    assert_eq!(loaded.name(), dir.file_name().unwrap().to_str().unwrap());
    // The weights file is as readable as the config beside it (any new file of the process),
    // not owner-only, and no temporary file is left behind.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = |f: &str| std::fs::metadata(dir.join(f)).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode("model.safetensors"), mode("config.json"));
    }
    assert!(!dir.join("model.safetensors.tmp").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn half_precision_weights_load_into_f32() {
    let model = RigidFormer::new(ModelConfig::tiny(), 6, &Device::Cpu).unwrap();
    for dtype in [DType::F16, DType::BF16] {
        let dir = tmp_dir("ckpt", &format!("{dtype:?}"));
        model.save_with_dtype(&dir, dtype).unwrap();
        let loaded = load_model(&dir, &Device::Cpu).unwrap();
        let (a, b) = (outputs(&model), outputs(loaded.as_ref()));
        let diff = common::max_pose_diff(&a[0], &b[0]);
        assert!(diff < 0.05 && diff.is_finite(), "{dtype:?}: {diff}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

#[test]
fn corrupted_and_mismatched_checkpoints_give_clear_errors() {
    let model = RigidFormer::new(ModelConfig::tiny(), 7, &Device::Cpu).unwrap();
    let dir = tmp_dir("ckpt", "bad");
    model.save(&dir).unwrap();
    let weights = std::fs::read(dir.join("model.safetensors")).unwrap();
    let config = std::fs::read_to_string(dir.join("config.json")).unwrap();

    // Missing directory / files.
    assert!(load_error(&dir.join("nope")).contains("config.json"));
    std::fs::remove_file(dir.join("model.safetensors")).unwrap();
    assert!(load_error(&dir).contains("model.safetensors"));

    // Truncated, garbage and empty weights.
    for bytes in [
        weights[..weights.len() / 2].to_vec(),
        b"not a tensor file at all".to_vec(),
        Vec::new(),
    ] {
        std::fs::write(dir.join("model.safetensors"), bytes).unwrap();
        let e = load_error(&dir);
        assert!(e.contains("corrupted"), "{e}");
    }
    // Flipped header length.
    let mut flipped = weights.clone();
    flipped[0..8].copy_from_slice(&u64::MAX.to_le_bytes());
    std::fs::write(dir.join("model.safetensors"), flipped).unwrap();
    assert!(load_error(&dir).contains("corrupted"));
    std::fs::write(dir.join("model.safetensors"), &weights).unwrap();

    // Broken or inconsistent configs.
    std::fs::write(dir.join("config.json"), "{ \"width\": ").unwrap();
    assert!(load_error(&dir).contains("not a valid configuration"));
    std::fs::write(
        dir.join("config.json"),
        config.replace("\"rigidformer\"", "\"other\""),
    )
    .unwrap();
    assert!(load_error(&dir).contains("architecture"));
    // A config of another size than the weights: names the first mismatched tensor's shape.
    let wider = serde_json::to_string(&ModelConfig {
        width: 64,
        ..ModelConfig::tiny()
    })
    .unwrap();
    std::fs::write(dir.join("config.json"), wider).unwrap();
    let e = load_error(&dir);
    assert!(e.contains("has shape") && e.contains("needs"), "{e}");
    // More blocks than stored: a missing tensor is named.
    let deeper = serde_json::to_string(&ModelConfig {
        blocks: 3,
        ..ModelConfig::tiny()
    })
    .unwrap();
    std::fs::write(dir.join("config.json"), deeper).unwrap();
    let e = load_error(&dir);
    assert!(
        e.contains("has no tensor") && e.contains("decoder.blocks.2"),
        "{e}"
    );
    // Fewer blocks than stored: the unused tensors are named.
    let shallower = serde_json::to_string(&ModelConfig {
        blocks: 1,
        anchor_taps: vec![0, 0],
        ..ModelConfig::tiny()
    })
    .unwrap();
    std::fs::write(dir.join("config.json"), shallower).unwrap();
    let e = load_error(&dir);
    assert!(e.contains("does not use"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}
