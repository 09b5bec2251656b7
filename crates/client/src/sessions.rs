//! The `dynaserve.v1.Sessions` calls of [`Client`]: create, step, get and set the state of,
//! fork, predict from, differentiate candidate paths from ([`Client::gradient`]), drive
//! ([`Interaction`]) and delete a session. Requests and answers are
//! the wire types ([`v1`]); a session's frames count steps and time from its start.
//!
//! A session belongs to its creator (the bearer token, see [`Client::with_bearer_token`], or
//! without authentication the caller's IP address) unless created `shared`; for anyone else it
//! does not exist (NOT_FOUND). An unknown or expired id is NOT_FOUND too.

use std::fmt;

use dynaserve_api::v1;
use futures::StreamExt;
use tokio::sync::mpsc;

use crate::client::{Client, ResponseStream, meta, response_stream, warnings};
use crate::error::ClientError;

/// Messages of an Interact stream buffered on the client before the server reads them.
pub const INTERACT_BUFFER: usize = 32;

/// A session just created ([`Client::create_session`]).
#[derive(Clone, Debug, PartialEq)]
pub struct CreatedSession {
    /// Its id, model, expiry, object count, frames per step and kinematic objects.
    pub info: v1::SessionInfo,
    /// Request id assigned by the server (`x-request-id`).
    pub request_id: String,
    /// The server's warnings about the scene (`x-dynaserve-warning`): one line per object
    /// parameter outside the range the model was trained on; empty when all are inside.
    pub warnings: Vec<String>,
}

/// A running Interact stream ([`Client::interact`]): every message sent on [`actions`]
/// (one step: its action and optional state corrections) is answered by one frame on
/// [`frames`] as soon as its batch has run.
///
/// [`actions`]: Interaction::actions
/// [`frames`]: Interaction::frames
pub struct Interaction {
    /// The session driven (`x-dynaserve-session`): the one named by the opening message, or
    /// the one created for this stream (deleted when the stream ends).
    pub session_id: String,
    /// Request id assigned by the server (`x-request-id`).
    pub request_id: String,
    /// Model serving the session.
    pub model: String,
    /// For a session created by the opening message, the server's warnings about its scene
    /// (`x-dynaserve-warning`), as for [`CreatedSession::warnings`].
    pub warnings: Vec<String>,
    /// The steps to send (the default message is a step whose kinematic objects hold still).
    /// Dropping it ends the input: the server answers the steps already sent, then ends the
    /// stream.
    pub actions: mpsc::Sender<v1::InteractRequest>,
    /// One frame per step sent, in order; an `Err` (e.g. NOT_FOUND when the session was
    /// deleted meanwhile) ends the stream. Dropping it cancels the stream on the server.
    pub frames: ResponseStream<v1::StepFrame>,
}

impl fmt::Debug for Interaction {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Interaction")
            .field("session_id", &self.session_id)
            .field("request_id", &self.request_id)
            .field("model", &self.model)
            .field("warnings", &self.warnings)
            .finish_non_exhaustive()
    }
}

impl Interaction {
    /// Closed loop: sends one step and waits for its frame. Use it only while no earlier
    /// step's frame is outstanding (otherwise that frame is the one returned). The status
    /// that ended the stream is returned as [`ClientError::Status`]; a stream that ended
    /// without one as [`ClientError::StreamEnded`].
    pub async fn step(&mut self, step: v1::InteractRequest) -> Result<v1::StepFrame, ClientError> {
        if self.actions.send(step).await.is_err() {
            // The call is over: its status, if any, is still to be read.
            while let Some(r) = self.frames.next().await {
                r?;
            }
            return Err(ClientError::StreamEnded("the frame of the step"));
        }
        match self.frames.next().await {
            Some(r) => r,
            None => Err(ClientError::StreamEnded("the frame of the step")),
        }
    }

    /// Ends the input (no further steps) and returns the frames still to come, the answers
    /// to the steps already sent; the stream ends after them.
    pub fn finish(self) -> ResponseStream<v1::StepFrame> {
        self.frames
    }
}

impl Client {
    /// Validates and prepares a scene once and keeps it with its state. RESOURCE_EXHAUSTED
    /// when the server holds its limit of sessions or of session memory (or the caller its
    /// quota), INVALID_ARGUMENT naming the field for bad input (or a scene that could never
    /// fit).
    pub async fn create_session(
        &mut self,
        request: v1::CreateSessionRequest,
    ) -> Result<CreatedSession, ClientError> {
        let resp = self
            .sessions()
            .create_session(self.request(request, true))
            .await?;
        Ok(CreatedSession {
            request_id: meta(resp.metadata(), "x-request-id"),
            warnings: warnings(resp.metadata()),
            info: resp.into_inner(),
        })
    }

    /// Advances the session's own state `steps` steps and streams one frame per step (poses
    /// in metres and `[x, y, z, w]` quaternions, one per object in scene order). Steps of one
    /// session run one call at a time, in arrival order; steps finished before a deadline
    /// stay applied. Dropping the stream cancels the steps not yet run.
    pub async fn step(
        &mut self,
        mut request: v1::StepRequest,
    ) -> Result<ResponseStream<v1::StepFrame>, ClientError> {
        request.timeout_ms = self.timeout_ms(request.timeout_ms);
        let resp = self.sessions().step(self.request(request, true)).await?;
        Ok(response_stream(resp.into_inner()))
    }

