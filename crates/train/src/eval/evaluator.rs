//! The evaluation loop: scenes in batches of [`BATCH`], every predictor's rollouts batched,
//! scenes scored in parallel and merged in scene order, and the report assembled at the end.

use std::time::Instant;

use dynaserve_model::SceneState;
use dynaserve_sim::{DatasetReader, SceneRecord};
use rayon::prelude::*;

use dynaserve_geometry::metrics::RmseAccumulator;

use super::horizon_plan::{HorizonPlan, Plans, plan};
use super::regimes::{ContactFlags, contact_flags};
use super::results::StatAcc;
use super::scoring::{Tally, score_scene};
use super::{
    ContactHistory, ContactSpread, CurvePoint, DatasetInfo, DriftReport, EvalError, EvalOptions,
    EvalReport, HorizonReport, LongRolloutReport, Predictor, RestingReport, RolloutRequest,
    ShapeDrift, StepSizeReport, observed_frames,
};

/// Scenes evaluated per parallel batch when streaming a dataset.
const BATCH: usize = 16;

const POOLING: &str = "RMSE over all objects of all scenes pooled at each horizon \
                       (not a mean of per-scene RMSEs)";

/// Accumulates one predictor's pooled errors over scenes in a fixed order.
struct Evaluator<'a> {
    predictor: &'a dyn Predictor,
    opts: EvalOptions,
    frames: usize,
    dt_frame: f64,
    plans: Plans,
    totals: Tally,
    scenes: usize,
    objects: usize,
    busy: std::time::Duration,
}

/// One horizon's report from its pooled errors (`rmse`: translation m^2, orientation deg^2)
/// and its per-object errors (m, deg) per [`ContactHistory`] (`contact`).
fn horizon_report(
    h: &HorizonPlan,
    rmse: &(RmseAccumulator, RmseAccumulator),
    contact: &[(StatAcc, StatAcc); 3],
) -> HorizonReport {
    let (trans, rot) = rmse;
    let mut all = (StatAcc::default(), StatAcc::default());
    for (t, r) in contact {
        all.0.merge(t);
        all.1.merge(r);
    }
    HorizonReport {
        horizon_s: h.horizon_s,
        frames: h.frames,
        steps: h.steps,
        translation_rmse_m: h.steps.and(trans.rmse()),
        orientation_rmse_deg: h.steps.and(rot.rmse()),
        objects: trans.count,
        translation_m: h.steps.and(all.0.stat_if_any()),
        orientation_deg: h.steps.and(all.1.stat_if_any()),
        by_contact: match h.steps {
            None => Vec::new(),
            Some(_) => ContactHistory::ALL
                .iter()
                .zip(contact)
                .filter_map(|(c, (t, r))| {
                    Some(ContactSpread {
                        contact: *c,
                        translation_rmse_m: t.rms(),
                        orientation_rmse_deg: r.rms(),
                        translation_m: t.stat_if_any()?,
                        orientation_deg: r.stat(),
                    })
                })
                .collect(),
        },
        missing: h
            .missing
            .clone()
            .or_else(|| (trans.count == 0).then(|| "no scenes evaluated".to_string())),
    }
}

impl<'a> Evaluator<'a> {
    fn new(
        predictor: &'a dyn Predictor,
        opts: &EvalOptions,
        frames: usize,
        dt_frame: f64,
    ) -> Result<Self, EvalError> {
        let plans = plan(opts, frames, dt_frame)?;
        Ok(Evaluator {
            predictor,
            opts: opts.clone(),
            frames,
            dt_frame,
            totals: Tally::empty(&plans),
            plans,
            scenes: 0,
            objects: 0,
            busy: std::time::Duration::ZERO,
        })
    }

