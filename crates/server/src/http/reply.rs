//! How an HTTP handler answers: a [`Reply`] is the call's request id and its outcome, a
//! response or an [`ApiError`] (whose `IntoResponse` gives the status, the error document and
//! `Retry-After`). The other types here are the headers and bodies the answers share.

use std::convert::Infallible;
use std::sync::Arc;

use axum::Json;
use axum::http::{HeaderMap, HeaderValue};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, IntoResponseParts, Response, ResponseParts};
use dynaserve_api::json;
use dynaserve_api::spec::{Frame, Prediction, Timing};
use futures::Stream;

use crate::engine::RequestCtx;
use crate::engine::sessions::StreamQuota;
use crate::error::ApiError;

/// A handler's answer: the request id (sent as `x-request-id`) and the outcome.
pub(super) type Reply<R = Response> = (RequestId, Result<R, ApiError>);

/// The id of a request, sent back as `x-request-id`.
#[derive(Clone, Debug)]
pub(super) struct RequestId(Arc<str>);

impl RequestId {
    /// The id of `ctx`.
    pub fn of(ctx: &RequestCtx) -> RequestId {
        RequestId(ctx.request_id.clone())
    }
}

impl std::fmt::Display for RequestId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl IntoResponseParts for RequestId {
    type Error = Infallible;

    fn into_response_parts(self, mut res: ResponseParts) -> Result<ResponseParts, Infallible> {
        set_header(res.headers_mut(), "x-request-id", &self.0);
        Ok(res)
    }
}

/// The model that answered, as `x-dynaserve-model`.
pub(super) struct Model(pub String);

impl IntoResponseParts for Model {
    type Error = Infallible;

    fn into_response_parts(self, mut res: ResponseParts) -> Result<ResponseParts, Infallible> {
        set_header(res.headers_mut(), "x-dynaserve-model", &self.0);
        Ok(res)
    }
}

/// One `x-dynaserve-warning` header per warning (object parameters outside the model's trained
/// range).
pub(super) struct Warnings(pub Vec<String>);

impl IntoResponseParts for Warnings {
    type Error = Infallible;

    fn into_response_parts(self, mut res: ResponseParts) -> Result<ResponseParts, Infallible> {
        for w in &self.0 {
            if let Ok(v) = HeaderValue::from_str(w) {
                res.headers_mut().append(dynaserve_api::WARNING_HEADER, v);
            }
        }
        Ok(res)
    }
}

/// The timings of a call that stepped scenes: `x-dynaserve-queue-ms`, `-forward-ms`,
/// `-total-ms` and the same as `Server-Timing`.
pub(super) struct Timed(pub json::RequestTiming);

impl IntoResponseParts for Timed {
    type Error = Infallible;

    fn into_response_parts(self, mut res: ResponseParts) -> Result<ResponseParts, Infallible> {
        let (t, headers) = (self.0, res.headers_mut());
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
        Ok(res)
    }
}

/// The answer of a Predict call (whole scenes or from a session).
pub(super) struct Predicted(pub Prediction);

impl IntoResponse for Predicted {
    fn into_response(self) -> Response {
        let body = self.0.to_json();
        let head = (Model(body.model.clone()), Timed(body.timing));
        (head, Warnings(self.0.warnings), Json(body)).into_response()
    }
}

/// One Server-Sent Event named `name` whose data is `body` as JSON.
pub(super) fn sse_event(name: &str, body: &impl serde::Serialize) -> Event {
    Event::default()
        .event(name)
        .data(serde_json::to_string(body).unwrap_or_default())
}

/// A server-sent-event stream of `events` with keep-alive comments; it holds the caller's
/// stream `quota` until it ends.
pub(super) fn sse<S>(events: S, quota: StreamQuota) -> impl IntoResponse
where
    S: Stream<Item = Result<Event, Infallible>> + Send + 'static,
{
    let events = futures::StreamExt::map(events, move |e| {
        let _ = &quota;
        e
    });
    Sse::new(events).keep_alive(KeepAlive::default())
}

/// Receives every frame of a stepping call, with the summed step timings (total: since
/// `arrival`); the first error ends it.
pub(super) async fn collect_frames(
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

fn set_header(headers: &mut HeaderMap, key: &'static str, value: &str) {
    if let Ok(v) = HeaderValue::from_str(value) {
        headers.insert(key, v);
    }
}
