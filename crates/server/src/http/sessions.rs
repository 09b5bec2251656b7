//! The session routes of the HTTP API (`/v1/sessions`), with the same semantics as the
//! `dynaserve.v1.Sessions` gRPC service. The session id is a path segment.
//!
//! | route | |
//! |---|---|
//! | `POST /v1/sessions` | create a session (`CreateSessionRequest` -> `SessionInfo`) |
//! | `GET /v1/sessions/{id}` | its state (`SessionState`) |
//! | `PUT /v1/sessions/{id}/state` | overwrite object states (`SetStateRequest` -> `SessionState`) |
//! | `POST /v1/sessions/{id}/step` | advance it (`StepRequest` -> `StepResponse`) |
//! | `POST /v1/sessions/{id}/fork` | copy it under a new id (`SessionInfo`) |
//! | `POST /v1/sessions/{id}/predict` | many variants from its state (`SessionPredictRequest` -> `PredictResponse`) |
//! | `POST /v1/sessions/{id}/gradient` | candidate paths scored and differentiated from its state (`SessionGradientRequest` -> `GradientResponse`) |
//! | `DELETE /v1/sessions/{id}` | delete it (204) |
//!
//! Unknown or expired ids, and sessions of another caller that are not `shared`, answer 404
//! with an `ErrorResponse` naming `session_id`: a session belongs to the caller that created
//! it (its bearer token, or without authentication its IP address).

use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::IntoResponse;
use axum::routing::{get, post, put};
use axum::{Json, Router};
use dynaserve_api::FieldError;
use dynaserve_api::json;
use dynaserve_api::spec::gradient::SessionGradientSpec;
use dynaserve_api::spec::session::{CreateSessionSpec, SessionPredictSpec, SetStateSpec, StepSpec};
use utoipa::OpenApi;

use super::extract::{AppState, Call, Spec};
use super::reply::{Model, Predicted, Reply, RequestId, Timed, Warnings, collect_frames};
use crate::engine::RequestCtx;

/// The OpenAPI description of the session routes (merged into the HTTP API's document).
#[derive(OpenApi)]
#[openapi(
    paths(create, get_state, set_state, step, fork, predict, gradient, delete),
    components(schemas(
        json::CreateSessionRequest,
        json::SessionInfo,
        json::SessionState,
        json::SetStateRequest,
        json::StepRequest,
        json::StepResponse,
        json::SessionPredictRequest,
        json::SessionVariant,
        json::ObjectState,
        json::ObjectPose,
        json::Action,
        json::SessionGradientRequest,
        json::GradientCandidate,
        json::GradientCost,
        json::CostTarget,
        json::GradientResponse,
        json::CandidateGradient,
        json::StepGradient,
        json::PoseGradient,
    ))
)]
pub struct SessionsDoc;

/// The session routes.
pub(super) fn routes() -> Router<AppState> {
    Router::new()
        .route("/v1/sessions", post(create))
        .route("/v1/sessions/{id}", get(get_state).delete(delete))
        .route("/v1/sessions/{id}/state", put(set_state))
        .route("/v1/sessions/{id}/step", post(step))
        .route("/v1/sessions/{id}/fork", post(fork))
        .route("/v1/sessions/{id}/predict", post(predict))
        .route("/v1/sessions/{id}/gradient", post(gradient))
}

impl Spec for CreateSessionSpec {
    const METHOD: &'static str = "create_session";
    type Json = json::CreateSessionRequest;
    fn read(r: &json::CreateSessionRequest, _: &str) -> Result<Self, FieldError> {
        CreateSessionSpec::from_json(r)
    }
}

impl Spec for SetStateSpec {
    const METHOD: &'static str = "set_state";
    type Json = json::SetStateRequest;
    fn read(r: &json::SetStateRequest, session_id: &str) -> Result<Self, FieldError> {
        SetStateSpec::from_json(session_id, r)
    }
}

impl Spec for StepSpec {
    const METHOD: &'static str = "session_step";
    type Json = json::StepRequest;
    fn read(r: &json::StepRequest, session_id: &str) -> Result<Self, FieldError> {
        Ok(StepSpec::from_json(session_id, r))
    }
}

