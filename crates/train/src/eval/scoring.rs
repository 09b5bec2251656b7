//! Scoring of one scene: its rollouts against the ground truth at every step and horizon, the
//! resting drift, and the stability and rigidity checks of the long rollout, tallied so that
//! scenes can be merged in a fixed order.

use std::collections::BTreeMap;

use dynaserve_geometry::geodesic_angle;
use dynaserve_geometry::metrics::{RmseAccumulator, squared_distance};
use dynaserve_model::{Pose, SceneState};
use dynaserve_sim::SceneRecord;
use nalgebra::{Quaternion, Vector3};

use super::horizon_plan::{Plans, RestPlan, StepPlan};
use super::regimes::{ContactFlags, touched};
use super::results::{ContactHistory, StatAcc};
use super::{
    EvalError, PAIRWISE_POINTS, Predictor, ProjectionWindow, QUATERNION_NORM_TOLERANCE, poses_at,
};

/// Pooled squared errors, `[step size][horizon or step]` of (translation m^2, orientation
/// deg^2).
pub(super) type ErrorGrid = Vec<Vec<(RmseAccumulator, RmseAccumulator)>>;

/// A predictor's drift over the resting window at one step size: translation (m) per
/// `shape_id` (all objects together is their union) and rotation (deg).
#[derive(Clone, Debug, Default)]
pub(super) struct PredictedDrift {
    pub(super) translation_by_shape: BTreeMap<i32, StatAcc>,
    pub(super) rotation: StatAcc,
}

impl PredictedDrift {
    /// The translation drift of every resting object.
    pub(super) fn translation(&self) -> StatAcc {
        let mut all = StatAcc::default();
        for acc in self.translation_by_shape.values() {
            all.merge(acc);
        }
        all
    }
}

/// Everything one predictor contributes for one scene (or, merged, for all scenes so far).
#[derive(Clone, Debug, Default)]
pub(super) struct Tally {
    pub(super) horizons: ErrorGrid,
    /// Per-object errors at every horizon by what the object touched, `[step size][horizon]
    /// [ContactHistory::index]` of (translation m, orientation deg).
    pub(super) horizon_contact: Vec<Vec<[(StatAcc, StatAcc); 3]>>,
    pub(super) curves: ErrorGrid,
    /// Ground-truth drift of the resting objects: (translation m, rotation deg).
    pub(super) rest_truth: (StatAcc, StatAcc),
    /// Predicted drift per step size.
    pub(super) rest_pred: Vec<PredictedDrift>,
    pub(super) at_rest: u64,
    pub(super) long_objects: u64,
    pub(super) long_failed_objects: u64,
    pub(super) long_failed_scenes: u64,
    pub(super) long_non_finite: u64,
    pub(super) max_qnorm_error: f64,
    pub(super) max_pairwise: f64,
    pub(super) projection: StatAcc,
    pub(super) projection_available: bool,
}

impl Tally {
    pub(super) fn empty(plans: &Plans) -> Tally {
        let grid = |n: &dyn Fn(&StepPlan) -> usize| -> ErrorGrid {
            plans
                .steps
                .iter()
                .map(|p| vec![(RmseAccumulator::default(), RmseAccumulator::default()); n(p)])
                .collect()
        };
        Tally {
            horizons: grid(&|p| p.horizons.len()),
            horizon_contact: plans
                .steps
                .iter()
                .map(|p| vec![Default::default(); p.horizons.len()])
                .collect(),
            curves: grid(&|p| p.curve_steps),
            rest_pred: vec![Default::default(); plans.steps.len()],
            ..Tally::default()
        }
    }

    pub(super) fn merge(&mut self, o: &Tally) {
        for (a, b) in [
            (&mut self.horizons, &o.horizons),
            (&mut self.curves, &o.curves),
        ] {
            for (ra, rb) in a.iter_mut().zip(b) {
                for (x, y) in ra.iter_mut().zip(rb) {
                    x.0.merge(&y.0);
                    x.1.merge(&y.1);
                }
            }
        }
        for (ra, rb) in self.horizon_contact.iter_mut().zip(&o.horizon_contact) {
            for (xa, xb) in ra.iter_mut().zip(rb) {
                for (x, y) in xa.iter_mut().zip(xb) {
                    x.0.merge(&y.0);
                    x.1.merge(&y.1);
                }
            }
        }
        self.rest_truth.0.merge(&o.rest_truth.0);
        self.rest_truth.1.merge(&o.rest_truth.1);
        for (x, y) in self.rest_pred.iter_mut().zip(&o.rest_pred) {
            for (id, acc) in &y.translation_by_shape {
                x.translation_by_shape.entry(*id).or_default().merge(acc);
            }
            x.rotation.merge(&y.rotation);
        }
        self.at_rest += o.at_rest;
        self.long_objects += o.long_objects;
        self.long_failed_objects += o.long_failed_objects;
        self.long_failed_scenes += o.long_failed_scenes;
        self.long_non_finite += o.long_non_finite;
        self.max_qnorm_error = self.max_qnorm_error.max(o.max_qnorm_error);
        self.max_pairwise = self.max_pairwise.max(o.max_pairwise);
        self.projection.merge(&o.projection);
        self.projection_available |= o.projection_available;
    }
}

