//! [`Client`]: one HTTP/2 connection to a server, its per-call settings (deadline, bearer
//! token, request id, affinity key) and the metadata every call sends and reads. The calls
//! themselves are in [`crate::world_model`] (the `WorldModel` service) and
//! [`crate::sessions`] (the `Sessions` service).

use std::pin::Pin;
use std::time::Duration;

use dynaserve_api::v1::sessions_client::SessionsClient;
use dynaserve_api::v1::world_model_client::WorldModelClient;
use futures::{Stream, StreamExt};
use tonic::metadata::{AsciiMetadataValue, MetadataMap};
use tonic::transport::{Channel, Endpoint};

use crate::error::ClientError;

/// How much later than the deadline the client's own `grpc-timeout` gives up, so that the
/// server's DEADLINE_EXCEEDED (sent at the deadline) arrives first.
pub const DEADLINE_BACKSTOP: Duration = Duration::from_millis(500);

/// The messages of a server stream in arrival order; an `Err` (the status that ended the
/// call) is the last item. Dropping the stream cancels the call on the server.
pub type ResponseStream<T> = Pin<Box<dyn Stream<Item = Result<T, ClientError>> + Send>>;

/// Metadata key of the bearer token.
const AUTHORIZATION: &str = "authorization";
/// Metadata key of the caller's request id, echoed by the server when it is at most 128
/// visible characters (otherwise the server assigns one).
const REQUEST_ID: &str = "x-request-id";
/// Metadata key the deployment's gateway hashes to pick a replica (sessions live in one).
const AFFINITY: &str = "x-dynaserve-affinity";

/// A typed client of both gRPC services, `dynaserve.v1.WorldModel` and
/// `dynaserve.v1.Sessions`, over one HTTP/2 connection (cheap to clone; clones share the
/// connection and start with the same settings).
///
/// Settings apply to every following call: [`Client::with_timeout`] (a deadline),
/// [`Client::with_bearer_token`] (`authorization: Bearer ...`), [`Client::with_request_id`]
/// (`x-request-id`) and [`Client::with_affinity`] (`x-dynaserve-affinity`).
#[derive(Clone, Debug)]
pub struct Client {
    channel: Channel,
    timeout: Option<Duration>,
    /// Metadata sent with every call, at most one value per key.
    headers: Vec<(&'static str, AsciiMetadataValue)>,
}

impl Client {
    /// Connects to a server, e.g. `http://127.0.0.1:50051`.
    pub async fn connect(url: &str) -> Result<Client, ClientError> {
        let endpoint =
            Endpoint::from_shared(url.to_string()).map_err(|e| ClientError::Connect {
                url: url.to_string(),
                source: e,
            })?;
        let channel = endpoint.connect().await.map_err(|e| ClientError::Connect {
            url: url.to_string(),
            source: e,
        })?;
        Ok(Client::from_channel(channel))
    }

    /// Wraps an existing channel (TLS, custom windows or keep-alive set on its endpoint).
    /// Messages of any size are sent and accepted; the server enforces its own limits.
    pub fn from_channel(channel: Channel) -> Client {
        Client {
            channel,
            timeout: None,
            headers: Vec::new(),
        }
    }

    /// The generated `WorldModel` stub on the client's connection (a cheap handle: the stubs
    /// are made per call, so that a `Client` stays small).
    pub(crate) fn world_model(&self) -> WorldModelClient<Channel> {
        WorldModelClient::new(self.channel.clone())
            .max_decoding_message_size(usize::MAX)
            .max_encoding_message_size(usize::MAX)
    }

    /// The generated `Sessions` stub on the client's connection.
    pub(crate) fn sessions(&self) -> SessionsClient<Channel> {
        SessionsClient::new(self.channel.clone())
            .max_decoding_message_size(usize::MAX)
            .max_encoding_message_size(usize::MAX)
    }

