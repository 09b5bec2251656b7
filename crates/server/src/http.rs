//! HTTP front end (axum): the same semantics as the gRPC API, in JSON.
//!
//! | route | |
//! |---|---|
//! | `POST /v1/rollout` | whole trajectory as JSON, or Server-Sent Events frame by frame when the body has `"stream": true` or the request sends `Accept: text/event-stream` |
//! | `POST /v1/predict` | many variants, final poses or every k-th frame |
//! | `POST /v1/generate` | PhysiFormer: sampled mesh trajectories as JSON, or SSE progress and samples ([`generate`]) |
//! | `GET /v1/models` | resident models and limits |
//! | `GET /health` | liveness: 200 while the process serves HTTP |
//! | `GET /ready` | readiness: 200 once models are loaded and warmed up, 503 while warming up or draining |
//! | `GET /metrics` | Prometheus text format |
//! | `GET /openapi.json` | OpenAPI 3.1 document generated from the handlers and JSON types |
//! | `GET /`, `GET /dashboard`, `GET /v1/examples` | the browser viewer and the operator dashboard ([`crate::viewer`]) |
//! | `/v1/sessions...` | sessions: create, step, state, fork, predict, delete ([`sessions`]) |
//!
//! Every response carries `x-request-id` (taken from the request header when valid); rollout
//! and predict responses also carry `x-dynaserve-queue-ms`, `x-dynaserve-forward-ms`,
//! `x-dynaserve-total-ms` and an equivalent `Server-Timing` header (SSE: per-frame timings in
//! the events and totals in the final `done` event). Errors are [`json::ErrorResponse`]
//! documents: 422 invalid input (naming the field), 429 overload (with `Retry-After`), 504
//! deadline exceeded, 503 unavailable, 500 internal.

use std::convert::Infallible;
use std::sync::Arc;

use axum::Router;
use axum::body::Body;
use axum::extract::{DefaultBodyLimit, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use dynaserve_api::json;
use dynaserve_api::spec::{Frame, PredictSpec, Prediction, RolloutSpec, Timing};
use futures::Stream;
use serde::de::DeserializeOwned;
use utoipa::OpenApi;

use crate::engine::{Engine, Protocol, RequestCtx};
use crate::error::ApiError;
use crate::security::Caller;

pub mod generate;
pub mod sessions;

#[derive(Clone)]
struct AppState {
    engine: Arc<Engine>,
}

/// The OpenAPI document of the HTTP API.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "Dynaserve HTTP API",
        description = "Learned physics world models: RigidFormer stepping rigid multi-object \
                       scenes forward (rollout, predict, sessions) and PhysiFormer sampling \
                       whole trajectories of rigid and elastic mesh scenes (generate). Units: \
                       metres, seconds, kilograms, radians; z up; ground plane z = 0; \
                       quaternions [x, y, z, w]. The gRPC API (dynaserve.v1) has the same \
                       semantics."
    ),
    paths(rollout, predict, list_models, health, ready, metrics),
    components(schemas(
        json::RolloutRequest,
        json::RolloutResponse,
        json::PredictRequest,
        json::PredictResponse,
        json::ListModelsResponse,
        json::ErrorResponse,
        json::StepFrame,
        json::SseDone,
    ))
)]
pub struct ApiDoc;

/// Builds the HTTP router.
pub fn router(engine: Arc<Engine>) -> Router {
    Router::new()
        .route("/v1/rollout", post(rollout))
        .route("/v1/predict", post(predict))
        .route("/v1/models", get(list_models))
        .route("/health", get(health))
        .route("/ready", get(ready))
        .route("/metrics", get(metrics))
        .route("/openapi.json", get(openapi))
        .merge(sessions::routes())
        .merge(generate::routes())
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        // Bodies are read with the configured limit in `read_json`, which names the field.
        .layer(DefaultBodyLimit::disable())
        .with_state(AppState { engine })
}

/// The router of the probe listener (`--health-addr`): `/health`, `/ready` and `/metrics`
/// only, each as on the API listener.
pub fn probes_router(engine: Arc<Engine>) -> Router {
    Router::new()
        .route("/health", get(health))
        .route("/ready", get(ready))
        .route("/metrics", get(metrics))
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .with_state(AppState { engine })
}

/// The context of an HTTP request; `caller` is whom it is attributed to (see [`Caller`]).
fn ctx_of(headers: &HeaderMap, caller: Caller) -> RequestCtx {
    let rid = headers.get("x-request-id").and_then(|v| v.to_str().ok());
    RequestCtx::new(Protocol::Http, rid, None).with_identity(caller.0)
}

