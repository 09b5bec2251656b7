//! `dynaserve sim`: generate, inspect and preview ground-truth datasets.
//!
//! ```text
//! dynaserve sim movi-b --scenes 1000 --out data/movi-b/train --seed 0 --split train
//! dynaserve sim wrecking-ball --scenes 20 --out data/wb6 --seed 0 --size 6
//! dynaserve sim physics-mix --scenes 500 --out data/physics-mix/train --seed 0 --split train
//! dynaserve sim push --scenes 200 --out data/push/train --seed 0 --split train
//! dynaserve sim mesh-d1 --scenes 400 --out data/physi/d1/train --seed 0 --split train
//! dynaserve sim inspect data/movi-b/train
//! dynaserve sim preview data/movi-b/train --out preview.png
//! dynaserve sim replay examples/scenes/collision.json --paths pusher.json
//! ```

pub mod split_args;

pub use split_args::{Split, SplitArgs};

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::{Args, Subcommand};

use crate::dataset::DatasetReader;
use crate::generators::{GenerateOptions, Generator};
use crate::mesh_scenes::cli::{self as mesh_cli, MeshGenerateArgs};
use crate::mesh_scenes::{MeshSet, is_mesh_dataset};
use crate::preview::write_preview;
use crate::replay::cli::{ReplayArgs, run_replay};
use crate::scenarios::{Materials, Scenario, ScenarioParameters};
use crate::stats::inspect;
use crate::writer::generate_dataset;
use split_args::{scene_progress, worker_pool};

/// Arguments of `dynaserve sim`.
#[derive(Args, Debug)]
pub struct SimArgs {
    /// What to do.
    #[command(subcommand)]
    pub command: SimCommand,
}

/// The `dynaserve sim` subcommands.
#[derive(Subcommand, Debug)]
pub enum SimCommand {
    /// Generate MOVi-A-like scenes (cube, cylinder, sphere; scale 0.7 or 1.4).
    #[command(name = "movi-a")]
    MoviA(GenerateArgs),
    /// Generate MOVi-B-like scenes (ten procedural shapes; scale uniform in [0.7, 1.4]).
    #[command(name = "movi-b")]
    MoviB(GenerateArgs),
    /// Generate WreckingBall scenes: a size^3 stack of cubes hit by a heavy ball.
    #[command(name = "wrecking-ball")]
    WreckingBall(WreckingBallArgs),
    /// Physics scenario: objects at rest from frame 0 (single objects, box towers, piles).
    Rest(RestArgs),
    /// Physics scenario: one object dropped from 0.5-3 m with random attitude and spin.
    Drop(ScenarioArgs),
    /// Physics scenario: objects launched along the floor that friction stops.
    Slide(ScenarioArgs),
    /// Physics scenario: two objects thrown at each other, in the air or along the floor.
    Collide(ScenarioArgs),
    /// Physics scenario: a tower of 2-4 boxes hit by a thrown object.
    #[command(name = "stack-hit")]
    StackHit(ScenarioArgs),
    /// Physics scenario: 1-3 objects on the floor pushed by a kinematic pusher (the last
    /// object, marked kinematic) following a random smooth path through them.
    Push(PushArgs),
    /// Physics scenario: 1-2 round objects (cylinder, cone, mug) lying on their side, set
    /// rolling along the floor; the facets of their sides slow them down.
    Roll(RollArgs),
    /// Physics scenarios: each scene draws one of rest, drop, slide, collide, stack-hit.
    #[command(name = "physics-mix")]
    PhysicsMix(ScenarioArgs),
    /// Mesh scenes: 1-5 convex rigid objects resting on the floor of a closed box, some sliding.
    #[command(name = "mesh-d1")]
    MeshD1(MeshGenerateArgs),
    /// Mesh scenes: as mesh-d1 with concave templates too.
    #[command(name = "mesh-d2")]
    MeshD2(MeshGenerateArgs),
    /// Mesh scenes: 1-5 or 6-10 rigid objects starting in the air, some spinning.
    #[command(name = "mesh-d3")]
    MeshD3(MeshGenerateArgs),
    /// Mesh scenes: elastic or mixed rigid/elastic objects, floor or airborne starts.
    #[command(name = "mesh-d4")]
    MeshD4(MeshGenerateArgs),
    /// Print statistics of a dataset split.
    Inspect(InspectArgs),
    /// Draw a few trajectories of a dataset split into a PNG.
    Preview(PreviewArgs),
    /// Replay a scene file in rapier, kinematic objects driven along given paths; prints the
    /// trajectory as JSON.
    Replay(ReplayArgs),
}

