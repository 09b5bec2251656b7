//! `dynaserve eval --model PHYSIFORMER --data DIR` on the official PhysiFormer data
//! ([`super::official_data`]), or with `--official-metrics` on a mesh dataset of ours: the
//! model's samples and two baselines (constant velocity,
//! free flight: constant velocity plus gravity) scored with the official metrics
//! ([`super::official_metrics`]) beside our per-vertex squared error, per scene and in all.

use std::time::Instant;

use anyhow::Context;
use dynaserve_model::PhysiFormer;
use dynaserve_sim::mesh_scenes::MeshDatasetReader;

use super::data::to_train_scene;
use super::eval::{PhysiEvalOptions, baseline, per_frame_sq};
use super::official_data::{OfficialExample, load_examples};
use super::official_metrics::{momentum_drift, mse, rigidity};

/// The scores of one method on one trajectory.
#[derive(Clone, Copy, Default)]
struct Scores {
    mse: f64,
    rigidity: f64,
    drift: f64,
    per_vertex: f64,
}

fn score(e: &OfficialExample, traj: &[f32], dt: f64) -> anyhow::Result<Scores> {
    let s = &e.scene;
    let per_frame = per_frame_sq(traj, &s.trajectory, s.frames);
    Ok(Scores {
        mse: mse(traj, &s.trajectory),
        rigidity: rigidity(&s.scene, traj, s.frames)?.unwrap_or(f64::NAN),
        drift: momentum_drift(&s.scene, traj, s.frames, &e.masses, dt),
        per_vertex: per_frame[1..].iter().sum::<f64>() / (s.frames - 1) as f64,
    })
}

/// NaN-skipping means of `mse`, `rigidity`, `per_vertex` over `rows`, and the pooled momentum
/// drift ratio (mean predicted drift over mean true drift `truth`).
fn summary(rows: &[Scores], truth: f64) -> (f64, f64, f64, f64) {
    // NaN-skipping means, as the official report's (a scene without an object of 3 vertices
    // has no rigidity).
    let m = |f: fn(&Scores) -> f64| {
        let v: Vec<f64> = rows.iter().map(f).filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    (
        m(|r| r.mse),
        m(|r| r.rigidity),
        m(|r| r.drift) / truth.max(1e-12),
        m(|r| r.per_vertex),
    )
}

/// The summary of an evaluation with the official metrics: per method (`model`, `constant
/// velocity`, `free flight`) its `mse` and `rigidity` (m^2 per coordinate), momentum drift
/// ratio to the ground truth's, and per-vertex squared error (m^2, frames 1..).
#[derive(Clone, Debug)]
pub struct OfficialReport {
    /// `(method, mse, rigidity, momentum_drift_ratio, per_vertex)`.
    pub rows: Vec<(&'static str, f64, f64, f64, f64)>,
}

/// Runs the evaluation on the official data at `o.data` and prints its tables.
pub fn run(o: &PhysiEvalOptions) -> anyhow::Result<OfficialReport> {
    let data = load_examples(&o.data)?;
    for why in &data.skipped {
        println!("skipped {why}");
    }
    score_examples(o, data.examples, "official example scenes")
}

/// Runs the evaluation with the official metrics on a mesh dataset of ours (`o.data`, a
/// `dynaserve sim mesh-*` split: each object's simulated mass) and prints its tables.
pub fn run_on_dataset(o: &PhysiEvalOptions) -> anyhow::Result<OfficialReport> {
    let reader = MeshDatasetReader::open(&o.data)
        .with_context(|| format!("cannot open mesh dataset {}", o.data.display()))?;
    let mut examples = Vec::new();
    for (i, s) in reader.iter().take(o.scenes.max(1)).enumerate() {
        let s = s?;
        examples.push(OfficialExample {
            name: format!("scene {i}"),
            masses: s.objects.iter().map(|obj| f64::from(obj.mass)).collect(),
            scene: to_train_scene(&s),
        });
    }
    score_examples(o, examples, "scenes")
}

/// Samples and scores `examples` (at most `o.scenes` of them) and prints the tables.
fn score_examples(
    o: &PhysiEvalOptions,
    mut examples: Vec<OfficialExample>,
    what: &str,
) -> anyhow::Result<OfficialReport> {
    anyhow::ensure!(!examples.is_empty(), "no scenes in {}", o.data.display());
    let device = dynaserve_model::device_from_name(&o.device)?;
    let model = PhysiFormer::load(&o.model, &device, false)?;
    let c = model.config().clone();
    examples.truncate(o.scenes.max(1));
    let dt = f64::from(c.dt_frame);
    let samples = o.samples.max(1);
    let (mut m_rows, mut cv_rows, mut ff_rows, mut truth) = (vec![], vec![], vec![], vec![]);
    let started = Instant::now();
    println!(
        "{} {what} of {}, {samples} samples each, {} steps",
        examples.len(),
        o.data.display(),
        o.steps
    );
    println!(
        "scene                    model mse   const-vel mse  free-flight mse  (m^2 per coordinate)"
    );
    for (i, e) in examples.iter().enumerate() {
        let s = &e.scene;
        anyhow::ensure!(
            s.frames <= c.frames,
            "{}: {} frames, the model samples at most {}",
            e.name,
            s.frames,
            c.frames
        );
        s.scene
            .validate(&c)
            .map_err(|err| anyhow::anyhow!("{}: {err}", e.name))?;
        truth.push(momentum_drift(
            &s.scene,
            &s.trajectory,
            s.frames,
            &e.masses,
            dt,
        ));
        cv_rows.push(score(e, &baseline(s, c.gravity, c.dt_frame, false), dt)?);
        ff_rows.push(score(e, &baseline(s, c.gravity, c.dt_frame, true), dt)?);
        let mut per_scene = Vec::new();
        for k in 0..samples {
            let seed = o.seed + (i * samples + k) as u64;
            let x = model
                .sample(&[(&s.scene, s.frames)], o.steps, seed)?
                .remove(0);
            per_scene.push(score(e, &x, dt)?);
        }
        let mean = per_scene.iter().map(|r| r.mse).sum::<f64>() / samples as f64;
        println!(
            "{:<24} {mean:.3e}   {:.3e}      {:.3e}",
            e.name, cv_rows[i].mse, ff_rows[i].mse
        );
        m_rows.extend(per_scene);
    }
    let truth_mean = truth.iter().sum::<f64>() / truth.len().max(1) as f64;
    println!(
        "\nofficial metrics over {} scenes ({:.1} s per sample); mse and rigidity m^2 per \
         coordinate, momentum drift as the official ratio to the ground truth's ({truth_mean:.3e} \
         kg m/s), per-vertex squared error m^2 over frames 1..",
        examples.len(),
        started.elapsed().as_secs_f64() / (examples.len() * samples) as f64
    );
    println!("method            mse         rigidity    momentum_drift_ratio  per-vertex m^2");
    let mut report = OfficialReport { rows: Vec::new() };
    for (name, rows) in [
        ("model", &m_rows),
        ("constant velocity", &cv_rows),
        ("free flight", &ff_rows),
    ] {
        let (a, b, d, p) = summary(rows, truth_mean);
        println!("{name:<17} {a:.3e}   {b:.3e}   {d:<20.3}  {p:.3e}");
        report.rows.push((name, a, b, d, p));
    }
    Ok(report)
}
