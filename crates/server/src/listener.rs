//! The accept loop of both listeners: a cap on open connections, an optional TLS handshake,
//! and the connection timeouts `axum::serve` does not offer.
//!
//! - At most `--max-connections` per listener, and at most `--max-connections-per-peer` from
//!   one IP address; a connection over either cap is closed at once.
//! - A connection must deliver a request's headers within `--header-read-timeout-s` of being
//!   accepted (TLS handshake, HTTP/2 preface and settings included); HTTP/1 connections must
//!   also start every further request within that time (idle keep-alive connections close).
//! - HTTP/2 connections are pinged every `--http2-keepalive-interval-s` and closed when a ping
//!   is not answered within `--http2-keepalive-timeout-s`.
//! - Request bodies that stop arriving are cut by `--body-read-timeout-s` (the HTTP router's
//!   body timeout, see [`crate::http`]; for gRPC a pause inside a message, [`DeadlineBody`]);
//!   bodies that trickle are cut by `--body-deadline-s` ([`DeadlineBody`]: the whole body over
//!   HTTP, each message of a gRPC request).
//! - Every request carries its connection's [`Peer`] address as an extension.
//! - Accept errors (e.g. out of file descriptors) are logged and retried after a pause, so a
//!   full process recovers as soon as connections close.
//!
//! The loop stops accepting when `stop` flips; open connections are then asked to close
//! gracefully (HTTP/1 after the response in flight, HTTP/2 with GOAWAY) and the returned future
//! finishes when all have closed.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::Router;
use axum::body::{Body, Bytes};
use axum::http::Request;
use hyper::body::{Frame, SizeHint};
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto::Builder;
use hyper_util::server::graceful::GracefulShutdown;
use hyper_util::service::TowerToHyperService;
use prometheus::{IntCounterVec, IntGauge};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::TcpListener;
use tokio::sync::{Semaphore, watch};
use tokio_rustls::TlsAcceptor;
use tower::ServiceExt;

use crate::config::{ConnectionConfig, secs};
use crate::metrics::Metrics;

/// HTTP/2 receive window of one stream, bytes: what a client may send ahead of the server.
///
/// h2 holds the DATA frames a stream has received until the application takes them and caps
/// the memory of small frames at half the connection window, closing the connection with
/// GOAWAY ENHANCE_YOUR_CALM past it. Before a request reaches its handler a client can fill the
/// stream window with small frames (a pipelined Interact action is one frame of 5 bytes and
/// more), each charged up to 256 bytes: with 64 KiB a stream's worth of 5-byte frames stays
/// under the cap, so a client that pipelines meets flow control (it waits), not a GOAWAY.
/// After that a client stream's body is read ahead (`crate::grpc`), so its frames do not
/// accumulate.
const H2_STREAM_WINDOW: u32 = 64 << 10;

/// HTTP/2 receive window of a connection, bytes (half of it is h2's cap on small frames, see
/// [`H2_STREAM_WINDOW`]).
const H2_CONNECTION_WINDOW: u32 = 8 << 20;

/// The connection builder of both listeners: HTTP/1 header read timeout, HTTP/2 keep-alive
/// pings as `config` sets them.
fn builder(config: &ConnectionConfig) -> Builder<TokioExecutor> {
    let mut b = Builder::new(TokioExecutor::new());
    b.http1()
        .timer(TokioTimer::new())
        .header_read_timeout(secs(config.header_read_timeout_s));
    let mut h2 = b.http2();
    h2.timer(TokioTimer::new())
        .initial_stream_window_size(H2_STREAM_WINDOW)
        .initial_connection_window_size(H2_CONNECTION_WINDOW);
    if let Some(every) = secs(config.http2_keepalive_interval_s) {
        h2.keep_alive_interval(every).keep_alive_timeout(
            secs(config.http2_keepalive_timeout_s).unwrap_or(Duration::from_secs(10)),
        );
    }
    b
}

/// Pause after an accept error before accepting again.
const ACCEPT_ERROR_PAUSE: Duration = Duration::from_millis(50);

