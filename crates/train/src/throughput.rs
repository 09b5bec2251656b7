//! `dynaserve throughput`: RigidFormer's serving throughput on one device, without a server:
//! the step of batches of MOVi-B scenes (simulated on the spot, the model's nominal points per
//! object), timed after a warm-up, as a median over repetitions and as scene-steps per second.
//! Run it once per device to compare them (the GPU kit runs it on the GPU and on the CPU).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use dynaserve_model::{SceneState, StepItem, WorldModel, device_from_name, load_rigidformer};
use dynaserve_sim::generators::generate_scene;
use dynaserve_sim::{GenerateOptions, Generator, SceneRecord};
use serde::Serialize;

use crate::eval::{ModelPredictor, observed_state};

/// Arguments of `dynaserve throughput`.
#[derive(clap::Args, Debug)]
pub struct ThroughputArgs {
    /// Device: `cpu`, `cuda` or `cuda:N` (a build with `--features cuda`).
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// RigidFormer model directory.
    #[arg(long, default_value = "models/rigidformer-small")]
    pub model: PathBuf,
    /// Batch sizes (scenes per step), comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 8, 32, 128, 256])]
    pub batches: Vec<usize>,
    /// Timed steps per batch size (after one warm-up step); the median is reported.
    #[arg(long, default_value_t = 5)]
    pub reps: usize,
    /// Objects per network pass (the model's default splits larger batches into passes of
    /// 160 objects, sized for CPU caches; a GPU wants one pass).
    #[arg(long)]
    pub max_pass_objects: Option<usize>,
    /// Write the table as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// One batch size's figures.
#[derive(Clone, Debug, Serialize)]
pub struct ThroughputRow {
    /// Scenes per step.
    pub batch: usize,
    /// Objects per step.
    pub objects: usize,
    /// Median seconds of one step of the batch.
    pub median_s: f64,
    /// `batch / median_s`.
    pub scene_steps_per_s: f64,
}

/// Distinct scenes the batches cycle through.
const SCENES: usize = 8;

/// `n` MOVi-B scenes of `points` reference points per object, simulated from `seed`, and the
/// state a step of k = 1 starts from in each (frames 23 and 24).
pub(crate) fn movi_b_step_inputs(
    seed: u64,
    n: usize,
    points: usize,
) -> anyhow::Result<(Vec<SceneRecord>, Vec<SceneState>)> {
    let mut opts = GenerateOptions::new(Generator::movi_b(), seed, "test", n);
    opts.points = points;
    let scenes = (0..n)
        .map(|i| Ok(generate_scene(&opts, i as u64)?.record))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let states = scenes
        .iter()
        .map(|s| observed_state(s, 24, 1))
        .collect::<Result<Vec<_>, _>>()?;
    Ok((scenes, states))
}

/// Times the step at every batch size and prints the table (and writes `--json`).
pub fn run(args: ThroughputArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.reps >= 1 && args.batches.iter().all(|&b| b >= 1),
        "--reps and every batch size must be at least 1"
    );
    let device = device_from_name(&args.device)?;
    let mut model = load_rigidformer(&args.model, &device, false)
        .with_context(|| format!("loading {}", args.model.display()))?;
    if let Some(n) = args.max_pass_objects {
        model = model.with_max_pass_objects(n);
    }
    let predictor = ModelPredictor::from_rigidformer(std::sync::Arc::new(model));
    let model: &dyn WorldModel = predictor.model().as_ref();
    let points = model.config().points_per_object.max(1);
    let (scenes, states) = movi_b_step_inputs(23, SCENES, points)?;
    let prepared = scenes
        .iter()
        .map(|s| model.prepare(predictor.inputs(s)))
        .collect::<Result<Vec<_>, _>>()?;
    let mut rows = Vec::new();
    println!(
        "RigidFormer step on {} ({}, {} points per object{}):",
        args.device,
        args.model.display(),
        points,
        args.max_pass_objects
            .map(|n| format!(", passes of {n} objects"))
            .unwrap_or_default()
    );
    println!("| batch | objects | median ms | scene-steps/s |");
    println!("| ---: | ---: | ---: | ---: |");
    for &batch in &args.batches {
        let items: Vec<StepItem<'_>> = (0..batch)
            .map(|i| StepItem {
                scene: &prepared[i % SCENES],
                state: &states[i % SCENES],
                dt_steps: 1,
            })
            .collect();
        let objects = (0..batch).map(|i| states[i % SCENES].current.len()).sum();
        model.step(&items)?;
        let mut times = Vec::with_capacity(args.reps);
        for _ in 0..args.reps {
            let t = Instant::now();
            model.step(&items)?;
            times.push(t.elapsed().as_secs_f64());
        }
        times.sort_by(f64::total_cmp);
        let median_s = times[times.len() / 2];
        let row = ThroughputRow {
            batch,
            objects,
            median_s,
            scene_steps_per_s: batch as f64 / median_s,
        };
        println!(
            "| {} | {} | {:.2} | {:.0} |",
            row.batch,
            row.objects,
            1e3 * row.median_s,
            row.scene_steps_per_s
        );
        rows.push(row);
    }
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&rows)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
