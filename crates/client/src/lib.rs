//! Rust clients of the Dynaserve API and what callers of a server need around them:
//!
//! - [`Client`]: both gRPC services, `WorldModel` (rollouts, Predict, ListModels, Generate) and
//!   `Sessions` (create, step, state, fork, Predict, Gradient, Interact, delete); [`http`]: the
//!   HTTP JSON / Server-Sent Events API;
//! - [`scene_file`]: the JSON scene file format, with mesh loading ([`mesh`]: Wavefront OBJ,
//!   ASCII PLY); [`random_scene`]: seeded random scenes;
//! - [`prom`]: the Prometheus text format of `/metrics`;
//! - [`cli`]: `dynaserve rollout`.
//!
//! ```no_run
//! # async fn demo() -> Result<(), dynaserve_client::ClientError> {
//! use dynaserve_client::{Client, scene_file, v1};
//! let mut client = Client::connect("http://127.0.0.1:50051").await?;
//! let request = scene_file::load("examples/scenes/box_tower.json")?;
//! let frames = client.rollout_collect(&request).await?;
//! println!("{} frames, last poses {:?}", frames.len(), frames.last().map(|f| &f.poses));
//!
//! // The same scene as a session: step it, fork it, step the fork.
//! let created = client
//!     .create_session(v1::CreateSessionRequest {
//!         model: request.model.clone(),
//!         scene: Some(request.scene.to_proto()),
//!         ..Default::default()
//!     })
//!     .await?;
//! let id = created.info.session_id;
//! let step = |session_id: &str| v1::StepRequest {
//!     session_id: session_id.to_string(),
//!     steps: 4,
//!     ..Default::default()
//! };
//! client.step_collect(step(&id)).await?;
//! let fork = client.fork(&id).await?;
//! let frames = client.step_collect(step(&fork.session_id)).await?;
//! assert_eq!(frames[0].step, 5);
//! client.delete_session(&fork.session_id).await?;
//! client.delete_session(&id).await?;
//! # Ok(()) }
//! ```
//!
//! Units and conventions: metres, seconds, kilograms; z up, ground plane z = 0; quaternions
//! `[x, y, z, w]`; a step advances `dt_steps` frames of the model's `dt_frame`.

#![warn(missing_docs)]

pub mod cli;
mod client;
mod error;
pub mod http;
pub mod mesh;
pub mod prom;
pub mod random_scene;
pub mod scene_file;
mod sessions;
mod world_model;

pub use client::{Client, DEADLINE_BACKSTOP, ResponseStream};
/// The response metadata key (and HTTP header) of the server's warnings about a request.
pub use dynaserve_api::WARNING_HEADER;
/// The JSON forms of the API's messages (scene files, HTTP bodies).
pub use dynaserve_api::json;
/// The gRPC wire types of `dynaserve.v1`, the requests and answers of most [`Client`] calls.
pub use dynaserve_api::v1;
pub use error::ClientError;
pub use sessions::{CreatedSession, INTERACT_BUFFER, Interaction};
pub use world_model::{Generated, Generation, Rollout};
