//! Evaluation core: autoregressive rollouts from two observed frames, scored at fixed physical
//! horizons. Every predictor (the baselines here, learned models through [`ModelPredictor`])
//! runs through exactly this code path.
//!
//! # Protocol
//!
//! For each scene and each step size `k` (frames): the predictor observes the poses at frames
//! `s - k` and `s`, where the start frame `s` is the same for every step size (default
//! [`DEFAULT_START_FRAME`] = 4, so `k` up to 4 fits), and rolls forward autoregressively in
//! steps of `k` frames. Its prediction after `h / k` steps is compared with the ground truth at
//! frame `s + h`, for the horizons `H` in seconds (default 0.5, 1, 2, 4 s; `h = H / dt_frame`,
//! so 12, 24, 48, 96 frames at 24 fps).
//!
//! A horizon is reported as missing, with the reason, never shifted to a nearby frame, when
//! `H / dt_frame` is not a whole number of frames, when `h` is not a multiple of `k`, when
//! `s + h` is beyond the last frame, or when `s - k < 0`.
//!
//! # Metrics (pooled)
//!
//! At each (step size, horizon): centre-of-mass translation RMSE in metres,
//! `sqrt(sum |p_pred - p_true|^2 / N)`, and orientation RMSE in degrees,
//! `sqrt(sum theta^2 / N)` with the geodesic angle `theta = 2 acos |<q_pred, q_true>|`, where
//! the sums run over all `N` objects of all scenes: the RMSE over the pool of objects, not the
//! mean of per-scene RMSEs (scenes with more objects weigh more). Sums are reduced in scene
//! order, so reports are reproducible bit for bit.

pub mod baselines;
pub mod model;

use std::time::Instant;

use dynaserve_geometry::geodesic_angle;
use dynaserve_geometry::metrics::{RmseAccumulator, squared_distance};
use dynaserve_model::{Pose, SceneState};
use dynaserve_sim::{DatasetReader, SceneRecord};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub use baselines::{Ballistic, Static};
pub use model::ModelPredictor;

/// Start frame `s` shared by all step sizes (the second observed frame).
pub const DEFAULT_START_FRAME: usize = 4;
/// Physical horizons in seconds after the start frame.
pub const DEFAULT_HORIZONS_S: [f64; 4] = [0.5, 1.0, 2.0, 4.0];
/// Step sizes in frames.
pub const DEFAULT_STEP_SIZES: [u32; 3] = [1, 2, 4];

/// Scenes evaluated per parallel batch when streaming a dataset.
const BATCH: usize = 16;

/// Errors of an evaluation; each says what and where.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Options or data that cannot be evaluated.
    #[error("evaluation: {0}")]
    Invalid(String),
    /// Dataset I/O failed.
    #[error(transparent)]
    Sim(#[from] dynaserve_sim::SimError),
    /// A learned model failed or rejected its input.
    #[error(transparent)]
    Model(#[from] dynaserve_model::ModelError),
    /// A predictor returned something unusable.
    #[error("predictor {predictor}, scene {scene}: {message}")]
    Predictor {
        /// Predictor name.
        predictor: String,
        /// Scene index in evaluation order.
        scene: usize,
        /// What was wrong.
        message: String,
    },
}

/// Anything that can roll a scene forward: baselines and learned world models alike.
///
/// `observed` holds the poses at frames `s - dt_steps` (`previous`) and `s` (`current`); the
/// result is `[steps][objects]`, entry `i` being the poses `(i + 1) * dt_steps` frames after
/// `s`. `scene` gives access to the reference clouds and physical parameters (never to the
/// future frames: predictors must not read `positions`/`rotations` beyond frame `s`, which the
/// evaluator cannot enforce; the baselines and [`ModelPredictor`] do not read them at all).
pub trait Predictor: Sync {
    /// Name for reports (a baseline name or the model's checkpoint name).
    fn name(&self) -> String;
    /// Rolls `scene` forward `steps` steps of `dt_steps` frames from `observed`.
    fn rollout(
        &self,
        scene: &SceneRecord,
        observed: &SceneState,
        dt_steps: u32,
        steps: usize,
    ) -> Result<Vec<Vec<Pose>>, EvalError>;
}

/// What to evaluate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalOptions {
    /// Start frame `s` (second observed frame), shared by all step sizes.
    pub start_frame: usize,
    /// Step sizes `k` in frames, each `>= 1`.
    pub step_sizes: Vec<u32>,
    /// Horizons in seconds after frame `s`, each `> 0`.
    pub horizons_s: Vec<f64>,
    /// Evaluate only the first `n` scenes.
    pub max_scenes: Option<usize>,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            start_frame: DEFAULT_START_FRAME,
            step_sizes: DEFAULT_STEP_SIZES.to_vec(),
            horizons_s: DEFAULT_HORIZONS_S.to_vec(),
            max_scenes: None,
        }
    }
}