/// Serves `router` on `listener` until `stop` flips, then closes connections gracefully.
/// `name` is the `listener` metric label (`grpc` or `http`).
pub async fn serve(
    name: &'static str,
    listener: TcpListener,
    router: Router,
    tls: Option<TlsAcceptor>,
    config: ConnectionConfig,
    metrics: Metrics,
    mut stop: watch::Receiver<bool>,
) {
    let builder = Arc::new(builder(&config));
    let slots = Arc::new(Semaphore::new(config.max_connections));
    let peers = PeerSlots::new(config.max_connections_per_peer);
    let first_request = secs(config.header_read_timeout_s);
    let graceful = GracefulShutdown::new();
    let open = metrics.open_connections.with_label_values(&[name]);
    let closed = metrics.closed_connections.clone();
    loop {
        let accepted = tokio::select! {
            r = listener.accept() => r,
            _ = stopped(&mut stop) => break,
        };
        let (stream, peer) = match accepted {
            Ok(a) => a,
            Err(e) => {
                tracing::warn!(listener = name, error = %e, "accept failed; retrying");
                tokio::time::sleep(ACCEPT_ERROR_PAUSE).await;
                continue;
            }
        };
        let Ok(permit) = slots.clone().try_acquire_owned() else {
            closed.with_label_values(&[name, "limit"]).inc();
            tracing::debug!(listener = name, %peer, "connection limit reached; closing");
            drop(stream);
            continue;
        };
        let Some(peer_slot) = peers.acquire(peer.ip()) else {
            closed.with_label_values(&[name, "limit"]).inc();
            tracing::debug!(listener = name, %peer, "per-peer connection limit reached; closing");
            drop(stream);
            continue;
        };
        let _ = stream.set_nodelay(true);
        // One clock from accept: the TLS handshake and the first request's headers share it.
        let first_request = first_request.map(|t| tokio::time::Instant::now() + t);
        let conn = Conn {
            name,
            builder: builder.clone(),
            router: router.clone(),
            first_request,
            closed: closed.clone(),
            open: open.clone(),
            peer,
        };
        let tls = tls.clone();
        let watcher = graceful.watcher();
        tokio::spawn(async move {
            let _permit = (permit, peer_slot);
            match tls {
                None => conn.run(stream, watcher).await,
                Some(acceptor) => {
                    let handshake = acceptor.accept(stream);
                    let r = match first_request {
                        Some(by) => tokio::time::timeout_at(by, handshake).await.ok(),
                        None => Some(handshake.await),
                    };
                    match r {
                        Some(Ok(s)) => conn.run(s, watcher).await,
                        Some(Err(e)) => {
                            conn.closed.with_label_values(&[name, "tls"]).inc();
                            tracing::debug!(listener = name, %peer, error = %e, "TLS handshake failed");
                        }
                        None => {
                            conn.closed.with_label_values(&[name, "timeout"]).inc();
                        }
                    }
                }
            }
        });
    }
    drop(listener);
    graceful.shutdown().await;
}

async fn stopped(rx: &mut watch::Receiver<bool>) {
    let _ = rx.wait_for(|s| *s).await;
}

/// One accepted connection and what it needs to be served.
struct Conn {
    name: &'static str,
    builder: Arc<Builder<TokioExecutor>>,
    router: Router,
    /// When the first request's headers must have arrived; `None` for no limit.
    first_request: Option<tokio::time::Instant>,
    closed: IntCounterVec,
    open: IntGauge,
    peer: SocketAddr,
}

