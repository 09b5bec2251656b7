//! RigidFormer training: `dynaserve train --config FILE [--resume]`, `dynaserve train export`,
//! `dynaserve train average`, `dynaserve train restarts` and `dynaserve train compare`.
//!
//! - [`config`]: the documented configuration (TOML or JSON);
//! - [`data`]: the streaming loader (worker thread, windows, augmentation) and the fit of the
//!   feature normalisation;
//! - [`events`]: event-weighted choice of a window's frame (impacts, first touches);
//! - [`stops`]: windows at the end of an object's motion (rolls, slides and tumbles that stop);
//! - [`optim`]: learning-rate schedule, gradient clipping, AdamW with per-parameter decay;
//! - [`trainer`]: the loop, its checkpoints, resume, CSV log and loss curve;
//! - [`run_dir`]: a run directory's checkpoint swap, resume point and log truncation, shared
//!   with PhysiFormer runs, and a checkpoint's training position;
//! - [`mod@export`]: a checkpoint written as a model directory;
//! - [`mod@average`]: model directories of one architecture averaged into one;
//! - [`restarts`]: training scenes that start where a model's own rollout leads, continued by
//!   rapier;
//! - [`compare`]: candidates against a release on the model card's key figures;
//! - [`horizon_guard`]: the key figures' horizons and the per-horizon guard on a candidate's
//!   translation RMSE, shared by the comparison and the planner clause;
//! - [`planner_record`]: a push planner's per-seed record and the ship rule's planner clause;
//! - [`plot`]: PNG line charts.

pub mod average;
pub mod compare;
pub mod config;
pub mod data;
pub mod events;
pub mod export;
pub mod heldout;
pub mod horizon_guard;
pub mod optim;
pub mod planner_record;
pub mod plot;
pub mod pushforward;
pub mod restarts;
pub mod run_dir;
pub mod stops;
#[cfg(test)]
mod test_records;
pub mod trainer;

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

pub use average::{AverageOptions, average};
pub use config::TrainConfig;
pub use export::{ExportOptions, export};
pub use trainer::{TrainOptions, TrainSummary, train};

