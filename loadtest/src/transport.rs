//! The two wire protocols: gRPC through `dynaserve-client`, and the HTTP JSON / Server-Sent
//! Events API through a minimal HTTP/1.1 client on hyper (one keep-alive connection per
//! caller, as a browser or a simple client would use).

use std::time::Instant;

use bytes::Bytes;
use dynaserve_client::{Client, ClientError};
use dynaserve_proto::json;
use futures::StreamExt;
use http_body_util::{BodyExt, Full};
use hyper::client::conn::http1::SendRequest;
use hyper::{Request, Uri};
use hyper_util::rt::TokioIo;

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

/// Canonical upper-case name of a gRPC status code.
pub fn grpc_code_name(code: tonic::Code) -> &'static str {
    use tonic::Code::*;
    match code {
        Ok => "OK",
        Cancelled => "CANCELLED",
        Unknown => "UNKNOWN",
        InvalidArgument => "INVALID_ARGUMENT",
        DeadlineExceeded => "DEADLINE_EXCEEDED",
        NotFound => "NOT_FOUND",
        AlreadyExists => "ALREADY_EXISTS",
        PermissionDenied => "PERMISSION_DENIED",
        ResourceExhausted => "RESOURCE_EXHAUSTED",
        FailedPrecondition => "FAILED_PRECONDITION",
        Aborted => "ABORTED",
        OutOfRange => "OUT_OF_RANGE",
        Unimplemented => "UNIMPLEMENTED",
        Internal => "INTERNAL",
        Unavailable => "UNAVAILABLE",
        DataLoss => "DATA_LOSS",
        Unauthenticated => "UNAUTHENTICATED",
    }
}

impl From<ClientError> for CallError {
    fn from(e: ClientError) -> CallError {
        let retry_after_ms = e.retry_after().map(|d| d.as_millis() as u64);
        let (code, message) = match &e {
            ClientError::Connect { .. } => ("connect".to_string(), e.to_string()),
            ClientError::Status(s) => (
                format!("grpc {}", grpc_code_name(s.code())),
                s.message().to_string(),
            ),
            ClientError::File { .. } => ("file".to_string(), e.to_string()),
        };
        CallError {
            code,
            message,
            retry_after_ms,
        }
    }
}

/// Host and port of an `http://host:port` URL.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HttpBase {
    /// Host name or address.
    pub host: String,
    /// Port (80 when the URL has none).
    pub port: u16,
}

impl HttpBase {
    /// Parses `http://host:port[/]`; other schemes and paths are rejected.
    pub fn parse(url: &str) -> Result<HttpBase, String> {
        let uri: Uri = url
            .parse()
            .map_err(|e| format!("{url:?} is not a URL: {e}"))?;
        match uri.scheme_str() {
            Some("http") => {}
            Some(s) => return Err(format!("{url:?}: only http:// is supported, not {s}://")),
            None => return Err(format!("{url:?}: expected http://host:port")),
        }
        let host = uri
            .host()
            .ok_or_else(|| format!("{url:?} has no host"))?
            .trim_start_matches('[')
            .trim_end_matches(']')
            .to_string();
        Ok(HttpBase {
            host,
            port: uri.port_u16().unwrap_or(80),
        })
    }

    /// `host:port` for the Host header.
    pub fn authority(&self) -> String {
        if self.host.contains(':') {
            format!("[{}]:{}", self.host, self.port)
        } else {
            format!("{}:{}", self.host, self.port)
        }
    }
}

/// One HTTP/1.1 keep-alive connection, reopened after a failure.
pub struct HttpConn {
    base: HttpBase,
    sender: Option<SendRequest<Full<Bytes>>>,
}

/// A response: status, selected headers, and the body still to be read.
pub struct HttpResponse {
    /// Status code.
    pub status: u16,
    /// `Retry-After` in milliseconds, when sent.
    pub retry_after_ms: Option<u64>,
    /// Response headers.
    pub headers: hyper::HeaderMap,
    /// The body.
    pub body: hyper::body::Incoming,
}

impl HttpConn {
    /// A connection to `base`, opened on first use.
    pub fn new(base: HttpBase) -> HttpConn {
        HttpConn { base, sender: None }
    }

