//! Planner calls: every variant of a Predict call steps as its own bulk-priority stream, all
//! joining the same passes; the call answers with the kept frames of every variant.

use std::sync::Arc;
use std::sync::atomic::Ordering;

use dynaserve_api::build::check_steps;
use dynaserve_api::spec::{PredictSpec, Prediction, Timing};
use futures::future::try_join_all;
use tracing::Instrument;

use super::Engine;
use super::registry::prepare_scenes;
use super::request::{GaugeGuard, RequestCtx, RequestRecord, with_deadline};
use super::stepper::{Stepper, StepperSpec};
use crate::error::ApiError;
use crate::scheduler::Priority;

impl Engine {
    /// Validates, admits and runs a Predict call.
    pub async fn predict(
        self: &Arc<Self>,
        req: PredictSpec,
        ctx: RequestCtx,
    ) -> Result<Prediction, ApiError> {
        let mut rec = RequestRecord::new(&self.metrics, &ctx, "predict");
        let span = tracing::info_span!(
            "predict",
            request_id = %ctx.request_id,
            protocol = ctx.protocol.as_str(),
            model = tracing::field::Empty,
            variants = req.variants.len()
        );
        let result = self.predict_inner(req, &ctx).instrument(span.clone()).await;
        span.in_scope(|| match result {
            Ok(r) => {
                rec.finish(None);
                Ok(r)
            }
            Err(e) => Err(rec.fail(e)),
        })
    }

    async fn predict_inner(
        self: &Arc<Self>,
        req: PredictSpec,
        ctx: &RequestCtx,
    ) -> Result<Prediction, ApiError> {
        self.admit_check()?;
        let entry = self.resolve(&req.model)?;
        tracing::Span::current().record("model", entry.name.as_str());
        let dt_steps = check_steps(req.steps, req.dt_steps, &entry.limits)?;
        let n = req.variants.len();
        if n == 0 || n > entry.limits.caps.max_variants {
            return Err(ApiError::invalid(
                "variants",
                format!(
                    "{n} variants given; 1..={} accepted",
                    entry.limits.caps.max_variants
                ),
            ));
        }
        let deadline = ctx.deadline_with(req.timeout_ms);
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
        let variants = with_deadline(
            deadline,
            prepare_scenes(&entry, req.variants, dt_steps, "variants"),
        )
        .await?;
        let (every, steps) = (req.every, req.steps);
        let runs = variants.into_iter().map(|(scene, state)| {
            let mut stepper = Stepper::new(
                entry.clone(),
                StepperSpec {
                    scene,
                    state,
                    dt_steps,
                    priority: Priority::Bulk,
                    deadline,
                    stream_id: self.next_stream.fetch_add(1, Ordering::Relaxed),
                    request_id: ctx.request_id.clone(),
                },
            );
            async move {
                let mut frames = Vec::new();
                let mut timing = Timing::default();
                for step in 1..=steps {
                    let mut frame = stepper.next(step < steps).await?;
                    if let Some(t) = frame.timing.take() {
                        timing.add_step(&t);
                    }
                    if step == steps || (every > 0 && step % every == 0) {
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
        // The variants step concurrently (mostly in the same passes): the request's timing is
        // that of its slowest variant, not the sum over variants.
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
