//! On-policy training scenes: the states a model's own rollout reaches, continued by rapier.
//!
//! For each scene written: a source scene and a start frame `s` are drawn, the model rolls out
//! `R` steps at step size 1 from the truth's frames `s - 1` and `s`, and rapier is restarted
//! from the model's last two poses (with the velocity they imply, as the `rapier` baseline
//! does: [`RapierRestart`]) and simulated for `--frames` frames. The scene stored is the
//! model's last two poses followed by rapier's frames, so every window of it is physics, and
//! its first windows start where the model's errors led (objects a little sunk, tilted or too
//! fast). Pushforward trains the model's own states against the original recording's next
//! pose; these scenes give those states the target physics gives them instead (the
//! data-as-demonstrator idea for learned simulators).
//!
//! ```sh
//! cargo run --release -p dynaserve-train --example restart_data -- \
//!     --model models/rigidformer-small --source data/movi-b/train \
//!     --out data/restart/movi-b --scenes 2000 --seed 77
//! ```
//!
//! Sources with kinematic objects (pushers) are refused: their path after the restart is not
//! known. A draw is skipped (and counted) when rapier cannot rebuild one of its shapes (a
//! degenerate hull) or when an object's centre goes 0.1 m below the floor's top: a model
//! state sunk so far that rapier lets the object fall through the floor.
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Parser;
use dynaserve_model::Pose;
use dynaserve_sim::dataset::{ShardInfo, encode_shard, prepare_dir, write_file, write_manifest};
use dynaserve_sim::{DatasetReader, ObjectRecord, SceneRecord};
use dynaserve_train::eval::{
    ModelPredictor, PointSelection, Predictor, RapierRestart, RolloutRequest, observed_state,
};
use dynaserve_train::train::data::mix;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// An object whose centre goes below this height (m) has fallen through the floor.
const FELL_THROUGH: f32 = -0.1;

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
    #[arg(long, default_value_t = 2000)]
    scenes: usize,
    /// Seed of the draws (source scene, start frame, rollout length).
    #[arg(long)]
    seed: u64,
    /// Longest model rollout before the restart, steps of one frame (drawn from 1 to this).
    #[arg(long, default_value_t = 48)]
    rollout_max: usize,
    /// Frames rapier simulates after the restart; each scene stores two more.
    #[arg(long, default_value_t = 30)]
    frames: usize,
    /// Scenes per shard.
    #[arg(long, default_value_t = 100)]
    per_shard: usize,
}

/// `q` or `-q`, whichever is nearer `prev` (quaternions stored sign-continuous in time).
fn continuous(prev: [f32; 4], q: [f32; 4]) -> [f32; 4] {
    let dot: f32 = (0..4).map(|i| prev[i] * q[i]).sum();
    if dot < 0.0 { q.map(|v| -v) } else { q }
}

