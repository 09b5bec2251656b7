//! HTTP front end (axum): the same semantics as the gRPC API, in JSON.
//!
//! | route | |
//! |---|---|
//! | `POST /v1/rollout` | whole trajectory as JSON, or Server-Sent Events frame by frame when the body has `"stream": true` or the request sends `Accept: text/event-stream` |
//! | `POST /v1/predict` | many variants, final poses or every k-th frame |
//! | `POST /v1/generate` | PhysiFormer: sampled mesh trajectories as JSON, or SSE progress and samples ([`generate_route`]) |
//! | `GET /v1/models` | resident models and limits |
//! | `GET /health` | liveness: 200 while the process serves HTTP |
//! | `GET /ready` | readiness: 200 once models are loaded and warmed up, 503 while warming up or draining |
//! | `GET /metrics` | Prometheus text format |
//! | `GET /openapi.json` | OpenAPI 3.1 document generated from the handlers and JSON types |
//! | `GET /`, `GET /dashboard`, `GET /v1/examples` | the browser viewer and the operator dashboard ([`crate::viewer`]) |
//! | `/v1/sessions...` | sessions: create, step, state, fork, predict, gradient, delete ([`sessions`]) |
//!
//! Every response carries `x-request-id` (taken from the request header when valid); rollout
//! and predict responses also carry `x-dynaserve-queue-ms`, `x-dynaserve-forward-ms`,
//! `x-dynaserve-total-ms` and an equivalent `Server-Timing` header (SSE: per-frame timings in
//! the events and totals in the final `done` event). Errors are [`json::ErrorResponse`]
//! documents: 422 invalid input (naming the field), 400 a call the model cannot serve
//! (FAILED_PRECONDITION: gradients from a model without them), 429 overload (with
//! `Retry-After`), 504 deadline exceeded, 503 unavailable, 500 internal.

use std::convert::Infallible;
use std::sync::Arc;

use axum::extract::{DefaultBodyLimit, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::sse::Event;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use dynaserve_api::FieldError;
use dynaserve_api::json;
use dynaserve_api::spec::{Frame, PredictSpec, RolloutSpec, Timing};
use futures::Stream;
use utoipa::OpenApi;

use crate::engine::{Engine, RequestCtx};
use crate::error::ApiError;
use extract::{AppState, Call, Spec, Streamed};
use reply::{Model, Predicted, Reply, RequestId, Timed, Warnings, collect_frames, sse, sse_event};

mod extract;
pub mod generate_route;
mod reply;
pub mod sessions;

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
        .merge(generate_route::routes())
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        // Bodies are read with the configured limit by the `Call` extractor, which names the
        // field.
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

impl Spec for RolloutSpec {
    const METHOD: &'static str = "rollout";
    type Json = json::RolloutRequest;
    fn read(r: &json::RolloutRequest, _: &str) -> Result<Self, FieldError> {
        RolloutSpec::from_json(r)
    }
    fn stream(r: &json::RolloutRequest) -> bool {
        r.stream
    }
}

impl Spec for PredictSpec {
    const METHOD: &'static str = "predict";
    type Json = json::PredictRequest;
    fn read(r: &json::PredictRequest, _: &str) -> Result<Self, FieldError> {
        PredictSpec::from_json(r)
    }
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
    Streamed { call, quota }: Streamed<RolloutSpec>,
) -> Reply {
    let (rid, arrival) = (RequestId::of(&call.ctx), call.ctx.arrival);
    let handle = match s.engine.start_rollout(call.spec, call.ctx).await {
        Ok(h) => h,
        Err(e) => return (rid, Err(e)),
    };
    let head = (Model(handle.model.clone()), Warnings(handle.warnings));
    if call.sse {
        let events = sse_events(handle.frames, rid.to_string(), arrival);
        return (rid, Ok((head, sse(events, quota)).into_response()));
    }
    let collected = collect_frames(handle.frames, arrival).await;
    drop(quota);
    let answer = collected.map(|(frames, timing)| {
        let body = json::RolloutResponse {
            model: handle.model,
            request_id: rid.to_string(),
            frames,
            timing,
        };
        (head, Timed(timing), Json(body)).into_response()
    });
    (rid, answer)
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
                sse_event("frame", &f.to_json())
            }
            Some(Err(e)) => {
                st.done = true;
                sse_event("error", &e.body())
            }
            None => {
                st.done = true;
                st.timing.total = st.arrival.elapsed();
                let done = json::SseDone {
                    request_id: st.request_id.clone(),
                    steps: st.steps,
                    timing: st.timing.to_json(),
                };
                sse_event("done", &done)
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
async fn predict(State(s): State<AppState>, call: Call<PredictSpec>) -> Reply<Predicted> {
    let rid = RequestId::of(&call.ctx);
    let prediction = s.engine.predict(call.spec, call.ctx).await;
    (rid, prediction.map(Predicted))
}

/// Resident models and the server's limits for each.
#[utoipa::path(
    get,
    path = "/v1/models",
    responses((status = 200, description = "Resident models", body = json::ListModelsResponse))
)]
async fn list_models(State(s): State<AppState>, ctx: RequestCtx) -> impl IntoResponse {
    let models = s
        .engine
        .list_models(&ctx)
        .iter()
        .map(|m| m.to_json())
        .collect();
    (
        RequestId::of(&ctx),
        Json(json::ListModelsResponse { models }),
    )
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
    doc.merge(generate_route::GenerateDoc::openapi());
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