fn set_header(headers: &mut HeaderMap, key: &'static str, value: &str) {
    if let Ok(v) = HeaderValue::from_str(value) {
        headers.insert(key, v);
    }
}

/// Appends one `x-dynaserve-warning` header per warning (object parameters outside the model's
/// trained range).
fn with_warnings(mut r: Response, warnings: &[String]) -> Response {
    for w in warnings {
        if let Ok(v) = HeaderValue::from_str(w) {
            r.headers_mut().append(dynaserve_api::WARNING_HEADER, v);
        }
    }
    r
}

fn error_response(e: ApiError, rid: &str) -> Response {
    let mut r = e.into_response();
    set_header(r.headers_mut(), "x-request-id", rid);
    r
}

/// A JSON answer with `status` carrying the request id.
fn json_response<T: serde::Serialize>(status: StatusCode, body: T, rid: &str) -> Response {
    let mut r = (status, axum::Json(body)).into_response();
    set_header(r.headers_mut(), "x-request-id", rid);
    r
}

/// A server-sent-event stream of `events` with keep-alive comments, carrying the request id and
/// the model that answers.
fn sse_response<S>(events: S, rid: &str, model: &str) -> Response
where
    S: Stream<Item = Result<Event, Infallible>> + Send + 'static,
{
    let mut r = Sse::new(events)
        .keep_alive(KeepAlive::default())
        .into_response();
    set_header(r.headers_mut(), "x-request-id", rid);
    set_header(r.headers_mut(), "x-dynaserve-model", model);
    r
}

/// Adds the model and timing headers of a call that stepped scenes.
fn timed(mut r: Response, model: &str, timing: &json::RequestTiming) -> Response {
    set_header(r.headers_mut(), "x-dynaserve-model", model);
    timing_headers(r.headers_mut(), timing);
    r
}

/// Reads a JSON request (see [`read_json`]) and converts it; a failure of either is counted
/// as a rejected `method` call and becomes the error response.
async fn parse<J: DeserializeOwned, T, E: Into<ApiError>>(
    engine: &Engine,
    ctx: &RequestCtx,
    method: &'static str,
    body: Body,
    convert: impl FnOnce(J) -> Result<T, E>,
) -> Result<T, Response> {
    read_json(engine, body)
        .await
        .and_then(|j| convert(j).map_err(Into::into))
        .map_err(|e| error_response(engine.reject(ctx, method, e), &ctx.request_id))
}

/// Receives every frame of a stepping call, with the summed step timings (total: since
/// `arrival`); the first error ends it.
async fn collect_frames(
    mut rx: tokio::sync::mpsc::Receiver<Result<Frame, ApiError>>,
    arrival: std::time::Instant,
) -> Result<(Vec<json::StepFrame>, json::RequestTiming), ApiError> {
    let mut frames = Vec::new();
    let mut timing = Timing::default();
    while let Some(item) = rx.recv().await {
        let f = item?;
        if let Some(t) = &f.timing {
            timing.add_step(t);
        }
        frames.push(f.to_json());
    }
    timing.total = arrival.elapsed();
    Ok((frames, timing.to_json()))
}

/// The answer of a Predict call (whole scenes or from a session).
fn prediction_response(r: Result<Prediction, ApiError>, rid: &str) -> Response {
    match r {
        Ok(out) => {
            let body = out.to_json();
            let (timing, model) = (body.timing, body.model.clone());
            let r = timed(json_response(StatusCode::OK, body, rid), &model, &timing);
            with_warnings(r, &out.warnings)
        }
        Err(e) => error_response(e, rid),
    }
}

fn timing_headers(headers: &mut HeaderMap, t: &json::RequestTiming) {
    set_header(
        headers,
        "x-dynaserve-queue-ms",
        &format!("{:.3}", t.queue_ms),
    );
    set_header(
        headers,
        "x-dynaserve-forward-ms",
        &format!("{:.3}", t.forward_ms),
    );
    set_header(
        headers,
        "x-dynaserve-total-ms",
        &format!("{:.3}", t.total_ms),
    );
    set_header(
        headers,
        "server-timing",
        &format!(
            "queue;dur={:.3}, forward;dur={:.3}, total;dur={:.3}",
            t.queue_ms, t.forward_ms, t.total_ms
        ),
    );
}