/// Options of the pose generators.
#[derive(Args, Debug, Clone)]
pub struct GenerateArgs {
    /// What every split generator takes.
    #[command(flatten)]
    pub split_args: SplitArgs,
    /// Reference surface points per object.
    #[arg(long, default_value_t = 1024)]
    pub points: usize,
    /// Scenes per shard file (default: 100, or 4 for wrecking-ball).
    #[arg(long)]
    pub scenes_per_shard: Option<usize>,
}

/// Options of the physics scenario generators.
#[derive(Args, Debug, Clone)]
pub struct ScenarioArgs {
    /// Shared generator options.
    #[command(flatten)]
    pub common: GenerateArgs,
    /// Contact materials of the objects.
    #[arg(long, value_enum, default_value_t = Materials::Kubric)]
    pub materials: Materials,
}

impl ScenarioArgs {
    /// Runs the scenario generator of `p` with these options' materials.
    fn run(&self, p: ScenarioParameters) -> anyhow::Result<()> {
        run_generate(
            Generator::scenarios(p.with_materials(self.materials)),
            &self.common,
        )
    }
}

/// Options of `dynaserve sim rest`.
#[derive(Args, Debug, Clone)]
pub struct RestArgs {
    /// Shared scenario options.
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Side range of a tower's cubes, metres, as `MIN,MAX` (default 0.7,1.4, the scale of
    /// every other object).
    #[arg(long, value_delimiter = ',', value_name = "MIN,MAX")]
    pub tower_scale: Option<Vec<f32>>,
}

/// Options of `dynaserve sim push`.
#[derive(Args, Debug, Clone)]
pub struct PushArgs {
    /// Shared scenario options.
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Largest deviation of the pusher's velocity from its smooth path's, drawn afresh every
    /// frame, m/s per horizontal axis (0: the smooth path alone).
    #[arg(long, default_value_t = 0.0)]
    pub jitter: f32,
}

/// Options of `dynaserve sim roll`.
#[derive(Args, Debug, Clone)]
pub struct RollArgs {
    /// Shared scenario options.
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Initial rolling speed range of each object's centre, m/s, as `MIN,MAX` (default
    /// 0.2,1.5). Slower launches end inside the scene's 4 s more often: about a third of the
    /// objects rest at the end at 0.03,0.3 against a quarter at the default.
    #[arg(long, value_delimiter = ',', value_name = "MIN,MAX")]
    pub speed: Option<Vec<f32>>,
}

/// Options of `dynaserve sim wrecking-ball`.
#[derive(Args, Debug, Clone)]
pub struct WreckingBallArgs {
    /// Shared generator options.
    #[command(flatten)]
    pub common: GenerateArgs,
    /// Cubes per side of the stack (4, 5, 6 give 64, 125, 216 cubes).
    #[arg(long, default_value_t = 4)]
    pub size: usize,
}

