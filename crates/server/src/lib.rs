//! The Dynaserve inference server: learned physics world models served over gRPC (tonic) and
//! HTTP (axum) with continuous batching across requests.
//!
//! transport ([`grpc`], [`http`]) -> [`engine`] -> [`scheduler`] -> model
//! (see `docs/architecture.md`):
//!
//! - [`grpc`], [`http`]: the `dynaserve.v1.WorldModel` service (plus health and reflection) and
//!   the JSON/SSE API with its OpenAPI document; each maps its wire form to and from the
//!   neutral vocabulary of `dynaserve_api::spec`, which validates requests too.
//! - [`families`]: the model families as plug-ins (RigidFormer, PhysiFormer, the rapier
//!   simulator) and the registry that loads a model directory in its family.
//! - [`engine`]: admission, rollout sessions (bounded per-stream output), Predict calls,
//!   warm-up, readiness and drain; protocol-independent.
//! - [`scheduler`]: one thread per resident model gathers the step jobs of every rollout
//!   stream and Predict call into batched forward passes (object budget, scene cap, maximum
//!   queue delay, two priority levels, deadlines and cancellation honoured before each pass).
//! - [`viewer`]: the browser viewer, the operator dashboard and `GET /v1/examples`.
//! - [`metrics`]: every exported metric; [`config`]: flags and environment variables;
//!   [`server`]: start-up and graceful shutdown; [`error`]: the one error type of both
//!   protocols; [`listener`]: the accept loop (connection cap, timeouts, TLS);
//!   [`security`]: authentication, TLS configuration, CORS and content-type policy.

pub mod config;
pub mod engine;
pub mod error;
pub mod families;
pub mod grpc;
pub mod http;
pub mod listener;
pub mod metrics;
pub mod scheduler;
pub mod security;
pub mod server;
pub mod viewer;

pub use config::ServeConfig;
pub use engine::Engine;
pub use engine::Models;
pub use error::ApiError;
pub use families::rigidformer::{load_models, load_models_on};
pub use server::{RunningServer, load_all, load_all_on, model_dirs, run, start};
