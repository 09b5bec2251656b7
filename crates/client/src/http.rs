//! The HTTP JSON / Server-Sent Events API through a small HTTP/1.1 client on hyper: one
//! keep-alive connection per [`HttpConn`], reopened after a failure, as a browser or a simple
//! client would use. Rollouts stream as SSE (`frame` events, then `done` or `error`).

use std::time::Instant;

use bytes::Bytes;
use dynaserve_api::json;
use http_body_util::{BodyExt, Full};
use hyper::client::conn::http1::SendRequest;
use hyper::{Request, Uri};
use hyper_util::rt::TokioIo;

/// A failed HTTP call: a short code for counting errors (`connect`, `transport`, `protocol`,
/// `incomplete`, `http 429 RESOURCE_EXHAUSTED`, `sse DEADLINE_EXCEEDED`, ...), the message and
/// the retry hint of an overload answer.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{code}: {message}")]
pub struct HttpError {
    /// Counting key.
    pub code: String,
    /// Human-readable detail.
    pub message: String,
    /// Retry hint sent with an overload answer, milliseconds.
    pub retry_after_ms: Option<u64>,
}

impl HttpError {
    /// An error with no retry hint.
    pub fn new(code: impl Into<String>, message: impl Into<String>) -> HttpError {
        HttpError {
            code: code.into(),
            message: message.into(),
            retry_after_ms: None,
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
    /// Parses `http://host:port[/]`; other schemes are rejected.
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

    /// The base of a socket address.
    pub fn from_addr(addr: std::net::SocketAddr) -> HttpBase {
        HttpBase {
            host: addr.ip().to_string(),
            port: addr.port(),
        }
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

/// A response: status, headers, and the body still to be read.
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

/// Reads a whole body.
pub async fn read_all(body: hyper::body::Incoming) -> Result<Bytes, HttpError> {
    body.collect()
        .await
        .map(|c| c.to_bytes())
        .map_err(|e| HttpError::new("transport", e.to_string()))
}

/// Turns a non-200 answer into an error keyed by its status and the error document's code
/// (`http 429 RESOURCE_EXHAUSTED`), with the field in the message.
pub async fn error_of(resp: HttpResponse) -> HttpError {
    let status = resp.status;
    let retry = resp.retry_after_ms;
    let text = read_all(resp.body)
        .await
        .map(|b| String::from_utf8_lossy(&b).into_owned())
        .unwrap_or_default();
    match serde_json::from_str::<json::ErrorResponse>(&text) {
        Ok(e) => HttpError {
            code: format!("http {status} {}", e.error.code),
            message: match e.error.field {
                Some(f) => format!("{f}: {}", e.error.message),
                None => e.error.message,
            },
            retry_after_ms: retry.or(e.error.retry_after_ms),
        },
        Err(_) => HttpError {
            code: format!("http {status}"),
            message: text.chars().take(200).collect(),
            retry_after_ms: retry,
        },
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

    /// Every complete event of a whole event-stream text.
    pub fn parse_all(text: &str) -> Vec<(String, String)> {
        SseParser::default().feed(text.as_bytes())
    }
}

/// One HTTP/1.1 keep-alive connection, opened on first use and reopened after a failure.
pub struct HttpConn {
    base: HttpBase,
    sender: Option<SendRequest<Full<Bytes>>>,
}

impl HttpConn {
    /// A connection to `base`, opened on first use.
    pub fn new(base: HttpBase) -> HttpConn {
        HttpConn { base, sender: None }
    }

    async fn connect(&mut self) -> Result<(), HttpError> {
        let addr = (self.base.host.as_str(), self.base.port);
        let fail = |e: &dyn std::fmt::Display| {
            HttpError::new("connect", format!("{}: {e}", self.base.authority()))
        };
        let stream = tokio::net::TcpStream::connect(addr)
            .await
            .map_err(|e| fail(&e))?;
        let _ = stream.set_nodelay(true);
        let (sender, conn) = hyper::client::conn::http1::handshake(TokioIo::new(stream))
            .await
            .map_err(|e| fail(&e))?;
        tokio::spawn(async move {
            let _ = conn.await;
        });
        self.sender = Some(sender);
        Ok(())
    }

    /// Sends one request with extra `headers`; `body` is sent as JSON when given.
    pub async fn request(
        &mut self,
        method: &str,
        path: &str,
        headers: &[(&str, &str)],
        body: Option<Bytes>,
    ) -> Result<HttpResponse, HttpError> {
        if self.sender.as_ref().is_none_or(|s| s.is_closed()) {
            self.connect().await?;
        }
        let Some(sender) = self.sender.as_mut() else {
            return Err(HttpError::new("connect", "no connection"));
        };
        if sender.ready().await.is_err() {
            self.sender = None;
            self.connect().await?;
        }
        let mut builder = Request::builder()
            .method(method)
            .uri(path)
            .header(hyper::header::HOST, self.base.authority());
        if body.is_some() {
            builder = builder.header(hyper::header::CONTENT_TYPE, "application/json");
        }
        for (k, v) in headers {
            builder = builder.header(*k, *v);
        }
        let req = builder
            .body(Full::new(body.unwrap_or_default()))
            .map_err(|e| HttpError::new("client", e.to_string()))?;
        let Some(sender) = self.sender.as_mut() else {
            return Err(HttpError::new("connect", "no connection"));
        };
        let resp = match sender.send_request(req).await {
            Ok(r) => r,
            Err(e) => {
                self.sender = None;
                return Err(HttpError::new("transport", e.to_string()));
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

    /// Reads a whole body, forgetting the connection if that fails.
    async fn body_of(&mut self, body: hyper::body::Incoming) -> Result<Bytes, HttpError> {
        read_all(body).await.inspect_err(|_| self.sender = None)
    }

    /// GET `path` and read the whole body as text.
    pub async fn get_text(&mut self, path: &str) -> Result<(u16, String), HttpError> {
        let r = self
            .request("GET", path, &[("accept", "*/*")], None)
            .await?;
        let status = r.status;
        let bytes = self.body_of(r.body).await?;
        Ok((status, String::from_utf8_lossy(&bytes).into_owned()))
    }

    /// A streamed rollout (`POST /v1/rollout` as Server-Sent Events), calling
    /// `on_frame(arrival time, frame)` for every frame. Returns the number of frames; a stream
    /// that ends without its `done` event is an `incomplete` error.
    pub async fn rollout_sse(
        &mut self,
        request: &json::RolloutRequest,
        on_frame: &mut (dyn FnMut(Instant, &json::StepFrame) + Send),
    ) -> Result<u32, HttpError> {
        let body =
            serde_json::to_vec(request).map_err(|e| HttpError::new("client", e.to_string()))?;
        let resp = self
            .request(
                "POST",
                "/v1/rollout",
                &[("accept", "text/event-stream")],
                Some(body.into()),
            )
            .await?;
        if resp.status != 200 {
            return Err(error_of(resp).await);
        }
        let mut body = resp.body;
        let mut parser = SseParser::default();
        let mut n = 0;
        let mut done = false;
        // Read to the end of the body even after `done`, so the connection can be reused.
        while let Some(frame) = body.frame().await {
            let frame = frame.map_err(|e| {
                self.sender = None;
                HttpError::new("transport", e.to_string())
            })?;
            let Some(data) = frame.data_ref() else {
                continue;
            };
            for (event, data) in parser.feed(data) {
                match event.as_str() {
                    "frame" => {
                        let f: json::StepFrame = serde_json::from_str(&data)
                            .map_err(|e| HttpError::new("protocol", format!("bad frame: {e}")))?;
                        n += 1;
                        on_frame(Instant::now(), &f);
                    }
                    "error" => {
                        let e: json::ErrorResponse = serde_json::from_str(&data).map_err(|e| {
                            HttpError::new("protocol", format!("bad error event: {e}"))
                        })?;
                        return Err(HttpError {
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
        if done {
            Ok(n)
        } else {
            Err(HttpError::new(
                "incomplete",
                format!("event stream ended after {n} frames without `done`"),
            ))
        }
    }

    /// One planner call (`POST /v1/predict`).
    pub async fn predict(
        &mut self,
        request: &json::PredictRequest,
    ) -> Result<json::PredictResponse, HttpError> {
        let body =
            serde_json::to_vec(request).map_err(|e| HttpError::new("client", e.to_string()))?;
        let resp = self
            .request(
                "POST",
                "/v1/predict",
                &[("accept", "application/json")],
                Some(body.into()),
            )
            .await?;
        if resp.status != 200 {
            return Err(error_of(resp).await);
        }
        let bytes = self.body_of(resp.body).await?;
        serde_json::from_slice(&bytes)
            .map_err(|e| HttpError::new("protocol", format!("bad predict response: {e}")))
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
        assert_eq!(
            HttpBase::from_addr("[::1]:9".parse().unwrap()).authority(),
            "[::1]:9"
        );
        assert!(HttpBase::parse("https://x:1").is_err());
        assert!(HttpBase::parse("localhost:1").is_err());
    }
}
