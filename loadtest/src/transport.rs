//! The two wire protocols, both through `dynaserve-client`: gRPC ([`Client`]) and the HTTP
//! JSON / Server-Sent Events API ([`HttpConn`], one keep-alive connection per caller), behind
//! one [`Conn`], with their failures as one [`CallError`] counted by code; and [`http_get`],
//! the one-shot GET of `/metrics`, readiness and model lists.

use std::time::{Duration, Instant};

use dynaserve_api::{code_name, json};
use dynaserve_client::http::{HttpBase, HttpConn, HttpError};
use dynaserve_client::{Client, ClientError};
use futures::StreamExt;

/// A failed call: a short code used to count errors (`grpc RESOURCE_EXHAUSTED`, `http 429`,
/// `connect`, `incomplete`, ...) and the message.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{code}: {message}")]
pub struct CallError {
    /// Counting key.
    pub code: String,
    /// Human-readable detail.
    pub message: String,
    /// Retry hint sent with an overload answer, milliseconds.
    pub retry_after_ms: Option<u64>,
}

impl CallError {
    /// An error with no retry hint.
    pub fn new(code: impl Into<String>, message: impl Into<String>) -> CallError {
        CallError {
            code: code.into(),
            message: message.into(),
            retry_after_ms: None,
        }
    }
}

impl From<ClientError> for CallError {
    fn from(e: ClientError) -> CallError {
        let retry_after_ms = e.retry_after().map(|d| d.as_millis() as u64);
        let (code, message) = match &e {
            ClientError::Connect { .. } => ("connect".to_string(), e.to_string()),
            ClientError::Status(s) => (
                format!("grpc {}", code_name(s.code())),
                s.message().to_string(),
            ),
            ClientError::File { .. } => ("file".to_string(), e.to_string()),
            ClientError::Metadata { .. } => ("metadata".to_string(), e.to_string()),
            ClientError::StreamEnded(_) => ("incomplete".to_string(), e.to_string()),
        };
        CallError {
            code,
            message,
            retry_after_ms,
        }
    }
}

impl From<HttpError> for CallError {
    fn from(e: HttpError) -> CallError {
        CallError {
            code: e.code,
            message: e.message,
            retry_after_ms: e.retry_after_ms,
        }
    }
}

/// A connection of either protocol.
pub enum Conn {
    /// gRPC (HTTP/2; clones of one [`Client`] share its connection).
    Grpc(Client),
    /// HTTP JSON / SSE over one HTTP/1.1 connection.
    Http(HttpConn),
}

impl Conn {
    /// Runs a streamed rollout, calling `on_frame(arrival time, frame)` for every frame.
    /// Returns the number of frames; fewer than `request.steps` is an `incomplete` error.
    pub async fn rollout(
        &mut self,
        request: &json::RolloutRequest,
        on_frame: &mut (dyn FnMut(Instant, &json::StepFrame) + Send),
    ) -> Result<u32, CallError> {
        let mut n = 0u32;
        match self {
            Conn::Grpc(c) => {
                let mut rollout = c.rollout(request).await?;
                while let Some(f) = rollout.frames.next().await {
                    let f = f?;
                    n += 1;
                    on_frame(Instant::now(), &f);
                }
            }
            Conn::Http(h) => n = h.rollout_sse(request, on_frame).await?,
        }
        if n < request.steps {
            return Err(CallError::new(
                "incomplete",
                format!("{n} of {} frames", request.steps),
            ));
        }
        Ok(n)
    }

    /// One planner call.
    pub async fn predict(
        &mut self,
        request: &json::PredictRequest,
    ) -> Result<json::PredictResponse, CallError> {
        match self {
            Conn::Grpc(c) => Ok(c.predict(request).await?),
            Conn::Http(h) => Ok(h.predict(request).await?),
        }
    }
}

/// GET a URL over HTTP and return the body when the status is 200.
pub async fn http_get(url: &str) -> Result<String, String> {
    let base = HttpBase::parse(url)?;
    let uri: hyper::Uri = url.parse().map_err(|e| format!("{url}: {e}"))?;
    let path = uri.path_and_query().map_or("/", |p| p.as_str()).to_string();
    let mut c = HttpConn::new(base);
    let (status, text) = tokio::time::timeout(Duration::from_secs(10), c.get_text(&path))
        .await
        .map_err(|_| format!("{url}: no answer within 10 s"))?
        .map_err(|e| format!("{url}: {e}"))?;
    if status != 200 {
        return Err(format!("{url}: HTTP {status}"));
    }
    Ok(text)
}
