//! What a model family gives the scheduler: its unit of work and the pass that runs many units
//! at once. The queue and the worker loop know nothing else about a model, so another kind of
//! work (a session step, a denoising step at flow time t) joins by implementing [`Family`].

use std::sync::Arc;

use dynaserve_model::{MAX_WORLD_EXTENT, Pose, PreparedScene, SceneState, StepItem, WorldModel};

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
    /// True when [`Family::run`] computes every item as its own forward, so a larger pass
    /// gains nothing: bulk passes then hold one item, and hold the device for one forward.
    fn separate_forwards(&self) -> bool {
        false
    }
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

    /// Items whose state the model would refuse (see `state_problem`) fail alone before
    /// the pass; the others go through one [`WorldModel::step`].
    fn run(&self, items: &[&SceneStep]) -> Result<Vec<Result<Vec<Pose>, String>>, String> {
        let problems: Vec<Option<String>> = items.iter().map(|s| state_problem(&s.state)).collect();
        let usable: Vec<&SceneStep> = items
            .iter()
            .zip(&problems)
            .filter(|(_, p)| p.is_none())
            .map(|(s, _)| *s)
            .collect();
        let mut out = if usable.is_empty() {
            Vec::new().into_iter()
        } else {
            self.step_pass(&usable)?.into_iter()
        };
        Ok(problems
            .into_iter()
            .map(|p| match p {
                Some(msg) => Err(msg),
                None => out
                    .next()
                    .unwrap_or_else(|| Err("model returned too few scenes".to_string())),
            })
            .collect())
    }
}

impl RigidSteps {
    /// One [`WorldModel::step`] over `items` (every state usable); each scene's output is
    /// checked to hold one pose per object.
    fn step_pass(&self, items: &[&SceneStep]) -> Result<Vec<Result<Vec<Pose>, String>>, String> {
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

/// Why a state is outside the model's domain (a pose translation not finite or beyond
/// [`MAX_WORLD_EXTENT`] metres, a rotation that is not a usable quaternion), naming the object;
/// `None` for a usable state. The message holds only this scene's data.
pub fn state_problem(state: &SceneState) -> Option<String> {
    let earlier = state.earlier.as_deref().unwrap_or_default();
    for (which, poses) in [
        ("earlier", earlier),
        ("previous", &state.previous[..]),
        ("current", &state.current[..]),
    ] {
        for (j, p) in poses.iter().enumerate() {
            if !pose_in_domain(p) {
                return Some(format!(
                    "objects[{j}]: {which} pose outside the model's domain (translation {:?} m, \
                     limit {MAX_WORLD_EXTENT} m)",
                    p.translation
                ));
            }
        }
    }
    None
}

/// True when the model accepts `p` (its own check, [`dynaserve_model::normalise_pose`]): a
/// finite translation within [`MAX_WORLD_EXTENT`] metres of the origin on every axis and a
/// usable rotation.
pub fn pose_in_domain(p: &Pose) -> bool {
    dynaserve_model::normalise_pose(p).is_ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(x: f32) -> Pose {
        Pose {
            translation: [x, 0.0, 1.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        }
    }

    #[test]
    fn a_state_outside_the_domain_is_named_by_object_and_pose() {
        let fine = SceneState::new(vec![at(0.0), at(1.0)], vec![at(0.0), at(1.1)]);
        assert_eq!(state_problem(&fine), None);
        let far = 2.0 * MAX_WORLD_EXTENT;
        let mut current = fine.clone();
        current.current[1] = at(far);
        let said = state_problem(&current).unwrap();
        assert!(said.starts_with("objects[1]: current pose"), "{said}");
        let mut earlier = fine.clone();
        earlier.earlier = Some(vec![at(f32::NAN), at(1.0)]);
        let said = state_problem(&earlier).unwrap();
        assert!(said.starts_with("objects[0]: earlier pose"), "{said}");
        earlier.earlier = Some(vec![at(0.0), at(0.9)]);
        assert_eq!(state_problem(&earlier), None);
    }
}