    /// The ground-truth contact flags of a batch of scenes (checked first), which every
    /// predictor's [`Evaluator::add`] of that batch shares: computed once per scene, not once
    /// per predictor.
    fn contact_flags(&self, scenes: &[SceneRecord]) -> Result<Vec<ContactFlags>, EvalError> {
        self.check(scenes)?;
        scenes
            .par_iter()
            .map(|s| contact_flags(s, self.opts.gravity))
            .collect()
    }

    /// Every scene of the batch has this evaluation's frame count and interval, objects and
    /// reference points.
    fn check(&self, scenes: &[SceneRecord]) -> Result<(), EvalError> {
        for (i, s) in scenes.iter().enumerate() {
            let index = self.scenes + i;
            if (f64::from(s.dt_frame) - self.dt_frame).abs() > 1e-9 * self.dt_frame.max(1.0) {
                return Err(EvalError::Invalid(format!(
                    "scene {index} has dt_frame {} s, the evaluation uses {} s",
                    s.dt_frame, self.dt_frame
                )));
            }
            if s.objects.is_empty() {
                return Err(EvalError::Invalid(format!("scene {index} has no objects")));
            }
            for (j, o) in s.objects.iter().enumerate() {
                if o.positions.len() != self.frames || o.rotations.len() != self.frames {
                    return Err(EvalError::Invalid(format!(
                        "scene {index} object {j} has {} positions and {} rotations, expected \
                         {} frames",
                        o.positions.len(),
                        o.rotations.len(),
                        self.frames
                    )));
                }
                if o.reference_points.is_empty() {
                    return Err(EvalError::Invalid(format!(
                        "scene {index} object {j} has no reference points"
                    )));
                }
            }
        }
        Ok(())
    }

    /// Evaluates a batch of scenes (rollouts batched by the predictor, scoring in parallel)
    /// and adds them in order; `flags[i]` are scene `i`'s contact flags from
    /// [`Evaluator::contact_flags`], which also checked the scenes.
    fn add(&mut self, scenes: &[SceneRecord], flags: &[ContactFlags]) -> Result<(), EvalError> {
        let t0 = Instant::now();
        let start = self.opts.start_frame;
        if flags.len() != scenes.len() {
            return Err(EvalError::Invalid(format!(
                "internal: {} contact flags for {} scenes",
                flags.len(),
                scenes.len()
            )));
        }
        // One request per (scene, step size), plus a k = 1 stability rollout when no step size
        // of 1 is evaluated.
        let has_k1 = self.plans.steps.iter().any(|p| p.k == 1 && p.steps > 0);
        let extra_long = self.plans.long_steps.filter(|_| !has_k1);
        let mut requests = Vec::new();
        for s in scenes {
            for p in &self.plans.steps {
                if p.steps > 0 {
                    requests.push(RolloutRequest {
                        scene: s,
                        observed: observed_frames(s, start, p.k, self.opts.two_frames)?,
                        dt_steps: p.k,
                        steps: p.steps,
                    });
                }
            }
            if let Some(n) = extra_long {
                requests.push(RolloutRequest {
                    scene: s,
                    observed: observed_frames(s, start, 1, self.opts.two_frames)?,
                    dt_steps: 1,
                    steps: n,
                });
            }
        }
        let results = self.predictor.rollout_batch(&requests)?;
        if results.len() != requests.len() {
            return Err(EvalError::Predictor {
                predictor: self.predictor.name(),
                scene: self.scenes,
                message: format!(
                    "answered {} of {} rollout requests",
                    results.len(),
                    requests.len()
                ),
            });
        }
        let mut answers = requests.into_iter().zip(results);
        let mut per_scene = Vec::with_capacity(scenes.len());
        for _ in scenes {
            let mut rollouts = Vec::with_capacity(self.plans.steps.len());
            for p in &self.plans.steps {
                if p.steps > 0 {
                    let (req, out) = answers.next().ok_or_else(|| {
                        EvalError::Invalid("internal: rollout requests out of order".into())
                    })?;
                    rollouts.push((req.observed, out));
                } else {
                    rollouts.push((SceneState::new(Vec::new(), Vec::new()), Vec::new()));
                }
            }
            let long = match extra_long {
                Some(_) => answers.next().map(|(req, out)| (req.observed, out)),
                None => None,
            };
            per_scene.push((rollouts, long));
        }
        let first = self.scenes;
        let long_plan = self
            .plans
            .steps
            .iter()
            .position(|p| p.k == 1 && p.steps > 0);
        let results: Vec<Tally> = scenes
            .par_iter()
            .zip(&per_scene)
            .zip(flags)
            .enumerate()
            .map(|(i, ((s, (rollouts, long)), flags))| {
                let long = match (self.plans.long_steps, long_plan) {
                    (None, _) => None,
                    (Some(_), Some(p)) => Some(&rollouts[p]),
                    (Some(_), None) => long.as_ref(),
                };
                score_scene(
                    self.predictor,
                    s,
                    first + i,
                    start,
                    self.dt_frame,
                    &self.plans,
                    self.opts.projection_every,
                    flags,
                    rollouts,
                    long,
                )
            })
            .collect::<Result<_, _>>()?;
        for (scene, tally) in scenes.iter().zip(&results) {
            self.totals.merge(tally);
            self.scenes += 1;
            self.objects += scene.objects.len();
        }
        self.busy += t0.elapsed();
        Ok(())
    }

