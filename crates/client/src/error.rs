//! [`ClientError`]: what a call of the client library can fail with.

use std::time::Duration;

/// Errors of the client library.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The server could not be reached.
    #[error("cannot connect to {url}: {source}")]
    Connect {
        /// Server URL.
        url: String,
        /// Cause.
        #[source]
        source: tonic::transport::Error,
    },
    /// The server answered with an error status (code, message naming the field, metadata
    /// with the request id and, for RESOURCE_EXHAUSTED, the retry hint).
    #[error("server error {}: {}", .0.code(), .0.message())]
    Status(#[from] tonic::Status),
    /// A scene or mesh file could not be read or parsed.
    #[error("{path}: {message}")]
    File {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// A value given for request metadata (a bearer token, a request id, an affinity key)
    /// cannot be sent as an HTTP/2 header value (it holds a control character, e.g. a line
    /// break).
    #[error("{name} cannot be sent as gRPC metadata: {message}")]
    Metadata {
        /// The metadata key, e.g. `authorization`.
        name: &'static str,
        /// Why the value was refused.
        message: String,
    },
    /// A stream ended before the answer a call waited for (the frame of an Interact step),
    /// without an error status.
    #[error("the stream ended before {0}")]
    StreamEnded(&'static str),
}

impl ClientError {
    /// The retry hint of a RESOURCE_EXHAUSTED answer (`grpc-retry-pushback-ms`), if any.
    pub fn retry_after(&self) -> Option<Duration> {
        self.status()?
            .metadata()
            .get("grpc-retry-pushback-ms")
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.parse().ok())
            .map(Duration::from_millis)
    }

    /// The server's error status, when the server answered with one ([`ClientError::Status`]).
    pub fn status(&self) -> Option<&tonic::Status> {
        match self {
            ClientError::Status(s) => Some(s),
            _ => None,
        }
    }
}
