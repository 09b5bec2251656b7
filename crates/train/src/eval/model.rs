//! Learned world models as evaluation predictors: [`ModelPredictor`] wraps any
//! [`WorldModel`] (RigidFormer or later ones) so it runs through the same evaluation path as
//! the baselines.

use std::sync::Arc;

use dynaserve_model::{ObjectInput, Pose, SceneState, WorldModel};
use dynaserve_sim::SceneRecord;

use super::{EvalError, Predictor};

/// A [`WorldModel`] as a [`Predictor`]: prepares the scene from its reference clouds and
/// physical parameters, then calls [`dynaserve_model::rollout`] (one scene per step call).
#[derive(Clone)]
pub struct ModelPredictor {
    model: Arc<dyn WorldModel>,
    points_per_object: Option<usize>,
}

impl ModelPredictor {
    /// Wraps a loaded model; every reference point of the data is passed to it.
    pub fn new(model: Arc<dyn WorldModel>) -> ModelPredictor {
        ModelPredictor {
            model,
            points_per_object: None,
        }
    }

    /// Passes only the first `n` reference points of each object (the stored clouds are
    /// i.i.d. area-weighted surface samples, so a prefix is an unbiased subsample). Useful to
    /// evaluate at the point count a model was trained with.
    pub fn with_points_per_object(mut self, n: usize) -> ModelPredictor {
        self.points_per_object = Some(n.max(1));
        self
    }

    /// The wrapped model.
    pub fn model(&self) -> &Arc<dyn WorldModel> {
        &self.model
    }
}

impl Predictor for ModelPredictor {
    fn name(&self) -> String {
        self.model.name().to_string()
    }

    fn rollout(
        &self,
        scene: &SceneRecord,
        observed: &SceneState,
        dt_steps: u32,
        steps: usize,
    ) -> Result<Vec<Vec<Pose>>, EvalError> {
        let model_dt = f64::from(self.model.config().dt_frame);
        let data_dt = f64::from(scene.dt_frame);
        if (model_dt - data_dt).abs() > 1e-6 * data_dt {
            return Err(EvalError::Invalid(format!(
                "model {} steps in frames of {model_dt} s but the data has frames of {data_dt} s",
                self.model.name()
            )));
        }
        let objects = scene
            .objects
            .iter()
            .map(|o| {
                let n = self
                    .points_per_object
                    .unwrap_or(o.reference_points.len())
                    .min(o.reference_points.len());
                ObjectInput {
                    reference: o.reference_points[..n].to_vec(),
                    mass: o.mass,
                    friction: o.friction,
                    restitution: o.restitution,
                }
            })
            .collect();
        let prepared = self.model.prepare(objects)?;
        Ok(dynaserve_model::rollout(
            self.model.as_ref(),
            &prepared,
            observed.clone(),
            dt_steps,
            steps,
            |_, _| {},
        )?)
    }
}
