//! Writes a split of scenes that start where a model's own rollout leads, continued by rapier
//! (`dynaserve_train::train::restarts`; docs/dataset.md, "Scenes that start where a model's
//! rollout leads").
//!
//! ```sh
//! cargo run --release -p dynaserve-train --example restart_data -- \
//!     --model models/rigidformer-small --source data/movi-b/train \
//!     --out data/restart/movi-b --scenes 4000 --seed 77
//! ```
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Parser;
use dynaserve_sim::DatasetReader;
use dynaserve_train::eval::{ModelPredictor, PointSelection};
use dynaserve_train::train::restarts::{RestartOptions, write_restarts};

#[derive(Parser)]
struct Args {
    /// Model directory whose rollouts start the scenes.
    #[arg(long)]
    model: PathBuf,
    /// Dataset split the scenes start from.
    #[arg(long)]
    source: PathBuf,
    /// Output split directory (must not hold a manifest).
    #[arg(long)]
    out: PathBuf,
    /// Scenes to draw (a draw whose shapes rapier cannot rebuild, or in which an object falls
    /// through the floor, is skipped).
    #[arg(long, default_value_t = RestartOptions::default().scenes)]
    scenes: usize,
    /// Seed of the draws (source scene, start frame, rollout length).
    #[arg(long)]
    seed: u64,
    /// Longest model rollout before the restart, steps of one frame (drawn from 1 to this).
    #[arg(long, default_value_t = RestartOptions::default().rollout_max)]
    rollout_max: usize,
    /// Frames rapier simulates after the restart; each scene stores two more.
    #[arg(long, default_value_t = RestartOptions::default().frames)]
    frames: usize,
    /// Scenes per shard.
    #[arg(long, default_value_t = RestartOptions::default().per_shard)]
    per_shard: usize,
}

fn main() -> anyhow::Result<()> {
    let a = Args::parse();
    let reader = DatasetReader::open(&a.source)?;
    let model = ModelPredictor::load(&a.model)
        .with_context(|| format!("loading {}", a.model.display()))?
        .with_points(PointSelection::Nominal);
    let opts = RestartOptions {
        scenes: a.scenes,
        seed: a.seed,
        rollout_max: a.rollout_max,
        frames: a.frames,
        per_shard: a.per_shard,
    };
    let t0 = Instant::now();
    let s = write_restarts(
        &model,
        &a.model.display().to_string(),
        &reader,
        &a.out,
        &opts,
        |drawn, skipped| {
            eprintln!(
                "{drawn}/{} scenes drawn, {skipped} skipped ({:.0} s)",
                a.scenes,
                t0.elapsed().as_secs_f64()
            )
        },
    )?;
    println!(
        "wrote {} scenes ({} objects, {} frames; {} of {} drawn skipped: a shape rapier could \
         not rebuild, or an object fell through the floor) to {} in {:.0} s",
        s.written,
        s.objects,
        s.manifest.frames,
        s.skipped,
        a.scenes,
        a.out.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
