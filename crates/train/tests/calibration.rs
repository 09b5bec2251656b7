//! The calibration suite (`dynaserve eval --suite calibration`) on a tiny generated MOVi-B split
//! with the bundled ensemble: every dynamic object is scored at every horizon inside the data,
//! the spread is the ensemble's (positive), the baseline the rollout's path length, and a
//! horizon past the data is reported missing; a single network, without a spread, is refused.

use std::path::{Path, PathBuf};

use dynaserve_sim::writer::generate_dataset;
use dynaserve_sim::{GenerateOptions, Generator};
use dynaserve_train::eval::ModelPredictor;
use dynaserve_train::eval::calibration::{
    CalibrationOptions, format_calibration_markdown, load_scenes, plot_calibration, run_calibration,
};

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!(
        "dynaserve-calibration-{name}-{}",
        std::process::id()
    ))
}

fn models() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models")
}

#[test]
fn the_calibration_suite_runs_on_a_tiny_generated_split() {
    let dir = temp("split");
    let mut opts = GenerateOptions::new(Generator::movi_b(), 4, "test", 2);
    opts.points = 128;
    opts.sim.frames = 16;
    generate_dataset(&opts, &dir, true, &|| {}).unwrap();
    let scenes = load_scenes(&dir, None).unwrap();
    assert_eq!(scenes.len(), 2);
    let model =
        ModelPredictor::load(&models().join("ensembles/rigidformer-small-ensemble")).unwrap();
    let copts = CalibrationOptions {
        horizons_steps: vec![2, 6, 40],
        ..CalibrationOptions::default()
    };
    let report = run_calibration(&model, &scenes, &copts, "tiny").unwrap();
    let objects: usize = scenes.iter().map(|s| s.objects.len()).sum();
    assert_eq!(report.kinematic_excluded, 0);
    assert_eq!(report.members.len(), 2);
    assert_eq!(report.horizons.len(), 2, "40 steps is past the 16 frames");
    assert_eq!(report.missing.len(), 1);
    assert_eq!(report.samples.len(), 2 * objects);
    for h in &report.horizons {
        assert_eq!(h.objects, objects);
        assert_eq!(
            h.spread_deciles.iter().map(|b| b.count).sum::<usize>(),
            objects
        );
        assert!(h.mean_spread_m > 0.0 && h.mean_spread_m.is_finite());
        assert!(h.mean_error_m.is_finite());
    }
    // The path length and the accumulated spread never shrink with the horizon, and the
    // accumulated spread holds at least the step's own.
    for s in report.samples.iter().filter(|s| s.steps == 6) {
        let early = report
            .samples
            .iter()
            .find(|e| e.steps == 2 && e.scene == s.scene && e.object == s.object)
            .unwrap();
        assert!(s.baseline_m >= early.baseline_m);
        assert!(s.accumulated_m >= early.accumulated_m);
        assert!(s.accumulated_m + 1e-9 >= f64::from(s.spread.position_m));
    }
    let md = format_calibration_markdown(&report);
    assert!(md.contains("Spearman spread"));
    let png = temp("plot").with_extension("png");
    plot_calibration(&png, &report).unwrap();
    assert!(std::fs::metadata(&png).unwrap().len() > 0);
    // A single network has no spread.
    let single = ModelPredictor::load(&models().join("rigidformer-small")).unwrap();
    assert!(run_calibration(&single, &scenes, &copts, "tiny").is_err());
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_file(&png);
}
