//! Learned world models as evaluation predictors: [`ModelPredictor`] wraps any
//! [`WorldModel`] (RigidFormer or later ones) so it runs through the same evaluation path as
//! the baselines, with a choice of input points per object ([`PointSelection`]) and an
//! optional simulated occlusion ([`Occlusion`]).

use std::sync::Arc;

use dynaserve_model::{
    ObjectInput, Pose, RigidFormer, SceneState, StepItem, TrainItem, WorldModel,
};
use dynaserve_sim::SceneRecord;
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use super::{EvalError, Predictor, ProjectionWindow, RolloutRequest};
use crate::train::data::mix;

/// Which of an object's stored reference points are given to the model. The stored clouds are
/// i.i.d. area-weighted surface samples, so a prefix of the cloud is an unbiased subsample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PointSelection {
    /// The first `points_per_object` points of the model's `config.json` (its nominal count).
    Nominal,
    /// The first `n` points (all of them if the cloud is smaller).
    Count(usize),
    /// Every stored point.
    All,
}

/// A simulated occluded view: after the selection, each object loses the `fraction` of its
/// points that lie farthest along a random direction (the points on one side of a plane, a
/// contiguous patch). The direction is drawn from a generator seeded by `seed` and the
/// object's own reference cloud, so it is the same for an object in every run, whatever the
/// evaluation order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Occlusion {
    /// Fraction of the selected points removed, in `[0, 1)`; at least one point is kept.
    pub fraction: f32,
    /// Seed of the cut directions.
    pub seed: u64,
}

impl Occlusion {
    /// The cut direction for a cloud (unit vector, body frame): drawn from a generator keyed
    /// on `seed` and the cloud's size and first points.
    pub fn direction(&self, points: &[[f32; 3]]) -> Vector3<f32> {
        let mut key = mix(self.seed ^ mix(points.len() as u64));
        for p in points.iter().take(4) {
            for v in p {
                key = mix(key ^ u64::from(v.to_bits()));
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(key);
        loop {
            let u = Vector3::<f32>::from_fn(|_, _| StandardNormal.sample(&mut rng));
            if u.norm() > 1e-3 {
                return u.normalize();
            }
        }
    }

    /// Removes the `round(fraction * n)` points of `points` (body frame, metres) that lie
    /// farthest along [`Occlusion::direction`], keeping the order of the others and at least
    /// one point. Deterministic for a given cloud and seed.
    pub fn apply(&self, points: &mut Vec<[f32; 3]>) {
        let n = points.len();
        if n < 2 {
            return;
        }
        let drop = ((self.fraction.clamp(0.0, 1.0) * n as f32).round() as usize).min(n - 1);
        if drop == 0 {
            return;
        }
        let u = self.direction(points);
        let mut order: Vec<(f32, usize)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (Vector3::from(*p).dot(&u), i))
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut keep = vec![false; n];
        for (_, i) in &order[..n - drop] {
            keep[*i] = true;
        }
        let mut i = 0;
        points.retain(|_| {
            i += 1;
            keep[i - 1]
        });
    }
}

/// A [`WorldModel`] as a [`Predictor`]: prepares the scene from its reference clouds and
/// physical parameters, then rolls it forward. Batches of rollouts advance together, one
/// batched model step per step index, so many scenes share each pass of the network.
#[derive(Clone)]
pub struct ModelPredictor {
    model: Arc<dyn WorldModel>,
    rigidformer: Option<Arc<RigidFormer>>,
    points: PointSelection,
    occlusion: Option<Occlusion>,
}

impl ModelPredictor {
    /// Wraps a loaded model; each object gets the model's nominal number of points
    /// ([`PointSelection::Nominal`]).
    pub fn new(model: Arc<dyn WorldModel>) -> ModelPredictor {
        ModelPredictor {
            model,
            rigidformer: None,
            points: PointSelection::Nominal,
            occlusion: None,
        }
    }

    /// Wraps a RigidFormer; unlike [`ModelPredictor::new`] this also reports the
    /// pre-projection rigidity residual ([`Predictor::projection_residuals`]).
    pub fn from_rigidformer(model: Arc<RigidFormer>) -> ModelPredictor {
        let as_world: Arc<dyn WorldModel> = model.clone();
        ModelPredictor {
            rigidformer: Some(model),
            ..ModelPredictor::new(as_world)
        }
    }