impl Conn {
    async fn run<S>(self, stream: S, watcher: hyper_util::server::graceful::Watcher)
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        self.open.inc();
        // Flips at the first request's headers; until then the connection runs on a clock.
        let started = Arc::new(AtomicBool::new(false));
        let flag = started.clone();
        let peer = Peer(self.peer);
        let service = self
            .router
            .map_request(move |mut r: Request<hyper::body::Incoming>| {
                flag.store(true, Ordering::Relaxed);
                r.extensions_mut().insert(peer);
                r
            });
        let service = TowerToHyperService::new(service);
        let conn = self
            .builder
            .serve_connection_with_upgrades(TokioIo::new(stream), service);
        let conn = watcher.watch(conn.into_owned());
        tokio::pin!(conn);
        let finished = match self.first_request {
            Some(t) => tokio::select! {
                _ = conn.as_mut() => true,
                _ = tokio::time::sleep_until(t) => false,
            },
            None => false,
        };
        if !finished {
            if self.first_request.is_some() && !started.load(Ordering::Relaxed) {
                // No request within the time: drop (close) the connection.
                self.closed.with_label_values(&[self.name, "timeout"]).inc();
            } else {
                let _ = conn.await;
            }
        }
        self.open.dec();
    }
}

/// The address of the peer a request came from (a request extension set by the listener).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Peer(pub SocketAddr);

/// Open connections per peer IP address of one listener, under a cap.
#[derive(Clone)]
struct PeerSlots {
    cap: usize,
    open: Arc<Mutex<HashMap<IpAddr, usize>>>,
}

/// One connection's place in [`PeerSlots`], given back when dropped.
struct PeerSlot {
    ip: IpAddr,
    open: Arc<Mutex<HashMap<IpAddr, usize>>>,
}

impl PeerSlots {
    /// `cap` connections per address; 0: no cap.
    fn new(cap: usize) -> PeerSlots {
        PeerSlots {
            cap,
            open: Arc::default(),
        }
    }

    /// A slot for one more connection from `ip`, or `None` when it has `cap` open (or the cap
    /// is off: then `Some` without counting).
    fn acquire(&self, ip: IpAddr) -> Option<Option<PeerSlot>> {
        if self.cap == 0 {
            return Some(None);
        }
        let mut open = self.open.lock().unwrap_or_else(|p| p.into_inner());
        let n = open.entry(ip).or_insert(0);
        if *n >= self.cap {
            return None;
        }
        *n += 1;
        Some(Some(PeerSlot {
            ip,
            open: self.open.clone(),
        }))
    }
}

impl Drop for PeerSlot {
    fn drop(&mut self) {
        let mut open = self.open.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(n) = open.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                open.remove(&self.ip);
            }
        }
    }
}

/// How a [`DeadlineBody`] bounds its body.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BodyLimit {
    /// The whole body must have arrived within the deadline of the request's start (HTTP, and
    /// gRPC calls whose client sends one message).
    Whole,
    /// gRPC client stream: the first message must have arrived within the deadline of the
    /// request's start, every later one within the deadline of its first byte; the wait
    /// between messages is not bounded.
    EachMessage,
}

/// The error a [`DeadlineBody`] ends with when its deadline passes.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct BodyDeadlineExceeded(pub String);

/// A request body cut off at `--body-deadline-s` ([`BodyLimit`]); a body that keeps
/// trickling a byte at a time cannot hold its connection longer. For gRPC it also enforces
/// `--body-read-timeout-s` while a message is under way (a pause inside a message; HTTP has
/// its own timer for that, `crate::security::http_policy`). Past either it ends with an error:
/// a [`BodyDeadlineExceeded`] (HTTP: 408) or, for gRPC, a `tonic::Status` INVALID_ARGUMENT
/// naming `request` that tonic answers with.
pub struct DeadlineBody {
    inner: Body,
    limit: BodyLimit,
    deadline: Option<Duration>,
    idle: Option<Duration>,
    grpc: bool,
    /// A message (or the whole body) is under way: the timers run.
    due: bool,
    /// When the message (or body) under way must be complete.
    deadline_timer: Option<Pin<Box<tokio::time::Sleep>>>,
    /// When the message under way must have sent its next bytes.
    idle_timer: Option<Pin<Box<tokio::time::Sleep>>>,
    /// gRPC framing: bytes of the current message's 5-byte prefix seen, its prefix, and the
    /// payload bytes still to come once the prefix is complete.
    prefix_seen: usize,
    prefix: [u8; 5],
    payload_left: usize,
    done: bool,
}

