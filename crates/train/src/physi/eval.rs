//! PhysiFormer evaluation on a mesh dataset split: per-frame per-vertex squared error of the
//! model's samples against the constant-velocity and ballistic (constant velocity plus
//! gravity) baselines, the rigidity residual of rigid objects, and a PNG of error by frame.

use std::path::{Path, PathBuf};

use dynaserve_geometry::metrics::rigidity_residual;
use dynaserve_model::PhysiFormer;
use dynaserve_model::physiformer::flow::TrainScene;
use dynaserve_model::physiformer::rigid::project_rigid;
use dynaserve_model::physiformer::scene::Material;

use super::data::load_scenes;
use crate::train::plot::{Series, line_chart};

/// What to evaluate.
#[derive(Clone, Debug)]
pub struct PhysiEvalOptions {
    /// PhysiFormer model directory.
    pub model: PathBuf,
    /// Mesh dataset split directory.
    pub data: PathBuf,
    /// Scenes evaluated (the first ones of the split).
    pub scenes: usize,
    /// Samples per scene (mean and spread over them).
    pub samples: usize,
    /// Denoising steps.
    pub steps: usize,
    /// Seed of the first sample.
    pub seed: u64,
    /// Error-by-frame PNG.
    pub plot: Option<PathBuf>,
    /// Device the model samples on (`cpu`, `cuda`, `cuda:N`).
    pub device: String,
}

/// Mean over frames `1..` and vertices of the squared distance, m^2, per frame `[T]`.
pub(crate) fn per_frame_sq(pred: &[f32], truth: &[f32], frames: usize) -> Vec<f64> {
    let per = pred.len() / frames;
    (0..frames)
        .map(|t| {
            let s: f64 = pred[t * per..(t + 1) * per]
                .iter()
                .zip(&truth[t * per..(t + 1) * per])
                .map(|(a, b)| ((a - b) as f64).powi(2))
                .sum();
            s / (per / 3) as f64
        })
        .collect()
}

/// Constant velocity (`gravity` false) or free flight (constant velocity plus gravity) from
/// the scene's frame 0, `[T, V, 3]`, unclamped.
pub(crate) fn baseline(s: &TrainScene, g: [f32; 3], dt: f32, gravity: bool) -> Vec<f32> {
    let mut out = Vec::with_capacity(s.trajectory.len());
    for t in 0..s.frames {
        let tt = t as f32 * dt;
        for (p, v) in s.scene.positions.iter().zip(&s.scene.velocities) {
            for d in 0..3 {
                let fall = if gravity { 0.5 * g[d] * tt * tt } else { 0.0 };
                out.push(p[d] + v[d] * tt + fall);
            }
        }
    }
    out
}

/// Mean rigidity residual (m^2) of the rigid objects of `traj` `[T, V, 3]`: frame 0 of each
/// object Kabsch-aligned onto every later frame.
fn rigidity(s: &TrainScene, traj: &[f32]) -> anyhow::Result<Option<f64>> {
    let nv = s.scene.vertices();
    let (mut sum, mut n) = (0.0, 0usize);
    for (o, m) in s.scene.materials.iter().enumerate() {
        if *m != Material::Rigid {
            continue;
        }
        let r = s.scene.vertex_offsets[o]..s.scene.vertex_offsets[o + 1];
        let at = |t: usize| -> Vec<[f32; 3]> {
            r.clone()
                .map(|i| {
                    let k = (t * nv + i) * 3;
                    [traj[k], traj[k + 1], traj[k + 2]]
                })
                .collect()
        };
        let reference = at(0);
        for t in 1..s.frames {
            sum += rigidity_residual(&reference, &at(t))?;
            n += 1;
        }
    }
    Ok((n > 0).then(|| sum / n as f64))
}

