//! One scene advancing through its model's scheduler, step by step: the only place that submits
//! steps and advances a scene's state. Rollout sessions, Predict variants and warm-up all drive
//! a [`Stepper`].

use std::sync::Arc;
use std::time::Instant;

use dynaserve_api::spec::{Frame, StepTiming};
use dynaserve_model::{MAX_WORLD_EXTENT, Pose, SceneState};
use tokio::sync::oneshot;

use super::registry::ModelEntry;
use crate::error::ApiError;
use crate::families::contract::{KinematicNext, SceneStep, Stepped, SteppedScene, pose_in_domain};
use crate::scheduler::{Done, Job, Priority, StepError};

/// The reply of one submitted step.
pub(crate) type StepReply = oneshot::Receiver<Result<Done<Stepped>, StepError>>;

/// A scene, its state and its place in the scheduler (one stream). Dropping it tells the
/// scheduler not to wait for the stream any more.
pub(crate) struct Stepper {
    entry: Arc<ModelEntry>,
    scene: Arc<dyn SteppedScene>,
    state: SceneState,
    dt_steps: u32,
    priority: Priority,
    deadline: Option<Instant>,
    stream_id: u64,
    caller: u64,
    request_id: Arc<str>,
    /// Steps completed.
    step: u32,
}

/// Where a stepper's scene comes from and how its steps are scheduled.
pub(crate) struct StepperSpec {
    /// The prepared scene.
    pub scene: Arc<dyn SteppedScene>,
    /// Its initial state.
    pub state: SceneState,
    /// Frames per step.
    pub dt_steps: u32,
    /// Scheduling class.
    pub priority: Priority,
    /// Deadline of every step.
    pub deadline: Option<Instant>,
    /// Stream id, unique per engine.
    pub stream_id: u64,
    /// Who asked ([`super::RequestCtx::caller`]).
    pub caller: u64,
    /// Request id for logs.
    pub request_id: Arc<str>,
}

/// The API error of a step that produced nothing.
pub(crate) fn step_error(e: StepError) -> ApiError {
    match e {
        StepError::DeadlineExceeded => ApiError::deadline("deadline exceeded while queued"),
        StepError::Model(m) => ApiError::internal(m),
        StepError::Stopped => ApiError::unavailable("server shutting down"),
    }
}

impl Stepper {
    /// A stepper at step 0.
    pub(crate) fn new(entry: Arc<ModelEntry>, spec: StepperSpec) -> Stepper {
        Stepper {
            entry,
            scene: spec.scene,
            state: spec.state,
            dt_steps: spec.dt_steps,
            priority: spec.priority,
            deadline: spec.deadline,
            stream_id: spec.stream_id,
            caller: spec.caller,
            request_id: spec.request_id,
            step: 0,
        }
    }

    /// The current state (previous and current poses).
    pub(crate) fn state(&self) -> &SceneState {
        &self.state
    }

    /// Queues the next step; `more_steps` says another will follow right after it.
    pub(crate) fn submit(&self, more_steps: bool) -> StepReply {
        self.submit_driven(None, more_steps)
    }

    /// Queues the next step with the kinematic objects' poses after it (`drive`, for a
    /// driven scene); [`Stepper::accept`] advances the stepper's state.
    pub(crate) fn submit_driven(
        &self,
        drive: Option<KinematicNext>,
        more_steps: bool,
    ) -> StepReply {
        let (reply, rx) = oneshot::channel();
        self.entry.scheduler.submit(Job {
            item: SceneStep {
                scene: self.scene.clone(),
                state: self.state.clone(),
                dt_steps: self.dt_steps,
                drive,
            },
            priority: self.priority,
            deadline: self.deadline,
            stream_id: self.stream_id,
            caller: self.caller,
            more_steps,
            request_id: self.request_id.clone(),
            reply,
        });
        rx
    }

    /// Takes a finished step: advances the state and returns the frame (with its timing and
    /// the model's spread, when it estimates one). A
    /// step whose poses leave the model's domain (not finite, or a translation beyond
    /// `MAX_WORLD_EXTENT`) ends the scene with OUT_OF_RANGE naming the object; the state is not
    /// advanced, so no later step runs on it.
    pub(crate) fn accept(&mut self, done: Done<Stepped>) -> Result<Frame, ApiError> {
        let Stepped {
            poses,
            carry,
            spread,
        } = done.output;
        check_domain(&poses, self.step + 1)?;
        self.step += 1;
        tracing::trace!(step = self.step, batch = done.batch_id, "step");
        self.state.advance(poses.clone());
        self.state.carry = carry;
        Ok(Frame {
            step: self.step,
            time: self.entry.time_at(self.step, self.dt_steps),
            poses,
            timing: Some(StepTiming {
                queue: done.queue_wait,
                forward: done.forward,
                batch_scenes: done.batch_scenes,
            }),
            spread: spread.unwrap_or_default(),
        })
    }

    /// Submits the next step, waits for it and accepts it.
    pub(crate) async fn next(&mut self, more_steps: bool) -> Result<Frame, ApiError> {
        match self.submit(more_steps).await {
            Ok(Ok(done)) => self.accept(done),
            Ok(Err(e)) => Err(step_error(e)),
            Err(_) => Err(ApiError::unavailable("server shutting down")),
        }
    }

    /// Tells the scheduler not to wait for this stream's next step (it paused).
    pub(crate) fn pause(&self) {
        self.entry.scheduler.idle(self.stream_id);
    }
}

/// OUT_OF_RANGE naming the first object whose new pose at `step` lies outside the model's
/// domain (a non-finite value, a translation beyond `MAX_WORLD_EXTENT` metres, a degenerate
/// rotation).
pub(crate) fn check_domain(poses: &[Pose], step: u32) -> Result<(), ApiError> {
    match poses.iter().position(|p| !pose_in_domain(p)) {
        None => Ok(()),
        Some(j) => {
            let field = format!("scene.objects[{j}]");
            Err(ApiError {
                code: tonic::Code::OutOfRange,
                message: format!(
                    "{field}: left the model's domain at step {step} (translation {:?} m; \
                     positions must stay finite and within {MAX_WORLD_EXTENT} m)",
                    poses[j].translation
                ),
                field: Some(field),
                retry_after: None,
                http_override: None,
            })
        }
    }
}

impl Drop for Stepper {
    fn drop(&mut self) {
        self.pause();
    }
}