/// Options of `dynaserve sim inspect`.
#[derive(Args, Debug)]
pub struct InspectArgs {
    /// Split directory (holding manifest.json).
    pub dir: PathBuf,
    /// Examine only the first N scenes.
    #[arg(long)]
    pub limit: Option<usize>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Options of `dynaserve sim preview`.
#[derive(Args, Debug)]
pub struct PreviewArgs {
    /// Split directory (holding manifest.json).
    pub dir: PathBuf,
    /// Output PNG file.
    #[arg(long)]
    pub out: PathBuf,
    /// First scene to draw.
    #[arg(long, default_value_t = 0)]
    pub scene: usize,
    /// Number of consecutive scenes to draw.
    #[arg(long, default_value_t = 1)]
    pub count: usize,
}

/// The two numbers of a `MIN,MAX` option (their order and sign are checked with the other
/// generator parameters).
fn range_arg(flag: &str, r: &[f32]) -> anyhow::Result<[f32; 2]> {
    let [lo, hi] = r[..] else {
        bail!("{flag} takes two numbers, MIN,MAX (got {r:?})");
    };
    Ok([lo, hi])
}

/// Runs a `dynaserve sim` subcommand.
pub fn run(args: SimArgs) -> anyhow::Result<()> {
    match args.command {
        SimCommand::MoviA(a) => run_generate(Generator::movi_a(), &a),
        SimCommand::MoviB(a) => run_generate(Generator::movi_b(), &a),
        SimCommand::WreckingBall(a) => run_generate(Generator::wrecking_ball(a.size)?, &a.common),
        SimCommand::Rest(a) => {
            let mut p = ScenarioParameters::new(vec![Scenario::Rest]);
            if let Some(r) = &a.tower_scale {
                p.tower_scale = range_arg("--tower-scale", r)?;
            }
            a.scenario.run(p)
        }
        SimCommand::Drop(a) => a.run(ScenarioParameters::new(vec![Scenario::Drop])),
        SimCommand::Slide(a) => a.run(ScenarioParameters::new(vec![Scenario::Slide])),
        SimCommand::Collide(a) => a.run(ScenarioParameters::new(vec![Scenario::Collide])),
        SimCommand::StackHit(a) => a.run(ScenarioParameters::new(vec![Scenario::StackHit])),
        SimCommand::Push(a) => {
            let mut p = ScenarioParameters::new(vec![Scenario::Push]);
            p.push_jitter = a.jitter;
            a.scenario.run(p)
        }
        SimCommand::Roll(a) => {
            let mut p = ScenarioParameters::new(vec![Scenario::Roll]);
            if let Some(r) = &a.speed {
                p.roll_speed = range_arg("--speed", r)?;
            }
            a.scenario.run(p)
        }
        SimCommand::PhysicsMix(a) => a.run(ScenarioParameters::new(Scenario::ALL.to_vec())),
        SimCommand::MeshD1(a) => mesh_cli::run_generate(MeshSet::D1, &a),
        SimCommand::MeshD2(a) => mesh_cli::run_generate(MeshSet::D2, &a),
        SimCommand::MeshD3(a) => mesh_cli::run_generate(MeshSet::D3, &a),
        SimCommand::MeshD4(a) => mesh_cli::run_generate(MeshSet::D4, &a),
        SimCommand::Inspect(a) => run_inspect(&a),
        SimCommand::Preview(a) => run_preview(&a),
        SimCommand::Replay(a) => run_replay(&a),
    }
}

fn run_generate(generator: Generator, a: &GenerateArgs) -> anyhow::Result<()> {
    let GenerateArgs {
        split_args: t,
        points,
        scenes_per_shard,
    } = a;
    t.check()?;
    if *points == 0 {
        bail!("--points must be at least 1");
    }
    let mut opts = GenerateOptions::new(generator, t.seed, t.split.name(), t.scenes);
    opts.points = *points;
    if let Some(k) = *scenes_per_shard {
        if k == 0 {
            bail!("--scenes-per-shard must be at least 1");
        }
        opts.scenes_per_shard = k;
    }
    let pool = worker_pool(t.threads)?;
    let bar = scene_progress(t.scenes)?;
    let start = Instant::now();
    let summary = pool
        .install(|| generate_dataset(&opts, &t.out, t.overwrite, &|| bar.inc(1)))
        .with_context(|| {
            format!(
                "generating {} into {}",
                opts.generator.name(),
                t.out.display()
            )
        })?;
    bar.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    let m = &summary.manifest;
    println!(
        "{} / {} (seed {}): {} scenes, {} objects ({:.2} per scene), {} frames at {:.4} s, {} \
         reference points",
        m.generator,
        m.split,
        m.seed,
        m.scenes,
        m.objects,
        m.objects as f64 / m.scenes.max(1) as f64,
        m.frames,
        m.dt_frame,
        m.reference_points
    );
    println!(
        "wrote {} shards, {:.1} MB ({:.1} kB per scene) to {}",
        m.shards.len(),
        summary.bytes as f64 / 1e6,
        summary.bytes as f64 / 1e3 / m.scenes.max(1) as f64,
        summary.dir.display()
    );
    println!(
        "took {:.1} s ({:.2} scenes/s, {:.0} ms per scene) on {} threads",
        secs,
        m.scenes as f64 / secs,
        1e3 * secs / m.scenes.max(1) as f64,
        pool.current_num_threads()
    );
    Ok(())
}

fn run_inspect(a: &InspectArgs) -> anyhow::Result<()> {
    if is_mesh_dataset(&a.dir)? {
        return mesh_cli::run_inspect(&a.dir, a.limit, a.json);
    }
    let reader = DatasetReader::open(&a.dir)?;
    let stats = inspect(&reader, a.limit)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&stats)?);
    } else {
        print!("{stats}");
    }
    Ok(())
}