impl Spec for SessionPredictSpec {
    const METHOD: &'static str = "session_predict";
    type Json = json::SessionPredictRequest;
    fn read(r: &json::SessionPredictRequest, session_id: &str) -> Result<Self, FieldError> {
        SessionPredictSpec::from_json(session_id, r)
    }
}

impl Spec for SessionGradientSpec {
    const METHOD: &'static str = "session_gradient";
    type Json = json::SessionGradientRequest;
    fn read(r: &json::SessionGradientRequest, session_id: &str) -> Result<Self, FieldError> {
        Ok(SessionGradientSpec::from_json(session_id, r))
    }
}

/// Create a session: the scene is validated and prepared once and kept with its state.
#[utoipa::path(
    post,
    path = "/v1/sessions",
    request_body = json::CreateSessionRequest,
    responses(
        (status = 201, description = "Created", body = json::SessionInfo),
        (status = 422, description = "Invalid input, or a session larger than the session memory could ever hold; `error.field` names the field", body = json::ErrorResponse),
        (status = 429, description = "Session count or memory limit reached (the server's or the caller's)", body = json::ErrorResponse),
    )
)]
async fn create(
    State(s): State<AppState>,
    call: Call<CreateSessionSpec>,
) -> Reply<impl IntoResponse> {
    let rid = RequestId::of(&call.ctx);
    let created = s.engine.create_session(call.spec, call.ctx).await;
    let answer = created.map(|(info, warnings)| {
        (
            StatusCode::CREATED,
            Warnings(warnings),
            Json(info.to_json()),
        )
    });
    (rid, answer)
}

/// A session's current state.
#[utoipa::path(
    get,
    path = "/v1/sessions/{id}",
    params(("id" = String, Path, description = "Session id")),
    responses(
        (status = 200, description = "State", body = json::SessionState),
        (status = 404, description = "Unknown or expired session, or another caller's", body = json::ErrorResponse),
    )
)]
async fn get_state(
    State(s): State<AppState>,
    Path(id): Path<String>,
    ctx: RequestCtx,
) -> Reply<impl IntoResponse> {
    let rid = RequestId::of(&ctx);
    let state = s.engine.session_state(&id, ctx).await;
    (rid, state.map(|v| Json(v.to_json())))
}

/// Overwrite some objects' states (e.g. from a real observation).
#[utoipa::path(
    put,
    path = "/v1/sessions/{id}/state",
    params(("id" = String, Path, description = "Session id")),
    request_body = json::SetStateRequest,
    responses(
        (status = 200, description = "The new state", body = json::SessionState),
        (status = 404, description = "Unknown or expired session, or another caller's", body = json::ErrorResponse),
        (status = 422, description = "Invalid input; `error.field` names the field", body = json::ErrorResponse),
    )
)]
async fn set_state(
    State(s): State<AppState>,
    call: Call<SetStateSpec>,
) -> Reply<impl IntoResponse> {
    let rid = RequestId::of(&call.ctx);
    let state = s.engine.set_session_state(call.spec, call.ctx).await;
    (rid, state.map(|v| Json(v.to_json())))
}

/// Advance the session `steps` steps; its state moves with every finished step.
#[utoipa::path(
    post,
    path = "/v1/sessions/{id}/step",
    params(("id" = String, Path, description = "Session id")),
    request_body = json::StepRequest,
    responses(
        (status = 200, description = "One frame per step", body = json::StepResponse),
        (status = 404, description = "Unknown or expired session, or another caller's", body = json::ErrorResponse),
        (status = 422, description = "Invalid input; `error.field` names the field", body = json::ErrorResponse),
        (status = 504, description = "Deadline (`timeout_ms`) exceeded", body = json::ErrorResponse),
    )
)]
async fn step(State(s): State<AppState>, call: Call<StepSpec>) -> Reply {
    let (rid, arrival) = (RequestId::of(&call.ctx), call.ctx.arrival);
    let session_id = call.spec.session_id.clone();
    let handle = match s.engine.session_step(call.spec, call.ctx).await {
        Ok(h) => h,
        Err(e) => return (rid, Err(e)),
    };
    let answer = collect_frames(handle.frames, arrival)
        .await
        .map(|(frames, timing)| {
            let body = json::StepResponse {
                session_id,
                frames,
                timing,
            };
            (Model(handle.model), Timed(timing), Json(body)).into_response()
        });
    (rid, answer)
}