    fn finish(self, dataset: Option<DatasetInfo>) -> EvalReport {
        let t = &self.totals;
        let step_sizes = self
            .plans
            .steps
            .iter()
            .zip(t.horizons.iter().zip(&t.curves).zip(&t.horizon_contact))
            .map(|(plan, ((totals, curve), contact))| StepSizeReport {
                dt_steps: plan.k,
                horizons: plan
                    .horizons
                    .iter()
                    .zip(totals.iter().zip(contact))
                    .map(|(h, (rmse, contact))| horizon_report(h, rmse, contact))
                    .collect(),
                curve: curve
                    .iter()
                    .enumerate()
                    .filter_map(|(i, (trans, rot))| {
                        let frames = (i + 1) * plan.k as usize;
                        Some(CurvePoint {
                            time_s: frames as f64 * self.dt_frame,
                            frames,
                            translation_rmse_m: trans.rmse()?,
                            orientation_rmse_deg: rot.rmse()?,
                        })
                    })
                    .collect(),
            })
            .collect();
        let long_rollout = match self.plans.long_steps {
            None => None,
            Some(steps) => Some(LongRolloutReport {
                dt_steps: 1,
                steps,
                objects: t.long_objects,
                failed_objects: t.long_failed_objects,
                failed_scenes: t.long_failed_scenes,
                non_finite_objects: t.long_non_finite,
                max_quaternion_norm_error: t.max_qnorm_error,
                max_pairwise_deviation_m: t.max_pairwise,
                projection_residual_m: t.projection_available.then(|| t.projection.stat()),
                missing: self.plans.long_missing.clone(),
            }),
        };
        let resting = self.plans.rest.as_ref().map(|r| {
            let drift =
                |dt_steps: u32, t: &StatAcc, r: &StatAcc, missing: Option<String>| DriftReport {
                    dt_steps,
                    translation_m: missing.is_none().then(|| t.stat()),
                    rotation_deg: missing.is_none().then(|| r.stat()),
                    missing,
                    by_shape: Vec::new(),
                };
            RestingReport {
                options: r.options.clone(),
                first_frame: r.a,
                last_frame: r.b,
                objects_at_rest: t.at_rest,
                objects: self.objects as u64,
                truth: drift(0, &t.rest_truth.0, &t.rest_truth.1, None),
                predicted: self
                    .plans
                    .steps
                    .iter()
                    .zip(&t.rest_pred)
                    .map(|(p, acc)| {
                        let missing = p.rest_missing.clone();
                        let mut d = drift(p.k, &acc.translation(), &acc.rotation, missing);
                        if d.missing.is_none() {
                            d.by_shape = acc
                                .translation_by_shape
                                .iter()
                                .map(|(&shape_id, a)| ShapeDrift {
                                    shape_id,
                                    shape: String::new(),
                                    translation_m: a.stat(),
                                })
                                .collect();
                        }
                        d
                    })
                    .collect(),
            }
        });
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
            long_rollout,
            resting,
            elapsed_s: self.busy.as_secs_f64(),
        }
    }
}

