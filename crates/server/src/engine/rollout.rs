//! Streamed rollouts: admission, then a session task that steps the scene and sends every
//! frame into a bounded channel, so that a slow reader pauses only its own rollout. A reader
//! that takes nothing for `--stream-stall-timeout-s` loses the stream: the session ends with
//! an error (kept in a slot reserved for it, so the client sees it after the buffered frames
//! if it ever reads again) and its rollout slot is freed.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Instant;

use dynaserve_api::spec::{Frame, RolloutSpec};
use tokio::sync::{OwnedSemaphorePermit, mpsc, watch};

use super::Engine;
use super::admission::{check_request_cost, check_steps};
use super::request::{Call, GaugeGuard, RequestCtx, sleep_until};
use super::stepper::{Stepper, StepperSpec, step_error};
use crate::error::ApiError;
use crate::families::built_scene::check_object_count;
use crate::scheduler::Priority;

/// A started rollout: frames (or one final error) arrive on `frames`.
pub struct RolloutHandle {
    /// Model serving the rollout.
    pub model: String,
    /// Request id.
    pub request_id: Arc<str>,
    /// Frames in step order; an `Err` ends the stream.
    pub frames: mpsc::Receiver<Result<Frame, ApiError>>,
    /// One line per object parameter outside the model's trained range (see
    /// [`dynaserve_model::OutOfRange::message`]); empty when all are inside.
    pub warnings: Vec<String>,
}

const DEADLINE_MSG: &str = "deadline exceeded";
const STALL_MSG: &str = "stream ended: the client read no frame for";
const CLOSE_MSG: &str =
    "server shutting down: the drain deadline passed before the rollout finished";

impl Engine {
    /// Validates and admits a rollout, then runs it in a session task. Frames arrive on the
    /// returned channel (bounded: a slow reader pauses the rollout).
    pub async fn start_rollout(
        self: &Arc<Self>,
        req: RolloutSpec,
        ctx: RequestCtx,
    ) -> Result<RolloutHandle, ApiError> {
        let span = tracing::info_span!(
            "rollout",
            request_id = %ctx.request_id,
            protocol = ctx.protocol.as_str(),
            model = tracing::field::Empty
        );
        let mut call = Call::new(&self.metrics, &ctx, "rollout", span);
        let steps = req.steps;
        let prepared = async {
            self.admit_check()?;
            let entry = self.resolve(&req.model)?;
            tracing::Span::current().record("model", entry.name.as_str());
            let dt_steps = check_steps(req.steps, req.dt_steps, &entry.limits)?;
            // The rollout's cost, before the slot is taken or the scene prepared.
            check_object_count(&req.scene, "scene", &entry.limits)?;
            check_request_cost(&[req.scene.objects.len()], req.steps, false, &entry.limits)?;
            let deadline = ctx.deadline_with(req.timeout_ms, self.config.default_timeout());
            let permit = self
                .rollout_slots
                .clone()
                .try_acquire_owned()
                .map_err(|_| {
                    ApiError::exhausted(
                        format!(
                            "{} rollouts are active, the server's limit; retry later",
                            self.config.max_active_rollouts
                        ),
                        self.retry_after(),
                    )
                })?;
            let (scene, state, warnings) = self
                .prepare_one(&entry, req.scene, dt_steps, Arc::from([]))
                .await?;
            let stepper = Stepper::new(
                entry.clone(),
                StepperSpec {
                    scene,
                    state,
                    dt_steps,
                    priority: Priority::Interactive,
                    deadline,
                    stream_id: self.next_stream.fetch_add(1, Ordering::Relaxed),
                    caller: ctx.caller(),
                    request_id: ctx.request_id.clone(),
                },
            );
            Ok::<_, ApiError>((entry, deadline, permit, stepper, warnings))
        };
        let (entry, deadline, permit, stepper, warnings) = call.admit(prepared).await?;
        // One slot more than the buffer, held for the final error.
        let (tx, rx) = mpsc::channel(self.config.stream_buffer + 1);
        let session = Session {
            stepper,
            steps,
            deadline,
            close: self.close_tx.subscribe(),
            stall_timeout: self.config.stream_stall_timeout(),
            stalled: self
                .metrics
                .stalled_streams
                .with_label_values(&[entry.name.as_str()]),
        };
        let gauge = self
            .metrics
            .active_rollouts
            .with_label_values(&[entry.name.as_str()]);
        gauge.inc();
        call.spawn(move |call| async move {
            let _permit: OwnedSemaphorePermit = permit;
            let _gauge = GaugeGuard(gauge, 1);
            let start = Instant::now();
            let r = session.run(tx).await;
            if r.is_ok() {
                tracing::info!(
                    steps,
                    ms = start.elapsed().as_secs_f64() * 1e3,
                    "rollout finished"
                );
            }
            call.end(r);
        });
        Ok(RolloutHandle {
            model: entry.name.clone(),
            request_id: ctx.request_id,
            frames: rx,
            warnings,
        })
    }
}

