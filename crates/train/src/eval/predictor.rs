//! What the evaluator rolls forward: the [`Predictor`] trait that baselines and learned models
//! implement, and the requests it answers.

use dynaserve_model::{Pose, SceneState};
use dynaserve_sim::SceneRecord;
use rayon::prelude::*;

use super::EvalError;

/// Anything that can roll a scene forward: baselines and learned world models alike.
///
/// `observed` holds the poses at frames `s - dt_steps` (`previous`) and `s` (`current`); the
/// result is `[steps][objects]`, entry `i` being the poses `(i + 1) * dt_steps` frames after
/// `s`. `scene` gives access to the reference clouds and physical parameters (never to the
/// future frames: predictors must not read `positions`/`rotations` beyond frame `s`, which the
/// evaluator cannot enforce; the baselines and [`ModelPredictor`](super::ModelPredictor) do not read them at all).
pub trait Predictor: Sync {
    /// Name for reports (a baseline name or the model's checkpoint name and input variant).
    fn name(&self) -> String;
    /// Rolls `scene` forward `steps` steps of `dt_steps` frames from `observed`.
    fn rollout(
        &self,
        scene: &SceneRecord,
        observed: &SceneState,
        dt_steps: u32,
        steps: usize,
    ) -> Result<Vec<Vec<Pose>>, EvalError>;

    /// Many independent rollouts; entry `i` of the result answers `requests[i]` exactly as
    /// [`Predictor::rollout`] would. The default runs the requests in parallel one by one;
    /// learned models override it to advance all requests together in batched steps.
    fn rollout_batch(
        &self,
        requests: &[RolloutRequest<'_>],
    ) -> Result<Vec<Vec<Vec<Pose>>>, EvalError> {
        requests
            .par_iter()
            .map(|r| self.rollout(r.scene, &r.observed, r.dt_steps, r.steps))
            .collect()
    }

    /// Whether the predictor reads a kinematic object's coming pose before the step
    /// ([`dynaserve_model::DynamicsConfig::kinematic_lead`]); driven rollouts
    /// ([`super::driven`]) then give it the states with the kinematic objects led. False for
    /// the baselines.
    fn leads_kinematic(&self) -> bool {
        false
    }

    /// Rigidity residual before the projection to a rigid motion, for predictors that have
    /// one: for each window (a state and the predictor's own next poses) and each object, the
    /// root-mean-square distance in metres between the predicted points before projection and
    /// their rigid projection. Result `[windows * objects]`, window-major, or `None` when the
    /// predictor has no such intermediate (the baselines).
    fn projection_residuals(
        &self,
        scene: &SceneRecord,
        windows: &[ProjectionWindow],
    ) -> Result<Option<Vec<f64>>, EvalError> {
        let _ = (scene, windows);
        Ok(None)
    }
}

/// One rollout for [`Predictor::rollout_batch`].
#[derive(Clone, Debug)]
pub struct RolloutRequest<'a> {
    /// The scene (reference clouds and parameters).
    pub scene: &'a SceneRecord,
    /// Poses at frames `s - dt_steps` and `s`.
    pub observed: SceneState,
    /// Step size in frames.
    pub dt_steps: u32,
    /// Number of steps.
    pub steps: usize,
}

/// One step of a rollout for [`Predictor::projection_residuals`]: the input state and the
/// poses the predictor returned from it.
#[derive(Clone, Debug)]
pub struct ProjectionWindow {
    /// The two most recent poses per object.
    pub state: SceneState,
    /// The predicted poses `dt_steps` frames after `state.current`, `[objects]`.
    pub next: Vec<Pose>,
    /// Step size in frames.
    pub dt_steps: u32,
}