/// What object `j` of `scene` touched in the ground truth over frames `from..=to` (the
/// regime table's tests, [`touched`]).
fn history(
    scene: &SceneRecord,
    flags: &ContactFlags,
    j: usize,
    from: usize,
    to: usize,
) -> ContactHistory {
    match touched(scene, flags, j, from..=to) {
        (true, _) => ContactHistory::Object,
        (false, true) => ContactHistory::FloorOnly,
        (false, false) => ContactHistory::None,
    }
}

fn translation_distance(a: &Pose, b: &Pose) -> f64 {
    squared_distance(&a.translation, &b.translation).sqrt()
}

/// `q x q*` with the raw (possibly non-unit) quaternion `q = [x, y, z, w]`, plus `p`.
fn raw_transform(pose: &Pose, x: [f32; 3]) -> Vector3<f64> {
    let [qx, qy, qz, qw] = pose.rotation.map(f64::from);
    let q = Quaternion::new(qw, qx, qy, qz);
    let v = Quaternion::from_imag(Vector3::new(
        f64::from(x[0]),
        f64::from(x[1]),
        f64::from(x[2]),
    ));
    (q * v * q.conjugate()).imag() + Vector3::from(pose.translation.map(f64::from))
}

fn pose_is_finite(p: &Pose) -> bool {
    p.translation
        .iter()
        .chain(&p.rotation)
        .all(|v| v.is_finite())
}

pub(super) fn quaternion_norm_error(p: &Pose) -> f64 {
    (p.rotation
        .iter()
        .map(|v| f64::from(*v).powi(2))
        .sum::<f64>()
        .sqrt()
        - 1.0)
        .abs()
}

/// At rest over the plan's window `a..=b` ([`super::RestingOptions::at_rest`]).
fn is_at_rest(o: &dynaserve_sim::ObjectRecord, r: &RestPlan, dt: f64) -> bool {
    r.options.at_rest(o, r.a, r.b, dt)
}

/// Poses of frame `s + step * k` from a rollout (`step = 0` is the observed frame).
fn rollout_pose<'a>(observed: &'a SceneState, rollout: &'a [Vec<Pose>], step: usize) -> &'a [Pose] {
    if step == 0 {
        &observed.current
    } else {
        &rollout[step - 1]
    }
}