/// Result at one (step size, horizon).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HorizonReport {
    /// Horizon in seconds after the start frame.
    pub horizon_s: f64,
    /// Horizon in frames, when it is a whole number of frames.
    pub frames: Option<usize>,
    /// Rollout steps to reach it (`frames / dt_steps`), when available.
    pub steps: Option<usize>,
    /// Pooled centre-of-mass translation RMSE, metres; `None` when missing.
    pub translation_rmse_m: Option<f64>,
    /// Pooled geodesic orientation RMSE, degrees; `None` when missing.
    pub orientation_rmse_deg: Option<f64>,
    /// Number of objects pooled.
    pub objects: u64,
    /// Why the horizon is missing, if it is.
    pub missing: Option<String>,
}

/// Results of one step size.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepSizeReport {
    /// Step size in frames.
    pub dt_steps: u32,
    /// One entry per requested horizon, in the requested order.
    pub horizons: Vec<HorizonReport>,
}

/// A full evaluation report (what `dynaserve eval --json` writes).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Predictor name.
    pub predictor: String,
    /// Dataset directory, generator, split and seed when evaluated from a dataset.
    pub dataset: Option<DatasetInfo>,
    /// Scenes evaluated.
    pub scenes: usize,
    /// Objects in those scenes.
    pub objects: usize,
    /// Frames per scene.
    pub frames: usize,
    /// Seconds per frame.
    pub dt_frame: f64,
    /// Start frame `s`.
    pub start_frame: usize,
    /// How the metrics pool errors.
    pub pooling: String,
    /// Results per step size, in the requested order.
    pub step_sizes: Vec<StepSizeReport>,
    /// Wall-clock time of the evaluation, seconds.
    pub elapsed_s: f64,
}

/// Where evaluated data came from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DatasetInfo {
    /// Split directory.
    pub dir: String,
    /// Generator name from the manifest.
    pub generator: String,
    /// Split name.
    pub split: String,
    /// Dataset seed.
    pub seed: u64,
    /// Gravity recorded in the manifest, m/s^2.
    pub gravity: [f32; 3],
}

const POOLING: &str = "RMSE over all objects of all scenes pooled at each horizon \
                       (not a mean of per-scene RMSEs)";

/// The poses of every object at frame `t`.
pub fn poses_at(scene: &SceneRecord, t: usize) -> Result<Vec<Pose>, EvalError> {
    scene
        .objects
        .iter()
        .enumerate()
        .map(|(j, o)| match (o.positions.get(t), o.rotations.get(t)) {
            (Some(p), Some(q)) => Ok(Pose {
                translation: *p,
                rotation: *q,
            }),
            _ => Err(EvalError::Invalid(format!(
                "object {j} has no frame {t} ({} frames)",
                o.positions.len().min(o.rotations.len())
            ))),
        })
        .collect()
}

/// The observed state for step size `k`: poses at frames `start - k` and `start`.
pub fn observed_state(scene: &SceneRecord, start: usize, k: u32) -> Result<SceneState, EvalError> {
    let k = k as usize;
    if k == 0 || k > start {
        return Err(EvalError::Invalid(format!(
            "step size {k} needs frame {start} - {k}, which does not exist"
        )));
    }
    Ok(SceneState {
        previous: poses_at(scene, start - k)?,
        current: poses_at(scene, start)?,
    })
}

#[derive(Clone, Debug)]
struct HorizonPlan {
    horizon_s: f64,
    frames: Option<usize>,
    /// `Some(steps)` when evaluated.
    steps: Option<usize>,
    missing: Option<String>,
}

#[derive(Clone, Debug)]
struct StepPlan {
    k: u32,
    /// Steps to roll out (the largest available horizon), 0 when nothing is available.
    steps: usize,
    horizons: Vec<HorizonPlan>,
}