async fn read_json<T: DeserializeOwned>(engine: &Engine, body: Body) -> Result<T, ApiError> {
    let limit = engine.config().max_request_bytes;
    let bytes = axum::body::to_bytes(body, limit).await.map_err(|e| {
        if let Some(m) = crate::listener::body_deadline_message(&e) {
            return ApiError::body_timeout(m);
        }
        if crate::security::is_body_timeout(&e) {
            return ApiError::body_timeout(
                "the request body stopped arriving before it was complete",
            );
        }
        ApiError::invalid(
            "request",
            format!("payload could not be read within the limit of {limit} bytes: {e}"),
        )
    })?;
    engine.check_payload(bytes.len())?;
    Ok(dynaserve_api::json_body::decode(&bytes)?)
}

fn wants_sse(headers: &HeaderMap) -> bool {
    headers
        .get(header::ACCEPT)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|a| a.contains("text/event-stream"))
}

/// Roll one scene forward.
///
/// Returns the whole trajectory as JSON, or Server-Sent Events (`frame` events with a
/// `StepFrame`, then one `done` event, or one `error` event with an `ErrorResponse`) when the
/// body has `"stream": true` or the request sends `Accept: text/event-stream`.
#[utoipa::path(
    post,
    path = "/v1/rollout",
    request_body = json::RolloutRequest,
    responses(
        (status = 200, description = "Trajectory (or an SSE stream of StepFrame events)", body = json::RolloutResponse),
        (status = 422, description = "Invalid input; `error.field` names the field", body = json::ErrorResponse),
        (status = 429, description = "Server full; retry after the Retry-After header", body = json::ErrorResponse),
        (status = 503, description = "Warming up or shutting down", body = json::ErrorResponse),
        (status = 504, description = "Deadline (`timeout_ms`) exceeded", body = json::ErrorResponse),
    )
)]
async fn rollout(
    State(s): State<AppState>,
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
        "rollout",
        body,
        |req: json::RolloutRequest| {
            RolloutSpec::from_json(&req).map(|spec| (spec, req.stream || wants_sse(&headers)))
        },
    );
    let (spec, sse) = match parsed.await {
        Ok(p) => p,
        Err(r) => return r,
    };
    // The caller's stream quota, held until the answer is complete.
    let quota = match s.engine.stream_quota(&ctx) {
        Ok(q) => q,
        Err(e) => return error_response(s.engine.reject(&ctx, "rollout", e), &rid),
    };
    let handle = match s.engine.start_rollout(spec, ctx).await {
        Ok(h) => h,
        Err(e) => return error_response(e, &rid),
    };
    let model = handle.model.clone();
    let warnings = handle.warnings;
    if sse {
        let events = sse_events(handle.frames, rid.to_string(), arrival);
        let events = futures::StreamExt::map(events, move |e| {
            let _ = &quota;
            e
        });
        let r = sse_response(events, &rid, &model);
        return with_warnings(r, &warnings);
    }
    let collected = collect_frames(handle.frames, arrival).await;
    drop(quota);
    let (frames, timing) = match collected {
        Ok(f) => f,
        Err(e) => return error_response(e, &rid),
    };
    let body = json::RolloutResponse {
        model: model.clone(),
        request_id: rid.to_string(),
        frames,
        timing,
    };
    let r = timed(json_response(StatusCode::OK, body, &rid), &model, &timing);
    with_warnings(r, &warnings)
}

fn sse_events(
    rx: tokio::sync::mpsc::Receiver<Result<Frame, ApiError>>,
    request_id: String,
    arrival: std::time::Instant,
) -> impl Stream<Item = Result<Event, Infallible>> {
    struct St {
        rx: tokio::sync::mpsc::Receiver<Result<Frame, ApiError>>,
        timing: Timing,
        steps: u32,
        done: bool,
        request_id: String,
        arrival: std::time::Instant,
    }
    let st = St {
        rx,
        timing: Timing::default(),
        steps: 0,
        done: false,
        request_id,
        arrival,
    };
    futures::stream::unfold(st, |mut st| async move {
        if st.done {
            return None;
        }
        let event = match st.rx.recv().await {
            Some(Ok(f)) => {
                if let Some(t) = &f.timing {
                    st.timing.add_step(t);
                }
                st.steps = f.step;
                Event::default()
                    .event("frame")
                    .data(serde_json::to_string(&f.to_json()).unwrap_or_default())
            }
            Some(Err(e)) => {
                st.done = true;
                Event::default()
                    .event("error")
                    .data(serde_json::to_string(&e.body()).unwrap_or_default())
            }
            None => {
                st.done = true;
                st.timing.total = st.arrival.elapsed();
                let done = json::SseDone {
                    request_id: st.request_id.clone(),
                    steps: st.steps,
                    timing: st.timing.to_json(),
                };
                Event::default()
                    .event("done")
                    .data(serde_json::to_string(&done).unwrap_or_default())
            }
        };
        Some((Ok(event), st))
    })
}

