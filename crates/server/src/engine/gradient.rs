//! Gradient calls: what the engine checks of their candidates and cost (errors name the field),
//! how a call's job goes through its model's gradient scheduler, and the answer built from the
//! model's output. The session form of the call is `sessions/gradient.rs`.
//!
//! - candidates `1..=max_variants`, each exactly `steps` actions that give every kinematic
//!   object's pose once (no implied speed above the bound, as in Predict);
//! - candidates x steps at most `--max-gradient-work` scene-steps ([`check_gradient_work`]);
//! - cost targets name an object of the scene and a step `1..=steps` (0: the last), with
//!   finite non-negative weights, a finite position and a unit quaternion;
//! - a call is bulk work on its model's gradient scheduler (`crate::scheduler::Gradients`):
//!   the calls queued together run in one pass, the device gate shares the device with the
//!   interactive steps of every model, and a call whose deadline passes while queued is
//!   answered DEADLINE_EXCEEDED without running.

use std::sync::atomic::Ordering;
use std::time::Instant;

use dynaserve_api::FieldError;
use dynaserve_api::limits::Limits;
use dynaserve_api::spec::gradient::{CandidateGradient, GradientCost, Gradients};
use dynaserve_api::spec::session::Action;
use dynaserve_api::spec::{Frame, Timing};
use dynaserve_model::{CostTarget, PathCost, PathGradient, Pose};
use tokio::sync::oneshot;

use super::Engine;
use super::registry::ModelEntry;
use super::request::{RequestCtx, with_deadline};
use super::sessions::input::{Targets, check_action, check_action_speeds};
use super::stepper::step_error;
use crate::error::{ApiError, count};
use crate::families::built_scene::unit_quaternion;
use crate::families::contract::GradientJob;
use crate::scheduler::{Done, Job, Priority};

/// INVALID_ARGUMENT naming `candidates` unless `1..=max_variants` of the model are given.
pub(crate) fn check_candidate_count(limits: &Limits, n: usize) -> Result<(), FieldError> {
    let max = limits.caps.max_variants;
    if n == 0 || n > max {
        return Err(FieldError::new(
            "candidates",
            format!("{n} candidates given; 1..={max} accepted"),
        ));
    }
    Ok(())
}

/// Checks a call's work, `candidates` x `steps` scene-steps, against `--max-gradient-work`;
/// above it, an error naming `candidates` whose message names both factors and the flag.
pub(crate) fn check_gradient_work(
    candidates: usize,
    steps: u32,
    limits: &Limits,
) -> Result<u64, FieldError> {
    let work = (candidates as u64).saturating_mul(u64::from(steps));
    let max = limits.caps.max_gradient_work;
    if work <= max {
        return Ok(work);
    }
    Err(FieldError::new(
        "candidates",
        format!(
            "{} x {} = {work} scene-steps exceeds the server's limit of {max} for one gradient \
             call (--max-gradient-work); lower candidates or steps",
            count(candidates as u64, "candidate", "candidates"),
            count(u64::from(steps), "step", "steps"),
        ),
    ))
}

/// The candidates' paths `[candidates][steps][kinematic objects]` (poses normalised, in object
/// order) from their actions: exactly `steps` per candidate, each giving every kinematic
/// object of `kinematic` (`[objects]`) its pose once, and none implying a speed above the
/// bound from the poses `start` (one per object) `dt_seconds` apart.
pub(crate) fn candidate_paths(
    candidates: &[Vec<Action>],
    steps: u32,
    kinematic: &[bool],
    start: &[Pose],
    dt_seconds: f32,
) -> Result<Vec<Vec<Vec<Pose>>>, FieldError> {
    let driven: Vec<usize> = (0..kinematic.len()).filter(|&j| kinematic[j]).collect();
    if driven.is_empty() {
        return Err(FieldError::new(
            "candidates",
            "the session has no kinematic objects; a gradient is taken with respect to their \
             poses (create the session with `kinematic`)",
        ));
    }
    candidates
        .iter()
        .enumerate()
        .map(|(c, actions)| {
            let field = format!("candidates[{c}].actions");
            if actions.len() != steps as usize {
                return Err(FieldError::new(
                    &field,
                    format!(
                        "{} given for {}; a gradient needs exactly one action per step",
                        count(actions.len() as u64, "action", "actions"),
                        count(u64::from(steps), "step", "steps"),
                    ),
                ));
            }
            let mut targets: Vec<Targets> = Vec::with_capacity(actions.len());
            for (s, a) in actions.iter().enumerate() {
                let f = format!("{field}[{s}]");
                let mut t = check_action(a, kinematic, &f)?;
                if let Some(&missing) = driven.iter().find(|j| !t.iter().any(|(k, _)| k == *j)) {
                    return Err(FieldError::new(
                        format!("{f}.kinematic"),
                        format!(
                            "kinematic object {missing} has no pose; a gradient needs every \
                             kinematic object's pose at every step"
                        ),
                    ));
                }
                t.sort_by_key(|(j, _)| *j);
                targets.push(t);
            }
            check_action_speeds(&targets, start, dt_seconds, &field)?;
            Ok(targets
                .into_iter()
                .map(|t| t.into_iter().map(|(_, p)| p).collect())
                .collect())
        })
        .collect()
}

