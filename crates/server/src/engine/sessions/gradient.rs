//! Gradient from a session: candidate paths of its kinematic objects, scored and
//! differentiated from its current state in one gradient pass (`super::super::gradient`); the
//! session itself does not move. The geometry is the session's (prepared once), so a call
//! carries only the paths and the cost.

use std::sync::Arc;

use dynaserve_api::spec::gradient::{Gradients, SessionGradientSpec};

use super::super::Engine;
use super::super::admission::check_steps;
use super::super::gradient::{
    answer, candidate_paths, check_candidate_count, check_gradient_work, path_cost,
};
use super::super::request::{Call, RequestCtx, with_deadline};
use crate::error::ApiError;
use crate::families::contract::GradientJob;

impl Engine {
    /// Validates, admits and runs a Gradient call from a session.
    pub async fn session_gradient(
        self: &Arc<Self>,
        req: SessionGradientSpec,
        ctx: RequestCtx,
    ) -> Result<Gradients, ApiError> {
        let span = tracing::info_span!(
            "session_gradient",
            request_id = %ctx.request_id,
            session = %req.session_id,
            candidates = req.candidates.len(),
            steps = req.steps
        );
        Call::new(&self.metrics, &ctx, "session_gradient", span)
            .answer(self.session_gradient_inner(req, &ctx))
            .await
    }

    async fn session_gradient_inner(
        self: &Arc<Self>,
        req: SessionGradientSpec,
        ctx: &RequestCtx,
    ) -> Result<Gradients, ApiError> {
        self.admit_check()?;
        let session = self.sessions.get(&req.session_id, ctx.identity)?;
        let entry = session.entry.clone();
        // A model without gradients says so before anything else is checked.
        if entry.gradients.is_none() {
            let why = entry.model().gradients_unsupported().unwrap_or_default();
            return Err(ApiError::failed_precondition(why));
        }
        let limits = &entry.limits;
        check_steps(req.steps, session.dt_steps, limits)?;
        let n = req.candidates.len();
        check_candidate_count(limits, n)?;
        check_gradient_work(n, req.steps, limits)?;
        let cost = path_cost(&req.cost, session.scene().len(), req.steps)?;
        let deadline = ctx.deadline_with(req.timeout_ms, self.config.default_timeout());
        // The session's state now; later calls on the session do not affect this one.
        let (state, base_step) = {
            let p = with_deadline(deadline, async { Ok(session.progress.lock().await) }).await?;
            (p.state.clone(), p.step)
        };
        let paths = candidate_paths(
            &req.candidates,
            req.steps,
            &session.kinematic,
            &state.current,
            session.dt_seconds(),
        )?;
        let job = GradientJob {
            scene: session.scene().clone(),
            state,
            kinematic: session.kinematic.clone(),
            paths,
            dt_steps: session.dt_steps,
            cost,
            deadline,
        };
        entry.model().check_gradient(&job)?;
        // The candidates count against the Predict variants in flight.
        let _slots = self.variant_slots(&entry, n)?;
        let done = self.run_gradient(&entry, job, ctx).await?;
        answer(
            &entry,
            done,
            req.steps,
            req.every,
            (base_step, session.dt_steps),
            ctx,
        )
    }
}
