//! Training scenes that start where a model's own rollout leads, continued by rapier.
//!
//! For each scene written, a source scene and a start frame `s` are drawn, the model rolls out
//! `R` steps at step size 1 from the recording's frames `s - 1` and `s`, and rapier is
//! restarted from the model's last two poses (with the velocity they imply, as the `rapier`
//! evaluation baseline is: [`RapierRestart`]) and simulated for [`RestartOptions::frames`]
//! frames. The scene stored is the model's two poses followed by rapier's frames, with the
//! source's objects: every window of it is physics, and its first windows start where the
//! model's errors led (objects a little sunk, tilted or too fast). Pushforward trains a model's
//! own states against the recording's next pose; these scenes give such states the pose
//! physics gives them (the data-as-demonstrator idea for learned simulators).
//!
//! Sources with kinematic objects (pushers) are refused: their path after a restart is not
//! known. A draw is skipped, and counted, when rapier cannot rebuild one of its shapes (a
//! degenerate hull) or when an object's centre goes [`FELL_THROUGH`] below the floor's top: a
//! model state sunk so far that rapier lets the object fall through the floor is not a lesson
//! in physics.

use std::path::Path;

use anyhow::Context;
use dynaserve_model::{Pose, SceneState};
use dynaserve_sim::dataset::{PoseShards, prepare_dir, write_manifest};
use dynaserve_sim::{DatasetReader, Manifest, ObjectRecord, SceneRecord};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::eval::{ModelPredictor, Predictor, RapierRestart, RolloutRequest, observed_state};
use crate::train::data::mix;

/// An object whose centre goes below this height has fallen through the floor, metres.
pub const FELL_THROUGH: f32 = -0.1;

/// What [`write_restarts`] draws and writes (also the options of `dynaserve train restarts`).
#[derive(Clone, Debug, PartialEq, Eq, clap::Args)]
pub struct RestartOptions {
    /// Scenes to draw (skipped draws are not replaced: a draw whose shapes rapier cannot
    /// rebuild, or in which an object falls through the floor).
    #[arg(long, default_value_t = RestartOptions::default().scenes)]
    pub scenes: usize,
    /// Seed of the draws (source scene, start frame, rollout length), per scene.
    #[arg(long)]
    pub seed: u64,
    /// Longest model rollout before the restart, steps of one frame (drawn from 1 to this).
    #[arg(long, default_value_t = RestartOptions::default().rollout_max)]
    pub rollout_max: usize,
    /// Frames rapier simulates after the restart; each scene stores two more.
    #[arg(long, default_value_t = RestartOptions::default().frames)]
    pub frames: usize,
    /// Scenes per shard.
    #[arg(long, default_value_t = RestartOptions::default().per_shard)]
    pub per_shard: usize,
    /// Replace a dataset already in the output directory instead of refusing.
    #[arg(long)]
    pub overwrite: bool,
}

impl Default for RestartOptions {
    fn default() -> Self {
        RestartOptions {
            scenes: 2000,
            seed: 0,
            rollout_max: 48,
            frames: 30,
            per_shard: 100,
            overwrite: false,
        }
    }
}

/// What [`write_restarts`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct RestartSummary {
    /// Scenes written.
    pub written: usize,
    /// Draws skipped because rapier could not rebuild the scene ([`Skip::Rebuild`]).
    pub rebuild_refused: usize,
    /// Draws skipped because an object fell through the floor ([`Skip::FellThrough`]).
    pub fell_through: usize,
    /// Rapier's message for the first draw it could not rebuild, if any.
    pub first_rebuild_error: Option<String>,
    /// Objects written.
    pub objects: usize,
    /// The manifest written.
    pub manifest: Manifest,
}

impl RestartSummary {
    /// Draws skipped, for either reason.
    pub fn skipped(&self) -> usize {
        self.rebuild_refused + self.fell_through
    }
}

/// One output scene's draw, from a generator keyed on `(seed, scene)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Draw {
    /// Index of the source scene.
    pub source: usize,
    /// Start frame `s` (the model observes frames `s - 1` and `s`).
    pub start: usize,
    /// Steps the model rolls out before the restart.
    pub steps: usize,
}

