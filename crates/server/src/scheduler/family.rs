//! What a model family gives the scheduler: its unit of work and the pass that runs many units
//! at once. The queue and the worker loop know nothing else about a model, so another kind of
//! work (a session step, a denoising step at flow time t) joins by implementing [`Family`].

use std::sync::Arc;

use dynaserve_model::{Pose, PreparedScene, SceneState, StepItem, WorldModel};

/// A model family as the scheduler sees it.
pub trait Family: Send + Sync + 'static {
    /// One unit of work (one scene to advance by one step).
    type Item: Send + 'static;
    /// What one unit produces.
    type Output: Send + 'static;

    /// Name for logs and metric labels.
    fn name(&self) -> &str;
    /// Cost of `item` against the pass budget's object count.
    fn cost(&self, item: &Self::Item) -> usize;
    /// One forward pass over `items`: packs them, runs the model once and unpacks one result
    /// per item, in order. `Err` fails the whole pass; an item's own `Err` fails only it.
    fn run(&self, items: &[&Self::Item]) -> Result<Vec<Result<Self::Output, String>>, String>;
}

/// One rigid scene to advance by one step.
#[derive(Clone, Debug)]
pub struct SceneStep {
    /// The prepared scene (shared by every step of a rollout).
    pub scene: Arc<PreparedScene>,
    /// Its two latest poses, `dt_steps` frames apart.
    pub state: SceneState,
    /// Step size in frames.
    pub dt_steps: u32,
}

/// Rigid-body world models ([`WorldModel`]): items are [`SceneStep`]s costing their object
/// count; a pass is one [`WorldModel::step`] and yields the new pose of every object.
pub struct RigidSteps {
    model: Arc<dyn WorldModel>,
}

impl RigidSteps {
    /// The family of `model`.
    pub fn new(model: Arc<dyn WorldModel>) -> RigidSteps {
        RigidSteps { model }
    }

    /// The model.
    pub fn model(&self) -> &Arc<dyn WorldModel> {
        &self.model
    }
}

impl Family for RigidSteps {
    type Item = SceneStep;
    type Output = Vec<Pose>;

    fn name(&self) -> &str {
        self.model.name()
    }

    fn cost(&self, item: &SceneStep) -> usize {
        item.scene.len()
    }

    fn run(&self, items: &[&SceneStep]) -> Result<Vec<Result<Vec<Pose>, String>>, String> {
        let batch: Vec<StepItem<'_>> = items
            .iter()
            .map(|s| StepItem {
                scene: &s.scene,
                state: &s.state,
                dt_steps: s.dt_steps,
            })
            .collect();
        let out = self.model.step(&batch).map_err(|e| e.to_string())?;
        Ok(out
            .into_iter()
            .zip(items)
            .map(|(poses, item)| {
                if poses.len() == item.scene.len() {
                    Ok(poses)
                } else {
                    Err(format!(
                        "model returned {} poses for {} objects",
                        poses.len(),
                        item.scene.len()
                    ))
                }
            })
            .collect())
    }
}