    /// Loads the checkpoint directory `dir` on the CPU: a RigidFormer through
    /// [`ModelPredictor::from_rigidformer`], any other model (an ensemble) through
    /// [`ModelPredictor::new`].
    pub fn load(dir: &std::path::Path) -> Result<ModelPredictor, dynaserve_model::ModelError> {
        ModelPredictor::load_on(dir, &dynaserve_model::Device::Cpu)
    }

    /// [`ModelPredictor::load`] on `device`.
    pub fn load_on(
        dir: &std::path::Path,
        device: &dynaserve_model::Device,
    ) -> Result<ModelPredictor, dynaserve_model::ModelError> {
        if dynaserve_model::read_architecture(dir)? == dynaserve_model::config::RIGIDFORMER {
            let model = dynaserve_model::load_rigidformer(dir, device, false)?;
            return Ok(ModelPredictor::from_rigidformer(Arc::new(model)));
        }
        Ok(ModelPredictor::new(dynaserve_model::load_model(
            dir, device,
        )?))
    }

    /// Passes only the first `n` reference points of each object (at least 1).
    pub fn with_points_per_object(self, n: usize) -> ModelPredictor {
        self.with_points(PointSelection::Count(n.max(1)))
    }

    /// Sets the point selection.
    pub fn with_points(mut self, points: PointSelection) -> ModelPredictor {
        self.points = points;
        self
    }

    /// Removes a contiguous patch of each object's selected points (see [`Occlusion`]).
    pub fn with_occlusion(mut self, occlusion: Occlusion) -> ModelPredictor {
        self.occlusion = Some(occlusion);
        self
    }

    /// The wrapped model.
    pub fn model(&self) -> &Arc<dyn WorldModel> {
        &self.model
    }

    /// Points requested per object before occlusion (`None`: all stored points).
    pub fn points_requested(&self) -> Option<usize> {
        match self.points {
            PointSelection::Nominal => Some(self.model.config().points_per_object.max(1)),
            PointSelection::Count(n) => Some(n),
            PointSelection::All => None,
        }
    }

    /// A short description of the model input, e.g. `512 points, 25% occluded`.
    pub fn input_description(&self) -> String {
        let pts = match self.points_requested() {
            Some(n) => format!("{n} points"),
            None => "all points".to_string(),
        };
        match self.occlusion {
            Some(o) => format!("{pts}, {:.0}% occluded", 100.0 * o.fraction),
            None => pts,
        }
    }

    /// The model inputs of a scene under this predictor's selection and occlusion.
    pub fn inputs(&self, scene: &SceneRecord) -> Vec<ObjectInput> {
        let limit = self.points_requested();
        scene
            .objects
            .iter()
            .map(|o| {
                let n = limit
                    .unwrap_or(o.reference_points.len())
                    .min(o.reference_points.len());
                let mut reference = o.reference_points[..n].to_vec();
                if let Some(occ) = &self.occlusion {
                    occ.apply(&mut reference);
                }
                ObjectInput {
                    reference,
                    mass: o.mass,
                    friction: o.friction,
                    restitution: o.restitution,
                    kinematic: o.kinematic,
                }
            })
            .collect()
    }

    fn check_dt(&self, scene: &SceneRecord) -> Result<(), EvalError> {
        let model_dt = f64::from(self.model.config().dt_frame);
        let data_dt = f64::from(scene.dt_frame);
        if (model_dt - data_dt).abs() > 1e-6 * data_dt {
            return Err(EvalError::Invalid(format!(
                "model {} steps in frames of {model_dt} s but the data has frames of {data_dt} s",
                self.model.name()
            )));
        }
        Ok(())
    }
}

impl Predictor for ModelPredictor {
    fn name(&self) -> String {
        format!("{} ({})", self.model.name(), self.input_description())
    }

    fn rollout(
        &self,
        scene: &SceneRecord,
        observed: &SceneState,
        dt_steps: u32,
        steps: usize,
    ) -> Result<Vec<Vec<Pose>>, EvalError> {
        let mut out = self.rollout_batch(&[RolloutRequest {
            scene,
            observed: observed.clone(),
            dt_steps,
            steps,
        }])?;
        out.pop()
            .ok_or_else(|| EvalError::Invalid("internal: no rollout returned".into()))
    }

