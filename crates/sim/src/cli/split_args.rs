//! What every split generator takes on the command line (pose and mesh sets alike): the scene
//! count, output directory, seed, split, threads and overwrite, with the worker pool and
//! progress bar a generation runs with.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};

/// Dataset split; part of every scene's seed, so splits never share a scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Split {
    /// Training split.
    Train,
    /// Validation split.
    Val,
    /// Test split.
    Test,
}

impl Split {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }
}

/// Options every split generator takes.
#[derive(Args, Debug, Clone)]
pub struct SplitArgs {
    /// Number of scenes.
    #[arg(long)]
    pub scenes: usize,
    /// Output directory (the split directory: manifest.json and shards go here).
    #[arg(long)]
    pub out: PathBuf,
    /// Dataset seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Split name.
    #[arg(long, value_enum, default_value_t = Split::Train)]
    pub split: Split,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Replace a dataset already in the output directory.
    #[arg(long)]
    pub overwrite: bool,
}

impl SplitArgs {
    /// Refuses a generation of no scenes.
    pub fn check(&self) -> anyhow::Result<()> {
        if self.scenes == 0 {
            bail!("--scenes must be at least 1");
        }
        Ok(())
    }
}

/// The worker pool of `--threads` (all cores when not given); 0 threads is an error.
pub(crate) fn worker_pool(threads: Option<usize>) -> anyhow::Result<rayon::ThreadPool> {
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        if t == 0 {
            bail!("--threads must be at least 1");
        }
        pool = pool.num_threads(t);
    }
    pool.build().context("starting worker threads")
}

/// A progress bar over the `scenes` scenes of a generation.
pub(crate) fn scene_progress(scenes: usize) -> anyhow::Result<ProgressBar> {
    let bar = ProgressBar::new(scenes as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} {elapsed_precise} [{bar:40}] {pos}/{len} scenes ({per_sec}, eta {eta})",
        )
        .context("progress bar template")?
        .progress_chars("=> "),
    );
    Ok(bar)
}
