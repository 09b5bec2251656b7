//! Per-request bookkeeping shared by every kind of request: the context a front end sets
//! (protocol, request id, arrival, transport deadline), the call every engine entry point
//! runs in (its span, and the record that counts its outcome in the metrics exactly once), and
//! deadline helpers.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use tracing::Instrument;

use crate::error::ApiError;
use crate::metrics::Metrics;

/// Which front end a request came through (the `protocol` metric label).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Protocol {
    /// tonic.
    Grpc,
    /// axum.
    Http,
}

impl Protocol {
    /// Label value.
    pub fn as_str(self) -> &'static str {
        match self {
            Protocol::Grpc => "grpc",
            Protocol::Http => "http",
        }
    }
}

/// Per-request context set by the front end.
#[derive(Clone, Debug)]
pub struct RequestCtx {
    /// Front end.
    pub protocol: Protocol,
    /// Request id (from `x-request-id` or generated).
    pub request_id: Arc<str>,
    /// Arrival time.
    pub arrival: Instant,
    /// Deadline from the transport (`grpc-timeout`), if any.
    pub deadline: Option<Instant>,
    /// Whom the request is attributed to for session ownership and per-caller quotas: an
    /// opaque key of the bearer token it authenticated with when authentication is on, else
    /// of its peer IP address; 0 when neither is known (see `crate::security::Caller`).
    pub identity: u64,
}

impl RequestCtx {
    /// A context arriving now.
    pub fn new(protocol: Protocol, request_id: Option<&str>, timeout: Option<Duration>) -> Self {
        let arrival = Instant::now();
        RequestCtx {
            protocol,
            request_id: request_id
                .filter(|s| valid_request_id(s))
                .map_or_else(new_request_id, str::to_string)
                .into(),
            arrival,
            deadline: timeout.map(|t| arrival + t),
            identity: 0,
        }
    }

    /// The same context attributed to `identity` (see [`RequestCtx::identity`]).
    pub fn with_identity(mut self, identity: u64) -> Self {
        self.identity = identity;
        self
    }

    /// The key the scheduler shares each class fairly between: the request's
    /// [`identity`](RequestCtx::identity) (its bearer token, else its peer IP address), else,
    /// when neither is known, the request itself.
    pub fn caller(&self) -> u64 {
        if self.identity != 0 {
            return self.identity;
        }
        use std::hash::BuildHasher;
        static KEYS: std::sync::OnceLock<std::collections::hash_map::RandomState> =
            std::sync::OnceLock::new();
        KEYS.get_or_init(Default::default)
            .hash_one(&*self.request_id)
    }

    /// The earlier of the transport deadline and `timeout_ms` after arrival (0: none); when
    /// the request names neither, `default` after arrival (the server's `--default-timeout-s`).
    pub(crate) fn deadline_with(
        &self,
        timeout_ms: u32,
        default: Option<Duration>,
    ) -> Option<Instant> {
        let field =
            (timeout_ms > 0).then(|| self.arrival + Duration::from_millis(timeout_ms.into()));
        match (self.deadline, field) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (None, None) => default.map(|d| self.arrival + d),
            (a, b) => a.or(b),
        }
    }
}

/// True when a client's `x-request-id` may be echoed: 1 to 128 visible ASCII characters (no
/// space, no control or non-ASCII byte); any other is replaced by a generated id.
fn valid_request_id(s: &str) -> bool {
    !s.is_empty() && s.len() <= 128 && s.bytes().all(|b| b.is_ascii_graphic())
}

/// A new unique request id (16 hex digits).
pub fn new_request_id() -> String {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    static BASE: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    let base = *BASE.get_or_init(|| {
        let t = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        // splitmix64 of the start time and pid, so restarts do not repeat ids.
        let mut z = t ^ (u64::from(std::process::id()) << 32);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    });
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    format!(
        "{:016x}",
        base.wrapping_add(n.wrapping_mul(0x9e37_79b9_7f4a_7c15))
    )
}

