//! The closed loop: a stream of client messages, one step each, answered by one frame each as
//! soon as its batch has run. The stream holds its session while it is open; waiting for the
//! client pauses only this stream (the scheduler is told not to wait for it).

use std::sync::Arc;

use dynaserve_api::spec::Frame;
use dynaserve_api::spec::session::{InteractOpen, InteractStep};
use futures::{Stream, StreamExt};
use tokio::sync::mpsc;

use super::super::Engine;
use super::super::request::{Call, RequestCtx, sleep_until};
use super::driven::Driven;
use super::input::{apply_states, check_action, check_target_speeds};
use super::{Session, not_found};
use crate::error::ApiError;
use crate::scheduler::Priority;

/// A started Interact stream: one frame (or one final error) per step message.
pub struct InteractHandle {
    /// The session driven (created for the stream, or named by it).
    pub session_id: String,
    /// Model serving it.
    pub model: String,
    /// Frames in step order; an `Err` ends the stream.
    pub frames: mpsc::Receiver<Result<Frame, ApiError>>,
    /// For a session created for the stream, one line per object parameter outside the
    /// model's trained range; empty otherwise.
    pub warnings: Vec<String>,
}

const CLOSE_MSG: &str = "server shutting down: the drain deadline passed during the stream";
const GONE: &str = "client went away";

impl Engine {
    /// Opens an Interact stream on the session `open` names (or creates for this stream; it is
    /// deleted when the stream ends) and answers every message of `input` with one frame.
    pub async fn interact<S>(
        self: &Arc<Self>,
        open: InteractOpen,
        input: S,
        ctx: RequestCtx,
    ) -> Result<InteractHandle, ApiError>
    where
        S: Stream<Item = Result<InteractStep, ApiError>> + Send + Unpin + 'static,
    {
        let span = tracing::info_span!("interact", request_id = %ctx.request_id);
        let mut call = Call::new(&self.metrics, &ctx, "interact", span);
        let opened = async {
            self.admit_check()?;
            match open {
                InteractOpen::Session(id) => {
                    Ok((self.sessions.get(&id, ctx.identity)?, false, Vec::new()))
                }
                InteractOpen::Create(spec) => {
                    let (s, warnings) = self.create_session_inner(spec, ctx.identity).await?;
                    Ok((s, true, warnings))
                }
            }
            .and_then(|opened| Ok((opened, self.stream_quota(&ctx)?)))
        };
        let ((session, owned, warnings), quota) = call.admit(opened).await?;
        let (tx, rx) = mpsc::channel(self.config.stream_buffer.max(1) + 1);
        let engine = self.clone();
        let handle = InteractHandle {
            session_id: session.id.clone(),
            model: session.entry.name.clone(),
            frames: rx,
            warnings,
        };
        call.spawn(move |call| async move {
            // The caller's stream quota is held until the stream ends.
            let _quota = quota;
            // The slot of the final error, reserved first so that it always fits.
            let last = tx.clone().reserve_owned().await;
            let r = engine.run_interact(&session, input, &ctx, &tx).await;
            if owned {
                engine.sessions.remove(&session.id);
            }
            if let Err(e) = &r
                && let Ok(last) = last
            {
                last.send(Err(e.clone()));
            }
            call.end(r);
        });
        Ok(handle)
    }

    async fn run_interact<S>(
        &self,
        session: &Arc<Session>,
        mut input: S,
        ctx: &RequestCtx,
        tx: &mpsc::Sender<Result<Frame, ApiError>>,
    ) -> Result<(), ApiError>
    where
        S: Stream<Item = Result<InteractStep, ApiError>> + Send + Unpin,
    {
        let mut close = self.close_tx.subscribe();
        let deadline = ctx.deadline;
        let mut progress = tokio::select! {
            g = session.progress.clone().lock_owned() => g,
            _ = tx.closed() => return Err(ApiError::cancelled(GONE)),
            _ = sleep_until(deadline) => return Err(ApiError::deadline("deadline exceeded while another call held the session")),
        };
        let driven_from = |state, step| {
            Driven::new(
                self,
                session,
                state,
                step,
                Priority::Interactive,
                deadline,
                ctx,
            )
        };
        let mut driven = driven_from(progress.state.clone(), progress.step);
        loop {
            // Waiting for the client: the scheduler must not wait for this stream.
            driven.pause();
            let msg = tokio::select! {
                m = input.next() => m,
                _ = tx.closed() => return Err(ApiError::cancelled(GONE)),
                _ = sleep_until(deadline) => return Err(ApiError::deadline("deadline exceeded")),
                _ = close.wait_for(|c| *c) => return Err(ApiError::unavailable(CLOSE_MSG)),
            };
            let Some(msg) = msg else {
                return Ok(());
            };
            // Deleted (or reaped) while the stream held it: it must not be stepped on as a
            // detached copy.
            if session.is_removed() {
                return Err(not_found(&session.id));
            }
            let step: InteractStep = msg?;
            session.touch();
            if !step.correct.is_empty() {
                let mut state = driven.state().clone();
                apply_states(&mut state, &step.correct, session.dt_seconds(), "correct")?;
                driven = driven_from(state, driven.step());
            }
            let targets = check_action(&step.action, &session.kinematic, "action")?;
            check_target_speeds(
                &targets,
                &driven.state().current,
                session.dt_seconds(),
                "action",
            )?;
            let permit = tokio::select! {
                p = tx.reserve() => p.map_err(|_| ApiError::cancelled(GONE))?,
                _ = close.wait_for(|c| *c) => return Err(ApiError::unavailable(CLOSE_MSG)),
            };
            let frame = tokio::select! {
                f = driven.next(&targets, false) => f?,
                _ = tx.closed() => return Err(ApiError::cancelled(GONE)),
                _ = close.wait_for(|c| *c) => return Err(ApiError::unavailable(CLOSE_MSG)),
            };
            progress.state = driven.state().clone();
            progress.step = driven.step();
            session.touch();
            permit.send(Ok(frame));
        }
    }
}
