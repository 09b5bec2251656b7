//! The accept loop of both listeners: a cap on open connections, an optional TLS handshake,
//! and the connection timeouts `axum::serve` does not offer.
//!
//! - At most `--max-connections` per listener; a connection over the cap is closed at once.
//! - A connection must deliver a request's headers within `--header-read-timeout-s` of being
//!   accepted (TLS handshake, HTTP/2 preface and settings included); HTTP/1 connections must
//!   also start every further request within that time (idle keep-alive connections close).
//! - HTTP/2 connections are pinged every `--http2-keepalive-interval-s` and closed when a ping
//!   is not answered within `--http2-keepalive-timeout-s`.
//! - Request bodies that stop arriving are cut by the HTTP router's body timeout
//!   (`--body-read-timeout-s`, see [`crate::http`]).
//! - Accept errors (e.g. out of file descriptors) are logged and retried after a pause, so a
//!   full process recovers as soon as connections close.
//!
//! The loop stops accepting when `stop` flips; open connections are then asked to close
//! gracefully (HTTP/1 after the response in flight, HTTP/2 with GOAWAY) and the returned future
//! finishes when all have closed.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use axum::Router;
use axum::http::Request;
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

/// The connection builder of both listeners: HTTP/1 header read timeout, HTTP/2 keep-alive
/// pings as `config` sets them.
fn builder(config: &ConnectionConfig) -> Builder<TokioExecutor> {
    let mut b = Builder::new(TokioExecutor::new());
    b.http1()
        .timer(TokioTimer::new())
        .header_read_timeout(secs(config.header_read_timeout_s));
    let mut h2 = b.http2();
    h2.timer(TokioTimer::new());
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
        };
        let tls = tls.clone();
        let watcher = graceful.watcher();
        tokio::spawn(async move {
            let _permit = permit;
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
        let service = self
            .router
            .map_request(move |r: Request<hyper::body::Incoming>| {
                flag.store(true, Ordering::Relaxed);
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
