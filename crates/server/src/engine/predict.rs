//! Planner calls: every variant of a Predict call steps as its own stream, all joining the
//! same passes, in the bulk class when the call costs more than `--bulk-cost`; the call
//! answers with the kept frames of every variant.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Instant;

use dynaserve_api::spec::{Frame, PredictSpec, Prediction, Timing};
use futures::future::try_join_all;
use tokio::sync::OwnedSemaphorePermit;

use super::Engine;
use super::admission::{check_request_cost, check_steps};
use super::registry::{ModelEntry, prepare_scenes};
use super::request::{Call, GaugeGuard, RequestCtx, for_variant, with_deadline};
use super::stepper::{Stepper, StepperSpec};
use crate::error::ApiError;
use crate::families::built_scene::check_object_count;
use crate::scheduler::Priority;

impl Engine {
    /// Validates, admits and runs a Predict call.
    pub async fn predict(
        self: &Arc<Self>,
        req: PredictSpec,
        ctx: RequestCtx,
    ) -> Result<Prediction, ApiError> {
        let span = tracing::info_span!(
            "predict",
            request_id = %ctx.request_id,
            protocol = ctx.protocol.as_str(),
            model = tracing::field::Empty,
            variants = req.variants.len()
        );
        Call::new(&self.metrics, &ctx, "predict", span)
            .answer(self.predict_inner(req, &ctx))
            .await
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
        check_variant_count(&entry, n)?;
        // The call's cost, before any slot is taken or scene prepared: object counts first,
        // so that a scene with too many objects is refused naming them.
        for (i, v) in req.variants.iter().enumerate() {
            check_object_count(v, &format!("variants[{i}]"), &entry.limits)?;
        }
        let objects: Vec<usize> = req.variants.iter().map(|v| v.objects.len()).collect();
        let cost = check_request_cost(&objects, req.steps, true, &entry.limits)?;
        let priority = self.predict_priority(cost);
        let deadline = ctx.deadline_with(req.timeout_ms, self.config.default_timeout());
        let _slots = self.variant_slots(&entry, n)?;
        let prepared = with_deadline(
            deadline,
            prepare_scenes(&entry, req.variants, dt_steps, "variants", Arc::from([])),
        )
        .await?;
        let warnings = self.range_warnings(&entry, &prepared);
        let steppers = prepared
            .scenes
            .into_iter()
            .map(|(scene, state)| {
                Stepper::new(
                    entry.clone(),
                    StepperSpec {
                        scene,
                        state,
                        dt_steps,
                        priority,
                        deadline,
                        stream_id: self.next_stream.fetch_add(1, Ordering::Relaxed),
                        caller: ctx.caller(),
                        request_id: ctx.request_id.clone(),
                    },
                )
            })
            .collect();
        let mut prediction = self
            .run_variants(&entry, steppers, req.steps, req.every, deadline, ctx)
            .await?;
        prediction.warnings = warnings;
        Ok(prediction)
    }

    /// The class of a Predict call (plain or on a session) of `object_steps`: bulk above
    /// `--bulk-cost`.
    pub(super) fn predict_priority(&self, object_steps: u64) -> Priority {
        if self.config.scheduling.predict_is_bulk(object_steps) {
            Priority::Bulk
        } else {
            Priority::Interactive
        }
    }

    /// Takes `n` of the server's in-flight variant slots (RESOURCE_EXHAUSTED when they are
    /// not free) and counts them in the model's active-Predict gauge until dropped.
    pub(super) fn variant_slots(
        &self,
        entry: &ModelEntry,
        n: usize,
    ) -> Result<VariantSlots, ApiError> {
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
        Ok(VariantSlots {
            _gauge: GaugeGuard(gauge, n as i64),
            _permit: permit,
        })
    }

    /// Steps every variant `steps` steps concurrently (mostly in the same passes) and answers
    /// with the kept frames of each: every `every`-th step (0: none) and the last. Ends with
    /// UNAVAILABLE when the drain deadline passes first.
    pub(super) async fn run_variants<V: Variant>(
        &self,
        entry: &ModelEntry,
        variants: Vec<V>,
        steps: u32,
        every: u32,
        deadline: Option<Instant>,
        ctx: &RequestCtx,
    ) -> Result<Prediction, ApiError> {
        let runs = variants
            .into_iter()
            .enumerate()
            .map(|(i, mut v)| async move {
                let mut frames = Vec::new();
                let mut timing = Timing::default();
                for step in 1..=steps {
                    let mut frame = v
                        .step(step as usize - 1, step < steps)
                        .await
                        .map_err(|e| for_variant(e, i))?;
                    if let Some(t) = frame.timing.take() {
                        timing.add_step(&t);
                    }
                    if step == steps || (every > 0 && step.is_multiple_of(every)) {
                        frames.push(frame);
                    }
                }
                Ok::<_, ApiError>((frames, timing))
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
            warnings: Vec::new(),
        })
    }
}

/// INVALID_ARGUMENT naming `variants` unless `1..=max_variants` of the model are given.
pub(super) fn check_variant_count(entry: &ModelEntry, n: usize) -> Result<(), ApiError> {
    let max = entry.limits.caps.max_variants;
    if n == 0 || n > max {
        return Err(ApiError::invalid(
            "variants",
            format!("{n} variants given; 1..={max} accepted"),
        ));
    }
    Ok(())
}

/// A Predict call's share of the in-flight variant slots and of the active-Predict gauge,
/// both given back when dropped.
pub(super) struct VariantSlots {
    _gauge: GaugeGuard,
    _permit: OwnedSemaphorePermit,
}

/// One variant of a Predict call: a stream of steps.
pub(super) trait Variant: Send {
    /// Runs step `i` (0-based) of the call; `more_steps` says another follows right after.
    fn step(
        &mut self,
        i: usize,
        more_steps: bool,
    ) -> impl Future<Output = Result<Frame, ApiError>> + Send;
}

impl Variant for Stepper {
    fn step(
        &mut self,
        _i: usize,
        more_steps: bool,
    ) -> impl Future<Output = Result<Frame, ApiError>> + Send {
        self.next(more_steps)
    }
}
