//! Rust clients of the Dynaserve API and what callers of a server need around them:
//!
//! - [`Client`]: the `WorldModel` gRPC API; [`http`]: the HTTP JSON / Server-Sent Events API;
//! - [`scene_file`]: the JSON scene file format, with mesh loading ([`mesh`]: Wavefront OBJ,
//!   ASCII PLY); [`random_scene`]: seeded random scenes;
//! - [`prom`]: the Prometheus text format of `/metrics`;
//! - [`cli`]: `dynaserve rollout`.
//!
//! ```no_run
//! # async fn demo() -> Result<(), dynaserve_client::ClientError> {
//! use dynaserve_client::{Client, scene_file};
//! let mut client = Client::connect("http://127.0.0.1:50051").await?;
//! let request = scene_file::load("examples/scenes/box_tower.json")?;
//! let frames = client.rollout_collect(&request).await?;
//! println!("{} frames, last poses {:?}", frames.len(), frames.last().map(|f| &f.poses));
//! # Ok(()) }
//! ```
//!
//! Units and conventions: metres, seconds, kilograms; z up, ground plane z = 0; quaternions
//! `[x, y, z, w]`; a step advances `dt_steps` frames of the model's `dt_frame`.

pub mod cli;
pub mod http;
pub mod mesh;
pub mod prom;
pub mod random_scene;
pub mod scene_file;

use std::time::Duration;

pub use dynaserve_api::json;
use dynaserve_api::v1;
use dynaserve_api::v1::world_model_client::WorldModelClient;
use futures::{Stream, StreamExt};
use tonic::transport::{Channel, Endpoint};

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
    /// with the retry hint for RESOURCE_EXHAUSTED).
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
}

impl ClientError {
    /// The retry hint of a RESOURCE_EXHAUSTED answer (`grpc-retry-pushback-ms`), if any.
    pub fn retry_after(&self) -> Option<Duration> {
        match self {
            ClientError::Status(s) => s
                .metadata()
                .get("grpc-retry-pushback-ms")
                .and_then(|v| v.to_str().ok())
                .and_then(|v| v.parse().ok())
                .map(Duration::from_millis),
            _ => None,
        }
    }
}

/// How much later than the deadline the client's own `grpc-timeout` gives up, so that the
/// server's DEADLINE_EXCEEDED (sent at the deadline) arrives first.
pub const DEADLINE_BACKSTOP: Duration = Duration::from_millis(500);

pub use dynaserve_api::WARNING_HEADER;

/// A running rollout: its frames in step order (an `Err` ends the stream).
pub struct Rollout {
    /// Request id assigned by the server (`x-request-id`).
    pub request_id: String,
    /// Model serving the rollout.
    pub model: String,
    /// The server's warnings about the request (`x-dynaserve-warning`): one line per object
    /// parameter outside the range the model was trained on; empty when all are inside.
    pub warnings: Vec<String>,
    /// The frames.
    pub frames: std::pin::Pin<Box<dyn Stream<Item = Result<json::StepFrame, ClientError>> + Send>>,
}

/// A typed client over one HTTP/2 connection (cheap to clone; clones share the connection).
#[derive(Clone, Debug)]
pub struct Client {
    inner: WorldModelClient<Channel>,
    timeout: Option<Duration>,
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

    /// Wraps an existing channel.
    pub fn from_channel(channel: Channel) -> Client {
        Client {
            inner: WorldModelClient::new(channel)
                .max_decoding_message_size(usize::MAX)
                .max_encoding_message_size(usize::MAX),
            timeout: None,
        }
    }

    /// Sets a deadline for every following Rollout and Predict call. It is sent in the
    /// request's `timeout_ms` field, which the server enforces on time (DEADLINE_EXCEEDED, also
    /// while the work is queued), and as a `grpc-timeout` [`DEADLINE_BACKSTOP`] later, so a
    /// server that cannot be reached still ends the call. (With `grpc-timeout` alone, tonic's
    /// own client timer fires first and reports CANCELLED instead of the server's answer.)
    pub fn with_timeout(mut self, timeout: Option<Duration>) -> Client {
        self.timeout = timeout;
        self
    }

