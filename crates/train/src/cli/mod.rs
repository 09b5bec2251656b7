//! `dynaserve eval`: score a trained model and the baselines on a dataset split (see
//! [`crate::eval`] for the protocol and the metrics, `docs/evaluation.md` for the reports).
//! Its flags are in `args`; `--suite physics` runs `suite` instead, `--suite calibration`
//! `calibration`.

use std::cell::RefCell;
use std::path::Path;

use anyhow::Context;
use dynaserve_sim::DatasetReader;
use indicatif::{ProgressBar, ProgressStyle};

use crate::eval::{
    Ballistic, ModelPredictor, Occlusion, PlotStyle, PointSelection, Predictor, RapierRestart,
    Static, SuiteEntry, SuiteReport, evaluate_dataset_many, format_markdown, format_suite,
    plot_errors,
};

mod args;
mod calibration;
mod suite;

pub use args::{BaselineKind, EvalArgs, SuiteKind};

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
    if args.rapier && args.model.is_none() {
        anyhow::bail!(
            "--rapier adds the rapier restart beside a --model; alone, it is --baseline rapier"
        );
    }
    if let Some(n) = args.rapier_cloud_points {
        if !(args.rapier || args.baseline == Some(BaselineKind::Rapier)) {
            anyhow::bail!(
                "--rapier-cloud-points shapes the rapier restart: give --rapier or --baseline rapier"
            );
        }
        if n < 4 {
            anyhow::bail!(
                "--rapier-cloud-points must be at least 4 (a hull needs a volume), got {n}"
            );
        }
    }
    if let (Some(model), [data]) = (&args.model, args.data.as_slice())
        && crate::physi::eval::is_physi_model(model)
    {
        let options = crate::physi::eval::PhysiEvalOptions {
            model: model.clone(),
            data: data.clone(),
            scenes: args.max_scenes.unwrap_or(50),
            samples: args.samples,
            steps: args.denoise_steps,
            seed: args.seed,
            plot: args.plot.clone(),
            device: args.device.clone(),
        };
        // The official example scenes (metadata.json + one OBJ per frame) get the official
        // metrics; our mesh datasets our own report.
        if crate::physi::official_data::is_official_examples(data) {
            return crate::physi::official_eval::run(&options).map(|_| ());
        }
        if args.official_metrics {
            return crate::physi::official_eval::run_on_dataset(&options).map(|_| ());
        }
        return crate::physi::eval::run(&options);
    }
    if args.suite == Some(SuiteKind::Calibration) {
        return calibration::run(&args);
    }
    if args.suite.is_some() {
        return suite::run(&args);
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
    // The restart of the data's own simulator, on exact shapes or the clouds' hulls.
    let rapier = || -> anyhow::Result<Entry> {
        let restart = RapierRestart::from_manifest(reader.manifest())?
            .with_cloud_points(args.rapier_cloud_points);
        Ok(Entry::baseline(&restart.name(), Box::new(restart)))
    };
    let mut predictors: Vec<Entry> = Vec::new();
    match (args.baseline, &args.model) {
        (Some(BaselineKind::Static), None) => {
            predictors.push(Entry::baseline("static", Box::new(Static)))
        }
        (Some(BaselineKind::Ballistic), None) => {
            predictors.push(Entry::baseline("ballistic", Box::new(ballistic)))
        }
        (Some(BaselineKind::Rapier), None) => predictors.push(rapier()?),
        (None, Some(dir)) => {
            let device = dynaserve_model::device_from_name(&args.device)?;
            let base = ModelPredictor::load_on(dir, &device)
                .with_context(|| format!("loading model {}", dir.display()))?;
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
            if args.rapier {
                predictors.push(rapier()?);
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
        // The simulator as a baseline alone, or as a column beside a model (not beside another
        // baseline).
        let rapier = Cli::try_parse_from(["eval", "--baseline", "rapier", "--data", "d"]).unwrap();
        assert_eq!(rapier.eval.baseline, Some(BaselineKind::Rapier));
        let beside = Cli::try_parse_from(["eval", "--model", "m", "--data", "d", "--rapier"]);
        assert!(beside.unwrap().eval.rapier);
        let alone = ["eval", "--baseline", "static", "--data", "d", "--rapier"];
        let err = run_eval(Cli::try_parse_from(alone).unwrap().eval).unwrap_err();
        assert!(err.to_string().contains("--baseline rapier"), "{err}");
        // Hulls of the clouds shape the restart only, and need a volume.
        let hulls = |extra: &[&str]| {
            let mut a = vec!["eval", "--data", "d", "--rapier-cloud-points"];
            a.extend_from_slice(extra);
            run_eval(Cli::try_parse_from(a).unwrap().eval)
                .unwrap_err()
                .to_string()
        };
        let err = hulls(&["128", "--baseline", "static"]);
        assert!(err.contains("give --rapier or --baseline rapier"), "{err}");
        let err = hulls(&["3", "--baseline", "rapier"]);
        assert!(err.contains("at least 4"), "{err}");
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