/// Errors of training and export; each names the file or setting at fault.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// A configuration value is invalid or a run directory is inconsistent.
    #[error("configuration: {0}")]
    Config(String),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The training data is unusable.
    #[error("data: {0}")]
    Data(String),
    /// The model rejected an input or failed.
    #[error(transparent)]
    Model(#[from] dynaserve_model::ModelError),
    /// Dataset I/O failed.
    #[error(transparent)]
    Sim(#[from] dynaserve_sim::SimError),
    /// A tensor operation failed.
    #[error("tensor: {0}")]
    Candle(#[from] candle_core::Error),
    /// A loss or gradient became NaN or infinite.
    #[error("non-finite value: {0}")]
    NonFinite(String),
    /// A chart could not be drawn.
    #[error("plot: {0}")]
    Plot(String),
}

/// `dynaserve train`: train from a configuration, export a run's checkpoint, average model
/// directories, or write restart scenes.
#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct TrainArgs {
    /// Export a checkpoint, average models or write restart scenes instead of training.
    #[command(subcommand)]
    pub action: Option<TrainAction>,
    /// Training configuration, TOML (`.toml`) or JSON (docs/training.md lists every knob).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Continue the run in `run.out_dir` from its last checkpoint (weights, optimizer moments,
    /// step, schedule and data position).
    #[arg(long)]
    pub resume: bool,
    /// Stop (with a checkpoint) after this many iterations in this invocation.
    #[arg(long)]
    pub stop_after: Option<u64>,
    /// Train on this device instead of the configuration's (`cpu`, `cuda` or `cuda:N`; CUDA
    /// needs a build with `--features cuda`).
    #[arg(long)]
    pub device: Option<String>,
    /// Wall-clock budget of this invocation, minutes: the run stops with a checkpoint after
    /// the iteration that passes it (as on Ctrl-C).
    #[arg(long)]
    pub minutes: Option<f64>,
    /// Minutes between checkpoints, replacing the configuration's `checkpoint_minutes`.
    #[arg(long)]
    pub checkpoint_minutes: Option<f64>,
}

impl TrainArgs {
    /// candle's element-wise pool size for this invocation: a training run leaves its data
    /// loader a core ([`dynaserve_model::training_elementwise_threads`]); exporting, averaging
    /// and writing restart scenes keep the default (`None`). For
    /// [`dynaserve_model::configure_compute_split`].
    pub fn elementwise_threads(&self) -> Option<usize> {
        self.action
            .is_none()
            .then(dynaserve_model::training_elementwise_threads)
    }
}

/// Subcommands of `dynaserve train`.
#[derive(clap::Subcommand, Debug)]
pub enum TrainAction {
    /// Write a run's checkpoint as a model directory (config.json, model.safetensors).
    Export {
        /// Run directory (holds `checkpoint/`).
        #[arg(long)]
        run: PathBuf,
        /// Output model directory.
        #[arg(long)]
        out: PathBuf,
        /// Export the exponential moving average of the weights instead of the raw weights.
        #[arg(long)]
        ema: bool,
        /// Stored weight type: f32, f16 or bf16.
        #[arg(long, default_value = "f32")]
        dtype: String,
    },
    /// Write the mean of several model directories' weights as one model directory. The
    /// models must share their architecture, inputs and normalisation, and should be
    /// fine-tuned from one common checkpoint; check the result with `dynaserve eval`.
    Average {
        /// A model directory (`config.json`, `model.safetensors`); give it two or more times.
        /// The first one's training and serving settings are kept.
        #[arg(long = "model", required = true, num_args = 1)]
        models: Vec<PathBuf>,
        /// Output model directory.
        #[arg(long)]
        out: PathBuf,
        /// Stored weight type: f32, f16 or bf16.
        #[arg(long, default_value = "f32")]
        dtype: String,
    },
    /// Write a split of scenes that start where a model's own rollout leads, continued by
    /// rapier (docs/dataset.md, "Scenes that start where a model's rollout leads").
    Restarts {
        /// Model directory whose rollouts start the scenes.
        #[arg(long)]
        model: PathBuf,
        /// Dataset split the scenes start from (no kinematic objects).
        #[arg(long)]
        source: PathBuf,
        /// Output split directory (refused if it holds a dataset, unless `--overwrite`).
        #[arg(long)]
        out: PathBuf,
        /// What to draw and write.
        #[command(flatten)]
        options: restarts::RestartOptions,
    },
    /// Judge candidates against a release on the model card's fourteen key figures and the
    /// fresh-scene guard, and by the planner clause where both directories hold a push planner
    /// record (docs/training.md, "Comparing a candidate with the release"). Each directory
    /// holds `eval.json`, `fresh.json` and `physics-suite.json` from `dynaserve eval`, and
    /// optionally `planner.json` from `push_planner.py --json`.
    Compare {
        /// The release's scorecard directory (e.g. `models/rigidformer-small/eval`).
        #[arg(long)]
        reference: PathBuf,
        /// A candidate's scorecard directory; repeatable.
        #[arg(long = "candidate", required = true, num_args = 1)]
        candidates: Vec<PathBuf>,
        /// Scorecards of one recipe at different seeds (two or more): each change is also
        /// given in their standard deviations.
        #[arg(long = "spread", num_args = 1)]
        spread: Vec<PathBuf>,
    },
    /// Print the experiment ledger (`docs/experiments.jsonl`): every training run with its
    /// parent, length, key figures, verdict and why (`docs/experiments.md` reads them).
    Ledger {
        /// The ledger file.
        #[arg(long, default_value = crate::ledger::DEFAULT_LEDGER)]
        file: PathBuf,
        /// Only runs whose id, verdict or why contains this text.
        #[arg(long)]
        grep: Option<String>,
        /// Line width of the table.
        #[arg(long, default_value_t = 160)]
        width: usize,
    },
}

/// Sets `flag` (a training run's stop request) once `minutes` of wall-clock time have passed.
fn stop_after_minutes(flag: Arc<AtomicBool>, minutes: f64) -> std::io::Result<()> {
    let budget = std::time::Duration::from_secs_f64(60.0 * minutes);
    std::thread::Builder::new()
        .name("train-budget".into())
        .spawn(move || {
            std::thread::sleep(budget);
            flag.store(true, Ordering::SeqCst);
        })
        .map(drop)
}

/// `dynaserve train compare`: reads the scorecards and prints one table per candidate.
fn run_compare(
    reference: &std::path::Path,
    candidates: &[PathBuf],
    spread: &[PathBuf],
) -> anyhow::Result<()> {
    let reference = compare::read_scorecard(reference)?;
    let spread = if spread.is_empty() {
        None
    } else {
        let runs = spread
            .iter()
            .map(|d| compare::read_scorecard(d))
            .collect::<anyhow::Result<Vec<_>>>()?;
        for run in &runs {
            compare::check_same_data(&reference, run)?;
        }
        println!(
            "seed spread: each figure's standard deviation over {} runs of one recipe ({})\n",
            runs.len(),
            spread
                .iter()
                .map(|d| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
        Some(compare::seed_spread(&runs)?)
    };
    for (i, dir) in candidates.iter().enumerate() {
        let candidate = compare::read_scorecard(dir)?;
        compare::check_same_data(&reference, &candidate)?;
        compare::check_same_planner(&reference, &candidate)?;
        if i > 0 {
            println!();
        }
        print!(
            "{}",
            compare::format_comparison(&reference, &candidate, spread.as_deref())
        );
    }
    Ok(())
}

/// `dynaserve train restarts`: loads the model and the source, writes the split with progress
/// per shard, and prints a summary.
fn run_restarts(
    model_dir: &std::path::Path,
    source: &std::path::Path,
    out: &std::path::Path,
    opts: &restarts::RestartOptions,
) -> anyhow::Result<()> {
    use anyhow::Context;
    let reader = dynaserve_sim::DatasetReader::open(source)?;
    let model = crate::eval::ModelPredictor::load(model_dir)
        .with_context(|| format!("loading {}", model_dir.display()))?
        .with_points(crate::eval::PointSelection::Nominal);
    let t0 = std::time::Instant::now();
    let name = model_dir.display().to_string();
    let s = restarts::write_restarts(&model, &name, &reader, out, opts, |drawn, skipped| {
        eprintln!(
            "{drawn}/{} scenes drawn, {skipped} skipped ({:.0} s)",
            opts.scenes,
            t0.elapsed().as_secs_f64()
        )
    })?;
    let first = s
        .first_rebuild_error
        .as_deref()
        .map(|e| format!(", the first: {e}"))
        .unwrap_or_default();
    println!(
        "wrote {} scenes ({} objects, {} frames) to {} in {:.0} s; {} of {} drawn skipped: \
         {} rapier could not rebuild{first}, {} with an object falling through the floor",
        s.written,
        s.objects,
        s.manifest.frames,
        out.display(),
        t0.elapsed().as_secs_f64(),
        s.skipped(),
        opts.scenes,
        s.rebuild_refused,
        s.fell_through,
    );
    Ok(())
}

/// The weight type named by `--dtype`.
fn parse_dtype(name: &str) -> anyhow::Result<candle_core::DType> {
    Ok(match name {
        "f32" => candle_core::DType::F32,
        "f16" => candle_core::DType::F16,
        "bf16" => candle_core::DType::BF16,
        other => anyhow::bail!("--dtype {other:?} is not one of f32, f16, bf16"),
    })
}

/// Sets `flag` on SIGINT (Ctrl-C) or SIGTERM, from a small signal thread.
pub fn stop_on_signals(flag: Arc<AtomicBool>) -> std::io::Result<()> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .build()?;
    std::thread::Builder::new()
        .name("train-signals".into())
        .spawn(move || {
            rt.block_on(async move {
                #[cfg(unix)]
                {
                    use tokio::signal::unix::{SignalKind, signal};
                    let Ok(mut term) = signal(SignalKind::terminate()) else {
                        return;
                    };
                    loop {
                        tokio::select! {
                            _ = tokio::signal::ctrl_c() => {},
                            _ = term.recv() => {},
                        }
                        flag.store(true, Ordering::SeqCst);
                    }
                }
                #[cfg(not(unix))]
                loop {
                    if tokio::signal::ctrl_c().await.is_err() {
                        return;
                    }
                    flag.store(true, Ordering::SeqCst);
                }
            })
        })?;
    Ok(())
}

/// Runs `dynaserve train` with parsed arguments.
pub fn run_cli(args: TrainArgs) -> anyhow::Result<()> {
    match args.action {
        Some(TrainAction::Export {
            run,
            out,
            ema,
            dtype,
        }) => {
            export(&ExportOptions {
                run,
                out: out.clone(),
                ema,
                dtype: parse_dtype(&dtype)?,
            })?;
            println!("exported to {}", out.display());
            return Ok(());
        }
        Some(TrainAction::Average { models, out, dtype }) => {
            let n = models.len();
            average(&AverageOptions {
                models,
                out: out.clone(),
                dtype: parse_dtype(&dtype)?,
            })?;
            println!(
                "the mean of {n} models' weights written to {}",
                out.display()
            );
            return Ok(());
        }
        Some(TrainAction::Restarts {
            model,
            source,
            out,
            options,
        }) => return run_restarts(&model, &source, &out, &options),
        Some(TrainAction::Compare {
            reference,
            candidates,
            spread,
        }) => return run_compare(&reference, &candidates, &spread),
        Some(TrainAction::Ledger { file, grep, width }) => {
            let mut runs = crate::ledger::read(&file)?;
            if let Some(g) = &grep {
                runs.retain(|r| {
                    r.id.contains(g.as_str())
                        || r.verdict.contains(g.as_str())
                        || r.why.contains(g.as_str())
                });
            }
            print!("{}", crate::ledger::table(&runs, width));
            println!("{} runs ({})", runs.len(), file.display());
            return Ok(());
        }
        None => {}
    }
    let Some(path) = args.config else {
        anyhow::bail!(
            "dynaserve train needs --config FILE (or the export, average, restarts or compare \
             subcommand)"
        );
    };
    for (name, v) in [
        ("--minutes", args.minutes),
        ("--checkpoint-minutes", args.checkpoint_minutes),
    ] {
        if let Some(v) = v {
            anyhow::ensure!(v.is_finite() && v > 0.0, "{name} must be a positive number");
        }
    }
    let stop = Arc::new(AtomicBool::new(false));
    stop_on_signals(stop.clone())?;
    if let Some(minutes) = args.minutes {
        stop_after_minutes(stop.clone(), minutes)?;
    }
    if crate::physi::train::is_physi_config(&path) {
        return crate::physi::train::run_with_checkpoint_minutes(
            &path,
            args.resume,
            args.stop_after,
            args.device.as_deref(),
            args.checkpoint_minutes,
            stop,
        );
    }
    let mut cfg = TrainConfig::from_file(&path)?;
    if let Some(device) = args.device {
        cfg.run.device = device;
    }
    if let Some(m) = args.checkpoint_minutes {
        cfg.run.checkpoint_minutes = m;
    }
    let summary = train(
        &cfg,
        &TrainOptions {
            resume: args.resume,
            stop: stop.clone(),
            stop_after: args.stop_after,
        },
    )?;
    let heldout = if summary.heldout_seconds > 0.0 {
        format!(
            ", {:.0} s scoring the held-out suite (heldout.csv)",
            summary.heldout_seconds
        )
    } else {
        String::new()
    };
    println!(
        "stopped at iteration {} of {} ({:.1} it/s this session, {:.0}% of it waiting for data, \
         last loss {:.4}{heldout}); checkpoint in {}",
        summary.step,
        cfg.optim.iterations,
        summary.iterations_per_second,
        100.0 * summary.data_wait_fraction,
        summary.last_loss,
        summary.checkpoint.display()
    );
    Ok(())
}