fn sleep(d: Option<Duration>) -> Option<Pin<Box<tokio::time::Sleep>>> {
    d.map(|d| Box::pin(tokio::time::sleep(d)))
}

impl DeadlineBody {
    /// `inner` due within `deadline` of now, as `limit` says, and pausing at most `idle`
    /// inside a message (`None`: no such limit); `grpc` picks the form of the error.
    pub fn new(
        inner: Body,
        limit: BodyLimit,
        deadline: Option<Duration>,
        idle: Option<Duration>,
        grpc: bool,
    ) -> DeadlineBody {
        DeadlineBody {
            inner,
            limit,
            deadline,
            idle,
            grpc,
            due: true,
            deadline_timer: sleep(deadline),
            idle_timer: sleep(idle),
            prefix_seen: 0,
            prefix: [0; 5],
            payload_left: 0,
            done: false,
        }
    }

    /// Follows the gRPC message framing through `data`: a message that completes stops the
    /// timers, one that starts starts them.
    fn track(&mut self, mut data: &[u8]) {
        while !data.is_empty() {
            if !self.due {
                // A new message starts: it is due within the deadline of its first byte.
                self.due = true;
                self.deadline_timer = sleep(self.deadline);
            }
            if self.prefix_seen < 5 {
                let k = (5 - self.prefix_seen).min(data.len());
                self.prefix[self.prefix_seen..self.prefix_seen + k].copy_from_slice(&data[..k]);
                self.prefix_seen += k;
                data = &data[k..];
                if self.prefix_seen == 5 {
                    let len = u32::from_be_bytes([
                        self.prefix[1],
                        self.prefix[2],
                        self.prefix[3],
                        self.prefix[4],
                    ]);
                    self.payload_left = len as usize;
                    if self.payload_left == 0 {
                        self.message_done();
                    }
                }
            } else {
                let k = self.payload_left.min(data.len());
                self.payload_left -= k;
                data = &data[k..];
                if self.payload_left == 0 {
                    self.message_done();
                }
            }
        }
    }

    fn message_done(&mut self) {
        self.prefix_seen = 0;
        self.payload_left = 0;
        self.due = false;
        self.deadline_timer = None;
        self.idle_timer = None;
    }

    fn error(&self, idle: bool) -> axum::BoxError {
        let what = match self.limit {
            BodyLimit::Whole if !self.grpc => "the request body",
            _ => "the request message",
        };
        let message = match (idle, self.idle, self.deadline) {
            (true, Some(t), _) => format!(
                "{what} stopped arriving: nothing came for {} s (--body-read-timeout-s)",
                t.as_secs_f64()
            ),
            (_, _, Some(t)) => format!(
                "{what} did not arrive within {} s of its start (--body-deadline-s); send it \
                 faster or in smaller requests",
                t.as_secs_f64()
            ),
            _ => format!("{what} did not arrive in time"),
        };
        if self.grpc {
            Box::new(crate::error::ApiError::invalid("request", message).to_status())
        } else {
            Box::new(BodyDeadlineExceeded(message))
        }
    }
}

