//! The Dynaserve inference server: learned physics world models served over gRPC (tonic) and
//! HTTP (axum) with continuous batching across requests.
//!
//! - [`scheduler`]: one thread per resident model gathers step requests from every rollout
//!   stream and Predict call into batched forward passes (object budget, scene cap, maximum
//!   queue delay, two priority levels, deadlines and cancellation honoured before each batch).
//! - [`engine`]: admission, rollout sessions (bounded per-stream output), Predict calls,
//!   readiness and drain; shared by both front ends.
//! - [`grpc`], [`http`]: the `dynaserve.v1.WorldModel` service (plus health and reflection) and
//!   the JSON/SSE API with its OpenAPI document.
//! - [`scene`]: validation with errors naming the field; [`metrics`]: every exported metric;
//!   [`config`]: flags and environment variables; [`server`]: start-up and graceful shutdown.

pub mod config;
pub mod engine;
pub mod error;
pub mod grpc;
pub mod http;
pub mod metrics;
pub mod scene;
pub mod scheduler;
pub mod server;

pub use config::ServeConfig;
pub use engine::Engine;
pub use error::ApiError;
pub use server::{RunningServer, load_models, model_dirs, run, start};