    fn timeout_ms(&self, field: u32) -> u32 {
        match self.timeout {
            Some(t) => {
                let ms = u32::try_from(t.as_millis()).unwrap_or(u32::MAX).max(1);
                if field == 0 { ms } else { field.min(ms) }
            }
            None => field,
        }
    }

    fn request<T>(&self, msg: T) -> tonic::Request<T> {
        let mut r = tonic::Request::new(msg);
        if let Some(t) = self.timeout {
            r.set_timeout(t + DEADLINE_BACKSTOP);
        }
        r
    }

    /// Starts a rollout; frames arrive as the server computes them. Dropping the returned
    /// [`Rollout`] cancels the rollout on the server.
    pub async fn rollout(
        &mut self,
        request: &json::RolloutRequest,
    ) -> Result<Rollout, ClientError> {
        let mut msg = request.to_proto();
        msg.timeout_ms = self.timeout_ms(msg.timeout_ms);
        let resp = self.inner.rollout(self.request(msg)).await?;
        let meta = |k: &str| {
            resp.metadata()
                .get(k)
                .and_then(|v| v.to_str().ok())
                .unwrap_or_default()
                .to_string()
        };
        let request_id = meta("x-request-id");
        let model = meta("x-dynaserve-model");
        let warnings = resp
            .metadata()
            .get_all(WARNING_HEADER)
            .iter()
            .filter_map(|v| v.to_str().ok().map(str::to_string))
            .collect();
        let frames = resp.into_inner().map(|r| {
            r.map(|f| json::StepFrame::from_proto(&f))
                .map_err(ClientError::from)
        });
        Ok(Rollout {
            request_id,
            model,
            warnings,
            frames: Box::pin(frames),
        })
    }

    /// Runs a rollout to its end and returns every frame.
    pub async fn rollout_collect(
        &mut self,
        request: &json::RolloutRequest,
    ) -> Result<Vec<json::StepFrame>, ClientError> {
        let mut rollout = self.rollout(request).await?;
        let mut frames = Vec::with_capacity(request.steps as usize);
        while let Some(f) = rollout.frames.next().await {
            frames.push(f?);
        }
        Ok(frames)
    }

    /// Rolls many variants forward in one call (planner use).
    pub async fn predict(
        &mut self,
        request: &json::PredictRequest,
    ) -> Result<json::PredictResponse, ClientError> {
        let mut msg = request.to_proto();
        msg.timeout_ms = self.timeout_ms(msg.timeout_ms);
        let resp = self.inner.predict(self.request(msg)).await?;
        let meta = resp.metadata().clone();
        let r = resp.into_inner();
        let ms = |k: &str| {
            meta.get(k)
                .and_then(|v| v.to_str().ok())
                .and_then(|v| v.parse::<f64>().ok())
                .unwrap_or(0.0)
        };
        Ok(json::PredictResponse {
            model: r.model,
            trajectories: r
                .trajectories
                .iter()
                .map(|t| json::Trajectory {
                    frames: t.frames.iter().map(json::StepFrame::from_proto).collect(),
                })
                .collect(),
            timing: json::RequestTiming {
                queue_ms: ms("x-dynaserve-queue-ms"),
                forward_ms: ms("x-dynaserve-forward-ms"),
                total_ms: ms("x-dynaserve-total-ms"),
            },
        })
    }

    /// Lists the resident models.
    pub async fn list_models(&mut self) -> Result<Vec<v1::ModelInfo>, ClientError> {
        Ok(self
            .inner
            .list_models(self.request(v1::ListModelsRequest {}))
            .await?
            .into_inner()
            .models)
    }
}
