//! Pushforward samples: the observed poses of a sample replaced by the model's own
//! predictions, so that training sees the inputs a rollout gives the model
//! (`DataConfig::pushforward` and `pushforward_steps`, docs/training.md).

use dynaserve_model::{Drive, Pose, RigidFormer, SceneState, StepItem, WorldModel, frame_targets};

use super::TrainError;
use super::data::Sample;

/// Steps the model (inference, no gradient) for every sample that carries pushforward poses,
/// all such samples in one batched pass per step, and makes its predictions the sample's
/// observed poses: after one step the current pose, after two both (the previous one is then
/// the first step's prediction). Each step is a [`Drive`] to the recorded frame after it, the
/// rule serving and driven evaluation follow too: kinematic objects keep their recorded poses
/// at every step (and a `kinematic_lead` model reads them before the step).
/// The first step has no earlier poses (as a rollout's first step from two poses); after two
/// steps a sample that carries earlier poses gets the recorded ones before its new previous.
/// Returns how many samples were replaced.
pub fn apply(model: &RigidFormer, samples: &mut [Sample]) -> Result<usize, TrainError> {
    // The recorded poses move out of the samples: they are used once.
    let (chosen, recorded): (Vec<usize>, Vec<Vec<Vec<Pose>>>) = samples
        .iter_mut()
        .enumerate()
        .filter_map(|(i, s)| Some((i, s.pushforward.take()?)))
        .filter(|(_, r)| r.len() >= 2)
        .unzip();
    if chosen.is_empty() {
        return Ok(0);
    }
    let steps = recorded.iter().map(|r| r.len() - 1).max().unwrap_or(1);
    let lead = model.config().dynamics.kinematic_lead;
    // Per chosen sample: the state the next step starts from, and its first predicted frame.
    let mut states: Vec<SceneState> = recorded
        .iter()
        .map(|r| SceneState::new(r[0].clone(), r[1].clone()))
        .collect();
    for step in 0..steps {
        // Samples with fewer recorded frames than `steps + 1` stop early.
        let active: Vec<usize> = (0..chosen.len())
            .filter(|&c| step < recorded[c].len() - 1)
            .collect();
        // Every kinematic object is driven to its recorded pose after this step: index
        // step + 2 of `recorded`, or the sample's own current frame after the last recorded one.
        let targets: Vec<Vec<(usize, Pose)>> = active
            .iter()
            .map(|&c| {
                let s = &samples[chosen[c]];
                let after = recorded[c].get(step + 2).unwrap_or(&s.state.current);
                frame_targets(&s.kinematic, after)
            })
            .collect();
        let drives: Vec<Drive<'_>> = active
            .iter()
            .zip(&targets)
            .map(|(&c, t)| Drive::new(&samples[chosen[c]].kinematic, t))
            .collect();
        let seen: Vec<SceneState> = active
            .iter()
            .zip(&drives)
            .map(|(&c, drive)| drive.input(&states[c], lead))
            .collect();
        let items: Vec<StepItem<'_>> = active
            .iter()
            .zip(&seen)
            .map(|(&c, state)| StepItem {
                scene: &samples[chosen[c]].scene,
                state,
                dt_steps: samples[chosen[c]].dt_steps,
            })
            .collect();
        let predicted = model.step(&items)?;
        for ((&c, poses), drive) in active.iter().zip(predicted).zip(&drives) {
            drive.finish(&mut states[c], poses);
        }
    }
    for (c, &i) in chosen.iter().enumerate() {
        let s = &mut samples[i];
        let st = &states[c];
        // After one step the previous (and earlier) poses are the recorded (noised) ones: keep
        // the sample's.
        if recorded[c].len() > 2 {
            s.state.previous = st.previous.clone();
            if s.state.earlier.is_some() {
                s.state.earlier = st.earlier.clone();
            }
        }
        s.state.current = st.current.clone();
    }
    Ok(chosen.len())
}