/// The model's form of a call's cost for a scene of `objects` objects rolled out `steps`
/// steps: step 0 becomes the last step; every field is checked (errors name
/// `cost.targets[i]...` or `cost.smoothness`).
pub(crate) fn path_cost(
    cost: &GradientCost,
    objects: usize,
    steps: u32,
) -> Result<PathCost, FieldError> {
    let weight = |w: f32, field: String| {
        if w.is_finite() && w >= 0.0 {
            Ok(w)
        } else {
            Err(FieldError::new(
                field,
                format!("{w} must be finite and >= 0"),
            ))
        }
    };
    let smoothness = weight(cost.smoothness, "cost.smoothness".into())?;
    let targets = cost
        .targets
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let f = format!("cost.targets[{i}]");
            if t.object as usize >= objects {
                return Err(FieldError::new(
                    format!("{f}.object"),
                    format!(
                        "object {} does not exist (the scene has {objects})",
                        t.object
                    ),
                ));
            }
            if t.step > steps {
                return Err(FieldError::new(
                    format!("{f}.step"),
                    format!("{} is outside 1..={steps} (0 means the last step)", t.step),
                ));
            }
            if t.position.iter().any(|v| !v.is_finite()) {
                return Err(FieldError::new(
                    format!("{f}.position"),
                    "must be finite (NaN or infinity given)",
                ));
            }
            Ok(CostTarget {
                object: t.object as usize,
                step: if t.step == 0 { steps } else { t.step } as usize,
                position: t.position,
                position_weight: weight(t.position_weight, format!("{f}.position_weight"))?,
                rotation: t
                    .rotation
                    .map(|q| unit_quaternion(q, &format!("{f}.rotation")))
                    .transpose()?,
                rotation_weight: weight(t.rotation_weight, format!("{f}.rotation_weight"))?,
            })
        })
        .collect::<Result<_, _>>()?;
    Ok(PathCost {
        targets,
        smoothness,
    })
}

impl Engine {
    /// Queues `job` (bulk work) on `entry`'s gradient scheduler and waits for its pass, at
    /// most until `job.deadline`; the model's output for it, one entry per candidate, with
    /// the pass's timing. FAILED_PRECONDITION when the model computes no gradients;
    /// UNAVAILABLE when the drain deadline passes first.
    pub(crate) async fn run_gradient(
        &self,
        entry: &ModelEntry,
        job: GradientJob,
        ctx: &RequestCtx,
    ) -> Result<Done<Vec<PathGradient>>, ApiError> {
        let Some(scheduler) = entry.gradients.as_ref() else {
            let why = entry.model().gradients_unsupported().unwrap_or_default();
            return Err(ApiError::failed_precondition(why));
        };
        let deadline: Option<Instant> = job.deadline;
        let (reply, rx) = oneshot::channel();
        scheduler.submit(Job {
            item: job,
            priority: Priority::Bulk,
            deadline,
            stream_id: self.next_stream.fetch_add(1, Ordering::Relaxed),
            caller: ctx.caller(),
            more_steps: false,
            request_id: ctx.request_id.clone(),
            reply,
        });
        let answered = async {
            rx.await
                .map_err(|_| ApiError::unavailable("server shutting down"))
        };
        let mut close = self.close_tx.subscribe();
        let done = tokio::select! {
            r = with_deadline(deadline, answered) => r?,
            _ = close.wait_for(|c| *c) => {
                return Err(ApiError::unavailable(
                    "server shutting down: the drain deadline passed before the call finished",
                ));
            }
        };
        let done = done.map_err(step_error)?;
        let output = done.output?;
        Ok(Done {
            output,
            queue_wait: done.queue_wait,
            forward: done.forward,
            batch_scenes: done.batch_scenes,
            batch_id: done.batch_id,
        })
    }
}

