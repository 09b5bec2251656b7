//! Rollouts of scenes with kinematic objects (a pusher following a path): the predictor steps
//! every scene one step at a time, and after each step the kinematic objects' predicted poses
//! are replaced by their recorded poses at that frame, so the next step's inputs hold the given
//! poses, as a session's `Step` with actions does on the server.

use dynaserve_model::{Pose, SceneState};
use dynaserve_sim::SceneRecord;

use super::{EvalError, Predictor, RolloutRequest, poses_at};

/// Whether any object of the scene is kinematic.
pub fn has_kinematic(scene: &SceneRecord) -> bool {
    scene.objects.iter().any(|o| o.kinematic)
}

/// Rolls every request forward from frame `starts[i]` (the frame of its `observed.current`),
/// one step of `dt_steps` frames at a time, the kinematic objects driven along their recorded
/// poses (read before the step too by a predictor that [`Predictor::leads_kinematic`]).
/// Entry `i` of the result answers `requests[i]` as [`Predictor::rollout_batch`] does:
/// `[steps][objects]`. A request without kinematic objects is stepped the same way, nothing
/// replaced.
pub fn driven_rollout_batch(
    predictor: &dyn Predictor,
    requests: &[RolloutRequest<'_>],
    starts: &[usize],
) -> Result<Vec<Vec<Vec<Pose>>>, EvalError> {
    if starts.len() != requests.len() {
        return Err(EvalError::Invalid(format!(
            "{} start frames for {} requests",
            starts.len(),
            requests.len()
        )));
    }
    let mut states: Vec<SceneState> = requests.iter().map(|r| r.observed.clone()).collect();
    let mut out: Vec<Vec<Vec<Pose>>> = requests
        .iter()
        .map(|r| Vec::with_capacity(r.steps))
        .collect();
    let most = requests.iter().map(|r| r.steps).max().unwrap_or(0);
    let lead = predictor.leads_kinematic();
    // Per request: its kinematic flags, or `None` when it has no kinematic object.
    let kinematic: Vec<Option<Vec<bool>>> = requests
        .iter()
        .map(|r| {
            has_kinematic(r.scene).then(|| r.scene.objects.iter().map(|o| o.kinematic).collect())
        })
        .collect();
    for step in 0..most {
        let live: Vec<usize> = (0..requests.len())
            .filter(|&i| step < requests[i].steps)
            .collect();
        // The recorded poses after this step of every live request with kinematic objects.
        let given: Vec<Option<Vec<Pose>>> = live
            .iter()
            .map(|&i| {
                let r = &requests[i];
                let frame = starts[i] + (step + 1) * r.dt_steps as usize;
                kinematic[i]
                    .as_ref()
                    .map(|_| poses_at(r.scene, frame))
                    .transpose()
            })
            .collect::<Result<_, EvalError>>()?;
        let batch: Vec<RolloutRequest<'_>> = live
            .iter()
            .zip(&given)
            .map(|(&i, given)| {
                let r = &requests[i];
                let observed = match (&kinematic[i], given) {
                    (Some(flags), Some(next)) if lead => states[i].lead_kinematic(flags, next),
                    _ => states[i].clone(),
                };
                RolloutRequest {
                    scene: r.scene,
                    observed,
                    dt_steps: r.dt_steps,
                    steps: 1,
                }
            })
            .collect();
        let next = predictor.rollout_batch(&batch)?;
        for ((&i, rollout), given) in live.iter().zip(next).zip(given) {
            let mut poses = rollout
                .into_iter()
                .next()
                .ok_or_else(|| EvalError::Predictor {
                    predictor: predictor.name(),
                    scene: i,
                    message: "returned no step".into(),
                })?;
            if let (Some(flags), Some(given)) = (&kinematic[i], given) {
                for ((p, g), &k) in poses.iter_mut().zip(given).zip(flags) {
                    if k {
                        *p = g;
                    }
                }
            }
            states[i].advance(poses.clone());
            out[i].push(poses);
        }
    }
    Ok(out)
}
