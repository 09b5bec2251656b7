//! `dynaserve eval`: score a baseline or a trained model on a dataset split (see
//! [`crate::eval`] for the protocol and the metrics).

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use dynaserve_sim::DatasetReader;
use indicatif::{ProgressBar, ProgressStyle};

use crate::eval::{
    Ballistic, DEFAULT_START_FRAME, EvalOptions, ModelPredictor, Predictor, Static,
    evaluate_dataset, format_table,
};

/// Baselines `dynaserve eval --baseline` knows.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BaselineKind {
    /// Every object stays at its last observed pose.
    Static,
    /// Constant angular velocity, free flight under the data's gravity, inelastic floor.
    Ballistic,
}

/// Arguments of `dynaserve eval`.
#[derive(clap::Args, Debug, Clone)]
pub struct EvalArgs {
    /// Baseline to evaluate.
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
    /// Dataset split directory (holding manifest.json).
    #[arg(long)]
    pub data: PathBuf,
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
    /// Reference points per object given to a model (a prefix of the stored cloud); default
    /// all.
    #[arg(long)]
    pub points_per_object: Option<usize>,
    /// Also write the report as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// Runs `dynaserve eval`: progress on stderr, the table on stdout, JSON to `--json`.
pub fn run_eval(args: EvalArgs) -> anyhow::Result<()> {
    let reader = DatasetReader::open(&args.data)
        .with_context(|| format!("opening dataset {}", args.data.display()))?;
    let predictor: Box<dyn Predictor> = match (args.baseline, &args.model) {
        (Some(BaselineKind::Static), None) => Box::new(Static),
        (Some(BaselineKind::Ballistic), None) => {
            Box::new(Ballistic::from_manifest(reader.manifest()))
        }
        (None, Some(dir)) => {
            let model = dynaserve_model::load_model(dir, &dynaserve_model::Device::Cpu)
                .with_context(|| format!("loading model {}", dir.display()))?;
            let mut p = ModelPredictor::new(Arc::clone(&model));
            if let Some(n) = args.points_per_object {
                p = p.with_points_per_object(n);
            }
            Box::new(p)
        }
        _ => anyhow::bail!("give exactly one of --baseline and --model"),
    };
    let opts = EvalOptions {
        start_frame: args.start_frame,
        step_sizes: args.step_sizes.clone(),
        horizons_s: args.horizons.clone(),
        max_scenes: args.max_scenes,
    };
    let total = args.max_scenes.unwrap_or(usize::MAX).min(reader.len());
    let bar = ProgressBar::new(total as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} scenes (eta {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(format!("eval {}", predictor.name()));
    let report = evaluate_dataset(predictor.as_ref(), &reader, &opts, &|done| {
        bar.set_position(done as u64)
    });
    bar.finish_and_clear();
    let report = report?;
    print!("{}", format_table(&report));
    println!(
        "evaluated {} scenes in {:.1} s",
        report.scenes, report.elapsed_s
    );
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))?;
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
