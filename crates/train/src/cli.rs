//! `dynaserve eval`: score a trained model and the baselines on a dataset split (see
//! [`crate::eval`] for the protocol and the metrics, `docs/evaluation.md` for the reports).

use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use dynaserve_sim::DatasetReader;
use indicatif::{ProgressBar, ProgressStyle};

use crate::eval::{
    Ballistic, DEFAULT_LONG_ROLLOUT_STEPS, DEFAULT_PROJECTION_EVERY, DEFAULT_START_FRAME,
    EvalOptions, ModelPredictor, Occlusion, PlotStyle, PointSelection, Predictor, RestingOptions,
    Static, SuiteEntry, SuiteReport, evaluate_dataset_many, format_markdown, format_suite,
    plot_errors,
};

/// Baselines `dynaserve eval --baseline` knows.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BaselineKind {
    /// Every object stays at its last observed pose.
    Static,
    /// Constant angular velocity, free flight under the data's gravity, inelastic floor.
    Ballistic,
}

/// Scenario suites `dynaserve eval --suite` knows.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SuiteKind {
    /// Rest, drop, slide, collide and stack-hit scenes: each scenario's own figures against
    /// rapier and the one-step error by contact regime.
    Physics,
}

/// Arguments of `dynaserve eval`.
///
/// With `--model`, one run evaluates the model with its nominal point count, with
/// `--variant-points` points and with `--occlude` of its points removed, plus the static and
/// ballistic baselines, all on the same scenes; `--no-variants` and `--no-baselines` turn
/// parts off.
#[derive(clap::Args, Debug, Clone)]
pub struct EvalArgs {
    /// Evaluate only this baseline.
    #[arg(
        long,
        value_enum,
        required_unless_present = "model",
        conflicts_with = "model"
    )]
    pub baseline: Option<BaselineKind>,
    /// Checkpoint directory of a trained model (config.json, model.safetensors) to evaluate.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Dataset split directory (holding manifest.json). With `--suite`, optional and
    /// repeatable: scenario datasets to score instead of the generated suite.
    #[arg(long, required_unless_present = "suite")]
    pub data: Vec<PathBuf>,
    /// Score a scenario suite instead of the error tables of a dataset.
    #[arg(long, value_enum)]
    pub suite: Option<SuiteKind>,
    /// Seed of the generated suite (split `test`).
    #[arg(long, default_value_t = crate::eval::physics_suite::DEFAULT_SUITE_SEED)]
    pub seed: u64,
    /// Scenes per group of the generated suite.
    #[arg(long, default_value_t = crate::eval::physics_suite::DEFAULT_SCENES_PER_GROUP)]
    pub suite_scenes: usize,
    /// Suite: score every N-th one-step window of each scene in the regime table.
    #[arg(long, default_value_t = 1)]
    pub window_stride: usize,
    /// Step sizes in frames, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1u32, 2, 4])]
    pub step_sizes: Vec<u32>,
    /// Horizons in seconds after the start frame, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [0.5f64, 1.0, 2.0, 4.0])]
    pub horizons: Vec<f64>,
    /// Start frame s: the predictor observes frames s - k and s.
    #[arg(long, default_value_t = DEFAULT_START_FRAME)]
    pub start_frame: usize,
    /// Evaluate only the first N scenes.
    #[arg(long)]
    pub max_scenes: Option<usize>,
    /// Reference points per object given to the model (a prefix of the stored cloud); default
    /// the model's nominal count (`points_per_object` of its config.json).
    #[arg(long)]
    pub points_per_object: Option<usize>,
    /// Point count of the second model variant.
    #[arg(long, default_value_t = 768)]
    pub variant_points: usize,
    /// Fraction of each object's points removed (one side of a random plane) in the third
    /// model variant.
    #[arg(long, default_value_t = 0.25)]
    pub occlude: f32,
    /// Seed of the occlusion planes.
    #[arg(long, default_value_t = 0)]
    pub occlusion_seed: u64,
    /// Evaluate the model only at its nominal point count (no 768-point or occluded variant).
    #[arg(long)]
    pub no_variants: bool,
    /// Do not evaluate the static and ballistic baselines next to the model.
    #[arg(long)]
    pub no_baselines: bool,
    /// Steps of the k = 1 stability rollout (0 turns it off).
    #[arg(long, default_value_t = DEFAULT_LONG_ROLLOUT_STEPS)]
    pub long_steps: usize,
    /// Check the pre-projection rigidity residual at every N-th state of the stability rollout
    /// (0 turns it off).
    #[arg(long, default_value_t = DEFAULT_PROJECTION_EVERY)]
    pub projection_every: usize,
    /// Do not report the resting drift.
    #[arg(long)]
    pub no_resting: bool,
    /// Write the report as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write the Markdown tables to this file.
    #[arg(long)]
    pub markdown: Option<PathBuf>,
    /// Write the error-against-time PNG to this file (default: next to --json, with .png).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// PhysiFormer models: samples drawn per scene (their mean and spread are reported).
    #[arg(long, default_value_t = 3)]
    pub samples: usize,
    /// PhysiFormer models: denoising steps per sample.
    #[arg(long, default_value_t = 25)]
    pub denoise_steps: usize,
}

