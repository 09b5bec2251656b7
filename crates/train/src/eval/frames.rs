//! Ground-truth poses of a recorded scene and the observed state a rollout starts from.

use dynaserve_model::{Pose, SceneState};
use dynaserve_sim::SceneRecord;

use super::EvalError;

/// The poses of every object at frame `t`.
pub fn poses_at(scene: &SceneRecord, t: usize) -> Result<Vec<Pose>, EvalError> {
    scene
        .objects
        .iter()
        .enumerate()
        .map(|(j, o)| match (o.positions.get(t), o.rotations.get(t)) {
            (Some(p), Some(q)) => Ok(Pose {
                translation: *p,
                rotation: *q,
            }),
            _ => Err(EvalError::Invalid(format!(
                "object {j} has no frame {t} ({} frames)",
                o.positions.len().min(o.rotations.len())
            ))),
        })
        .collect()
}

/// [`observed_state`], with the poses before the last two withheld when `two_frames` (as for a
/// client that sends two poses).
pub fn observed_frames(
    scene: &SceneRecord,
    start: usize,
    k: u32,
    two_frames: bool,
) -> Result<SceneState, EvalError> {
    let mut state = observed_state(scene, start, k)?;
    if two_frames {
        state.earlier = None;
    }
    Ok(state)
}

/// The observed state for step size `k`: poses at frames `start - k` and `start`, and at
/// `start - 2k` when the scene has it (read by models with history inputs only).
pub fn observed_state(scene: &SceneRecord, start: usize, k: u32) -> Result<SceneState, EvalError> {
    let k = k as usize;
    if k == 0 || k > start {
        return Err(EvalError::Invalid(format!(
            "step size {k} needs frame {start} - {k}, which does not exist"
        )));
    }
    Ok(SceneState {
        previous: poses_at(scene, start - k)?,
        current: poses_at(scene, start)?,
        earlier: match start.checked_sub(2 * k) {
            Some(f) => Some(poses_at(scene, f)?),
            None => None,
        },
        carry: Default::default(),
    })
}