/// One engine call: its metrics record and its span. Every entry point opens one; the call
/// runs its admission (and, when it answers at once, all of its work) in the span, and its
/// outcome is recorded exactly once, by [`Call::answer`], [`Call::end`], [`Call::fail`] or
/// [`Call::finish`], or as cancelled when the call is dropped without one (client went away).
/// A streamed call hands itself on to the task that produces its stream ([`Call::spawn`]).
pub(crate) struct Call {
    rec: RequestRecord,
    span: tracing::Span,
}

impl Call {
    /// Counts the request under `method` and opens its record, logged in `span`.
    pub(crate) fn new(
        metrics: &Metrics,
        ctx: &RequestCtx,
        method: &'static str,
        span: tracing::Span,
    ) -> Call {
        Call {
            rec: RequestRecord::new(metrics, ctx, method),
            span,
        }
    }

    /// Runs `fut` in the span; its error is logged and recorded as the call's outcome. On
    /// success the call goes on (the outcome is recorded later).
    pub(crate) async fn admit<T>(
        &mut self,
        fut: impl Future<Output = Result<T, ApiError>>,
    ) -> Result<T, ApiError> {
        let r = fut.instrument(self.span.clone()).await;
        r.map_err(|e| self.fail_now(e))
    }

    /// [`Call::admit`] for admission that does not wait.
    pub(crate) fn admit_now<T>(
        &mut self,
        f: impl FnOnce() -> Result<T, ApiError>,
    ) -> Result<T, ApiError> {
        self.span.in_scope(f).map_err(|e| self.fail_now(e))
    }

    /// Runs a call that answers at once: `fut` in the span, its outcome recorded.
    pub(crate) async fn answer<T>(
        mut self,
        fut: impl Future<Output = Result<T, ApiError>>,
    ) -> Result<T, ApiError> {
        let v = self.admit(fut).await?;
        self.rec.finish(None);
        Ok(v)
    }

    /// Spawns the task of a streamed call in the span, handing it the call to
    /// [`end`](Call::end) when the stream is over.
    pub(crate) fn spawn<F>(self, task: impl FnOnce(Call) -> F)
    where
        F: Future<Output = ()> + Send + 'static,
    {
        let span = self.span.clone();
        tokio::spawn(task(self).instrument(span));
    }

    /// Records a streamed call's outcome (logging its error).
    pub(crate) fn end(mut self, outcome: Result<(), ApiError>) {
        match outcome {
            Ok(()) => self.rec.finish(None),
            Err(e) => {
                self.fail_now(e);
            }
        }
    }

    /// Logs and records a failure in the span, returning the error.
    pub(crate) fn fail(mut self, e: ApiError) -> ApiError {
        self.fail_now(e)
    }

    /// Records a success.
    pub(crate) fn finish(mut self) {
        self.rec.finish(None);
    }

    fn fail_now(&mut self, e: ApiError) -> ApiError {
        self.span.in_scope(|| self.rec.fail(e))
    }
}

/// Records a request's outcome in the metrics exactly once; a request dropped without an
/// outcome (client went away) counts as cancelled.
struct RequestRecord {
    metrics: Metrics,
    protocol: &'static str,
    method: &'static str,
    arrival: Instant,
    done: bool,
}

impl RequestRecord {
    /// Counts the request and starts its record.
    fn new(metrics: &Metrics, ctx: &RequestCtx, method: &'static str) -> RequestRecord {
        metrics
            .requests
            .with_label_values(&[ctx.protocol.as_str(), method])
            .inc();
        RequestRecord {
            metrics: metrics.clone(),
            protocol: ctx.protocol.as_str(),
            method,
            arrival: ctx.arrival,
            done: false,
        }
    }

    /// Records the outcome (once; later calls do nothing).
    fn finish(&mut self, error: Option<&ApiError>) {
        if !self.done {
            self.done = true;
            self.metrics.finish_request(
                self.protocol,
                self.method,
                self.arrival.elapsed(),
                error.map(ApiError::reason),
            );
        }
    }

    /// Logs and records a failure, returning the error.
    fn fail(&mut self, e: ApiError) -> ApiError {
        tracing::info!(code = e.code_name(), error = %e.message, "request failed");
        self.finish(Some(&e));
        e
    }
}