/// The draw of output scene `scene` from `sources` source scenes of `frames` frames.
pub fn draw(opts: &RestartOptions, scene: usize, sources: usize, frames: usize) -> Draw {
    let mut rng = ChaCha8Rng::seed_from_u64(mix(opts.seed ^ mix(scene as u64)));
    let source = rng.random_range(0..sources);
    let start = rng.random_range(1..frames);
    let steps = rng.random_range(1..=opts.rollout_max);
    Draw {
        source,
        start,
        steps,
    }
}

/// The source scenes of `draws`, in order, each source shard read once (a draw per scene
/// would decode a whole shard per scene).
fn read_drawn(source: &DatasetReader, draws: &[Draw]) -> anyhow::Result<Vec<SceneRecord>> {
    let mut scenes: Vec<Option<SceneRecord>> = vec![None; draws.len()];
    for (k, info) in source.manifest().shards.iter().enumerate() {
        let range = info.first_scene..info.first_scene + info.scenes;
        if !draws.iter().any(|d| range.contains(&d.source)) {
            continue;
        }
        let shard = source.read_shard(k)?;
        for (slot, d) in scenes.iter_mut().zip(draws) {
            if range.contains(&d.source) {
                *slot = shard.get(d.source - info.first_scene).cloned();
            }
        }
    }
    scenes
        .into_iter()
        .zip(draws)
        .map(|(s, d)| s.with_context(|| format!("source scene {} is in no shard", d.source)))
        .collect()
}

/// `q` or `-q`, whichever is nearer `prev` (quaternions are stored sign-continuous in time).
fn continuous(prev: [f32; 4], q: [f32; 4]) -> [f32; 4] {
    let dot: f32 = (0..4).map(|i| prev[i] * q[i]).sum();
    if dot < 0.0 { q.map(|v| -v) } else { q }
}

/// `scene` restarted in rapier from `restart` (poses one frame apart) and simulated `frames`
/// frames: a scene of `frames + 2` frames, `restart.previous`, `restart.current` and then
/// rapier's, with `scene`'s objects; [`Skip`] says why there is none.
pub fn continue_in_rapier(
    rapier: &RapierRestart,
    scene: &SceneRecord,
    restart: &SceneState,
    frames: usize,
) -> Result<SceneRecord, Skip> {
    let cont = rapier
        .rollout(scene, restart, 1, frames)
        .map_err(|e| Skip::Rebuild(format!("{e:#}")))?;
    if cont
        .iter()
        .flatten()
        .any(|p| p.translation[2] < FELL_THROUGH)
    {
        return Err(Skip::FellThrough);
    }
    let objects = scene
        .objects
        .iter()
        .enumerate()
        .map(|(j, o)| {
            let poses = [&restart.previous[j], &restart.current[j]]
                .into_iter()
                .chain(cont.iter().map(|f: &Vec<Pose>| &f[j]));
            let (mut positions, mut rotations) = (Vec::new(), Vec::<[f32; 4]>::new());
            for p in poses {
                positions.push(p.translation);
                rotations.push(match rotations.last() {
                    Some(&prev) => continuous(prev, p.rotation),
                    None => p.rotation,
                });
            }
            ObjectRecord {
                positions,
                rotations,
                ..o.clone()
            }
        })
        .collect();
    Ok(SceneRecord {
        objects,
        dt_frame: scene.dt_frame,
    })
}

/// Why [`continue_in_rapier`] made no scene from a draw.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Skip {
    /// Rapier refused the scene (its message; the cases seen are degenerate random hulls).
    Rebuild(String),
    /// An object's centre went below [`FELL_THROUGH`].
    FellThrough,
}