/// Scores one scene's rollouts (`rollouts[p]` answers `plans.steps[p]`, `long` is the `k = 1`
/// rollout of the stability check; `flags` are the scene's ground-truth contacts).
#[allow(clippy::too_many_arguments)]
pub(super) fn score_scene(
    predictor: &dyn Predictor,
    scene: &SceneRecord,
    scene_index: usize,
    start: usize,
    dt_frame: f64,
    plans: &Plans,
    projection_every: usize,
    flags: &ContactFlags,
    rollouts: &[(SceneState, Vec<Vec<Pose>>)],
    long: Option<&(SceneState, Vec<Vec<Pose>>)>,
) -> Result<Tally, EvalError> {
    let bad = |message: String| EvalError::Predictor {
        predictor: predictor.name(),
        scene: scene_index,
        message,
    };
    let n = scene.objects.len();
    let mut tally = Tally::empty(plans);
    for (pi, (plan, (observed, rollout))) in plans.steps.iter().zip(rollouts).enumerate() {
        if rollout.len() != plan.steps {
            return Err(bad(format!(
                "returned {} steps, expected {} (k = {})",
                rollout.len(),
                plan.steps,
                plan.k
            )));
        }
        for (i, poses) in rollout.iter().enumerate() {
            if poses.len() != n {
                return Err(bad(format!(
                    "returned {} poses at step {} (k = {}), the scene has {n} objects",
                    poses.len(),
                    i + 1,
                    plan.k
                )));
            }
        }
        // Every step inside the data: the curve; the horizons are a subset of it.
        let mut step_errors = Vec::with_capacity(plan.curve_steps);
        for i in 1..=plan.curve_steps {
            let truth = poses_at(scene, start + i * plan.k as usize)?;
            let mut acc = (RmseAccumulator::default(), RmseAccumulator::default());
            let horizon = plan.horizons.iter().position(|h| h.steps == Some(i));
            let frame = start + i * plan.k as usize;
            for (j, (p, t)) in rollout[i - 1].iter().zip(&truth).enumerate() {
                let d2 = squared_distance(&p.translation, &t.translation);
                let theta = geodesic_angle(p.rotation, t.rotation);
                if !d2.is_finite() || !theta.is_finite() {
                    return Err(bad(format!(
                        "non-finite pose for object {j} at step {i} (k = {}): {p:?}",
                        plan.k
                    )));
                }
                acc.0.add_squared(d2);
                acc.1.add(theta.to_degrees());
                if let Some(h) = horizon {
                    let c = history(scene, flags, j, start, frame).index();
                    let (t, r) = &mut tally.horizon_contact[pi][h][c];
                    t.add(d2.sqrt());
                    r.add(theta.to_degrees());
                }
            }
            step_errors.push(acc);
        }
        for (h, acc) in plan.horizons.iter().zip(tally.horizons[pi].iter_mut()) {
            if let Some(steps) = h.steps {
                *acc = step_errors[steps - 1];
            }
        }
        tally.curves[pi] = step_errors;
        if let (Some(r), None) = (&plans.rest, &plan.rest_missing) {
            let ku = plan.k as usize;
            let pa = rollout_pose(observed, rollout, (r.a - start) / ku);
            let pb = rollout_pose(observed, rollout, (r.b - start) / ku);
            for (j, o) in scene.objects.iter().enumerate() {
                if is_at_rest(o, r, dt_frame) {
                    let acc = &mut tally.rest_pred[pi];
                    acc.translation_by_shape
                        .entry(o.shape_id)
                        .or_default()
                        .add(translation_distance(&pa[j], &pb[j]));
                    acc.rotation
                        .add(geodesic_angle(pa[j].rotation, pb[j].rotation).to_degrees());
                }
            }
        }
    }
    if let Some(r) = &plans.rest {
        for o in &scene.objects {
            if is_at_rest(o, r, dt_frame) {
                tally.at_rest += 1;
                tally
                    .rest_truth
                    .0
                    .add(squared_distance(&o.positions[r.a], &o.positions[r.b]).sqrt());
                tally
                    .rest_truth
                    .1
                    .add(geodesic_angle(o.rotations[r.a], o.rotations[r.b]).to_degrees());
            }
        }
    }
    if let (Some(long_steps), Some((observed, rollout))) = (plans.long_steps, long) {
        if rollout.len() < long_steps || rollout.iter().any(|p| p.len() != n) {
            return Err(bad(format!(
                "returned {} steps for the {long_steps}-step stability rollout",
                rollout.len()
            )));
        }
        let rollout = &rollout[..long_steps];
        let mut scene_failed = false;
        for (j, o) in scene.objects.iter().enumerate() {
            let pts = &o.reference_points[..o.reference_points.len().min(PAIRWISE_POINTS)];
            let mut non_finite = false;
            let mut failed = false;
            for poses in rollout {
                let p = &poses[j];
                if !pose_is_finite(p) {
                    non_finite = true;
                    failed = true;
                    continue;
                }
                let qe = quaternion_norm_error(p);
                tally.max_qnorm_error = tally.max_qnorm_error.max(qe);
                failed |= qe > QUATERNION_NORM_TOLERANCE;
                let world: Vec<Vector3<f64>> = pts.iter().map(|x| raw_transform(p, *x)).collect();
                for a in 0..pts.len() {
                    for b in a + 1..pts.len() {
                        let reference = squared_distance(&pts[a], &pts[b]).sqrt();
                        let dev = ((world[a] - world[b]).norm() - reference).abs();
                        tally.max_pairwise = tally.max_pairwise.max(dev);
                    }
                }
            }
            tally.long_objects += 1;
            tally.long_failed_objects += u64::from(failed);
            tally.long_non_finite += u64::from(non_finite);
            scene_failed |= failed;
        }
        tally.long_failed_scenes += u64::from(scene_failed);
        if projection_every > 0 && !scene_failed {
            let windows: Vec<ProjectionWindow> = (0..long_steps)
                .step_by(projection_every)
                .map(|i| ProjectionWindow {
                    state: SceneState::new(
                        match i {
                            0 => observed.previous.clone(),
                            _ => rollout_pose(observed, rollout, i - 1).to_vec(),
                        },
                        rollout_pose(observed, rollout, i).to_vec(),
                    ),
                    next: rollout[i].clone(),
                    dt_steps: 1,
                })
                .collect();
            if let Some(residuals) = predictor.projection_residuals(scene, &windows)? {
                tally.projection_available = true;
                for r in residuals {
                    tally.projection.add(r);
                }
            }
        }
    }
    Ok(tally)
}