    async fn connect(&mut self) -> Result<(), CallError> {
        let addr = (self.base.host.as_str(), self.base.port);
        let stream = tokio::net::TcpStream::connect(addr)
            .await
            .map_err(|e| CallError::new("connect", format!("{}: {e}", self.base.authority())))?;
        let _ = stream.set_nodelay(true);
        let (sender, conn) = hyper::client::conn::http1::handshake(TokioIo::new(stream))
            .await
            .map_err(|e| CallError::new("connect", format!("{}: {e}", self.base.authority())))?;
        tokio::spawn(async move {
            let _ = conn.await;
        });
        self.sender = Some(sender);
        Ok(())
    }

    /// Sends one request; `body` is JSON when given.
    pub async fn send(
        &mut self,
        method: &str,
        path: &str,
        body: Option<Bytes>,
        accept: &str,
    ) -> Result<HttpResponse, CallError> {
        if self.sender.as_ref().is_none_or(|s| s.is_closed()) {
            self.connect().await?;
        }
        let Some(sender) = self.sender.as_mut() else {
            return Err(CallError::new("connect", "no connection"));
        };
        if sender.ready().await.is_err() {
            self.sender = None;
            self.connect().await?;
        }
        let mut builder = Request::builder()
            .method(method)
            .uri(path)
            .header(hyper::header::HOST, self.base.authority())
            .header(hyper::header::ACCEPT, accept);
        if body.is_some() {
            builder = builder.header(hyper::header::CONTENT_TYPE, "application/json");
        }
        let req = builder
            .body(Full::new(body.unwrap_or_default()))
            .map_err(|e| CallError::new("client", e.to_string()))?;
        let Some(sender) = self.sender.as_mut() else {
            return Err(CallError::new("connect", "no connection"));
        };
        let resp = match sender.send_request(req).await {
            Ok(r) => r,
            Err(e) => {
                self.sender = None;
                return Err(CallError::new("transport", e.to_string()));
            }
        };
        let status = resp.status().as_u16();
        let retry_after_ms = resp
            .headers()
            .get(hyper::header::RETRY_AFTER)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.trim().parse::<f64>().ok())
            .map(|s| (s * 1000.0) as u64);
        let (parts, body) = resp.into_parts();
        Ok(HttpResponse {
            status,
            retry_after_ms,
            headers: parts.headers,
            body,
        })
    }

    /// GET `path` and read the whole body as text.
    pub async fn get_text(&mut self, path: &str) -> Result<(u16, String), CallError> {
        let r = self.send("GET", path, None, "*/*").await?;
        let status = r.status;
        let bytes = read_all(r.body).await.inspect_err(|_| self.sender = None)?;
        Ok((status, String::from_utf8_lossy(&bytes).into_owned()))
    }
}

async fn read_all(body: hyper::body::Incoming) -> Result<Bytes, CallError> {
    body.collect()
        .await
        .map(|c| c.to_bytes())
        .map_err(|e| CallError::new("transport", e.to_string()))
}

/// Turns a non-200 HTTP answer into an error keyed by its status and the error document's
/// code (`http 429 RESOURCE_EXHAUSTED`).
async fn http_error(resp: HttpResponse) -> CallError {
    let status = resp.status;
    let retry = resp.retry_after_ms;
    let text = read_all(resp.body)
        .await
        .map(|b| String::from_utf8_lossy(&b).into_owned())
        .unwrap_or_default();
    let (code, message) = match serde_json::from_str::<json::ErrorResponse>(&text) {
        Ok(e) => (
            format!("http {status} {}", e.error.code),
            match e.error.field {
                Some(f) => format!("{f}: {}", e.error.message),
                None => e.error.message,
            },
        ),
        Err(_) => (format!("http {status}"), text.chars().take(200).collect()),
    };
    CallError {
        code,
        message,
        retry_after_ms: retry.or_else(|| {
            serde_json::from_str::<json::ErrorResponse>(&text)
                .ok()
                .and_then(|e| e.error.retry_after_ms)
        }),
    }
}

/// Incremental Server-Sent Events parser: feed bytes, take complete `(event, data)` pairs.
#[derive(Default, Debug)]
pub struct SseParser {
    buf: Vec<u8>,
}