/// Runs the evaluation and prints its tables.
pub fn run(o: &PhysiEvalOptions) -> anyhow::Result<()> {
    let device = dynaserve_model::device_from_name(&o.device)?;
    let model = PhysiFormer::load(&o.model, &device, false)?;
    let c = model.config().clone();
    let mut scenes = load_scenes(std::slice::from_ref(&o.data))?;
    scenes.truncate(o.scenes.max(1));
    let frames = scenes.iter().map(|s| s.frames).max().unwrap_or(0);
    let samples = o.samples.max(1);
    // [sample][frame] sums over scenes, and per-frame counts.
    let mut model_err = vec![vec![0f64; frames]; samples];
    // The same samples after the rigid projection of their rigid objects.
    let mut proj_err = vec![vec![0f64; frames]; samples];
    let mut cv = vec![0f64; frames];
    let mut ball = vec![0f64; frames];
    let mut count = vec![0f64; frames];
    let (mut rig_m, mut rig_b, mut rig_t, mut rig_n) = (0.0, 0.0, 0.0, 0usize);
    let started = std::time::Instant::now();
    for (i, s) in scenes.iter().enumerate() {
        let bcv = baseline(s, c.gravity, c.dt_frame, false);
        let bb = baseline(s, c.gravity, c.dt_frame, true);
        for (t, e) in per_frame_sq(&bcv, &s.trajectory, s.frames)
            .iter()
            .enumerate()
        {
            cv[t] += e;
            count[t] += 1.0;
        }
        for (t, e) in per_frame_sq(&bb, &s.trajectory, s.frames)
            .iter()
            .enumerate()
        {
            ball[t] += e;
        }
        for (k, (errs, perrs)) in model_err.iter_mut().zip(&mut proj_err).enumerate() {
            let seed = o.seed + (i * samples + k) as u64;
            let x = model
                .sample(&[(&s.scene, s.frames)], o.steps, seed)?
                .remove(0);
            for (t, e) in per_frame_sq(&x, &s.trajectory, s.frames).iter().enumerate() {
                errs[t] += e;
            }
            let mut xp = x.clone();
            project_rigid(&s.scene, s.frames, &mut xp)?;
            for (t, e) in per_frame_sq(&xp, &s.trajectory, s.frames)
                .iter()
                .enumerate()
            {
                perrs[t] += e;
            }
            if let (Some(m), Some(b), Some(tr)) = (
                rigidity(s, &x)?,
                rigidity(s, &bb)?,
                rigidity(s, &s.trajectory)?,
            ) {
                rig_m += m;
                rig_b += b;
                rig_t += tr;
                rig_n += 1;
            }
        }
    }
    let secs = started.elapsed().as_secs_f64();
    let mean_sd_of = |errs: &[Vec<f64>], t: usize| -> (f64, f64) {
        let v: Vec<f64> = errs.iter().map(|e| e[t] / count[t].max(1.0)).collect();
        let m = v.iter().sum::<f64>() / v.len() as f64;
        let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
        (m, sd)
    };
    let mean_sd = |t: usize| mean_sd_of(&model_err, t);
    println!(
        "{} scenes of {}, {} samples each, {} steps ({:.1} s per sample)",
        scenes.len(),
        o.data.display(),
        samples,
        o.steps,
        secs / (scenes.len() * samples) as f64
    );
    println!("per-vertex squared error, m^2 (model: mean +- spread over samples)");
    println!("frame   model                 rigid-projected  const-velocity  ballistic");
    for t in (0..frames).filter(|t| t % 4 == 0 || *t == frames - 1) {
        let (m, sd) = mean_sd(t);
        let n = count[t].max(1.0);
        println!(
            "{t:>5}   {m:.3e} +- {sd:.1e}   {:.3e}        {:.3e}       {:.3e}",
            mean_sd_of(&proj_err, t).0,
            cv[t] / n,
            ball[t] / n
        );
    }
    let avg = |v: &[f64]| -> f64 {
        (1..frames).map(|t| v[t] / count[t].max(1.0)).sum::<f64>() / (frames - 1).max(1) as f64
    };
    let model_all: Vec<f64> = (0..frames).map(|t| mean_sd(t).0 * count[t]).collect();
    let proj_all: Vec<f64> = (0..frames)
        .map(|t| mean_sd_of(&proj_err, t).0 * count[t])
        .collect();
    println!(
        "mean over frames 1..{}: model {:.3e}  rigid-projected {:.3e}  const-velocity {:.3e}  ballistic {:.3e}",
        frames - 1,
        avg(&model_all),
        avg(&proj_all),
        avg(&cv),
        avg(&ball)
    );
    if rig_n > 0 {
        let n = rig_n as f64;
        println!(
            "rigidity residual of rigid objects, m^2: model {:.3e} (0 after the rigid projection)  ballistic {:.3e}  ground truth {:.3e}",
            rig_m / n,
            rig_b / n,
            rig_t / n
        );
    }
    if let Some(p) = &o.plot {
        let series = |name: &str, v: &[f64]| Series {
            name: name.into(),
            points: (1..frames)
                .map(|t| (t as f64, v[t] / count[t].max(1.0)))
                .collect(),
        };
        line_chart(
            p,
            "per-vertex squared error by frame",
            "frame",
            "m^2",
            &[
                series("PhysiFormer", &model_all),
                series("PhysiFormer, rigid-projected", &proj_all),
                series("constant velocity", &cv),
                series("ballistic", &ball),
            ],
            true,
        )?;
        println!("wrote {}", p.display());
    }
    Ok(())
}

/// True when `dir` holds a PhysiFormer model (its `config.json` names the architecture).
pub fn is_physi_model(dir: &Path) -> bool {
    dynaserve_model::physiformer::read_physi_config(dir).is_ok()
}
