//! The `dynaserve.v1.WorldModel` calls of [`Client`]: Rollout, Predict and ListModels, which
//! take and return the JSON forms ([`json`], the form of scene files), and Generate, which
//! takes and returns the wire types ([`v1`]).

use std::fmt;

use dynaserve_api::{json, v1};
use futures::StreamExt;

use crate::client::{Client, ResponseStream, meta, response_stream, warnings};
use crate::error::ClientError;

/// A running rollout: its frames in step order (an `Err` ends the stream).
pub struct Rollout {
    /// Request id assigned by the server (`x-request-id`).
    pub request_id: String,
    /// Model serving the rollout.
    pub model: String,
    /// The server's warnings about the request (`x-dynaserve-warning`): one line per object
    /// parameter outside the range the model was trained on; empty when all are inside.
    pub warnings: Vec<String>,
    /// The frames, one per step: poses in metres and `[x, y, z, w]` quaternions, one per
    /// object in scene order. Dropping the stream cancels the rollout on the server.
    pub frames: ResponseStream<json::StepFrame>,
}

impl fmt::Debug for Rollout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Rollout")
            .field("request_id", &self.request_id)
            .field("model", &self.model)
            .field("warnings", &self.warnings)
            .finish_non_exhaustive()
    }
}

/// A running Generate call: one [`v1::GenerateProgress`] event per denoising step, then one
/// [`v1::GeneratedSample`] per requested sample (an `Err` ends the stream).
pub struct Generation {
    /// Request id assigned by the server (`x-request-id`).
    pub request_id: String,
    /// Model serving the call (a PhysiFormer model).
    pub model: String,
    /// The events in arrival order. Dropping the stream cancels the call on the server and
    /// frees its sample slots.
    pub events: ResponseStream<v1::GenerateEvent>,
}

impl fmt::Debug for Generation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Generation")
            .field("request_id", &self.request_id)
            .field("model", &self.model)
            .finish_non_exhaustive()
    }
}

/// A Generate call run to its end ([`Client::generate_collect`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Generated {
    /// Request id assigned by the server (`x-request-id`).
    pub request_id: String,
    /// Model that served the call.
    pub model: String,
    /// One event per denoising step, in step order.
    pub progress: Vec<v1::GenerateProgress>,
    /// One trajectory per requested sample, in sample order: frames `frame * dt_frame`
    /// seconds apart, vertices flattened xyz in metres, objects in request order.
    pub samples: Vec<v1::GeneratedSample>,
}

impl Client {
    /// Starts a rollout; frames arrive as the server computes them. Dropping the returned
    /// [`Rollout`] cancels the rollout on the server.
    pub async fn rollout(
        &mut self,
        request: &json::RolloutRequest,
    ) -> Result<Rollout, ClientError> {
        let mut msg = request.to_proto();
        msg.timeout_ms = self.timeout_ms(msg.timeout_ms);
        let resp = self.world_model().rollout(self.request(msg, true)).await?;
        let request_id = meta(resp.metadata(), "x-request-id");
        let model = meta(resp.metadata(), "x-dynaserve-model");
        let warnings = warnings(resp.metadata());
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

    /// Rolls many variants forward in one call (planner use): per variant the final frame or
    /// every `every`-th, and the server's queue, forward and total times in milliseconds.
    pub async fn predict(
        &mut self,
        request: &json::PredictRequest,
    ) -> Result<json::PredictResponse, ClientError> {
        let mut msg = request.to_proto();
        msg.timeout_ms = self.timeout_ms(msg.timeout_ms);
        let resp = self.world_model().predict(self.request(msg, true)).await?;
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

    /// Lists the resident models with their limits (steps, variants, objects, points,
    /// vertices, frames, denoising steps, samples, request cost) and configuration.
    pub async fn list_models(&mut self) -> Result<Vec<v1::ModelInfo>, ClientError> {
        let msg = v1::ListModelsRequest {};
        Ok(self
            .world_model()
            .list_models(self.request(msg, true))
            .await?
            .into_inner()
            .models)
    }

    /// Starts sampling trajectories of a mesh scene with a PhysiFormer model; events arrive
    /// as the denoising steps complete. The request is sent as given, apart from the
    /// client's deadline ([`Client::with_timeout`]). A request the server refuses at once
    /// (invalid input, over the cost ceiling, server full) fails here; a failure later (a
    /// deadline passed mid-way) ends the event stream.
    pub async fn generate(
        &mut self,
        mut request: v1::GenerateRequest,
    ) -> Result<Generation, ClientError> {
        request.timeout_ms = self.timeout_ms(request.timeout_ms);
        let resp = self
            .world_model()
            .generate(self.request(request, true))
            .await?;
        Ok(Generation {
            request_id: meta(resp.metadata(), "x-request-id"),
            model: meta(resp.metadata(), "x-dynaserve-model"),
            events: response_stream(resp.into_inner()),
        })
    }

    /// Runs a Generate call to its end and returns its progress events and samples.
    pub async fn generate_collect(
        &mut self,
        request: v1::GenerateRequest,
    ) -> Result<Generated, ClientError> {
        let mut g = self.generate(request).await?;
        let mut out = Generated {
            request_id: std::mem::take(&mut g.request_id),
            model: std::mem::take(&mut g.model),
            ..Generated::default()
        };
        while let Some(ev) = g.events.next().await {
            match ev?.event {
                Some(v1::generate_event::Event::Progress(p)) => out.progress.push(p),
                Some(v1::generate_event::Event::Sample(s)) => out.samples.push(s),
                None => {}
            }
        }
        Ok(out)
    }
}