/// Writes a split of restart scenes into `out` (which must not hold a manifest unless
/// [`RestartOptions::overwrite`]): draws
/// [`RestartOptions::scenes`] scenes from `source`, rolls `model` out from each (all of a
/// shard's rollouts batched), continues them in rapier ([`continue_in_rapier`]) and writes the
/// shards and a manifest: the source's, with `generator` `restart` and the source's generator,
/// the source and the model named in `generator_parameters`. `on_shard(drawn, skipped)`
/// reports progress after each shard.
pub fn write_restarts(
    model: &ModelPredictor,
    model_name: &str,
    source: &DatasetReader,
    out: &Path,
    opts: &RestartOptions,
    mut on_shard: impl FnMut(usize, usize),
) -> anyhow::Result<RestartSummary> {
    anyhow::ensure!(
        opts.scenes > 0 && opts.per_shard > 0 && opts.rollout_max > 0 && opts.frames > 0,
        "scenes, scenes per shard, the longest rollout and the frames must be at least 1"
    );
    let src = source.manifest().clone();
    anyhow::ensure!(
        src.frames >= 2 && !source.is_empty(),
        "{}: no scenes of two frames or more to start from",
        source.dir().display()
    );
    if let Some(i) = source
        .object_parameters()?
        .iter()
        .position(|objects| objects.iter().any(|&(_, kinematic)| kinematic))
    {
        anyhow::bail!(
            "{}: scene {i} has a kinematic object, whose path after a restart is not known",
            source.dir().display()
        );
    }
    let rapier = RapierRestart::from_manifest(&src)?;
    prepare_dir(out, opts.overwrite)?;
    let frames = opts.frames + 2;
    let mut written = PoseShards::default();
    let (mut rebuild_refused, mut fell_through, mut first_rebuild_error) = (0, 0, None);
    for first in (0..opts.scenes).step_by(opts.per_shard) {
        let end = (first + opts.per_shard).min(opts.scenes);
        let draws: Vec<Draw> = (first..end)
            .map(|i| draw(opts, i, source.len(), src.frames))
            .collect();
        let scenes = read_drawn(source, &draws)?;
        let requests = scenes
            .iter()
            .zip(&draws)
            .map(|(scene, d)| {
                Ok(RolloutRequest {
                    scene,
                    observed: observed_state(scene, d.start, 1)?,
                    dt_steps: 1,
                    steps: d.steps,
                })
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let restarts = requests
            .iter()
            .zip(model.rollout_batch(&requests)?)
            .map(|(r, roll)| {
                // The model's last two poses (the recording's frame s if it stepped once).
                let mut roll = roll.into_iter().rev();
                let current = roll.next().context("the model returned an empty rollout")?;
                let previous = roll.next().unwrap_or_else(|| r.observed.current.clone());
                Ok(SceneState {
                    previous,
                    current,
                    earlier: None,
                    carry: Default::default(),
                })
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let made: Vec<Result<SceneRecord, Skip>> = requests
            .par_iter()
            .zip(&restarts)
            .map(|(r, restart)| continue_in_rapier(&rapier, r.scene, restart, opts.frames))
            .collect();
        for skip in made.iter().filter_map(|m| m.as_ref().err()) {
            match skip {
                Skip::FellThrough => fell_through += 1,
                Skip::Rebuild(e) => {
                    rebuild_refused += 1;
                    first_rebuild_error.get_or_insert_with(|| e.clone());
                }
            }
        }
        let made: Vec<SceneRecord> = made.into_iter().flatten().collect();
        written.write(out, &made, frames, src.reference_points)?;
        on_shard(end, rebuild_refused + fell_through);
    }
    anyhow::ensure!(
        written.scenes > 0,
        "every one of {} draws was skipped",
        opts.scenes
    );
    let mut manifest = src;
    if let Some(p) = manifest.generator_parameters.as_object_mut() {
        let params = [
            (
                "restart_source_generator",
                manifest.generator.clone().into(),
            ),
            ("restart_source", source.dir().display().to_string().into()),
            ("restart_model", model_name.into()),
            ("restart_rollout_max", opts.rollout_max.into()),
            ("restart_frames", opts.frames.into()),
        ];
        for (k, v) in params {
            p.insert(k.into(), v);
        }
    }
    manifest.generator = "restart".into();
    manifest.seed = opts.seed;
    manifest.frames = frames;
    manifest.scenes = written.scenes;
    manifest.objects = written.objects;
    manifest.shards = written.shards;
    manifest.scenarios = None;
    write_manifest(out, &manifest).with_context(|| format!("writing {}", out.display()))?;
    Ok(RestartSummary {
        written: manifest.scenes,
        rebuild_refused,
        fell_through,
        first_rebuild_error,
        objects: manifest.objects,
        manifest,
    })
}
