//! A stepper whose kinematic objects follow given poses, and the session `Step` call.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Instant;

use dynaserve_api::spec::Frame;
use dynaserve_api::spec::session::StepSpec;
use dynaserve_model::{Drive, SceneState};
use tokio::sync::mpsc;

use super::super::Engine;
use super::super::admission::{check_request_cost, check_steps};
use super::super::request::{Call, RequestCtx, sleep_until};
use super::super::stepper::{Stepper, StepperSpec, step_error};
use super::Session;
use super::input::{Targets, check_action_speeds, check_actions};
use crate::error::ApiError;
use crate::families::contract::KinematicNext;
use crate::scheduler::Priority;

/// One stream of steps from a session's state: the model is told the kinematic objects'
/// poses after each step ([`KinematicNext`]; a family reads them as it needs), and its output for
/// those objects is replaced by them before the state advances ([`Drive`]). Frame step
/// indices and times count from `base_step`.
pub(crate) struct Driven {
    stepper: Stepper,
    kinematic: Arc<[bool]>,
    base_step: u32,
    session: Arc<Session>,
}

impl Driven {
    /// A stream of steps from `state`, `base_step` steps after the session's start.
    pub(crate) fn new(
        engine: &Engine,
        session: &Arc<Session>,
        state: SceneState,
        base_step: u32,
        priority: Priority,
        deadline: Option<Instant>,
        ctx: &RequestCtx,
    ) -> Driven {
        let stepper = Stepper::new(
            session.entry.clone(),
            StepperSpec {
                scene: session.scene().clone(),
                state,
                dt_steps: session.dt_steps,
                priority,
                deadline,
                stream_id: engine.next_stream.fetch_add(1, Ordering::Relaxed),
                caller: ctx.caller(),
                request_id: ctx.request_id.clone(),
            },
        );
        Driven {
            stepper,
            kinematic: session.kinematic.clone(),
            base_step,
            session: session.clone(),
        }
    }

    /// The current state.
    pub(crate) fn state(&self) -> &SceneState {
        self.stepper.state()
    }

    /// Steps taken since the session's start.
    pub(crate) fn step(&self) -> u32 {
        self.base_step
    }

    /// Runs one step with the kinematic poses `targets`; `more_steps` says another follows
    /// right after. Cancel-safe: dropped before the reply, the state has not moved.
    pub(crate) async fn next(
        &mut self,
        targets: &Targets,
        more_steps: bool,
    ) -> Result<Frame, ApiError> {
        // The one driven step (`dynaserve_model::Drive`): the kinematic poses after the step go
        // to the family with the step, and replace its outputs for those objects after it.
        let drive = Drive::new(&self.kinematic, targets);
        let reply = self.stepper.submit_driven(
            Some(KinematicNext {
                kinematic: self.kinematic.clone(),
                next: drive.given_poses(self.stepper.state()),
            }),
            more_steps,
        );
        let mut done = match reply.await {
            Ok(Ok(done)) => done,
            Ok(Err(e)) => return Err(step_error(e)),
            Err(_) => return Err(ApiError::unavailable("server shutting down")),
        };
        drive.overwrite(self.stepper.state(), &mut done.output.poses);
        let mut frame = self.stepper.accept(done)?;
        self.base_step += 1;
        frame.step = self.base_step;
        frame.time = self
            .session
            .entry
            .time_at(self.base_step, self.session.dt_steps);
        Ok(frame)
    }

    /// Tells the scheduler not to wait for this stream (waiting for the client).
    pub(crate) fn pause(&self) {
        self.stepper.pause();
    }
}

/// A started `Step` call: frames (or one final error) arrive on `frames`.
pub struct StepHandle {
    /// Model serving the session.
    pub model: String,
    /// Frames in step order; an `Err` ends the stream.
    pub frames: mpsc::Receiver<Result<Frame, ApiError>>,
}

const CLOSE_MSG: &str = "server shutting down: the drain deadline passed before the steps finished";

impl Engine {
    /// Validates a `Step` call, then runs it in a task that holds the session and writes its
    /// state back after every step: a client that goes away or a deadline that passes leaves
    /// the session at its last finished step.
    pub async fn session_step(
        self: &Arc<Self>,
        req: StepSpec,
        ctx: RequestCtx,
    ) -> Result<StepHandle, ApiError> {
        let span = tracing::info_span!(
            "session_step",
            request_id = %ctx.request_id,
            session = %req.session_id,
            steps = req.steps
        );
        let mut call = Call::new(&self.metrics, &ctx, "session_step", span);
        let prepared = async {
            self.admit_check()?;
            let session = self.sessions.get(&req.session_id, ctx.identity)?;
            check_steps(req.steps, session.dt_steps, &session.entry.limits)?;
            check_request_cost(
                &[session.scene().len()],
                req.steps,
                false,
                &session.entry.limits,
            )?;
            let targets = check_actions(&req.actions, req.steps, &session.kinematic, "actions")?;
            let quota = self.stream_quota(&ctx)?;
            Ok::<_, ApiError>((session, targets, quota))
        };
        let (session, targets, quota) = call.admit(prepared).await?;
        let deadline = ctx.deadline_with(req.timeout_ms, self.config.default_timeout());
        // Room for every frame and the final error: the call's own frames are its only backlog,
        // and the error always reaches a client that reads again.
        let (tx, rx) = mpsc::channel(targets.len() + 1);
        let engine = self.clone();
        let model = session.entry.name.clone();
        call.spawn(move |call| async move {
            // The caller's stream quota is held until the steps end.
            let _quota = quota;
            let r = engine.run_steps(session, targets, deadline, ctx, &tx).await;
            if let Err(e) = &r {
                let _ = tx.try_send(Err(e.clone()));
            }
            call.end(r);
        });
        Ok(StepHandle { model, frames: rx })
    }

    async fn run_steps(
        &self,
        session: Arc<Session>,
        targets: Vec<Targets>,
        deadline: Option<Instant>,
        ctx: RequestCtx,
        tx: &mpsc::Sender<Result<Frame, ApiError>>,
    ) -> Result<(), ApiError> {
        let mut close = self.close_tx.subscribe();
        let mut progress = tokio::select! {
            g = session.progress.clone().lock_owned() => g,
            _ = sleep_until(deadline) => return Err(ApiError::deadline("deadline exceeded while another call held the session")),
            _ = tx.closed() => return Err(ApiError::cancelled("client went away")),
        };
        // Kinematic poses may not imply more than the velocity bound, from the session's
        // state as this call found it.
        check_action_speeds(
            &targets,
            &progress.state.current,
            session.dt_seconds(),
            "actions",
        )?;
        let mut driven = Driven::new(
            self,
            &session,
            progress.state.clone(),
            progress.step,
            Priority::Interactive,
            deadline,
            &ctx,
        );
        let n = targets.len();
        for (i, t) in targets.iter().enumerate() {
            let permit = tx
                .try_reserve()
                .map_err(|_| ApiError::cancelled("client went away"))?;
            let frame = tokio::select! {
                f = driven.next(t, i + 1 < n) => f?,
                _ = tx.closed() => return Err(ApiError::cancelled("client went away")),
                _ = sleep_until(deadline) => return Err(ApiError::deadline("deadline exceeded")),
                _ = close.wait_for(|c| *c) => return Err(ApiError::unavailable(CLOSE_MSG)),
            };
            progress.state = driven.state().clone();
            progress.step = driven.step();
            session.touch();
            permit.send(Ok(frame));
        }
        Ok(())
    }
}