fn plan(opts: &EvalOptions, frames: usize, dt_frame: f64) -> Result<Vec<StepPlan>, EvalError> {
    if opts.step_sizes.is_empty() || opts.horizons_s.is_empty() {
        return Err(EvalError::Invalid(
            "need at least one step size and one horizon".into(),
        ));
    }
    if opts.step_sizes.contains(&0) {
        return Err(EvalError::Invalid("step sizes must be at least 1".into()));
    }
    if let Some(h) = opts
        .horizons_s
        .iter()
        .find(|h| !(h.is_finite() && **h > 0.0))
    {
        return Err(EvalError::Invalid(format!(
            "horizons must be positive seconds, got {h}"
        )));
    }
    if !(dt_frame.is_finite() && dt_frame > 0.0) {
        return Err(EvalError::Invalid(format!(
            "dt_frame must be positive, got {dt_frame}"
        )));
    }
    if opts.start_frame >= frames {
        return Err(EvalError::Invalid(format!(
            "start frame {} is beyond the data ({frames} frames)",
            opts.start_frame
        )));
    }
    let last = frames - 1;
    Ok(opts
        .step_sizes
        .iter()
        .map(|&k| {
            let horizons: Vec<HorizonPlan> = opts
                .horizons_s
                .iter()
                .map(|&horizon_s| {
                    let exact = horizon_s / dt_frame;
                    let rounded = exact.round();
                    let frames_h = ((exact - rounded).abs() <= 1e-6 * exact.max(1.0))
                        .then_some(rounded as usize);
                    let missing = match frames_h {
                        None => Some(format!(
                            "{horizon_s} s is {exact:.3} frames of {dt_frame} s, not a whole number"
                        )),
                        Some(_) if k as usize > opts.start_frame => Some(format!(
                            "step size {k} needs frame {} - {k} < 0",
                            opts.start_frame
                        )),
                        Some(h) if h % k as usize != 0 => {
                            Some(format!("{h} frames is not a multiple of the step size {k}"))
                        }
                        Some(h) if opts.start_frame + h > last => Some(format!(
                            "frame {} + {h} is beyond the last frame {last}",
                            opts.start_frame
                        )),
                        Some(_) => None,
                    };
                    HorizonPlan {
                        horizon_s,
                        frames: frames_h,
                        steps: match (missing.is_none(), frames_h) {
                            (true, Some(h)) => Some(h / k as usize),
                            _ => None,
                        },
                        missing,
                    }
                })
                .collect();
            let steps = horizons.iter().filter_map(|h| h.steps).max().unwrap_or(0);
            StepPlan { k, steps, horizons }
        })
        .collect())
}

/// Per-scene squared-error sums, `[step size][horizon]` of (translation m^2, orientation deg^2).
type SceneErrors = Vec<Vec<(RmseAccumulator, RmseAccumulator)>>;

fn evaluate_scene(
    predictor: &dyn Predictor,
    scene: &SceneRecord,
    scene_index: usize,
    start: usize,
    frames: usize,
    plans: &[StepPlan],
) -> Result<SceneErrors, EvalError> {
    let bad = |message: String| EvalError::Predictor {
        predictor: predictor.name(),
        scene: scene_index,
        message,
    };
    if scene.objects.is_empty() {
        return Err(EvalError::Invalid(format!(
            "scene {scene_index} has no objects"
        )));
    }
    for (j, o) in scene.objects.iter().enumerate() {
        if o.positions.len() != frames || o.rotations.len() != frames {
            return Err(EvalError::Invalid(format!(
                "scene {scene_index} object {j} has {} positions and {} rotations, expected \
                 {frames} frames",
                o.positions.len(),
                o.rotations.len()
            )));
        }
    }
    let n = scene.objects.len();
    let mut out = Vec::with_capacity(plans.len());
    for plan in plans {
        let mut row =
            vec![(RmseAccumulator::default(), RmseAccumulator::default()); plan.horizons.len()];
        if plan.steps > 0 {
            let observed = observed_state(scene, start, plan.k)?;
            let rollout = predictor.rollout(scene, &observed, plan.k, plan.steps)?;
            if rollout.len() != plan.steps {
                return Err(bad(format!(
                    "returned {} steps, expected {}",
                    rollout.len(),
                    plan.steps
                )));
            }
            for (h, acc) in plan.horizons.iter().zip(row.iter_mut()) {
                let (Some(steps), Some(hf)) = (h.steps, h.frames) else {
                    continue;
                };
                let predicted = &rollout[steps - 1];
                if predicted.len() != n {
                    return Err(bad(format!(
                        "returned {} poses at step {steps}, the scene has {n} objects",
                        predicted.len()
                    )));
                }
                let truth = poses_at(scene, start + hf)?;
                for (j, (p, t)) in predicted.iter().zip(&truth).enumerate() {
                    let d2 = squared_distance(&p.translation, &t.translation);
                    let theta = geodesic_angle(p.rotation, t.rotation);
                    if !d2.is_finite() || !theta.is_finite() {
                        return Err(bad(format!(
                            "non-finite pose for object {j} at step {steps} (k = {}): {p:?}",
                            plan.k
                        )));
                    }
                    acc.0.add_squared(d2);
                    acc.1.add(theta.to_degrees());
                }
            }
        }
        out.push(row);
    }
    Ok(out)
}

