//! Pushforward samples: the current pose of a sample replaced by the model's own one-step
//! prediction, so that training sees the inputs a rollout gives the model
//! (`DataConfig::pushforward`, docs/training.md).

use dynaserve_model::{RigidFormer, SceneState, StepItem, WorldModel};

use super::TrainError;
use super::data::Sample;

/// Steps the model (inference, no gradient) for every sample that carries pushforward poses,
/// in one batched pass, and makes its prediction the sample's current pose; kinematic objects
/// keep their recorded pose. Returns how many samples were replaced.
pub fn apply(model: &RigidFormer, samples: &mut [Sample]) -> Result<usize, TrainError> {
    // The recorded poses move out of the samples: they are used once.
    let (chosen, states): (Vec<usize>, Vec<SceneState>) = samples
        .iter_mut()
        .enumerate()
        .filter_map(|(i, s)| {
            let (previous, current) = s.pushforward.take()?;
            Some((i, SceneState { previous, current }))
        })
        .unzip();
    if chosen.is_empty() {
        return Ok(0);
    }
    let items: Vec<StepItem<'_>> = chosen
        .iter()
        .zip(&states)
        .map(|(&i, state)| StepItem {
            scene: &samples[i].scene,
            state,
            dt_steps: samples[i].dt_steps,
        })
        .collect();
    let predicted = model.step(&items)?;
    drop(items);
    for (&i, poses) in chosen.iter().zip(predicted) {
        let s = &mut samples[i];
        for (j, pose) in poses.into_iter().enumerate() {
            if !s.kinematic.get(j).copied().unwrap_or(false) {
                s.state.current[j] = pose;
            }
        }
    }
    Ok(chosen.len())
}