impl hyper::body::Body for DeadlineBody {
    type Data = Bytes;
    type Error = axum::BoxError;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Self::Error>>> {
        let this = &mut *self;
        if this.done {
            return Poll::Ready(None);
        }
        // What has arrived counts before the clock: a server busy elsewhere does not fail a
        // client whose bytes are already here.
        match Pin::new(&mut this.inner).poll_frame(cx) {
            Poll::Ready(Some(Ok(frame))) => {
                if let Some(data) = frame.data_ref() {
                    if this.limit == BodyLimit::EachMessage {
                        let data = data.clone();
                        this.track(&data);
                    }
                    if this.due && !data.is_empty() {
                        this.idle_timer = sleep(this.idle);
                    }
                }
                return Poll::Ready(Some(Ok(frame)));
            }
            Poll::Ready(Some(Err(e))) => return Poll::Ready(Some(Err(Box::new(e)))),
            Poll::Ready(None) => {
                this.done = true;
                this.message_done();
                return Poll::Ready(None);
            }
            Poll::Pending => {}
        }
        let late = |t: &mut Option<Pin<Box<tokio::time::Sleep>>>, cx: &mut Context<'_>| {
            t.as_mut().is_some_and(|t| t.as_mut().poll(cx).is_ready())
        };
        let over = late(&mut this.deadline_timer, cx);
        let stalled = !over && late(&mut this.idle_timer, cx);
        if over || stalled {
            this.done = true;
            let e = this.error(stalled);
            this.message_done();
            return Poll::Ready(Some(Err(e)));
        }
        Poll::Pending
    }

    fn is_end_stream(&self) -> bool {
        self.done || self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

/// `req` with its body under `--body-deadline-s` (`deadline`) and, inside a message, under
/// `idle` (see [`DeadlineBody`]); unchanged when both are `None`.
pub fn with_body_deadline(
    req: Request<Body>,
    deadline: Option<Duration>,
    idle: Option<Duration>,
    limit: BodyLimit,
    grpc: bool,
) -> Request<Body> {
    if deadline.is_none() && idle.is_none() {
        return req;
    }
    req.map(|b| Body::new(DeadlineBody::new(b, limit, deadline, idle, grpc)))
}

/// The message of a [`BodyDeadlineExceeded`] in `e`'s source chain, if there is one.
pub fn body_deadline_message(e: &(dyn std::error::Error + 'static)) -> Option<String> {
    let mut cur = Some(e);
    while let Some(err) = cur {
        if let Some(d) = err.downcast_ref::<BodyDeadlineExceeded>() {
            return Some(d.0.clone());
        }
        cur = err.source();
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(len: u32) -> Vec<u8> {
        let mut b = vec![0u8];
        b.extend_from_slice(&len.to_be_bytes());
        b.extend(std::iter::repeat_n(7u8, len as usize));
        b
    }

    #[tokio::test]
    async fn the_clock_runs_only_while_a_grpc_message_is_under_way() {
        let mut b = DeadlineBody::new(
            Body::empty(),
            BodyLimit::EachMessage,
            Some(Duration::from_secs(1)),
            Some(Duration::from_secs(1)),
            true,
        );
        // The first message is due from the start.
        assert!(b.due && b.deadline_timer.is_some());
        let mut bytes = frame(3);
        bytes.extend(frame(0));
        b.track(&bytes);
        assert!(!b.due && b.deadline_timer.is_none() && b.idle_timer.is_none());
        // A message split anywhere, its prefix included, keeps the clock running until its
        // last byte.
        let next = frame(10);
        b.track(&next[..2]);
        assert!(b.due && b.deadline_timer.is_some());
        b.track(&next[2..9]);
        assert!(b.due);
        b.track(&next[9..]);
        assert!(!b.due);
        // Two messages and the start of a third in one chunk.
        let mut chunk = frame(1);
        chunk.extend(frame(2));
        chunk.extend(&frame(4)[..6]);
        b.track(&chunk);
        assert!(b.due && b.payload_left == 3);
    }

    #[test]
    fn per_peer_slots_are_counted_and_given_back() {
        let slots = PeerSlots::new(2);
        let a: IpAddr = [10, 0, 0, 1].into();
        let b: IpAddr = [10, 0, 0, 2].into();
        let first = slots.acquire(a).unwrap();
        let second = slots.acquire(a).unwrap();
        assert!(slots.acquire(a).is_none());
        assert!(slots.acquire(b).unwrap().is_some());
        drop(first);
        assert!(slots.acquire(a).is_some());
        drop(second);
        assert!(slots.open.lock().unwrap().is_empty());
        assert!(
            PeerSlots::new(0).acquire(a).unwrap().is_none(),
            "no cap, nothing counted"
        );
    }
}
