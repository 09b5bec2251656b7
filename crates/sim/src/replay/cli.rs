//! `dynaserve sim replay`: a scene file replayed in rapier with kinematic objects driven along
//! given paths; the trajectory is printed (or written) as JSON ([`Replay`]).
//!
//! ```text
//! dynaserve sim replay examples/scenes/collision.json --steps 48
//! dynaserve sim replay scene.json --paths pusher.json --out replay.json
//! ```

use std::io::Read;
use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;

use super::{PathsDoc, Replay, ReplayOptions, parse_scene, replay};

/// Options of `dynaserve sim replay`.
#[derive(Args, Debug, Clone)]
pub struct ReplayArgs {
    /// Scene file: a rollout request or session create body, or a bare scene (JSON).
    pub scene: PathBuf,
    /// Paths of kinematic objects, `{"paths": [{"object": 1, "poses": [[x, y, z, qx, qy, qz,
    /// qw], ...]}]}` with one pose per step; `-` reads standard input.
    #[arg(long)]
    pub paths: Option<PathBuf>,
    /// Steps to replay (default: the paths' length, else the scene file's `steps`).
    #[arg(long)]
    pub steps: Option<usize>,
    /// Frames per step (default: the scene file's `dt_steps`, else 1).
    #[arg(long)]
    pub dt_steps: Option<u32>,
    /// Interval of one frame, seconds (the model's frame interval).
    #[arg(long, default_value_t = 1.0 / 24.0)]
    pub dt_frame: f32,
    /// Output JSON file (default: standard output).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

fn read(path: &PathBuf) -> anyhow::Result<String> {
    if path.as_os_str() == "-" {
        let mut text = String::new();
        std::io::stdin()
            .read_to_string(&mut text)
            .context("reading standard input")?;
        return Ok(text);
    }
    std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))
}

/// Replays the scene of `a` and returns its trajectory.
pub fn replay_args(a: &ReplayArgs) -> anyhow::Result<Replay> {
    let file = parse_scene(&read(&a.scene)?).with_context(|| a.scene.display().to_string())?;
    let paths = match &a.paths {
        Some(p) => {
            let doc: PathsDoc = serde_json::from_str(&read(p)?)
                .with_context(|| format!("paths file {}", p.display()))?;
            doc.paths
        }
        None => Vec::new(),
    };
    let steps = match (a.steps, paths.first(), file.steps) {
        (Some(s), _, _) => s,
        (None, Some(p), _) => p.poses.len(),
        (None, None, Some(s)) => s,
        (None, None, None) => bail!("give --steps: the scene file has no steps and no path"),
    };
    let opts = ReplayOptions {
        dt_frame: a.dt_frame,
        dt_steps: a.dt_steps.or(file.dt_steps).unwrap_or(1),
        ..ReplayOptions::default()
    };
    Ok(replay(&file.scene, &paths, steps, &opts)?)
}

/// Runs `dynaserve sim replay`.
pub fn run_replay(a: &ReplayArgs) -> anyhow::Result<()> {
    let r = replay_args(a)?;
    let text = serde_json::to_string(&r)?;
    match &a.out {
        Some(out) => {
            std::fs::write(out, text).with_context(|| format!("writing {}", out.display()))?
        }
        None => println!("{text}"),
    }
    Ok(())
}
