//! `dynaserve import`: converts checkpoints of other implementations into model directories
//! that `dynaserve serve --models-dir` serves.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use dynaserve_model::PhysiFormer;

/// What to import.
#[derive(Args)]
pub struct ImportArgs {
    #[command(subcommand)]
    what: What,
}

#[derive(Subcommand)]
enum What {
    /// A checkpoint of the official PhysiFormer code: its `.pt` as the training writes it
    /// (`model`, `ema.shadow`, `args`), or a `.safetensors` export of the state dict with the
    /// training arguments as JSON (`--args`).
    Physiformer(PhysiformerArgs),
}

/// `dynaserve import physiformer`.
#[derive(Args)]
struct PhysiformerArgs {
    /// The official checkpoint (`.pt`, or `.safetensors` with `--args`).
    #[arg(long)]
    checkpoint: PathBuf,
    /// The model directory to write (`config.json`, `model.safetensors`, `card.md`); its
    /// name is the model's name. Created; an existing model there is replaced.
    #[arg(long)]
    out: PathBuf,
    /// The training arguments of a `.safetensors` export, as a JSON object.
    #[arg(long)]
    args: Option<PathBuf>,
    /// Import the raw weights (`model`) instead of the EMA weights (`ema.shadow`), which the
    /// official inference uses by default.
    #[arg(long)]
    no_ema: bool,
    /// Largest object count a served scene may have (default: the checkpoint's object slots,
    /// at least 10, as the official demo runs it).
    #[arg(long)]
    max_objects: Option<usize>,
}

/// Runs `dynaserve import`.
pub fn run(args: ImportArgs) -> anyhow::Result<()> {
    match args.what {
        What::Physiformer(a) => {
            let device = candle_core::Device::Cpu;
            let model = PhysiFormer::import_official(
                &a.checkpoint,
                a.args.as_deref(),
                &a.out,
                !a.no_ema,
                a.max_objects,
                &device,
            )
            .with_context(|| format!("importing {}", a.checkpoint.display()))?;
            let c = model.config();
            println!(
                "wrote {}: PhysiFormer (official architecture), {:.1} M parameters, width {}, {} \
                 blocks, {} frames, up to {} vertices and {} objects",
                a.out.display(),
                model.parameter_count() as f64 / 1e6,
                c.official.hidden,
                c.official.depth,
                c.frames,
                c.max_vertices,
                c.max_objects
            );
            println!(
                "serve it: dynaserve serve --models-dir {}",
                a.out
                    .parent()
                    .map_or_else(|| ".".into(), |p| p.display().to_string())
            );
            Ok(())
        }
    }
}