    /// Runs [`Client::step`] to its end and returns every frame.
    pub async fn step_collect(
        &mut self,
        request: v1::StepRequest,
    ) -> Result<Vec<v1::StepFrame>, ClientError> {
        let mut frames = Vec::with_capacity(request.steps as usize);
        let mut stream = self.step(request).await?;
        while let Some(f) = stream.next().await {
            frames.push(f?);
        }
        Ok(frames)
    }

    /// Overwrites the state (pose and motion) of some or all objects, e.g. from a real
    /// observation; returns the session's new state.
    pub async fn set_state(
        &mut self,
        request: v1::SetStateRequest,
    ) -> Result<v1::SessionState, ClientError> {
        let resp = self
            .sessions()
            .set_state(self.request(request, true))
            .await?;
        Ok(resp.into_inner())
    }

    /// The session's current state: step count, time in seconds, every object's pose and
    /// its pose one step before, and when the session expires.
    pub async fn get_state(&mut self, session_id: &str) -> Result<v1::SessionState, ClientError> {
        let msg = v1::GetStateRequest {
            session_id: session_id.to_string(),
        };
        let resp = self.sessions().get_state(self.request(msg, true)).await?;
        Ok(resp.into_inner())
    }

    /// Copies the session (its state, sharing the prepared scene) under a new id; the copy
    /// belongs to the caller. RESOURCE_EXHAUSTED as for [`Client::create_session`].
    pub async fn fork(&mut self, session_id: &str) -> Result<v1::SessionInfo, ClientError> {
        let msg = v1::ForkRequest {
            session_id: session_id.to_string(),
        };
        let resp = self.sessions().fork(self.request(msg, true)).await?;
        Ok(resp.into_inner())
    }

    /// Deletes the session (NOT_FOUND if it does not exist; PERMISSION_DENIED for a shared
    /// session the caller did not create).
    pub async fn delete_session(&mut self, session_id: &str) -> Result<(), ClientError> {
        let msg = v1::DeleteSessionRequest {
            session_id: session_id.to_string(),
        };
        self.sessions()
            .delete_session(self.request(msg, true))
            .await?;
        Ok(())
    }

    /// Rolls many variants of the session's current state forward at once (bulk priority),
    /// each with its own state overrides and actions; the session itself does not move.
    /// Returns one trajectory per variant, in variant order: every `every`-th step plus the
    /// final one (the final one only when `every` is 0).
    pub async fn predict_session(
        &mut self,
        mut request: v1::SessionPredictRequest,
    ) -> Result<v1::PredictResponse, ClientError> {
        request.timeout_ms = self.timeout_ms(request.timeout_ms);
        let resp = self.sessions().predict(self.request(request, true)).await?;
        Ok(resp.into_inner())
    }

    /// Scores candidate paths of the session's kinematic objects and differentiates the score
    /// (bulk priority; concurrent calls on a model share a pass); the session itself does not
    /// move. Each candidate gives every kinematic object's pose at every step; each answer, in
    /// candidate order, holds the candidate's cost, its gradient with respect to every
    /// kinematic pose (`steps[s].kinematic[k]`: translation per metre, rotation per radian of
    /// a world-axis rotation, objects in index order) and the rollout's frames (every
    /// `every`-th step plus the final one). FAILED_PRECONDITION when the session's model
    /// computes no gradients (ListModels' `gradients`), INVALID_ARGUMENT naming the field for
    /// bad candidates or cost, or more than `max_gradient_work` candidates x steps.
    pub async fn gradient(
        &mut self,
        mut request: v1::SessionGradientRequest,
    ) -> Result<v1::GradientResponse, ClientError> {
        request.timeout_ms = self.timeout_ms(request.timeout_ms);
        let resp = self
            .sessions()
            .gradient(self.request(request, true))
            .await?;
        Ok(resp.into_inner())
    }

    /// Opens an Interact stream (closed-loop control). `open` names the session to drive
    /// (`session_id`) or creates one for this stream (`create`); the steps follow on the
    /// returned [`Interaction`]. A refused opening (an unknown session, bad input, no room
    /// for a new session) fails here. No deadline applies (see [`Client::with_timeout`]).
    pub async fn interact(
        &mut self,
        open: v1::InteractRequest,
    ) -> Result<Interaction, ClientError> {
        let (actions, rx) = mpsc::channel(INTERACT_BUFFER);
        let steps =
            futures::stream::unfold(rx, |mut rx| async move { rx.recv().await.map(|m| (m, rx)) });
        let input = futures::stream::once(async { open }).chain(steps);
        let resp = self.sessions().interact(self.request(input, false)).await?;
        Ok(Interaction {
            session_id: meta(resp.metadata(), "x-dynaserve-session"),
            request_id: meta(resp.metadata(), "x-request-id"),
            model: meta(resp.metadata(), "x-dynaserve-model"),
            warnings: warnings(resp.metadata()),
            actions,
            frames: response_stream(resp.into_inner()),
        })
    }
}