    fn leads_kinematic(&self) -> bool {
        self.model.config().dynamics.kinematic_lead
    }

    /// All requests advance together: step `i` of every request that has one is computed in
    /// one [`WorldModel::step`] call (which splits it into passes under its object budget).
    fn rollout_batch(
        &self,
        requests: &[RolloutRequest<'_>],
    ) -> Result<Vec<Vec<Vec<Pose>>>, EvalError> {
        for r in requests {
            self.check_dt(r.scene)?;
        }
        let prepared = requests
            .par_iter()
            .map(|r| self.model.prepare(self.inputs(r.scene)))
            .collect::<Result<Vec<_>, _>>()?;
        let mut states: Vec<SceneState> = requests.iter().map(|r| r.observed.clone()).collect();
        let mut out: Vec<Vec<Vec<Pose>>> = requests
            .iter()
            .map(|r| Vec::with_capacity(r.steps))
            .collect();
        let longest = requests.iter().map(|r| r.steps).max().unwrap_or(0);
        for step in 0..longest {
            let active: Vec<usize> = (0..requests.len())
                .filter(|&i| requests[i].steps > step)
                .collect();
            let items: Vec<StepItem<'_>> = active
                .iter()
                .map(|&i| StepItem {
                    scene: &prepared[i],
                    state: &states[i],
                    dt_steps: requests[i].dt_steps,
                })
                .collect();
            let next = self.model.step(&items)?;
            if next.len() != active.len() {
                return Err(EvalError::Invalid(format!(
                    "model {} answered {} of {} scenes in a step",
                    self.model.name(),
                    next.len(),
                    active.len()
                )));
            }
            for (&i, poses) in active.iter().zip(next) {
                let state = &mut states[i];
                state.advance(poses.clone());
                out[i].push(poses);
            }
        }
        Ok(out)
    }

    /// For RigidFormer: the anchor positions the network predicts before the Kabsch
    /// projection (`2 A_t - A_{t-1} + a`), against their projection `R A_ref + p`; per window
    /// and object, `sqrt(mean_k |A_pre,k - A_post,k|^2)` over the K anchors, metres. Computed
    /// with the training forward pass on the same inputs (same weights; the kernels agree with
    /// inference up to rounding).
    fn projection_residuals(
        &self,
        scene: &SceneRecord,
        windows: &[ProjectionWindow],
    ) -> Result<Option<Vec<f64>>, EvalError> {
        let Some(rf) = &self.rigidformer else {
            return Ok(None);
        };
        self.check_dt(scene)?;
        let prepared = rf.prepare(self.inputs(scene))?;
        let objects = prepared.len().max(1);
        let k = rf.config().anchors;
        let mut out = Vec::with_capacity(windows.len() * objects);
        // Keep each forward pass near the model's inference object budget.
        let per_pass = (dynaserve_model::rigidformer::DEFAULT_MAX_PASS_OBJECTS / objects).max(1);
        for chunk in windows.chunks(per_pass) {
            let items: Vec<TrainItem<'_>> = chunk
                .iter()
                .map(|w| TrainItem {
                    scene: &prepared,
                    state: &w.state,
                    target: &w.next,
                    dt_steps: w.dt_steps,
                    kinematic: &[],
                })
                .collect();
            let forward = rf.train_forward(&items)?;
            let to_vec = |t: &candle_core::Tensor| -> Result<Vec<f32>, EvalError> {
                t.flatten_all()
                    .and_then(|t| t.to_vec1::<f32>())
                    .map_err(|e| EvalError::Model(e.into()))
            };
            let pre = to_vec(&forward.positions_pre)?;
            let post = to_vec(&forward.positions_post)?;
            for (a, b) in pre.chunks(3 * k).zip(post.chunks(3 * k)) {
                let sq: f64 = a
                    .iter()
                    .zip(b)
                    .map(|(x, y)| (f64::from(*x) - f64::from(*y)).powi(2))
                    .sum();
                out.push((sq / k as f64).sqrt());
            }
        }
        Ok(Some(out))
    }
}