impl Drop for RequestRecord {
    fn drop(&mut self) {
        if !self.done {
            self.finish(Some(&ApiError::cancelled("client went away")));
        }
    }
}

/// Decrements an active-work gauge when dropped.
pub(crate) struct GaugeGuard(pub(crate) prometheus::IntGauge, pub(crate) i64);

impl Drop for GaugeGuard {
    fn drop(&mut self) {
        self.0.sub(self.1);
    }
}

/// A variant's step error naming variant `i`: a field of its scene (`scene.objects[j]...`,
/// e.g. an object that left the model's domain) becomes `variants[i].objects[j]...`, in the
/// field and at the head of the message.
pub(crate) fn for_variant(mut e: ApiError, i: usize) -> ApiError {
    if let Some(rest) = e.field.as_deref().and_then(|f| f.strip_prefix("scene.")) {
        let old = format!("scene.{rest}");
        let new = format!("variants[{i}].{rest}");
        if let Some(m) = e.message.strip_prefix(&old) {
            e.message = format!("{new}{m}");
        }
        e.field = Some(new);
    }
    e
}

/// Runs `fut` until `deadline`, answering DEADLINE_EXCEEDED past it.
pub(crate) async fn with_deadline<T>(
    deadline: Option<Instant>,
    fut: impl std::future::Future<Output = Result<T, ApiError>>,
) -> Result<T, ApiError> {
    match deadline {
        Some(d) => tokio::time::timeout_at(d.into(), fut)
            .await
            .map_err(|_| ApiError::deadline("deadline exceeded"))?,
        None => fut.await,
    }
}

/// Sleeps until `deadline`, or forever without one.
pub(crate) async fn sleep_until(deadline: Option<Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d.into()).await,
        None => std::future::pending().await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scheduling_caller_is_the_identity_else_the_request() {
        let a = RequestCtx::new(Protocol::Grpc, Some("req-a"), None);
        let b = RequestCtx::new(Protocol::Http, Some("req-b"), None);
        // Without an identity each request is its own caller, the same on every call.
        assert_ne!(a.caller(), b.caller());
        assert_eq!(a.caller(), a.caller());
        // With one, every request of that identity is one caller.
        let (a, b) = (a.with_identity(42), b.with_identity(42));
        assert_eq!((a.caller(), b.caller()), (42, 42));
    }

    #[tokio::test]
    async fn a_call_records_one_outcome_whichever_way_it_ends() {
        let metrics = Metrics::new(&[]);
        let ctx = RequestCtx::new(Protocol::Grpc, None, None);
        let call = |method| Call::new(&metrics, &ctx, method, tracing::Span::none());
        // Refused in admission: the refusal is the outcome, not a cancellation on drop.
        let mut refused = call("refused");
        let e = ApiError::invalid("steps", "0 steps");
        assert!(refused.admit(async { Err::<(), _>(e) }).await.is_err());
        drop(refused);
        // Answered at once.
        assert_eq!(call("answered").answer(async { Ok(7) }).await.unwrap(), 7);
        // Streamed: the task ends the call.
        let (done_tx, done_rx) = tokio::sync::oneshot::channel();
        call("streamed").spawn(move |c| async move {
            c.end(Err(ApiError::deadline("deadline exceeded")));
            let _ = done_tx.send(());
        });
        done_rx.await.unwrap();
        // Dropped without an outcome: the client went away.
        drop(call("dropped"));
        for (method, reason) in [
            ("refused", Some("invalid_argument")),
            ("answered", None),
            ("streamed", Some("deadline_exceeded")),
            ("dropped", Some("cancelled")),
        ] {
            let counted =
                |v: &prometheus::IntCounterVec, labels: &[&str]| v.with_label_values(labels).get();
            assert_eq!(counted(&metrics.requests, &["grpc", method]), 1, "{method}");
            let outcomes = metrics
                .request_duration
                .with_label_values(&["grpc", method])
                .get_sample_count();
            assert_eq!(outcomes, 1, "{method}");
            for r in crate::metrics::FAILURE_REASONS {
                let n = counted(&metrics.failures, &["grpc", method, r]);
                assert_eq!(n, u64::from(reason == Some(*r)), "{method} {r}");
            }
        }
    }
}