impl EvalArgs {
    /// The evaluation options these arguments ask for.
    pub fn options(&self) -> EvalOptions {
        EvalOptions {
            start_frame: self.start_frame,
            step_sizes: self.step_sizes.clone(),
            horizons_s: self.horizons.clone(),
            max_scenes: self.max_scenes,
            long_rollout_steps: self.long_steps,
            projection_every: self.projection_every,
            resting: (!self.no_resting).then(RestingOptions::default),
        }
    }

    /// Where the plot goes: `--plot`, else `--json` with the extension `.png`, else nowhere.
    pub fn plot_path(&self) -> Option<PathBuf> {
        self.plot
            .clone()
            .or_else(|| self.json.as_ref().map(|j| j.with_extension("png")))
    }
}

/// One predictor of a run: its column label, its input (learned models), whether it is learned.
struct Entry {
    label: String,
    input: Option<String>,
    predictor: Box<dyn Predictor>,
    learned: bool,
}

impl Entry {
    fn baseline(label: &str, predictor: Box<dyn Predictor>) -> Entry {
        Entry {
            label: label.into(),
            input: None,
            predictor,
            learned: false,
        }
    }
}

fn write_file(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

/// Runs `dynaserve eval`: progress on stderr, the summary on stdout, JSON, Markdown and the
/// plot to the requested files.
pub fn run_eval(args: EvalArgs) -> anyhow::Result<()> {
    if let (Some(model), [data]) = (&args.model, args.data.as_slice())
        && crate::physi::eval::is_physi_model(model)
    {
        return crate::physi::eval::run(&crate::physi::eval::PhysiEvalOptions {
            model: model.clone(),
            data: data.clone(),
            scenes: args.max_scenes.unwrap_or(50),
            samples: args.samples,
            steps: args.denoise_steps,
            seed: args.seed,
            plot: args.plot.clone(),
        });
    }
    if args.suite.is_some() {
        return crate::eval::suite_cli::run(&args);
    }
    let started = std::time::Instant::now();
    let data = match args.data.as_slice() {
        [one] => one,
        _ => anyhow::bail!("give one --data directory (several only with --suite)"),
    };
    let reader =
        DatasetReader::open(data).with_context(|| format!("opening dataset {}", data.display()))?;
    if !(0.0..1.0).contains(&args.occlude) {
        anyhow::bail!("--occlude must be in [0, 1), got {}", args.occlude);
    }
    let ballistic = Ballistic::from_manifest(reader.manifest());
    let mut predictors: Vec<Entry> = Vec::new();
    match (args.baseline, &args.model) {
        (Some(BaselineKind::Static), None) => {
            predictors.push(Entry::baseline("static", Box::new(Static)))
        }
        (Some(BaselineKind::Ballistic), None) => {
            predictors.push(Entry::baseline("ballistic", Box::new(ballistic)))
        }
        (None, Some(dir)) => {
            let model =
                dynaserve_model::load_rigidformer(dir, &dynaserve_model::Device::Cpu, false)
                    .with_context(|| format!("loading model {}", dir.display()))?;
            let base = ModelPredictor::from_rigidformer(Arc::new(model));
            let nominal = match args.points_per_object {
                Some(n) => base.clone().with_points_per_object(n),
                None => base.clone().with_points(PointSelection::Nominal),
            };
            let mut push = |label: String, p: ModelPredictor| {
                predictors.push(Entry {
                    label,
                    input: Some(p.input_description()),
                    predictor: Box::new(p),
                    learned: true,
                })
            };
            push("model".into(), nominal.clone());
            if !args.no_variants {
                push(
                    format!("model-{}", args.variant_points),
                    base.with_points_per_object(args.variant_points),
                );
                push(
                    "model-occluded".into(),
                    nominal.with_occlusion(Occlusion {
                        fraction: args.occlude,
                        seed: args.occlusion_seed,
                    }),
                );
            }
            if !args.no_baselines {
                predictors.push(Entry::baseline("static", Box::new(Static)));
                predictors.push(Entry::baseline("ballistic", Box::new(ballistic)));
            }
        }
        _ => anyhow::bail!("give exactly one of --baseline and --model"),
    }
    let opts = args.options();
    let scenes = args.max_scenes.unwrap_or(usize::MAX).min(reader.len());
    let bar = ProgressBar::new((scenes * predictors.len()) as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} scene evaluations (eta {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message("eval");
    let done = RefCell::new(vec![0usize; predictors.len()]);
    let labels: Vec<String> = predictors.iter().map(|p| p.label.clone()).collect();
    let refs: Vec<&dyn Predictor> = predictors.iter().map(|p| p.predictor.as_ref()).collect();
    let reports = evaluate_dataset_many(&refs, &reader, &opts, &|i, n| {
        let mut d = done.borrow_mut();
        d[i] = n;
        bar.set_position(d.iter().sum::<usize>() as u64);
        if let Some(next) = labels.get(i + 1).or(labels.first()) {
            bar.set_message(format!("eval {next}"));
        }
    });
    bar.finish_and_clear();
    let reports = reports?;
    let suite = SuiteReport {
        entries: predictors
            .iter()
            .zip(reports)
            .map(|(p, report)| SuiteEntry {
                label: p.label.clone(),
                input: p.input.clone(),
                report,
            })
            .collect(),
        elapsed_s: started.elapsed().as_secs_f64(),
    };
    print!("{}", format_suite(&suite));
    println!(
        "\nevaluated {} scenes x {} predictors in {:.1} s",
        suite.entries.first().map(|e| e.report.scenes).unwrap_or(0),
        suite.entries.len(),
        suite.elapsed_s
    );
    if let Some(path) = &args.json {
        write_file(path, &(serde_json::to_string_pretty(&suite)? + "\n"))?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &args.markdown {
        write_file(path, &format_markdown(&suite))?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = args.plot_path() {
        // The nominal model at every step size, its variants and the baselines at the
        // smallest.
        let entries: Vec<(&str, &crate::eval::EvalReport, PlotStyle)> = predictors
            .iter()
            .zip(&suite.entries)
            .enumerate()
            .map(|(i, (p, e))| {
                let style = match (p.learned, i) {
                    (true, 0) => PlotStyle::EveryStepSize,
                    (true, _) => PlotStyle::SmallestStepSize,
                    (false, _) => PlotStyle::Baseline,
                };
                (e.label.as_str(), &e.report, style)
            })
            .collect();
        let title = format!(
            "{} on {} scenes: error against time",
            suite
                .entries
                .first()
                .map(|e| e.report.predictor.as_str())
                .unwrap_or(""),
            suite.entries.first().map(|e| e.report.scenes).unwrap_or(0)
        );
        plot_errors(&path, &title, &entries)
            .with_context(|| format!("drawing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        eval: EvalArgs,
    }

    #[test]
    fn parses_lists_and_requires_one_predictor() {
        let cli = Cli::try_parse_from([
            "eval",
            "--baseline",
            "ballistic",
            "--data",
            "d",
            "--step-sizes",
            "1,4",
        ])
        .unwrap();
        assert_eq!(cli.eval.baseline, Some(BaselineKind::Ballistic));
        assert_eq!(cli.eval.step_sizes, vec![1, 4]);
        assert_eq!(cli.eval.horizons, vec![0.5, 1.0, 2.0, 4.0]);
        assert_eq!(cli.eval.start_frame, 4);
        assert!(Cli::try_parse_from(["eval", "--data", "d"]).is_err());
        assert!(
            Cli::try_parse_from([
                "eval",
                "--data",
                "d",
                "--baseline",
                "static",
                "--model",
                "m"
            ])
            .is_err()
        );
    }

    #[test]
    fn the_physics_suite_needs_no_dataset() {
        let cli =
            Cli::try_parse_from(["eval", "--baseline", "ballistic", "--suite", "physics"]).unwrap();
        assert_eq!(cli.eval.suite, Some(SuiteKind::Physics));
        assert!(cli.eval.data.is_empty());
        assert_eq!(cli.eval.seed, 7);
        assert!(Cli::try_parse_from(["eval", "--baseline", "ballistic"]).is_err());
        let two =
            Cli::try_parse_from(["eval", "--baseline", "static", "--data", "a", "--data", "b"])
                .unwrap();
        let err = run_eval(two.eval).unwrap_err();
        assert!(err.to_string().contains("--suite"), "{err}");
    }

    #[test]
    fn missing_dataset_is_a_clear_error() {
        let cli = Cli::try_parse_from([
            "eval",
            "--baseline",
            "static",
            "--data",
            "/nonexistent/dynaserve-split",
        ])
        .unwrap();
        let err = run_eval(cli.eval).unwrap_err();
        assert!(format!("{err:#}").contains("manifest.json"), "{err:#}");
    }
}