/// Copy the session's state under a new id (the prepared scene is shared).
#[utoipa::path(
    post,
    path = "/v1/sessions/{id}/fork",
    params(("id" = String, Path, description = "Session id")),
    responses(
        (status = 201, description = "The copy", body = json::SessionInfo),
        (status = 404, description = "Unknown or expired session, or another caller's", body = json::ErrorResponse),
        (status = 429, description = "Session count or memory limit reached", body = json::ErrorResponse),
    )
)]
async fn fork(
    State(s): State<AppState>,
    Path(id): Path<String>,
    ctx: RequestCtx,
) -> Reply<impl IntoResponse> {
    let rid = RequestId::of(&ctx);
    let forked = s.engine.fork_session(&id, ctx).await;
    (
        rid,
        forked.map(|info| (StatusCode::CREATED, Json(info.to_json()))),
    )
}

/// Roll many variants of the session's state forward (planner calls); the session does not
/// move.
#[utoipa::path(
    post,
    path = "/v1/sessions/{id}/predict",
    params(("id" = String, Path, description = "Session id")),
    request_body = json::SessionPredictRequest,
    responses(
        (status = 200, description = "One trajectory per variant", body = json::PredictResponse),
        (status = 404, description = "Unknown or expired session, or another caller's", body = json::ErrorResponse),
        (status = 422, description = "Invalid input; `error.field` names the field", body = json::ErrorResponse),
        (status = 429, description = "Server full; retry after the Retry-After header", body = json::ErrorResponse),
    )
)]
async fn predict(State(s): State<AppState>, call: Call<SessionPredictSpec>) -> Reply<Predicted> {
    let rid = RequestId::of(&call.ctx);
    let prediction = s.engine.session_predict(call.spec, call.ctx).await;
    (rid, prediction.map(Predicted))
}

/// Score candidate paths of the session's kinematic objects and differentiate the score: each
/// candidate is rolled out from the session's state as a session Predict would roll it out,
/// and the answer holds its cost, the cost's gradient with respect to every kinematic pose of
/// the path and the rollout. The session does not move.
#[utoipa::path(
    post,
    path = "/v1/sessions/{id}/gradient",
    params(("id" = String, Path, description = "Session id")),
    request_body = json::SessionGradientRequest,
    responses(
        (status = 200, description = "One answer per candidate", body = json::GradientResponse),
        (status = 400, description = "FAILED_PRECONDITION: the session's model computes no gradients (an ensemble, the simulator)", body = json::ErrorResponse),
        (status = 404, description = "Unknown or expired session, or another caller's", body = json::ErrorResponse),
        (status = 422, description = "Invalid input, or more work than --max-gradient-work; `error.field` names the field", body = json::ErrorResponse),
        (status = 429, description = "Server full; retry after the Retry-After header", body = json::ErrorResponse),
        (status = 504, description = "Deadline (`timeout_ms`) exceeded, also while queued", body = json::ErrorResponse),
    )
)]
async fn gradient(
    State(s): State<AppState>,
    call: Call<SessionGradientSpec>,
) -> Reply<impl IntoResponse> {
    let rid = RequestId::of(&call.ctx);
    let answer = s.engine.session_gradient(call.spec, call.ctx).await;
    let answer = answer.map(|g| {
        let body = g.to_json();
        (Model(body.model.clone()), Timed(body.timing), Json(body))
    });
    (rid, answer)
}

/// Delete the session.
#[utoipa::path(
    delete,
    path = "/v1/sessions/{id}",
    params(("id" = String, Path, description = "Session id")),
    responses(
        (status = 204, description = "Deleted"),
        (status = 403, description = "Another caller's shared session: only its owner deletes it", body = json::ErrorResponse),
        (status = 404, description = "Unknown or expired session, or another caller's", body = json::ErrorResponse),
    )
)]
async fn delete(
    State(s): State<AppState>,
    Path(id): Path<String>,
    ctx: RequestCtx,
) -> Reply<StatusCode> {
    let rid = RequestId::of(&ctx);
    let deleted = s.engine.delete_session(&id, ctx).await;
    (rid, deleted.map(|()| StatusCode::NO_CONTENT))
}
