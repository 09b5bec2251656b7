//! The held-out watch (`[heldout]`): the physics suite scored along a run, so that a training
//! loss that falls while the contacts on new scenes stay where they were shows while the run
//! goes on, not after it.
//!
//! At the start of a run the suite's scenes are generated once, in memory, from
//! `heldout.seed` (a seed neither the training splits, 0 to 2, nor the evaluation suite, 7,
//! uses). Every `heldout.every` iterations, at the last and before the first of a fresh run, the
//! weight average (the raw weights when the run keeps none) is written as a model directory
//! (`heldout/model/`), loaded for inference like a served model and scored with the
//! gravity-ballistic baseline beside it ([`run_suite`]). Each score:
//! - appends rows to `heldout.csv` (long form, [`HELDOUT_HEADER`]): per regime and step size
//!   the model's and the baseline's translation RMSE and their ratio; per scenario figure the
//!   model's mean, rapier's, and how many samples met the figure's target;
//! - writes the whole report to `heldout/step-NNNNNNNN.json`;
//! - redraws `heldout.png` (ballistic-over-model ratio of the contact regimes against the
//!   iteration);
//! - prints one line with the contact ratios.
//!
//! Scoring reads the weights and changes nothing the run depends on, so a run is the same with
//! or without the watch, and a resumed run keeps the rows up to its checkpoint.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use candle_core::Tensor;
use dynaserve_model::config::RIGIDFORMER;
use dynaserve_model::{Device, ModelConfig, load_rigidformer};

use super::TrainError;
pub use super::config::HeldoutConfig;
use super::export::write_model;
use super::plot::{Series, line_chart};
use super::run_dir::{io, truncate_log};
use crate::eval::physics_suite::{PhysicsSuiteReport, SuiteOptions, SuiteScene, generate_suite};
use crate::eval::regimes::Regime;
use crate::eval::{Ballistic, ModelPredictor, Predictor, physics_suite::run_suite};

/// Header of `heldout.csv`. `table` is `regime` or `figure`; for a regime row `model` and
/// `reference` are the model's and the ballistic baseline's translation RMSE (m) and `ratio`
/// the second over the first; for a figure row they are the model's and rapier's means (in
/// `unit`) and `met` the samples meeting the figure's target.
pub const HELDOUT_HEADER: &str = "step,weights,table,name,unit,k,model,reference,ratio,met,samples";

/// The watch of one run: its scenes, generated once, and where the scores go.
pub struct HeldoutWatch {
    config: HeldoutConfig,
    scenes: Vec<SuiteScene>,
    options: SuiteOptions,
    out: PathBuf,
}

/// What one score found, as [`HeldoutWatch::score`] prints it.
#[derive(Clone, Debug)]
pub struct HeldoutScore {
    /// The iteration scored.
    pub step: u64,
    /// The whole report.
    pub report: PhysicsSuiteReport,
}

impl HeldoutWatch {
    /// The watch of the run in `out` (`None` when `config.every` is 0): generates the scenes
    /// and, when resuming from `resumed_step`, keeps the rows of `heldout.csv` up to it.
    pub fn start(
        config: &HeldoutConfig,
        out: &Path,
        gravity: [f32; 3],
        resumed_step: Option<u64>,
    ) -> Result<Option<HeldoutWatch>, TrainError> {
        if config.every == 0 {
            return Ok(None);
        }
        config.validate()?;
        let started = Instant::now();
        let scenes = generate_suite(
            config.seed,
            "test",
            config.scenes,
            config.points,
            dynaserve_sim::Materials::Kubric,
        )
        .map_err(eval_err)?;
        eprintln!(
            "held-out suite: {} scenes (seed {}, {} per group) generated in {:.1} s, scored every {} iterations",
            scenes.len(),
            config.seed,
            config.scenes,
            started.elapsed().as_secs_f64(),
            config.every
        );
        let csv = out.join("heldout.csv");
        match resumed_step {
            Some(step) => truncate_log(&csv, HELDOUT_HEADER, step)?,
            None => std::fs::write(&csv, format!("{HELDOUT_HEADER}\n")).map_err(io(&csv))?,
        }
        Ok(Some(HeldoutWatch {
            config: config.clone(),
            scenes,
            options: SuiteOptions {
                step_sizes: config.step_sizes.clone(),
                window_stride: config.window_stride,
                gravity,
                ..SuiteOptions::default()
            },
            out: out.to_path_buf(),
        }))
    }

    /// Whether iteration `step` of a schedule of `iterations` is scored: every
    /// `heldout.every`-th, and the last.
    pub fn due(&self, step: u64, iterations: u64) -> bool {
        step.is_multiple_of(self.config.every) || step == iterations
    }

