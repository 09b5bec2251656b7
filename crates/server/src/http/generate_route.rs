//! `POST /v1/generate`: a mesh scene sampled whole by a PhysiFormer model, with the same
//! semantics as the gRPC `Generate` call. Answers with every sample as JSON, or as
//! Server-Sent Events (`progress` per denoising step, `sample` per sample, then `done`, or one
//! `error`) when the body has `"stream": true` or the request sends
//! `Accept: text/event-stream`.

use std::convert::Infallible;
use std::time::Instant;

use axum::extract::State;
use axum::response::IntoResponse;
use axum::response::sse::Event;
use axum::routing::post;
use axum::{Json, Router};
use dynaserve_api::FieldError;
use dynaserve_api::json;
use dynaserve_api::spec::Timing;
use dynaserve_api::spec::sampling::{GenerateEvent, GenerateSpec};
use futures::Stream;
use tokio::sync::mpsc;
use utoipa::OpenApi;

use super::extract::{AppState, Spec, Streamed};
use super::reply::{Model, Reply, RequestId, Timed, sse, sse_event};
use crate::error::ApiError;

/// The OpenAPI description of `POST /v1/generate` (merged into the HTTP API's document).
#[derive(OpenApi)]
#[openapi(
    paths(generate),
    components(schemas(
        json::GenerateRequest,
        json::GenerateResponse,
        json::GenerateProgress,
        json::GeneratedSample,
        json::GenerateDone,
        json::MeshScene,
        json::MeshObject,
        json::MeshFrame,
        json::ObjectFrame,
        json::Material,
        json::Sampler,
    ))
)]
pub struct GenerateDoc;

/// The Generate route.
pub(super) fn routes() -> Router<AppState> {
    Router::new().route("/v1/generate", post(generate))
}

type Events = mpsc::Receiver<Result<GenerateEvent, ApiError>>;

impl Spec for GenerateSpec {
    const METHOD: &'static str = "generate";
    type Json = json::GenerateRequest;
    fn read(r: &json::GenerateRequest, _: &str) -> Result<Self, FieldError> {
        GenerateSpec::from_json(r)
    }
    fn stream(r: &json::GenerateRequest) -> bool {
        r.stream
    }
}

/// Sample whole trajectories of a mesh scene (rigid and elastic objects) with a PhysiFormer
/// model.
///
/// Returns every sample as JSON, or Server-Sent Events (`progress` events with a
/// `GenerateProgress` per denoising step, `sample` events with a `GeneratedSample`, then one
/// `done` event with a `GenerateDone`, or one `error` event with an `ErrorResponse`) when the
/// body has `"stream": true` or the request sends `Accept: text/event-stream`.
#[utoipa::path(
    post,
    path = "/v1/generate",
    request_body = json::GenerateRequest,
    responses(
        (status = 200, description = "Sampled trajectories (or an SSE stream of progress and sample events)", body = json::GenerateResponse),
        (status = 422, description = "Invalid input; `error.field` names the field", body = json::ErrorResponse),
        (status = 429, description = "Server full; retry after the Retry-After header", body = json::ErrorResponse),
        (status = 503, description = "Warming up or shutting down", body = json::ErrorResponse),
        (status = 504, description = "Deadline (`timeout_ms`) exceeded", body = json::ErrorResponse),
    )
)]
async fn generate(
    State(s): State<AppState>,
    Streamed { call, quota }: Streamed<GenerateSpec>,
) -> Reply {
    let (rid, arrival) = (RequestId::of(&call.ctx), call.ctx.arrival);
    let handle = match s.engine.start_generate(call.spec, call.ctx).await {
        Ok(h) => h,
        Err(e) => return (rid, Err(e)),
    };
    let model = Model(handle.model.clone());
    if call.sse {
        let events = sse_events(handle.events, rid.to_string(), arrival);
        return (rid, Ok((model, sse(events, quota)).into_response()));
    }
    let collected = collect(handle.events, arrival).await;
    drop(quota);
    let answer = collected.map(|(samples, timing)| {
        let body = json::GenerateResponse {
            model: handle.model,
            request_id: rid.to_string(),
            denoise_steps: handle.steps,
            samples,
            timing,
        };
        (model, Timed(timing), Json(body)).into_response()
    });
    (rid, answer)
}

/// Every sample of a call, with the summed step timings (total: since `arrival`); the first
/// error ends it.
async fn collect(
    mut rx: Events,
    arrival: Instant,
) -> Result<(Vec<json::GeneratedSample>, json::RequestTiming), ApiError> {
    let mut samples = Vec::new();
    let mut timing = Timing::default();
    while let Some(item) = rx.recv().await {
        match item? {
            GenerateEvent::Progress(p) => timing.add_step(&p.timing),
            GenerateEvent::Sample(s) => samples.push(s.to_json()),
        }
    }
    timing.total = arrival.elapsed();
    Ok((samples, timing.to_json()))
}

fn sse_events(
    rx: Events,
    request_id: String,
    arrival: Instant,
) -> impl Stream<Item = Result<Event, Infallible>> {
    struct St {
        rx: Events,
        timing: Timing,
        samples: u32,
        done: bool,
        request_id: String,
        arrival: Instant,
    }
    let st = St {
        rx,
        timing: Timing::default(),
        samples: 0,
        done: false,
        request_id,
        arrival,
    };
    futures::stream::unfold(st, |mut st| async move {
        if st.done {
            return None;
        }
        let event = match st.rx.recv().await {
            Some(Ok(GenerateEvent::Progress(p))) => {
                st.timing.add_step(&p.timing);
                sse_event("progress", &p.to_json())
            }
            Some(Ok(GenerateEvent::Sample(s))) => {
                st.samples += 1;
                sse_event("sample", &s.to_json())
            }
            Some(Err(e)) => {
                st.done = true;
                sse_event("error", &e.body())
            }
            None => {
                st.done = true;
                st.timing.total = st.arrival.elapsed();
                let done = json::GenerateDone {
                    request_id: st.request_id.clone(),
                    samples: st.samples,
                    timing: st.timing.to_json(),
                };
                sse_event("done", &done)
            }
        };
        Some((Ok(event), st))
    })
}