/// The answer of a Gradient call from its pass (`done`): per candidate its cost, gradients and
/// the kept frames of its rollout (every `every`-th step and the last; step indices and times
/// from `base_step` steps of `dt_steps` frames). INTERNAL when the model's rollout of a
/// candidate does not hold `steps` steps.
pub(crate) fn answer(
    entry: &ModelEntry,
    done: Done<Vec<PathGradient>>,
    steps: u32,
    every: u32,
    (base_step, dt_steps): (u32, u32),
    ctx: &RequestCtx,
) -> Result<Gradients, ApiError> {
    let candidates = done
        .output
        .into_iter()
        .map(|g| {
            if g.poses.len() != steps as usize || g.translation.len() != steps as usize {
                return Err(ApiError::internal(format!(
                    "model returned a rollout of {} steps and gradients of {} for {steps} steps",
                    g.poses.len(),
                    g.translation.len()
                )));
            }
            let frames = (1..=steps)
                .zip(g.poses)
                .filter(|(s, _)| *s == steps || (every > 0 && s.is_multiple_of(every)))
                .map(|(s, poses)| Frame {
                    step: base_step + s,
                    time: entry.time_at(base_step + s, dt_steps),
                    poses,
                    timing: None,
                    spread: Vec::new(),
                })
                .collect();
            Ok(CandidateGradient {
                cost: g.cost,
                translation: g.translation,
                rotation: g.rotation,
                frames,
            })
        })
        .collect::<Result<_, _>>()?;
    Ok(Gradients {
        model: entry.name.clone(),
        candidates,
        timing: Timing {
            queue: done.queue_wait,
            forward: done.forward,
            total: ctx.arrival.elapsed(),
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::families::built_scene::tests::limits;
    use dynaserve_api::spec::gradient::CostTarget as Target;

    fn at(x: f32) -> Pose {
        Pose {
            translation: [x, 0.0, 0.05],
            rotation: [0.0, 0.0, 0.0, 1.0],
        }
    }

    fn action(poses: &[(u32, f32)]) -> Action {
        Action {
            kinematic: poses.iter().map(|&(j, x)| (j, at(x))).collect(),
        }
    }

    #[test]
    fn candidates_need_every_kinematic_pose_at_every_step_in_object_order() {
        let mask = [false, true, true];
        let start = [at(0.0), at(-0.3), at(0.3)];
        let ok = vec![
            action(&[(2, 0.31), (1, -0.29)]),
            action(&[(1, -0.28), (2, 0.32)]),
        ];
        let paths = candidate_paths(std::slice::from_ref(&ok), 2, &mask, &start, 0.1).unwrap();
        assert_eq!(paths[0][0], vec![at(-0.29), at(0.31)]);
        let e = candidate_paths(&[ok[..1].to_vec()], 2, &mask, &start, 0.1).unwrap_err();
        assert_eq!(e.field, "candidates[0].actions");
        assert!(e.message.starts_with("1 action given for 2 steps"), "{e:?}");
        let short = vec![ok[0].clone(), action(&[(1, -0.28)])];
        let e = candidate_paths(&[ok.clone(), short], 2, &mask, &start, 0.1).unwrap_err();
        assert_eq!(e.field, "candidates[1].actions[1].kinematic");
        assert!(
            e.message.contains("kinematic object 2 has no pose"),
            "{e:?}"
        );
        let e = candidate_paths(&[ok], 2, &[false; 3], &start, 0.1).unwrap_err();
        assert_eq!(e.field, "candidates");
    }

    #[test]
    fn cost_targets_name_their_field_and_step_zero_is_the_last() {
        let t = Target {
            object: 1,
            step: 0,
            position: [0.5, 0.0, 0.1],
            position_weight: 1.0,
            rotation: None,
            rotation_weight: 0.0,
        };
        let cost = |t: Target| GradientCost {
            targets: vec![t],
            smoothness: 0.1,
        };
        assert_eq!(path_cost(&cost(t), 2, 8).unwrap().targets[0].step, 8);
        let field = |t: Target| path_cost(&cost(t), 2, 8).unwrap_err().field;
        assert_eq!(field(Target { object: 2, ..t }), "cost.targets[0].object");
        assert_eq!(field(Target { step: 9, ..t }), "cost.targets[0].step");
        let negative = Target {
            position_weight: -1.0,
            ..t
        };
        assert_eq!(field(negative), "cost.targets[0].position_weight");
        let zero = Target {
            rotation: Some([0.0; 4]),
            ..t
        };
        assert_eq!(field(zero), "cost.targets[0].rotation");
    }

    #[test]
    fn work_names_both_factors_and_the_flag() {
        let l = limits();
        assert_eq!(check_gradient_work(2, 100, &l), Ok(200));
        let e = check_gradient_work(3, 100, &l).unwrap_err();
        assert_eq!(e.field, "candidates");
        assert_eq!(
            e.message,
            "3 candidates x 100 steps = 300 scene-steps exceeds the server's limit of 200 for \
             one gradient call (--max-gradient-work); lower candidates or steps"
        );
        assert_eq!(
            check_candidate_count(&l, 0).unwrap_err().field,
            "candidates"
        );
        assert!(check_candidate_count(&l, 9).is_err());
    }
}
