//! What an HTTP handler extracts from its request: the [`RequestCtx`] of any call, and a
//! [`Call`] (context plus the body read into an engine spec) for calls with a JSON body.
//!
//! A body that cannot be read, decoded or converted rejects the call the way the engine
//! would: it is counted as a failed call of its method ([`Engine::reject`]) and answered with
//! the error and the request id.

use std::sync::Arc;

use axum::body::Body;
use axum::extract::{FromRequest, FromRequestParts, Path, Request};
use axum::http::request::Parts;
use axum::http::{HeaderMap, header};
use axum::response::{IntoResponse, Response};
use dynaserve_api::FieldError;
use serde::de::DeserializeOwned;

use super::reply::RequestId;
use crate::engine::sessions::StreamQuota;
use crate::engine::{Engine, Protocol, RequestCtx};
use crate::error::ApiError;
use crate::security::Caller;

/// The state of the HTTP routes: the engine their handlers call.
#[derive(Clone)]
pub(super) struct AppState {
    /// The engine.
    pub engine: Arc<Engine>,
}

/// The context of an HTTP request: its `x-request-id` (when valid) and its caller.
impl<S: Send + Sync> FromRequestParts<S> for RequestCtx {
    type Rejection = std::convert::Infallible;

    async fn from_request_parts(parts: &mut Parts, _state: &S) -> Result<Self, Self::Rejection> {
        let rid = parts
            .headers
            .get("x-request-id")
            .and_then(|v| v.to_str().ok());
        let caller = Caller::of(&parts.extensions);
        Ok(RequestCtx::new(Protocol::Http, rid, None).with_identity(caller.0))
    }
}

/// An engine spec read from a JSON request body.
pub(super) trait Spec: Sized + Send {
    /// The method the call is counted and logged as.
    const METHOD: &'static str;
    /// The JSON body.
    type Json: DeserializeOwned;
    /// The spec of `json`; `session_id` is the route's `{id}` (empty on routes without one).
    fn read(json: &Self::Json, session_id: &str) -> Result<Self, FieldError>;
    /// Whether `json` asks for server-sent events (`"stream": true`).
    fn stream(_json: &Self::Json) -> bool {
        false
    }
}

/// A call with a JSON body: its context and the body read as `T`.
pub(super) struct Call<T> {
    /// The request's context.
    pub ctx: RequestCtx,
    /// The body.
    pub spec: T,
    /// Whether the answer is asked for as server-sent events (the body's `"stream": true` or
    /// `Accept: text/event-stream`); only streaming routes look at it.
    pub sse: bool,
}

impl<T: Spec> FromRequest<AppState> for Call<T> {
    type Rejection = Response;

    async fn from_request(req: Request, state: &AppState) -> Result<Self, Response> {
        let (mut parts, body) = req.into_parts();
        let id = Option::<Path<String>>::from_request_parts(&mut parts, state)
            .await
            .map_err(IntoResponse::into_response)?;
        let Ok(ctx) = RequestCtx::from_request_parts(&mut parts, state).await;
        let engine = &state.engine;
        let read = read_json::<T::Json>(engine, body).await.and_then(|json| {
            let spec = T::read(&json, id.as_ref().map_or("", |p| &p.0))?;
            Ok((spec, T::stream(&json) || wants_sse(&parts.headers)))
        });
        let (spec, sse) = read.map_err(|e| reject(engine, &ctx, T::METHOD, e))?;
        Ok(Call { ctx, spec, sse })
    }
}

/// A streaming call: a [`Call`] that holds one of its caller's streams until its answer is
/// complete; a caller over its stream quota is rejected.
pub(super) struct Streamed<T> {
    /// The call.
    pub call: Call<T>,
    /// The caller's stream, released when dropped.
    pub quota: StreamQuota,
}

impl<T: Spec> FromRequest<AppState> for Streamed<T> {
    type Rejection = Response;

    async fn from_request(req: Request, state: &AppState) -> Result<Self, Response> {
        let call = Call::<T>::from_request(req, state).await?;
        let engine = &state.engine;
        let quota = engine
            .stream_quota(&call.ctx)
            .map_err(|e| reject(engine, &call.ctx, T::METHOD, e))?;
        Ok(Streamed { call, quota })
    }
}

/// Counts `e` as a rejected `method` call and answers it with the request id.
fn reject(engine: &Engine, ctx: &RequestCtx, method: &'static str, e: ApiError) -> Response {
    (RequestId::of(ctx), engine.reject(ctx, method, e)).into_response()
}

/// Reads a JSON body within the configured size limit; a failure names the field.
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