/// Accumulates pooled errors over scenes in a fixed order.
struct Evaluator<'a> {
    predictor: &'a dyn Predictor,
    opts: EvalOptions,
    frames: usize,
    dt_frame: f64,
    plans: Vec<StepPlan>,
    totals: SceneErrors,
    scenes: usize,
    objects: usize,
}

impl<'a> Evaluator<'a> {
    fn new(
        predictor: &'a dyn Predictor,
        opts: &EvalOptions,
        frames: usize,
        dt_frame: f64,
    ) -> Result<Self, EvalError> {
        let plans = plan(opts, frames, dt_frame)?;
        let totals = plans
            .iter()
            .map(|p| {
                vec![(RmseAccumulator::default(), RmseAccumulator::default()); p.horizons.len()]
            })
            .collect();
        Ok(Evaluator {
            predictor,
            opts: opts.clone(),
            frames,
            dt_frame,
            plans,
            totals,
            scenes: 0,
            objects: 0,
        })
    }

    /// Evaluates a batch of scenes in parallel and adds them in order.
    fn add(&mut self, scenes: &[SceneRecord]) -> Result<(), EvalError> {
        for (i, s) in scenes.iter().enumerate() {
            if (f64::from(s.dt_frame) - self.dt_frame).abs() > 1e-9 * self.dt_frame.max(1.0) {
                return Err(EvalError::Invalid(format!(
                    "scene {} has dt_frame {} s, the evaluation uses {} s",
                    self.scenes + i,
                    s.dt_frame,
                    self.dt_frame
                )));
            }
        }
        let first = self.scenes;
        let results: Vec<SceneErrors> = scenes
            .par_iter()
            .enumerate()
            .map(|(i, s)| {
                evaluate_scene(
                    self.predictor,
                    s,
                    first + i,
                    self.opts.start_frame,
                    self.frames,
                    &self.plans,
                )
            })
            .collect::<Result<_, _>>()?;
        for (scene, errors) in scenes.iter().zip(results) {
            for (total_row, row) in self.totals.iter_mut().zip(errors) {
                for (t, e) in total_row.iter_mut().zip(row) {
                    t.0.merge(&e.0);
                    t.1.merge(&e.1);
                }
            }
            self.scenes += 1;
            self.objects += scene.objects.len();
        }
        Ok(())
    }

    fn finish(self, dataset: Option<DatasetInfo>, started: Instant) -> EvalReport {
        let step_sizes = self
            .plans
            .iter()
            .zip(&self.totals)
            .map(|(plan, totals)| StepSizeReport {
                dt_steps: plan.k,
                horizons: plan
                    .horizons
                    .iter()
                    .zip(totals)
                    .map(|(h, (trans, rot))| HorizonReport {
                        horizon_s: h.horizon_s,
                        frames: h.frames,
                        steps: h.steps,
                        translation_rmse_m: h.steps.and(trans.rmse()),
                        orientation_rmse_deg: h.steps.and(rot.rmse()),
                        objects: trans.count,
                        missing: h.missing.clone().or_else(|| {
                            (trans.count == 0).then(|| "no scenes evaluated".to_string())
                        }),
                    })
                    .collect(),
            })
            .collect();
        EvalReport {
            predictor: self.predictor.name(),
            dataset,
            scenes: self.scenes,
            objects: self.objects,
            frames: self.frames,
            dt_frame: self.dt_frame,
            start_frame: self.opts.start_frame,
            pooling: POOLING.to_string(),
            step_sizes,
            elapsed_s: started.elapsed().as_secs_f64(),
        }
    }
}

/// Evaluates `predictor` on in-memory scenes (all with the same frame count and `dt_frame`).
pub fn evaluate_scenes(
    predictor: &dyn Predictor,
    scenes: &[SceneRecord],
    opts: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    let started = Instant::now();
    let first = scenes
        .first()
        .ok_or_else(|| EvalError::Invalid("no scenes to evaluate".into()))?;
    let frames = first
        .objects
        .first()
        .map(|o| o.positions.len())
        .ok_or_else(|| EvalError::Invalid("scene 0 has no objects".into()))?;
    let take = opts.max_scenes.unwrap_or(scenes.len()).min(scenes.len());
    let mut ev = Evaluator::new(predictor, opts, frames, f64::from(first.dt_frame))?;
    for chunk in scenes[..take].chunks(BATCH) {
        ev.add(chunk)?;
    }
    Ok(ev.finish(None, started))
}

