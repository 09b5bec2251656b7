//! PhysiFormer training runs end to end on a tiny generated mesh split: a new run takes the
//! configured prior, `--resume` continues it, and a resume asking for another prior is refused.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use dynaserve_model::physiformer::config::TrajectoryPrior;
use dynaserve_model::physiformer::read_physi_config;
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
    run(&static_cfg, false, Some(1), stop.clone()).unwrap();
    let model = read_physi_config(&out.join("checkpoint")).unwrap();
    assert_eq!(model.prior, TrajectoryPrior::Static);

    let other = config(&dir, &data, &out, "ballistic");
    let err = run(&other, true, Some(1), stop.clone()).unwrap_err();
    assert!(format!("{err:#}").contains("prior"), "{err:#}");
    run(&static_cfg, true, Some(1), stop).unwrap();
    let log = std::fs::read_to_string(out.join("log.csv")).unwrap();
    assert_eq!(log.lines().count(), 3, "header and two iterations:\n{log}");
    std::fs::remove_dir_all(&dir).unwrap();
}
