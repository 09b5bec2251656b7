//! What a model family gives the scheduler: its unit of work and the pass that runs many units
//! at once. The queue and the worker loop know nothing else about a model, so another kind of
//! work (a session step, a denoising step at flow time t) joins by implementing [`Family`].

use std::sync::Arc;

use dynaserve_model::PathGradient;

use crate::error::ApiError;
use crate::families::contract::{GradientJob, SceneStep, Stepped, SteppingModel};

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
    #[allow(clippy::type_complexity)]
    fn run(&self, items: &[&Self::Item]) -> Result<Vec<Result<Self::Output, String>>, String>;
    /// True when [`Family::run`] computes every item as its own forward, so a larger pass
    /// gains nothing: bulk passes then hold one item, and hold the device for one forward.
    fn separate_forwards(&self) -> bool {
        false
    }
    /// Objects of one network forward when [`Family::run`] splits a pass into forwards of
    /// that size: the scheduler then sizes its passes in whole forwards.
    fn forward_objects(&self) -> Option<usize> {
        None
    }
    /// True when every item of the family is bulk work (gradient calls): no interactive item
    /// of this scheduler can wait behind its passes, so they may take the whole pass budget
    /// (the device gate still shares the device with other schedulers' interactive work).
    fn only_bulk(&self) -> bool {
        false
    }
}

/// Stepping models ([`SteppingModel`]): items are [`SceneStep`]s costing their object count;
/// a pass is one [`SteppingModel::step`] and yields the new pose of every object.
pub struct Steps {
    model: Arc<dyn SteppingModel>,
}

impl Steps {
    /// The family of `model`.
    pub fn new(model: Arc<dyn SteppingModel>) -> Steps {
        Steps { model }
    }

    /// The model.
    pub fn model(&self) -> &Arc<dyn SteppingModel> {
        &self.model
    }
}

impl Family for Steps {
    type Item = SceneStep;
    type Output = Stepped;

    fn name(&self) -> &str {
        self.model.name()
    }

    fn cost(&self, item: &SceneStep) -> usize {
        item.scene.len()
    }

    fn run(&self, items: &[&SceneStep]) -> Result<Vec<Result<Stepped, String>>, String> {
        self.model.step(items)
    }

    fn forward_objects(&self) -> Option<usize> {
        self.model.forward_objects()
    }
}

/// Gradient calls of a stepping model ([`SteppingModel::gradients`]): an item is one call's
/// [`GradientJob`], costing its work (candidates x steps); a pass is one `gradients` call over
/// every job in it. Every job is bulk work. Its scheduler is named `{model}/gradients` in logs
/// and metric labels, where a "scene" is one call and an "object" one candidate-step.
pub struct Gradients {
    model: Arc<dyn SteppingModel>,
    name: String,
}

impl Gradients {
    /// The gradient family of `model`.
    pub fn new(model: Arc<dyn SteppingModel>) -> Gradients {
        let name = format!("{}/gradients", model.name());
        Gradients { model, name }
    }
}

impl Family for Gradients {
    type Item = GradientJob;
    /// A call's own failure (a passed deadline, a model that computes no gradients) keeps its
    /// API error.
    type Output = Result<Vec<PathGradient>, ApiError>;

    fn name(&self) -> &str {
        &self.name
    }

    fn cost(&self, item: &GradientJob) -> usize {
        item.work()
    }

    /// A failed pass of one call is that call's failure, and a refusal of the model as a whole
    /// (FAILED_PRECONDITION) every call's; any other failure of a shared pass fails the pass,
    /// so that the worker runs each call again alone and only the one at fault fails.
    fn run(&self, items: &[&GradientJob]) -> Result<Vec<Result<Self::Output, String>>, String> {
        match self.model.gradients(items) {
            Ok(out) => Ok(out.into_iter().map(|g| Ok(Ok(g))).collect()),
            Err(e) if items.len() == 1 || e.code == tonic::Code::FailedPrecondition => {
                Ok(items.iter().map(|_| Ok(Err(e.clone()))).collect())
            }
            Err(e) => Err(e.message),
        }
    }

    fn only_bulk(&self) -> bool {
        true
    }
}
