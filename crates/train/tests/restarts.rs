//! Restart scenes (`dynaserve_train::train::restarts`) written from generated MOVi-B scenes with
//! the shipped checkpoint: each stored scene is the model's own last two poses followed by
//! exactly what rapier does from them, with the source's objects; sources with pushers are
//! refused.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use dynaserve_model::{Pose, SceneState};
use dynaserve_sim::writer::generate_dataset;
use dynaserve_sim::{DatasetReader, GenerateOptions, Generator, Scenario};
use dynaserve_train::eval::{
    ModelPredictor, Predictor, RapierRestart, RolloutRequest, observed_state, poses_at,
};
use dynaserve_train::train::restarts::{
    RestartOptions, Skip, continue_in_rapier, draw, write_restarts,
};

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("dynaserve-restarts-{name}-{}", std::process::id()))
}

fn source(generator: Generator, dir: &Path, scenes: usize) -> DatasetReader {
    let mut opts = GenerateOptions::new(generator, 11, "train", scenes);
    opts.points = 256;
    opts.sim.frames = 16;
    generate_dataset(&opts, dir, true, &|| {}).unwrap();
    DatasetReader::open(dir).unwrap()
}

fn shipped() -> ModelPredictor {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rigidformer-small");
    let model =
        dynaserve_model::load_rigidformer(&dir, &dynaserve_model::Device::Cpu, false).unwrap();
    ModelPredictor::from_rigidformer(Arc::new(model))
}

/// Largest difference of translations (m) and of quaternion components (sign-aligned).
fn differ(a: &[Pose], b: &[Pose]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(p, q)| {
            let t = (0..3).map(|d| (p.translation[d] - q.translation[d]).abs());
            let s = if (0..4).map(|i| p.rotation[i] * q.rotation[i]).sum::<f32>() < 0.0 {
                -1.0
            } else {
                1.0
            };
            let r = (0..4).map(|i| (p.rotation[i] - s * q.rotation[i]).abs());
            t.chain(r).fold(0.0, f32::max)
        })
        .fold(0.0, f32::max)
}

#[test]
fn restart_scenes_are_the_models_poses_then_rapier() {
    let src_dir = temp("movi");
    let out = temp("out");
    let _ = std::fs::remove_dir_all(&out);
    let reader = source(Generator::movi_b(), &src_dir, 3);
    let model = shipped();
    let opts = RestartOptions {
        scenes: 3,
        seed: 5,
        rollout_max: 4,
        frames: 6,
        per_shard: 2,
        overwrite: false,
    };
    let mut reports = Vec::new();
    let summary = write_restarts(&model, "shipped", &reader, &out, &opts, |d, s| {
        reports.push((d, s))
    })
    .unwrap();
    assert_eq!(
        (
            summary.skipped(),
            summary.fell_through,
            &summary.first_rebuild_error
        ),
        (0, 0, &None),
        "MOVi-B shapes rebuild and nothing falls through"
    );
    assert_eq!(reports, vec![(2, 0), (3, 0)], "progress after each shard");
    let written = DatasetReader::open(&out).unwrap();
    let m = written.manifest();
    assert_eq!(
        (m.generator.as_str(), m.frames, m.scenes),
        ("restart", 8, 3)
    );
    assert_eq!(m.generator_parameters["restart_source_generator"], "movi-b");
    assert_eq!(m.generator_parameters["restart_model"], "shipped");
    assert_eq!(m.shards.len(), 2);
    let rapier = RapierRestart::from_manifest(reader.manifest()).unwrap();
    for i in 0..3 {
        let d = draw(&opts, i, reader.len(), reader.manifest().frames);
        let (start, steps) = (d.start, d.steps);
        let src = reader.get(d.source).unwrap();
        let got = written.get(i).unwrap();
        assert_eq!(got.objects.len(), src.objects.len());
        for (g, o) in got.objects.iter().zip(&src.objects) {
            assert_eq!(
                (&g.reference_points, g.mass, g.friction, g.shape_id),
                (&o.reference_points, o.mass, o.friction, o.shape_id)
            );
            for w in g.rotations.windows(2) {
                let dot: f32 = (0..4).map(|k| w[0][k] * w[1][k]).sum();
                assert!(dot >= 0.0, "quaternions sign-continuous");
            }
        }
        // Frames 0 and 1: the model's last two poses of its rollout from the recording.
        let request = RolloutRequest {
            scene: &src,
            observed: observed_state(&src, start, 1).unwrap(),
            dt_steps: 1,
            steps,
        };
        let roll = model
            .rollout(request.scene, &request.observed, 1, steps)
            .unwrap();
        let before = if steps >= 2 {
            roll[steps - 2].clone()
        } else {
            request.observed.current.clone()
        };
        assert!(
            differ(&poses_at(&got, 0).unwrap(), &before) < 1e-4,
            "scene {i}: frame 0"
        );
        assert!(
            differ(&poses_at(&got, 1).unwrap(), &roll[steps - 1]) < 1e-4,
            "scene {i}: frame 1"
        );
        // Frames 2..: rapier restarted from the stored frames 0 and 1.
        let state = SceneState {
            previous: poses_at(&got, 0).unwrap(),
            current: poses_at(&got, 1).unwrap(),
            earlier: None,
            carry: Default::default(),
        };
        let cont = rapier.rollout(&got, &state, 1, opts.frames).unwrap();
        for (f, want) in cont.iter().enumerate() {
            assert!(
                differ(&poses_at(&got, f + 2).unwrap(), want) < 1e-5,
                "scene {i}: frame {}",
                f + 2
            );
        }
    }
    // A state with every object under the floor slab is skipped as falling through it.
    let src = reader.get(0).unwrap();
    let mut sunk = poses_at(&src, 0).unwrap();
    for p in &mut sunk {
        p.translation[2] = -5.0;
    }
    let state = SceneState {
        previous: sunk.clone(),
        current: sunk,
        earlier: None,
        carry: Default::default(),
    };
    assert_eq!(
        continue_in_rapier(&rapier, &src, &state, 4).unwrap_err(),
        Skip::FellThrough
    );
    // A second run into the same directory is refused, not merged; with `overwrite` it
    // replaces the split.
    assert!(write_restarts(&model, "shipped", &reader, &out, &opts, |_, _| {}).is_err());
    let again = RestartOptions {
        scenes: 1,
        overwrite: true,
        ..opts
    };
    write_restarts(&model, "shipped", &reader, &out, &again, |_, _| {}).unwrap();
    assert_eq!(DatasetReader::open(&out).unwrap().len(), 1);
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_dir_all(&src_dir);
}

#[test]
fn sources_with_pushers_are_refused() {
    let src_dir = temp("push");
    let out = temp("push-out");
    let _ = std::fs::remove_dir_all(&out);
    let reader = source(Generator::scenario(Scenario::Push), &src_dir, 1);
    let opts = RestartOptions {
        scenes: 1,
        seed: 1,
        rollout_max: 2,
        frames: 4,
        per_shard: 1,
        overwrite: false,
    };
    let err = write_restarts(&shipped(), "shipped", &reader, &out, &opts, |_, _| {})
        .unwrap_err()
        .to_string();
    assert!(err.contains("kinematic"), "{err}");
    assert!(!out.exists(), "refused before the output directory is made");
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_dir_all(&src_dir);
}