/// One streamed rollout: steps its scene one step at a time.
struct Session {
    stepper: Stepper,
    steps: u32,
    deadline: Option<Instant>,
    close: watch::Receiver<bool>,
    /// How long the client may read nothing before the stream ends.
    stall_timeout: Option<std::time::Duration>,
    /// `dynaserve_stalled_streams_total` of the model.
    stalled: prometheus::IntCounter,
}

impl Session {
    /// Runs the rollout to its end, a deadline, a drain close or the client's disappearance.
    /// The final error, if any, is also sent to the client.
    async fn run(mut self, tx: mpsc::Sender<Result<Frame, ApiError>>) -> Result<(), ApiError> {
        let mut close = self.close.clone();
        // The slot of the final error: reserved first, so an error reaches even a client whose
        // buffer is full.
        let last = match tx.clone().reserve_owned().await {
            Ok(p) => p,
            Err(_) => return Err(ApiError::cancelled("client went away")),
        };
        let r = self.steps_into(&tx, &mut close).await;
        if let Err(e) = &r {
            last.send(Err(e.clone()));
        }
        r
    }

    async fn steps_into(
        &mut self,
        tx: &mpsc::Sender<Result<Frame, ApiError>>,
        close: &mut watch::Receiver<bool>,
    ) -> Result<(), ApiError> {
        for step in 1..=self.steps {
            // Reserve room for the frame before asking for the step: a client that reads slowly
            // pauses only this rollout, and the scheduler is told not to wait for it meanwhile.
            let permit = match tx.try_reserve() {
                Ok(p) => p,
                Err(mpsc::error::TrySendError::Closed(())) => {
                    return Err(ApiError::cancelled("client went away"));
                }
                Err(mpsc::error::TrySendError::Full(())) => {
                    self.stepper.pause();
                    let stall = self.stall_timeout.map(|t| Instant::now() + t);
                    tokio::select! {
                        p = tx.reserve() => match p {
                            Ok(p) => p,
                            Err(_) => return Err(ApiError::cancelled("client went away")),
                        },
                        _ = sleep_until(self.deadline) => {
                            return Err(ApiError::deadline(DEADLINE_MSG));
                        }
                        _ = sleep_until(stall) => {
                            self.stalled.inc();
                            let t = self.stall_timeout.unwrap_or_default().as_secs_f64();
                            tracing::info!(step, stall_s = t, "client stopped reading; stream ended");
                            return Err(ApiError::cancelled(format!("{STALL_MSG} {t} s")));
                        }
                        _ = close.wait_for(|c| *c) => {
                            return Err(ApiError::unavailable(CLOSE_MSG));
                        }
                    }
                }
            };
            let rx = self.stepper.submit(step < self.steps);
            let outcome = tokio::select! {
                r = rx => match r {
                    Ok(Ok(done)) => Ok(done),
                    Ok(Err(e)) => Err(step_error(e)),
                    Err(_) => Err(ApiError::unavailable("server shutting down")),
                },
                // Dropping `rx` here lets the scheduler discard the queued step.
                _ = tx.closed() => return Err(ApiError::cancelled("client went away")),
                _ = sleep_until(self.deadline) => Err(ApiError::deadline(DEADLINE_MSG)),
                _ = close.wait_for(|c| *c) => Err(ApiError::unavailable(CLOSE_MSG)),
            };
            match outcome {
                Ok(done) => permit.send(Ok(self.stepper.accept(done)?)),
                // The error goes into the reserved slot (`run`).
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }
}