fn main() -> anyhow::Result<()> {
    let a = Args::parse();
    anyhow::ensure!(a.scenes > 0 && a.per_shard > 0 && a.rollout_max > 0 && a.frames >= 8);
    let reader = DatasetReader::open(&a.source)?;
    let src = reader.manifest().clone();
    anyhow::ensure!(src.frames >= 3, "{}: too few frames", a.source.display());
    let model = ModelPredictor::load(&a.model)
        .with_context(|| format!("loading {}", a.model.display()))?
        .with_points(PointSelection::Nominal);
    let rapier = RapierRestart::from_manifest(&src)?;
    prepare_dir(&a.out, false)?;
    let frames = a.frames + 2;
    let (mut shards, mut objects) = (Vec::new(), 0usize);
    let (mut written, mut skipped) = (0usize, 0usize);
    let t0 = Instant::now();
    for (shard, first) in (0..a.scenes).step_by(a.per_shard).enumerate() {
        let end = (first + a.per_shard).min(a.scenes);
        // Draws per scene, from a generator keyed on (seed, scene).
        let draws: Vec<(usize, usize, usize)> = (first..end)
            .map(|i| {
                let mut rng = ChaCha8Rng::seed_from_u64(mix(a.seed ^ mix(i as u64)));
                let scene = rng.random_range(0..reader.len());
                let start = rng.random_range(1..src.frames);
                let steps = rng.random_range(1..=a.rollout_max);
                (scene, start, steps)
            })
            .collect();
        let sources = draws
            .iter()
            .map(|&(i, _, _)| reader.get(i))
            .collect::<Result<Vec<_>, _>>()?;
        if let Some((&(i, _, _), _)) = draws
            .iter()
            .zip(&sources)
            .find(|(_, s)| s.objects.iter().any(|o| o.kinematic))
        {
            anyhow::bail!(
                "{}: scene {i} has a kinematic object, whose path after a restart is not known",
                a.source.display()
            );
        }
        let requests = sources
            .iter()
            .zip(&draws)
            .map(|(scene, &(_, start, steps))| {
                Ok(RolloutRequest {
                    scene,
                    observed: observed_state(scene, start, 1)?,
                    dt_steps: 1,
                    steps,
                })
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let rollouts = model.rollout_batch(&requests)?;
        let made = requests
            .par_iter()
            .zip(&rollouts)
            .map(|(r, roll)| -> anyhow::Result<Option<SceneRecord>> {
                // The model's last two poses (the truth's frame s if it stepped once).
                let now = roll.last().expect("at least one step").clone();
                let before = match roll.len() {
                    1 => r.observed.current.clone(),
                    n => roll[n - 2].clone(),
                };
                let restart = dynaserve_model::SceneState {
                    previous: before.clone(),
                    current: now.clone(),
                    earlier: None,
                };
                // A shape rapier cannot rebuild (a degenerate hull) skips the scene.
                let Ok(cont) = rapier.rollout(r.scene, &restart, 1, a.frames) else {
                    return Ok(None);
                };
                // A model state deep enough in the floor that rapier lets an object fall
                // through it is not a lesson in physics: the scene is skipped.
                if cont
                    .iter()
                    .flatten()
                    .any(|p| p.translation[2] < FELL_THROUGH)
                {
                    return Ok(None);
                }
                let objects = r
                    .scene
                    .objects
                    .iter()
                    .enumerate()
                    .map(|(j, o)| {
                        let poses = [&before[j], &now[j]]
                            .into_iter()
                            .chain(cont.iter().map(|f: &Vec<Pose>| &f[j]));
                        let (mut positions, mut rotations) = (Vec::new(), Vec::new());
                        for p in poses {
                            positions.push(p.translation);
                            let q = match rotations.last() {
                                Some(&prev) => continuous(prev, p.rotation),
                                None => p.rotation,
                            };
                            rotations.push(q);
                        }
                        ObjectRecord {
                            positions,
                            rotations,
                            ..o.clone()
                        }
                    })
                    .collect();
                Ok(Some(SceneRecord {
                    objects,
                    dt_frame: r.scene.dt_frame,
                }))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        skipped += made.iter().filter(|s| s.is_none()).count();
        let made: Vec<SceneRecord> = made.into_iter().flatten().collect();
        let file = format!("shard-{shard:05}.safetensors");
        write_file(
            &a.out.join(&file),
            &encode_shard(&made, frames, src.reference_points)?,
        )?;
        let n: usize = made.iter().map(|s| s.objects.len()).sum();
        objects += n;
        shards.push(ShardInfo {
            file,
            scenes: made.len(),
            objects: n,
            first_scene: written,
        });
        written += made.len();
        eprintln!(
            "{end}/{} scenes drawn, {skipped} skipped ({:.0} s)",
            a.scenes,
            t0.elapsed().as_secs_f64()
        );
    }
    let mut manifest = src;
    if let Some(p) = manifest.generator_parameters.as_object_mut() {
        p.insert(
            "restart_source_generator".into(),
            manifest.generator.clone().into(),
        );
        p.insert(
            "restart_source".into(),
            a.source.display().to_string().into(),
        );
        p.insert("restart_model".into(), a.model.display().to_string().into());
        p.insert("restart_rollout_max".into(), a.rollout_max.into());
        p.insert("restart_frames".into(), a.frames.into());
    }
    manifest.generator = "restart".into();
    manifest.seed = a.seed;
    manifest.frames = frames;
    manifest.scenes = written;
    manifest.objects = objects;
    manifest.shards = shards;
    manifest.scenarios = None;
    write_manifest(&a.out, &manifest)?;
    println!(
        "wrote {written} scenes ({objects} objects, {frames} frames; {skipped} of {} drawn \
         skipped: a shape rapier could not rebuild, or an object fell through the floor) to {} in {:.0} s",
        a.scenes,
        a.out.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