    /// Sets a deadline for every following call; `None` removes it. Calls whose request has
    /// a `timeout_ms` field (Rollout, Predict, Generate, Step, session Predict and Gradient)
    /// send it there, where the server enforces it on time (DEADLINE_EXCEEDED, also while the
    /// work is queued; a smaller `timeout_ms` already in the request is kept). Every call except
    /// Interact also sends a `grpc-timeout` [`DEADLINE_BACKSTOP`] later, so a server that
    /// cannot be reached still ends the call. (With `grpc-timeout` alone, tonic's own client
    /// timer fires first and reports CANCELLED instead of the server's answer.) An Interact
    /// stream lasts as long as its caller drives it and has no deadline.
    pub fn with_timeout(mut self, timeout: Option<Duration>) -> Client {
        self.timeout = timeout;
        self
    }

    /// Authenticates every following call with `authorization: Bearer <token>` (servers
    /// started with auth tokens refuse calls without one as UNAUTHENTICATED); `None` stops
    /// sending it. The token also decides who owns the sessions the client creates. The value
    /// is marked sensitive: the client's `Debug` output does not show it.
    pub fn with_bearer_token<'a>(
        self,
        token: impl Into<Option<&'a str>>,
    ) -> Result<Client, ClientError> {
        let value = token.into().map(|t| format!("Bearer {t}"));
        self.with_header(AUTHORIZATION, value.as_deref(), true)
    }

    /// Sends `x-request-id: <id>` with every following call, to find the calls in the
    /// server's logs; `None` stops sending it. The server echoes an id of at most 128 visible
    /// ASCII characters in its answers (metadata and error statuses) and replaces any other
    /// with one of its own.
    pub fn with_request_id<'a>(
        self,
        id: impl Into<Option<&'a str>>,
    ) -> Result<Client, ClientError> {
        self.with_header(REQUEST_ID, id.into(), false)
    }

    /// Sends `x-dynaserve-affinity: <key>` with every following call; `None` stops sending
    /// it. Sessions live in one replica's memory: behind the deployment's gateway, the calls
    /// of a session and of its forks must carry the same key (any string, e.g. one random key
    /// per planner) so that they reach the replica holding them.
    pub fn with_affinity<'a>(self, key: impl Into<Option<&'a str>>) -> Result<Client, ClientError> {
        self.with_header(AFFINITY, key.into(), false)
    }

    fn with_header(
        mut self,
        name: &'static str,
        value: Option<&str>,
        sensitive: bool,
    ) -> Result<Client, ClientError> {
        self.headers.retain(|(k, _)| *k != name);
        if let Some(v) = value {
            let mut v = AsciiMetadataValue::try_from(v).map_err(|e| ClientError::Metadata {
                name,
                message: e.to_string(),
            })?;
            v.set_sensitive(sensitive);
            self.headers.push((name, v));
        }
        Ok(self)
    }

    /// The deadline for a request whose `timeout_ms` field holds `field` (0: none): the
    /// smaller of the two.
    pub(crate) fn timeout_ms(&self, field: u32) -> u32 {
        match self.timeout {
            Some(t) => {
                let ms = u32::try_from(t.as_millis()).unwrap_or(u32::MAX).max(1);
                if field == 0 { ms } else { field.min(ms) }
            }
            None => field,
        }
    }

    /// A request carrying `msg`, the client's metadata and, when `deadline`, the backstop
    /// `grpc-timeout`.
    pub(crate) fn request<T>(&self, msg: T, deadline: bool) -> tonic::Request<T> {
        let mut r = tonic::Request::new(msg);
        if deadline && let Some(t) = self.timeout {
            r.set_timeout(t + DEADLINE_BACKSTOP);
        }
        let meta = r.metadata_mut();
        for (k, v) in &self.headers {
            meta.insert(*k, v.clone());
        }
        r
    }
}