/// Evaluates `predictor` on a dataset split, streaming it shard by shard; `progress(done)` is
/// called after each batch of scenes with the number of scenes done so far.
pub fn evaluate_dataset(
    predictor: &dyn Predictor,
    reader: &DatasetReader,
    opts: &EvalOptions,
    progress: &dyn Fn(usize),
) -> Result<EvalReport, EvalError> {
    let started = Instant::now();
    let m = reader.manifest();
    let mut ev = Evaluator::new(predictor, opts, m.frames, f64::from(m.dt_frame))?;
    let limit = opts.max_scenes.unwrap_or(usize::MAX).min(reader.len());
    let mut batch = Vec::with_capacity(BATCH);
    for scene in reader.iter() {
        if ev.scenes + batch.len() >= limit {
            break;
        }
        batch.push(scene?);
        if batch.len() == BATCH {
            ev.add(&batch)?;
            batch.clear();
            progress(ev.scenes);
        }
    }
    if !batch.is_empty() {
        ev.add(&batch)?;
        progress(ev.scenes);
    }
    if ev.scenes == 0 {
        return Err(EvalError::Invalid(format!(
            "{} holds no scenes to evaluate",
            reader.dir().display()
        )));
    }
    let info = DatasetInfo {
        dir: reader.dir().display().to_string(),
        generator: m.generator.clone(),
        split: m.split.clone(),
        seed: m.seed,
        gravity: m.gravity,
    };
    Ok(ev.finish(Some(info), started))
}

fn fmt_metric(v: Option<f64>, decimals: usize) -> String {
    match v {
        Some(x) => format!("{x:.decimals$}"),
        None => "-".to_string(),
    }
}

/// The report as a plain-text table: one row per horizon, translation RMSE (m) and
/// orientation RMSE (deg) per step size as columns, missing entries as `-` with the reasons
/// listed below the table.
pub fn format_table(report: &EvalReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let source = match &report.dataset {
        Some(d) => format!(
            "{} ({} split, seed {}, {})",
            d.generator, d.split, d.seed, d.dir
        ),
        None => "in-memory scenes".to_string(),
    };
    let _ = writeln!(s, "predictor: {}   data: {source}", report.predictor);
    let _ = writeln!(
        s,
        "{} scenes, {} objects, {} frames of {:.4} s; observed frames s-k and s = {}; {}",
        report.scenes,
        report.objects,
        report.frames,
        report.dt_frame,
        report.start_frame,
        report.pooling
    );
    let mut header = format!("{:<18}", "horizon");
    for k in &report.step_sizes {
        let _ = write!(
            header,
            " | {:>11} {:>11}",
            format!("k={} trans m", k.dt_steps),
            format!("k={} rot deg", k.dt_steps)
        );
    }
    let _ = writeln!(s, "{header}");
    let _ = writeln!(s, "{}", "-".repeat(header.len()));
    let rows = report
        .step_sizes
        .first()
        .map(|k| k.horizons.len())
        .unwrap_or(0);
    for r in 0..rows {
        let h = &report.step_sizes[0].horizons[r];
        let label = match h.frames {
            Some(f) => format!("{} s ({f} fr)", h.horizon_s),
            None => format!("{} s", h.horizon_s),
        };
        let mut line = format!("{label:<18}");
        for k in &report.step_sizes {
            let e = &k.horizons[r];
            let _ = write!(
                line,
                " | {:>11} {:>11}",
                fmt_metric(e.translation_rmse_m, 4),
                fmt_metric(e.orientation_rmse_deg, 2)
            );
        }
        let _ = writeln!(s, "{line}");
    }
    let mut notes = Vec::new();
    for k in &report.step_sizes {
        for h in &k.horizons {
            if let Some(why) = &h.missing {
                notes.push(format!("  k={} at {} s: {why}", k.dt_steps, h.horizon_s));
            }
        }
    }
    if !notes.is_empty() {
        let _ = writeln!(s, "missing (never shifted to another frame):");
        for n in notes {
            let _ = writeln!(s, "{n}");
        }
    }
    s
}

#[cfg(test)]
pub(crate) mod tests;