/// Roll many scene variants forward (planner calls).
#[utoipa::path(
    post,
    path = "/v1/predict",
    request_body = json::PredictRequest,
    responses(
        (status = 200, description = "One trajectory per variant", body = json::PredictResponse),
        (status = 422, description = "Invalid input; `error.field` names the field", body = json::ErrorResponse),
        (status = 429, description = "Server full; retry after the Retry-After header", body = json::ErrorResponse),
        (status = 503, description = "Warming up or shutting down", body = json::ErrorResponse),
        (status = 504, description = "Deadline (`timeout_ms`) exceeded", body = json::ErrorResponse),
    )
)]
async fn predict(
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
        "predict",
        body,
        |req: json::PredictRequest| PredictSpec::from_json(&req),
    );
    let spec = match parsed.await {
        Ok(r) => r,
        Err(r) => return r,
    };
    prediction_response(s.engine.predict(spec, ctx).await, &rid)
}

/// Resident models and the server's limits for each.
#[utoipa::path(
    get,
    path = "/v1/models",
    responses((status = 200, description = "Resident models", body = json::ListModelsResponse))
)]
async fn list_models(State(s): State<AppState>, caller: Caller, headers: HeaderMap) -> Response {
    let ctx = ctx_of(&headers, caller);
    let list = json::ListModelsResponse {
        models: s
            .engine
            .list_models(&ctx)
            .iter()
            .map(|m| m.to_json())
            .collect(),
    };
    let mut resp = axum::Json(list).into_response();
    set_header(resp.headers_mut(), "x-request-id", &ctx.request_id);
    resp
}

/// Liveness: 200 while the process serves HTTP.
#[utoipa::path(get, path = "/health", responses((status = 200, description = "Alive")))]
async fn health() -> Response {
    axum::Json(serde_json::json!({ "status": "alive" })).into_response()
}

/// Readiness: 200 once every model is loaded and warmed up; 503 before that and while draining.
#[utoipa::path(
    get,
    path = "/ready",
    responses(
        (status = 200, description = "Ready"),
        (status = 503, description = "Warming up or draining"),
    )
)]
async fn ready(State(s): State<AppState>) -> Response {
    if s.engine.is_ready() {
        axum::Json(serde_json::json!({ "status": "ready", "models": s.engine.model_names() }))
            .into_response()
    } else {
        let status = if s.engine.is_draining() {
            "draining"
        } else {
            "warming_up"
        };
        (
            StatusCode::SERVICE_UNAVAILABLE,
            axum::Json(serde_json::json!({ "status": status })),
        )
            .into_response()
    }
}

/// Prometheus metrics in the text exposition format.
#[utoipa::path(
    get,
    path = "/metrics",
    responses((status = 200, description = "Prometheus text format 0.0.4", content_type = "text/plain"))
)]
async fn metrics(State(s): State<AppState>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
        )],
        s.engine.metrics().render(),
    )
        .into_response()
}

async fn openapi() -> Response {
    let mut doc = ApiDoc::openapi();
    doc.merge(crate::viewer::ViewerDoc::openapi());
    doc.merge(sessions::SessionsDoc::openapi());
    doc.merge(generate::GenerateDoc::openapi());
    axum::Json(doc).into_response()
}

async fn method_not_allowed(method: axum::http::Method) -> Response {
    (
        StatusCode::METHOD_NOT_ALLOWED,
        axum::Json(json::ErrorResponse {
            error: json::ErrorDetail {
                code: "METHOD_NOT_ALLOWED".into(),
                message: format!("{method} is not allowed on this route; see /openapi.json"),
                field: None,
                retry_after_ms: None,
            },
        }),
    )
        .into_response()
}

async fn not_found() -> Response {
    (
        StatusCode::NOT_FOUND,
        axum::Json(json::ErrorResponse {
            error: json::ErrorDetail {
                code: "NOT_FOUND".into(),
                message: "no such route; see /openapi.json".into(),
                field: None,
                retry_after_ms: None,
            },
        }),
    )
        .into_response()
}