/// Evaluates `predictor` on in-memory scenes (all with the same frame count and `dt_frame`).
pub fn evaluate_scenes(
    predictor: &dyn Predictor,
    scenes: &[SceneRecord],
    opts: &EvalOptions,
) -> Result<EvalReport, EvalError> {
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
        let flags = ev.contact_flags(chunk)?;
        ev.add(chunk, &flags)?;
    }
    Ok(ev.finish(None))
}

/// Evaluates `predictor` on a dataset split, streaming it shard by shard; `progress(done)` is
/// called after each batch of scenes with the number of scenes done so far.
pub fn evaluate_dataset(
    predictor: &dyn Predictor,
    reader: &DatasetReader,
    opts: &EvalOptions,
    progress: &dyn Fn(usize),
) -> Result<EvalReport, EvalError> {
    let mut reports = evaluate_dataset_many(&[predictor], reader, opts, &|_, done| progress(done))?;
    reports
        .pop()
        .ok_or_else(|| EvalError::Invalid("no report".into()))
}

/// Evaluates several predictors on the same scenes of a dataset split in one streaming pass
/// (each batch of scenes is read once and given to every predictor in turn). Reports are in
/// the order of `predictors`. `progress(predictor, done)` is called after each predictor's
/// batch with the number of scenes that predictor has done.
pub fn evaluate_dataset_many(
    predictors: &[&dyn Predictor],
    reader: &DatasetReader,
    opts: &EvalOptions,
    progress: &dyn Fn(usize, usize),
) -> Result<Vec<EvalReport>, EvalError> {
    if predictors.is_empty() {
        return Err(EvalError::Invalid("no predictor to evaluate".into()));
    }
    let m = reader.manifest();
    let opts = &EvalOptions {
        gravity: m.gravity,
        ..opts.clone()
    };
    let mut evs = predictors
        .iter()
        .map(|p| Evaluator::new(*p, opts, m.frames, f64::from(m.dt_frame)))
        .collect::<Result<Vec<_>, _>>()?;
    let limit = opts.max_scenes.unwrap_or(usize::MAX).min(reader.len());
    let mut batch = Vec::with_capacity(BATCH);
    let mut read = 0;
    let mut flush = |batch: &mut Vec<SceneRecord>| -> Result<(), EvalError> {
        let flags = evs[0].contact_flags(batch)?;
        for (i, ev) in evs.iter_mut().enumerate() {
            ev.add(batch, &flags)?;
            progress(i, ev.scenes);
        }
        batch.clear();
        Ok(())
    };
    for scene in reader.iter() {
        if read >= limit {
            break;
        }
        batch.push(scene?);
        read += 1;
        if batch.len() == BATCH {
            flush(&mut batch)?;
        }
    }
    if !batch.is_empty() {
        flush(&mut batch)?;
    }
    if read == 0 {
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
    Ok(evs
        .into_iter()
        .map(|ev| {
            let mut report = ev.finish(Some(info.clone()));
            // Name the shapes of the per-shape drift from the manifest.
            for d in report.resting.iter_mut().flat_map(|r| &mut r.predicted) {
                for x in &mut d.by_shape {
                    if let Some(shape) = m.shapes.iter().find(|s| s.id == x.shape_id) {
                        x.shape.clone_from(&shape.name);
                    }
                }
            }
            report
        })
        .collect())
}
