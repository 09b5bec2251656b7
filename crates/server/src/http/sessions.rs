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
//! | `DELETE /v1/sessions/{id}` | delete it (204) |
//!
//! Unknown or expired ids, and sessions of another caller that are not `shared`, answer 404
//! with an `ErrorResponse` naming `session_id`: a session belongs to the caller that created
//! it (its bearer token, or without authentication its IP address).

use axum::Router;
use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post, put};
use dynaserve_api::json;
use dynaserve_api::spec::session::{CreateSessionSpec, SessionPredictSpec, SetStateSpec, StepSpec};
use utoipa::OpenApi;

use crate::security::Caller;

use super::{
    AppState, collect_frames, ctx_of, error_response, json_response as ok, parse,
    prediction_response, set_header, timed, with_warnings,
};

/// The OpenAPI description of the session routes (merged into the HTTP API's document).
#[derive(OpenApi)]
#[openapi(
    paths(create, get_state, set_state, step, fork, predict, delete),
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
    caller: Caller,
    headers: HeaderMap,
    body: Body,
) -> Response {
    let ctx = ctx_of(&headers, caller);
    let rid = ctx.request_id.clone();
    let parsed = parse(
        &s.engine,
        &ctx,
        "create_session",
        body,
        |r: json::CreateSessionRequest| CreateSessionSpec::from_json(&r),
    );
    let spec = match parsed.await {
        Ok(r) => r,
        Err(r) => return r,
    };
    match s.engine.create_session(spec, ctx).await {
        Ok((info, warnings)) => {
            with_warnings(ok(StatusCode::CREATED, info.to_json(), &rid), &warnings)
        }
        Err(e) => error_response(e, &rid),
    }
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
    caller: Caller,
    headers: HeaderMap,
) -> Response {
    let ctx = ctx_of(&headers, caller);
    let rid = ctx.request_id.clone();
    match s.engine.session_state(&id, ctx).await {
        Ok(v) => ok(StatusCode::OK, v.to_json(), &rid),
        Err(e) => error_response(e, &rid),
    }
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
    Path(id): Path<String>,
    caller: Caller,
    headers: HeaderMap,
    body: Body,
) -> Response {
    let ctx = ctx_of(&headers, caller);
    let rid = ctx.request_id.clone();
    let parsed = parse(
        &s.engine,
        &ctx,
        "set_state",
        body,
        |r: json::SetStateRequest| SetStateSpec::from_json(&id, &r),
    );
    let spec = match parsed.await {
        Ok(r) => r,
        Err(r) => return r,
    };
    match s.engine.set_session_state(spec, ctx).await {
        Ok(v) => ok(StatusCode::OK, v.to_json(), &rid),
        Err(e) => error_response(e, &rid),
    }
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
async fn step(
    State(s): State<AppState>,
    Path(id): Path<String>,
    caller: Caller,
    headers: HeaderMap,
    body: Body,
) -> Response {
    let ctx = ctx_of(&headers, caller);
    let rid = ctx.request_id.clone();
    let arrival = ctx.arrival;
    let parsed = parse(
        &s.engine,
        &ctx,
        "session_step",
        body,
        |r: json::StepRequest| Ok::<_, dynaserve_api::FieldError>(StepSpec::from_json(&id, &r)),
    );
    let spec = match parsed.await {
        Ok(r) => r,
        Err(r) => return r,
    };
    let handle = match s.engine.session_step(spec, ctx).await {
        Ok(h) => h,
        Err(e) => return error_response(e, &rid),
    };
    let (frames, timing) = match collect_frames(handle.frames, arrival).await {
        Ok(f) => f,
        Err(e) => return error_response(e, &rid),
    };
    let body = json::StepResponse {
        session_id: id,
        frames,
        timing,
    };
    timed(ok(StatusCode::OK, body, &rid), &handle.model, &timing)
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
    caller: Caller,
    headers: HeaderMap,
) -> Response {
    let ctx = ctx_of(&headers, caller);
    let rid = ctx.request_id.clone();
    match s.engine.fork_session(&id, ctx).await {
        Ok(info) => ok(StatusCode::CREATED, info.to_json(), &rid),
        Err(e) => error_response(e, &rid),
    }
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
async fn predict(
    State(s): State<AppState>,
    Path(id): Path<String>,
    caller: Caller,
    headers: HeaderMap,
    body: Body,
) -> Response {
    let ctx = ctx_of(&headers, caller);
    let rid = ctx.request_id.clone();
    let parsed = parse(
        &s.engine,
        &ctx,
        "session_predict",
        body,
        |r: json::SessionPredictRequest| SessionPredictSpec::from_json(&id, &r),
    );
    let spec = match parsed.await {
        Ok(r) => r,
        Err(r) => return r,
    };
    prediction_response(s.engine.session_predict(spec, ctx).await, &rid)
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
    caller: Caller,
    headers: HeaderMap,
) -> Response {
    let ctx = ctx_of(&headers, caller);
    let rid = ctx.request_id.clone();
    match s.engine.delete_session(&id, ctx).await {
        Ok(()) => {
            let mut r = StatusCode::NO_CONTENT.into_response();
            set_header(r.headers_mut(), "x-request-id", &rid);
            r
        }
        Err(e) => error_response(e, &rid),
    }
}
