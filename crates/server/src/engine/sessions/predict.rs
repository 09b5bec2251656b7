//! Predict from a session: every variant starts from the session's current state with its own
//! overrides and action sequence, and steps as its own bulk-priority stream; the session itself
//! does not move. The geometry is the session's (prepared once), so a call carries only the
//! differences between variants.

use std::sync::Arc;

use dynaserve_api::build::check_steps;
use dynaserve_api::session_input::{apply_states, check_actions};
use dynaserve_api::spec::session::SessionPredictSpec;
use dynaserve_api::spec::{Prediction, Timing};
use futures::future::try_join_all;
use tracing::Instrument;

use super::super::Engine;
use super::super::request::{GaugeGuard, RequestCtx, RequestRecord, with_deadline};
use super::driven::Driven;
use crate::error::ApiError;
use crate::scheduler::Priority;

impl Engine {
    /// Validates, admits and runs a Predict call from a session.
    pub async fn session_predict(
        self: &Arc<Self>,
        req: SessionPredictSpec,
        ctx: RequestCtx,
    ) -> Result<Prediction, ApiError> {
        let mut rec = RequestRecord::new(&self.metrics, &ctx, "session_predict");
        let span = tracing::info_span!(
            "session_predict",
            request_id = %ctx.request_id,
            session = %req.session_id,
            variants = req.variants.len()
        );
        match self
            .session_predict_inner(req, &ctx)
            .instrument(span.clone())
            .await
        {
            Ok(r) => {
                rec.finish(None);
                Ok(r)
            }
            Err(e) => Err(span.in_scope(|| rec.fail(e))),
        }
    }

    async fn session_predict_inner(
        self: &Arc<Self>,
        req: SessionPredictSpec,
        ctx: &RequestCtx,
    ) -> Result<Prediction, ApiError> {
        self.admit_check()?;
        let session = self.sessions.get(&req.session_id)?;
        let entry = session.entry.clone();
        check_steps(req.steps, session.dt_steps, &entry.limits)?;
        let n = req.variants.len();
        let max = entry.limits.caps.max_variants;
        if n == 0 || n > max {
            return Err(ApiError::invalid(
                "variants",
                format!("{n} variants given; 1..={max} accepted"),
            ));
        }
        let deadline = ctx.deadline_with(req.timeout_ms);
        // The session's state now; later calls on the session do not affect this one.
        let (base, base_step) = {
            let p = with_deadline(deadline, async { Ok(session.progress.lock().await) }).await?;
            (p.state.clone(), p.step)
        };
        let mut starts = Vec::with_capacity(n);
        for (i, v) in req.variants.iter().enumerate() {
            let mut state = base.clone();
            apply_states(
                &mut state,
                &v.state,
                session.dt_seconds(),
                &format!("variants[{i}].state"),
            )?;
            let targets = check_actions(
                &v.actions,
                req.steps,
                &session.kinematic,
                &format!("variants[{i}].actions"),
            )?;
            starts.push((state, targets));
        }
        let permit = u32::try_from(n)
            .ok()
            .and_then(|k| self.predict_slots.clone().try_acquire_many_owned(k).ok())
            .ok_or_else(|| {
                ApiError::exhausted(
                    format!(
                        "{n} variants would exceed the server's limit of {} in flight; retry later",
                        self.config.max_predict_variants
                    ),
                    self.retry_after(),
                )
            })?;
        let gauge = self
            .metrics
            .active_predict
            .with_label_values(&[entry.name.as_str()]);
        gauge.add(n as i64);
        let _gauge = GaugeGuard(gauge, n as i64);
        let _permit = permit;
        let (every, steps) = (req.every, req.steps);
        let runs = starts.into_iter().map(|(state, targets)| {
            let mut driven = Driven::new(
                self,
                &session,
                state,
                base_step,
                Priority::Bulk,
                deadline,
                ctx.request_id.clone(),
            );
            async move {
                let mut frames = Vec::new();
                let mut timing = Timing::default();
                for (i, t) in targets.iter().enumerate() {
                    let step = i as u32 + 1;
                    let mut frame = driven.next(t, step < steps).await?;
                    if let Some(t) = frame.timing.take() {
                        timing.add_step(&t);
                    }
                    if step == steps || (every > 0 && step.is_multiple_of(every)) {
                        frames.push(frame);
                    }
                }
                Ok::<_, ApiError>((frames, timing))
            }
        });
        let mut close = self.close_tx.subscribe();
        let all = tokio::select! {
            r = with_deadline(deadline, try_join_all(runs)) => r?,
            _ = close.wait_for(|c| *c) => {
                return Err(ApiError::unavailable(
                    "server shutting down: the drain deadline passed before the call finished",
                ));
            }
        };
        let mut timing = Timing::default();
        let mut trajectories = Vec::with_capacity(all.len());
        for (frames, t) in all {
            timing.queue = timing.queue.max(t.queue);
            timing.forward = timing.forward.max(t.forward);
            trajectories.push(frames);
        }
        timing.total = ctx.arrival.elapsed();
        Ok(Prediction {
            model: entry.name.clone(),
            trajectories,
            timing,
        })
    }
}