    /// Scores `weights` (by parameter name, for a model of `config`) at iteration `step` on
    /// `device`; `average` says whether they are the weight average (module docs).
    pub fn score(
        &self,
        step: u64,
        config: &ModelConfig,
        weights: &HashMap<String, Tensor>,
        average: bool,
        device: &Device,
    ) -> Result<HeldoutScore, TrainError> {
        let dir = self.out.join("heldout");
        let model_dir = dir.join("model");
        write_model(&model_dir, config, weights)?;
        let model = load_rigidformer(&model_dir, device, false)?.with_name(RIGIDFORMER);
        let predictor = ModelPredictor::from_rigidformer(Arc::new(model));
        let ballistic = Ballistic {
            gravity: self.options.gravity,
            floor_z: Some(0.0),
        };
        let predictors: [(&str, &dyn Predictor); 2] =
            [("model", &predictor), ("ballistic", &ballistic)];
        let source = format!("held-out suite (seed {}, split test)", self.config.seed);
        let report = run_suite(
            &predictors,
            &self.scenes,
            &self.options,
            &source,
            &|_, _| {},
        )
        .map_err(eval_err)?;
        let json = dir.join(format!("step-{step:08}.json"));
        let text = serde_json::to_string_pretty(&report)
            .map_err(|e| TrainError::Config(format!("held-out report: {e}")))?;
        std::fs::write(&json, text + "\n").map_err(io(&json))?;
        let csv = self.out.join("heldout.csv");
        let rows = csv_rows(step, if average { "average" } else { "raw" }, &report);
        let mut file = std::fs::OpenOptions::new()
            .append(true)
            .open(&csv)
            .map_err(io(&csv))?;
        std::io::Write::write_all(&mut file, rows.as_bytes()).map_err(io(&csv))?;
        if let Err(e) = plot_heldout(&self.out) {
            eprintln!("held-out chart not drawn: {e}");
        }
        Ok(HeldoutScore { step, report })
    }
}

impl HeldoutScore {
    /// One line: the ballistic-over-model ratio of the two contact regimes at every step size
    /// (as the chart: free flight's and resting's ratios say more about the baseline).
    pub fn summary(&self) -> String {
        let mut s = format!("held-out at iteration {}:", self.step);
        for row in &self.report.regimes {
            if ![Regime::FloorContact, Regime::ObjectContact].contains(&row.regime) {
                continue;
            }
            if let Some([Some(r), _]) = row.ballistic_over_model {
                let _ = write!(s, " {} k={} {r:.2}x;", row.regime.name(), row.k);
            }
        }
        s
    }
}

fn eval_err(e: crate::eval::EvalError) -> TrainError {
    TrainError::Data(format!("held-out suite: {e}"))
}

fn cell(v: Option<f64>) -> String {
    v.map(|v| v.to_string()).unwrap_or_default()
}

/// The `heldout.csv` rows of one report (model first, ballistic second).
fn csv_rows(step: u64, weights: &str, r: &PhysicsSuiteReport) -> String {
    let mut out = String::new();
    for row in &r.regimes {
        let [model, reference] = [0, 1].map(|i| row.predictors.get(i)?.translation_rmse_m);
        let ratio = row.ballistic_over_model.and_then(|[t, _]| t);
        let _ = writeln!(
            out,
            "{step},{weights},regime,{},m,{},{},{},{},,{}",
            row.regime.name(),
            row.k,
            cell(model),
            cell(reference),
            cell(ratio),
            row.count
        );
    }
    // The scenario figures come from rollouts at step size 1.
    for f in &r.figures {
        let model = f.predictors.first();
        let _ = writeln!(
            out,
            "{step},{weights},figure,{}/{}/{},{},1,{},{},,{},{}",
            f.scenario,
            f.group,
            f.figure,
            f.unit,
            cell(model.map(|m| m.mean)),
            cell(f.rapier.as_ref().map(|m| m.mean)),
            model
                .and_then(|m| m.met)
                .map(|m| m.to_string())
                .unwrap_or_default(),
            f.samples
        );
    }
    out
}

/// Redraws `heldout.png` from `heldout.csv`: the two contact regimes at every step size (the
/// baseline is exact in free flight and far off at rest, so those ratios, in the CSV, would
/// only flatten the chart).
fn plot_heldout(out: &Path) -> Result<(), TrainError> {
    let path = out.join("heldout.csv");
    let text = std::fs::read_to_string(&path).map_err(io(&path))?;
    let contact = [Regime::FloorContact.name(), Regime::ObjectContact.name()];
    let mut series: Vec<Series> = Vec::new();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() < 9 || f[2] != "regime" || !contact.contains(&f[3]) {
            continue;
        }
        let (Ok(step), Ok(ratio)) = (f[0].parse::<f64>(), f[8].parse::<f64>()) else {
            continue;
        };
        let name = format!("{} k={}", f[3], f[5]);
        match series.iter_mut().find(|s| s.name == name) {
            Some(s) => s.points.push((step, ratio)),
            None => series.push(Series {
                name,
                points: vec![(step, ratio)],
            }),
        }
    }
    if series.is_empty() {
        return Ok(());
    }
    series.sort_by(|a, b| a.name.cmp(&b.name));
    line_chart(
        &out.join("heldout.png"),
        "Held-out suite, contacts: ballistic error over the model's (higher is better)",
        "iteration",
        "translation RMSE ratio",
        &series,
        false,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Scored every `every`-th iteration and at the last even off the cadence; off by default.
    #[test]
    fn due_at_the_cadence_and_the_last_iteration() {
        let dir = std::env::temp_dir().join(format!("dynaserve-heldout-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let off = HeldoutWatch::start(&HeldoutConfig::default(), &dir, [0.0, 0.0, -9.81], None);
        assert!(off.unwrap().is_none());
        let config = HeldoutConfig {
            every: 3,
            scenes: 1,
            points: 64,
            ..HeldoutConfig::default()
        };
        let watch = HeldoutWatch::start(&config, &dir, [0.0, 0.0, -9.81], None)
            .unwrap()
            .unwrap();
        let due: Vec<u64> = (0..=7).filter(|&s| watch.due(s, 7)).collect();
        assert_eq!(due, [0, 3, 6, 7]);
        let bad = HeldoutConfig {
            step_sizes: vec![0],
            ..config
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("heldout.step_sizes")
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
