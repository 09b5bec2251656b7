//! Rollouts of scenes with kinematic objects (a pusher following a path): the predictor steps
//! every scene one step at a time, and after each step the kinematic objects' predicted poses
//! are replaced by their recorded poses at that frame, so the next step's inputs hold the given
//! poses. Each step is a [`Drive`] to the recorded frame, the rule a session's `Step` with
//! actions follows on the server and pushforward training follows too.

use dynaserve_model::{Drive, Pose, SceneState, frame_targets};
use dynaserve_sim::SceneRecord;

use super::{EvalError, Predictor, RolloutRequest, poses_at};

/// Whether any object of the scene is kinematic.
pub fn has_kinematic(scene: &SceneRecord) -> bool {
    scene.objects.iter().any(|o| o.kinematic)
}

/// The recorded poses at `frame` of the objects flagged in `kinematic` (`[objects]`) of
/// `scene`, as a driven step's targets; none for a scene without kinematic objects.
pub fn recorded_targets(
    scene: &SceneRecord,
    kinematic: &[bool],
    frame: usize,
) -> Result<Vec<(usize, Pose)>, EvalError> {
    if !kinematic.contains(&true) {
        return Ok(Vec::new());
    }
    Ok(frame_targets(kinematic, &poses_at(scene, frame)?))
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
    // Per request: its kinematic flags, `[objects]`.
    let kinematic: Vec<Vec<bool>> = requests
        .iter()
        .map(|r| r.scene.objects.iter().map(|o| o.kinematic).collect())
        .collect();
    for step in 0..most {
        let live: Vec<usize> = (0..requests.len())
            .filter(|&i| step < requests[i].steps)
            .collect();
        // The recorded poses after this step of the kinematic objects of every live request
        // (none for a request without kinematic objects).
        let targets: Vec<Vec<(usize, Pose)>> = live
            .iter()
            .map(|&i| {
                let r = &requests[i];
                let frame = starts[i] + (step + 1) * r.dt_steps as usize;
                recorded_targets(r.scene, &kinematic[i], frame)
            })
            .collect::<Result<_, EvalError>>()?;
        let drives: Vec<Drive<'_>> = live
            .iter()
            .zip(&targets)
            .map(|(&i, t)| Drive::new(&kinematic[i], t))
            .collect();
        let batch: Vec<RolloutRequest<'_>> = live
            .iter()
            .zip(&drives)
            .map(|(&i, drive)| {
                let r = &requests[i];
                RolloutRequest {
                    scene: r.scene,
                    observed: drive.input(&states[i], lead),
                    dt_steps: r.dt_steps,
                    steps: 1,
                }
            })
            .collect();
        let next = predictor.rollout_batch(&batch)?;
        for ((&i, rollout), drive) in live.iter().zip(next).zip(&drives) {
            let poses = rollout
                .into_iter()
                .next()
                .ok_or_else(|| EvalError::Predictor {
                    predictor: predictor.name(),
                    scene: i,
                    message: "returned no step".into(),
                })?;
            out[i].push(drive.finish(&mut states[i], poses).to_vec());
        }
    }
    Ok(out)
}
