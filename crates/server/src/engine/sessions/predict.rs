//! Predict from a session: every variant starts from the session's current state with its own
//! overrides and action sequence, and steps as its own bulk-priority stream; the session itself
//! does not move. The geometry is the session's (prepared once), so a call carries only the
//! differences between variants.

use std::sync::Arc;

use dynaserve_api::spec::session::SessionPredictSpec;
use dynaserve_api::spec::{Frame, Prediction};

use super::super::Engine;
use super::super::admission::{check_request_cost, check_steps};
use super::super::predict::{Variant, check_variant_count};
use super::super::request::{Call, RequestCtx, with_deadline};
use super::driven::Driven;
use super::input::{Targets, apply_states, check_action_speeds, check_actions};
use crate::error::ApiError;

impl Engine {
    /// Validates, admits and runs a Predict call from a session.
    pub async fn session_predict(
        self: &Arc<Self>,
        req: SessionPredictSpec,
        ctx: RequestCtx,
    ) -> Result<Prediction, ApiError> {
        let span = tracing::info_span!(
            "session_predict",
            request_id = %ctx.request_id,
            session = %req.session_id,
            variants = req.variants.len()
        );
        Call::new(&self.metrics, &ctx, "session_predict", span)
            .answer(self.session_predict_inner(req, &ctx))
            .await
    }

    async fn session_predict_inner(
        self: &Arc<Self>,
        req: SessionPredictSpec,
        ctx: &RequestCtx,
    ) -> Result<Prediction, ApiError> {
        self.admit_check()?;
        let session = self.sessions.get(&req.session_id, ctx.identity)?;
        let entry = session.entry.clone();
        check_steps(req.steps, session.dt_steps, &entry.limits)?;
        let n = req.variants.len();
        check_variant_count(&entry, n)?;
        // Every variant steps the session's scene.
        let cost = check_request_cost(
            &vec![session.scene().len(); n],
            req.steps,
            true,
            &entry.limits,
        )?;
        let deadline = ctx.deadline_with(req.timeout_ms, self.config.default_timeout());
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
            check_action_speeds(
                &targets,
                &state.current,
                session.dt_seconds(),
                &format!("variants[{i}].actions"),
            )?;
            starts.push((state, targets));
        }
        let _slots = self.variant_slots(&entry, n)?;
        let variants = starts
            .into_iter()
            .map(|(state, targets)| DrivenVariant {
                driven: Driven::new(
                    self,
                    &session,
                    state,
                    base_step,
                    self.predict_priority(cost),
                    deadline,
                    ctx,
                ),
                targets,
            })
            .collect();
        self.run_variants(&entry, variants, req.steps, req.every, deadline, ctx)
            .await
    }
}

/// A variant from a session: its kinematic objects follow its own actions.
struct DrivenVariant {
    driven: Driven,
    /// Kinematic poses, one entry per step.
    targets: Vec<Targets>,
}

impl Variant for DrivenVariant {
    fn step(
        &mut self,
        i: usize,
        more_steps: bool,
    ) -> impl Future<Output = Result<Frame, ApiError>> + Send {
        self.driven.next(&self.targets[i], more_steps)
    }
}