/// The value of response metadata `key`, empty when absent.
pub(crate) fn meta(map: &MetadataMap, key: &str) -> String {
    map.get(key)
        .and_then(|v| v.to_str().ok())
        .unwrap_or_default()
        .to_string()
}

/// The server's warnings about a request (`x-dynaserve-warning`, one entry per object
/// parameter outside the model's trained range).
pub(crate) fn warnings(map: &MetadataMap) -> Vec<String> {
    map.get_all(dynaserve_api::WARNING_HEADER)
        .iter()
        .filter_map(|v| v.to_str().ok().map(str::to_string))
        .collect()
}

/// A server stream as a [`ResponseStream`], its statuses as [`ClientError::Status`].
pub(crate) fn response_stream<T: Send + 'static>(s: tonic::Streaming<T>) -> ResponseStream<T> {
    Box::pin(s.map(|r| r.map_err(ClientError::from)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lazy() -> Client {
        let channel = Endpoint::from_static("http://127.0.0.1:1").connect_lazy();
        Client::from_channel(channel)
    }

    fn sent(c: &Client, key: &str) -> Vec<String> {
        let r = c.request((), false);
        r.metadata()
            .get_all(key)
            .iter()
            .map(|v| v.to_str().unwrap().to_string())
            .collect()
    }

    #[tokio::test]
    async fn settings_are_sent_once_each_and_can_be_removed() {
        let c = lazy()
            .with_bearer_token("secret-token")
            .unwrap()
            .with_request_id("run-7")
            .unwrap()
            .with_affinity("planner-3")
            .unwrap();
        assert_eq!(sent(&c, AUTHORIZATION), ["Bearer secret-token"]);
        assert_eq!(sent(&c, REQUEST_ID), ["run-7"]);
        assert_eq!(sent(&c, AFFINITY), ["planner-3"]);
        assert!(!format!("{c:?}").contains("secret-token"), "{c:?}");
        let c = c.with_request_id("run-8").unwrap();
        assert_eq!(sent(&c, REQUEST_ID), ["run-8"]);
        let c = c
            .with_bearer_token(None)
            .unwrap()
            .with_affinity(None)
            .unwrap();
        assert!(sent(&c, AUTHORIZATION).is_empty() && sent(&c, AFFINITY).is_empty());
        // A clone keeps the settings; changing it leaves the original alone.
        let other = c.clone().with_request_id(None).unwrap();
        assert_eq!(sent(&c, REQUEST_ID), ["run-8"]);
        assert!(sent(&other, REQUEST_ID).is_empty());
    }

    #[tokio::test]
    async fn values_that_are_no_header_value_are_refused_naming_the_key() {
        let e = lazy().with_bearer_token("two\nlines").unwrap_err();
        assert!(
            matches!(
                e,
                ClientError::Metadata {
                    name: "authorization",
                    ..
                }
            ),
            "{e}"
        );
        let e = lazy().with_request_id("nul\0").unwrap_err();
        assert!(
            matches!(
                e,
                ClientError::Metadata {
                    name: "x-request-id",
                    ..
                }
            ),
            "{e}"
        );
    }

    #[tokio::test]
    async fn the_deadline_goes_into_timeout_ms_and_a_later_grpc_timeout() {
        let c = lazy();
        assert_eq!(c.timeout_ms(0), 0);
        assert_eq!(c.timeout_ms(250), 250);
        assert!(c.request((), true).metadata().get("grpc-timeout").is_none());
        let c = c.with_timeout(Some(Duration::from_millis(800)));
        assert_eq!(c.timeout_ms(0), 800);
        assert_eq!(c.timeout_ms(250), 250);
        assert_eq!(c.timeout_ms(5000), 800);
        let r = c.request((), true);
        assert_eq!(r.metadata().get("grpc-timeout").unwrap(), "1300000u");
        assert!(
            c.request((), false)
                .metadata()
                .get("grpc-timeout")
                .is_none()
        );
    }
}