fn run_preview(a: &PreviewArgs) -> anyhow::Result<()> {
    if is_mesh_dataset(&a.dir)? {
        return mesh_cli::run_preview(&a.dir, a.scene, &a.out);
    }
    let reader = DatasetReader::open(&a.dir)?;
    if a.count == 0 {
        bail!("--count must be at least 1");
    }
    if a.scene >= reader.len() {
        bail!(
            "--scene {} is out of range: the split has {} scenes",
            a.scene,
            reader.len()
        );
    }
    let end = (a.scene + a.count).min(reader.len());
    let scenes = (a.scene..end)
        .map(|i| reader.get(i).map(|s| (i, s)))
        .collect::<Result<Vec<_>, _>>()?;
    let m = reader.manifest();
    let title = format!(
        "{} / {}: scenes {}..{} ({} objects)",
        m.generator,
        m.split,
        a.scene,
        end,
        scenes.iter().map(|(_, s)| s.objects.len()).sum::<usize>()
    );
    let with_text = write_preview(&scenes, &title, &a.out)?;
    println!(
        "wrote {}{}",
        a.out.display(),
        if with_text {
            ""
        } else {
            " (without text: no usable font)"
        }
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Top {
        #[command(subcommand)]
        command: Top2,
    }

    #[derive(clap::Subcommand)]
    enum Top2 {
        Sim(SimArgs),
    }

    fn parse(args: &[&str]) -> Result<SimCommand, clap::Error> {
        let mut all = vec!["dynaserve", "sim"];
        all.extend_from_slice(args);
        Top::try_parse_from(all).map(|t| match t.command {
            Top2::Sim(s) => s.command,
        })
    }

    #[test]
    fn parses_the_documented_commands() {
        match parse(&[
            "movi-b", "--scenes", "200", "--out", "d", "--seed", "2", "--split", "test",
        ])
        .unwrap()
        {
            SimCommand::MoviB(a) => {
                let t = &a.split_args;
                assert_eq!(
                    (t.scenes, t.seed, t.split, a.points),
                    (200, 2, Split::Test, 1024)
                );
                assert_eq!(t.out, PathBuf::from("d"));
            }
            other => panic!("parsed {other:?}"),
        }
        match parse(&[
            "wrecking-ball",
            "--scenes",
            "2",
            "--out",
            "w",
            "--size",
            "6",
        ])
        .unwrap()
        {
            SimCommand::WreckingBall(a) => {
                assert_eq!((a.size, a.common.split_args.split), (6, Split::Train))
            }
            other => panic!("parsed {other:?}"),
        }
        assert!(matches!(
            parse(&["inspect", "d", "--limit", "5"]).unwrap(),
            SimCommand::Inspect(InspectArgs { limit: Some(5), .. })
        ));
        assert!(parse(&["preview", "d", "--out", "p.png"]).is_ok());
        assert!(
            parse(&[
                "movi-b", "--scenes", "2", "--out", "d", "--split", "holdout"
            ])
            .is_err()
        );
        assert!(
            parse(&["movi-b", "--out", "d"]).is_err(),
            "--scenes is required"
        );
    }

    #[test]
    fn rejects_bad_values_with_errors() {
        let bad = |args: &[&str]| match parse(args).unwrap() {
            SimCommand::MoviA(a) => run_generate(Generator::movi_a(), &a).unwrap_err(),
            other => panic!("parsed {other:?}"),
        };
        let dir = std::env::temp_dir().join(format!("dynaserve-sim-cli-{}", std::process::id()));
        let out = dir.to_string_lossy().into_owned();
        assert!(
            bad(&["movi-a", "--scenes", "0", "--out", &out])
                .to_string()
                .contains("--scenes")
        );
        assert!(
            bad(&["movi-a", "--scenes", "1", "--out", &out, "--points", "0"])
                .to_string()
                .contains("--points")
        );
        let err = run_inspect(&InspectArgs {
            dir: dir.join("missing"),
            limit: None,
            json: false,
        })
        .unwrap_err();
        assert!(err.to_string().contains("manifest.json"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn roll_speed_reaches_the_scenes_and_bad_ranges_are_refused() {
        let dir = std::env::temp_dir().join(format!("dynaserve-sim-roll-{}", std::process::id()));
        let out = dir.to_string_lossy().into_owned();
        let run = |speed: &str| {
            let args = ["roll", "--scenes", "3", "--out", &out, "--overwrite"];
            let mut args = args.to_vec();
            args.extend(["--speed", speed]);
            run(SimArgs {
                command: parse(&args).unwrap(),
            })
        };
        let err = format!("{:#}", run("0.3").unwrap_err());
        assert!(err.contains("--speed takes two numbers"), "{err}");
        let err = format!("{:#}", run("0.3,0.1").unwrap_err());
        assert!(err.contains("range"), "{err}");
        run("0.05,0.1").unwrap();
        let reader = DatasetReader::open(&dir).unwrap();
        let recorded = &reader.manifest().generator_parameters["roll_speed"];
        assert_eq!(recorded, &serde_json::json!([0.05f32, 0.1f32]));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