impl SseParser {
    /// Appends received bytes and returns the events completed by them.
    pub fn feed(&mut self, bytes: &[u8]) -> Vec<(String, String)> {
        self.buf.extend_from_slice(bytes);
        let mut out = Vec::new();
        loop {
            // Events end with a blank line; accept \n\n and \r\n\r\n.
            let lf = self
                .buf
                .windows(2)
                .position(|w| w == b"\n\n")
                .map(|p| (p, 2));
            let crlf = self
                .buf
                .windows(4)
                .position(|w| w == b"\r\n\r\n")
                .map(|p| (p, 4));
            let end = match (lf, crlf) {
                (Some(a), Some(b)) => Some(if a.0 <= b.0 { a } else { b }),
                (a, b) => a.or(b),
            };
            let Some((pos, len)) = end else { break };
            let block: Vec<u8> = self.buf.drain(..pos + len).collect();
            let text = String::from_utf8_lossy(&block[..pos]);
            let mut event = String::from("message");
            let mut data = String::new();
            for line in text.lines() {
                let line = line.trim_end_matches('\r');
                if let Some(v) = line.strip_prefix("event:") {
                    event = v.trim().to_string();
                } else if let Some(v) = line.strip_prefix("data:") {
                    if !data.is_empty() {
                        data.push('\n');
                    }
                    data.push_str(v.strip_prefix(' ').unwrap_or(v));
                }
            }
            if !data.is_empty() {
                out.push((event, data));
            }
        }
        out
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
            Conn::Http(h) => {
                let body = serde_json::to_vec(request)
                    .map_err(|e| CallError::new("client", e.to_string()))?;
                let resp = h
                    .send(
                        "POST",
                        "/v1/rollout",
                        Some(body.into()),
                        "text/event-stream",
                    )
                    .await?;
                if resp.status != 200 {
                    return Err(http_error(resp).await);
                }
                let mut body = resp.body;
                let mut parser = SseParser::default();
                let mut done = false;
                while let Some(frame) = body.frame().await {
                    let frame = frame.map_err(|e| {
                        h.sender = None;
                        CallError::new("transport", e.to_string())
                    })?;
                    let Some(data) = frame.data_ref() else {
                        continue;
                    };
                    for (event, data) in parser.feed(data) {
                        match event.as_str() {
                            "frame" => {
                                let f: json::StepFrame =
                                    serde_json::from_str(&data).map_err(|e| {
                                        CallError::new("protocol", format!("bad frame: {e}"))
                                    })?;
                                n += 1;
                                on_frame(Instant::now(), &f);
                            }
                            "error" => {
                                let e: json::ErrorResponse =
                                    serde_json::from_str(&data).map_err(|e| {
                                        CallError::new("protocol", format!("bad error event: {e}"))
                                    })?;
                                return Err(CallError {
                                    code: format!("sse {}", e.error.code),
                                    message: e.error.message,
                                    retry_after_ms: e.error.retry_after_ms,
                                });
                            }
                            "done" => done = true,
                            _ => {}
                        }
                    }
                }
                if !done {
                    return Err(CallError::new(
                        "incomplete",
                        format!("event stream ended after {n} frames without `done`"),
                    ));
                }
            }
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
            Conn::Http(h) => {
                let body = serde_json::to_vec(request)
                    .map_err(|e| CallError::new("client", e.to_string()))?;
                let resp = h
                    .send("POST", "/v1/predict", Some(body.into()), "application/json")
                    .await?;
                if resp.status != 200 {
                    return Err(http_error(resp).await);
                }
                let bytes = read_all(resp.body).await.inspect_err(|_| h.sender = None)?;
                serde_json::from_slice(&bytes)
                    .map_err(|e| CallError::new("protocol", format!("bad predict response: {e}")))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sse_events_split_across_reads() {
        let mut p = SseParser::default();
        assert!(p.feed(b"event: frame\ndata: {\"a\"").is_empty());
        let ev = p.feed(b":1}\n\n: keep-alive\n\nevent: done\r\ndata: x\r\n\r\n");
        assert_eq!(
            ev,
            vec![
                ("frame".to_string(), "{\"a\":1}".to_string()),
                ("done".to_string(), "x".to_string())
            ]
        );
        assert!(p.feed(b"").is_empty());
    }

    #[test]
    fn base_urls() {
        let b = HttpBase::parse("http://127.0.0.1:8080/").unwrap();
        assert_eq!((b.host.as_str(), b.port), ("127.0.0.1", 8080));
        assert_eq!(b.authority(), "127.0.0.1:8080");
        assert_eq!(
            HttpBase::parse("http://[::1]:9").unwrap().authority(),
            "[::1]:9"
        );
        assert!(HttpBase::parse("https://x:1").is_err());
        assert!(HttpBase::parse("localhost:1").is_err());
    }
}
