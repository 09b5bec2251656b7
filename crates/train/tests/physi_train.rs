//! PhysiFormer training runs end to end on a tiny generated mesh split: a new run takes the
//! configured prior, `--resume` continues it, and a resume asking for another prior is refused;
//! a run started from a model directory (`init`) starts from its weights.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use dynaserve_model::physiformer::config::TrajectoryPrior;
use dynaserve_model::physiformer::read_physi_config;
use dynaserve_model::{Device, PhysiFormer};
use dynaserve_sim::mesh_scenes::{MeshGenerateOptions, MeshSet, generate_mesh_dataset};
use dynaserve_train::physi::train::run;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("dynaserve-physi-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn config(dir: &Path, data: &Path, out: &Path, prior: &str) -> PathBuf {
    let path = dir.join(format!("{prior}.toml"));
    std::fs::write(
        &path,
        format!(
            "architecture = \"physiformer\"\npreset = \"tiny\"\nprior = \"{prior}\"\n\
             train = [{data:?}]\nout_dir = {out:?}\nlog_every = 1\n\n\
             [optim]\nbatch_size = 1\niterations = 4\nwarmup = 1\n"
        ),
    )
    .unwrap();
    path
}

#[test]
fn a_run_keeps_its_prior_and_a_resume_asking_for_another_is_refused() {
    let dir = tmp("run");
    let data = dir.join("d1");
    let opts = MeshGenerateOptions::new(MeshSet::D1, 3, "train", 2);
    generate_mesh_dataset(&opts, &data, false, &|| {}).unwrap();
    let out = dir.join("run");
    let stop = Arc::new(AtomicBool::new(false));
    let static_cfg = config(&dir, &data, &out, "static");
    run(&static_cfg, false, Some(1), None, stop.clone()).unwrap();
    let model = read_physi_config(&out.join("checkpoint")).unwrap();
    assert_eq!(model.prior, TrajectoryPrior::Static);

    let other = config(&dir, &data, &out, "ballistic");
    let err = run(&other, true, Some(1), None, stop.clone()).unwrap_err();
    assert!(format!("{err:#}").contains("prior"), "{err:#}");
    run(&static_cfg, true, Some(1), None, stop).unwrap();
    let log = std::fs::read_to_string(out.join("log.csv")).unwrap();
    assert_eq!(log.lines().count(), 3, "header and two iterations:\n{log}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `init` starts a new run from a model directory's weights and configuration, with
/// `correction_ramp_frames` applied; at learning rate 0 its first checkpoint holds exactly
/// those weights, and a resume asking for another ramp is refused.
#[test]
fn a_run_starts_from_an_init_model_with_the_ramp_it_asks_for() {
    let dir = tmp("init");
    let data = dir.join("d1");
    let opts = MeshGenerateOptions::new(MeshSet::D1, 2, "train", 3);
    generate_mesh_dataset(&opts, &data, false, &|| {}).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let first = dir.join("first");
    run(
        &config(&dir, &data, &first, "static"),
        false,
        Some(1),
        None,
        stop.clone(),
    )
    .unwrap();
    let init = first.join("checkpoint");

    let tuned = dir.join("tuned");
    let write = |ramp: usize| {
        let path = dir.join(format!("tuned-{ramp}.toml"));
        std::fs::write(
            &path,
            format!(
                "architecture = \"physiformer\"\npreset = \"small\"\ninit = {init:?}\n\
                 correction_ramp_frames = {ramp}\ntrain = [{data:?}]\nout_dir = {tuned:?}\n\n\
                 [optim]\nbatch_size = 1\niterations = 2\nwarmup = 1\nlr = 0.0\nweight_decay = 0.0\n"
            ),
        )
        .unwrap();
        path
    };
    run(&write(6), false, Some(1), None, stop.clone()).unwrap();
    let cfg = read_physi_config(&tuned.join("checkpoint")).unwrap();
    assert_eq!(cfg.correction_ramp_frames, 6);
    // The init model's configuration (tiny, static prior), not the named preset's.
    assert_eq!(cfg.prior, TrajectoryPrior::Static);
    assert_eq!(cfg.official, read_physi_config(&init).unwrap().official);
    let weights = |d: &Path| {
        let m = PhysiFormer::load(d, &Device::Cpu, false).unwrap();
        let data = m.varmap().data().lock().unwrap();
        let mut w: Vec<(String, Vec<f32>)> = data
            .iter()
            .map(|(k, v)| {
                let t = v
                    .as_tensor()
                    .flatten_all()
                    .unwrap()
                    .to_vec1::<f32>()
                    .unwrap();
                (k.clone(), t)
            })
            .collect();
        w.sort_by(|a, b| a.0.cmp(&b.0));
        w
    };
    assert_eq!(weights(&tuned.join("checkpoint")), weights(&init));

    let err = run(&write(3), true, Some(1), None, stop).unwrap_err();
    assert!(
        format!("{err:#}").contains("correction_ramp_frames"),
        "{err:#}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
