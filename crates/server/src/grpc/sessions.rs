//! The `dynaserve.v1.Sessions` service: each call maps its message to the neutral session
//! vocabulary (`dynaserve_api::spec::session`), calls the engine and maps the answer back.

use std::sync::Arc;

use dynaserve_api::spec::gradient::SessionGradientSpec;
use dynaserve_api::spec::session::{
    CreateSessionSpec, InteractOpen, InteractStep, SessionPredictSpec, SetStateSpec, StepSpec,
};
use dynaserve_api::spec::{Frame, Timing, millis};
use dynaserve_api::v1;
use dynaserve_api::v1::sessions_server::{Sessions as SessionsApi, SessionsServer};
use futures::StreamExt;
use prost::Message;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use super::{FrameStream, ctx_of, insert, insert_warnings, with_request_id};
use crate::engine::{Engine, RequestCtx};
use crate::error::ApiError;
use tonic::metadata::MetadataMap;

/// Implementation of the generated `Sessions` service trait.
pub struct SessionsService {
    engine: Arc<Engine>,
}

/// The service, with the same message size limits as `WorldModel`.
pub fn server(engine: Arc<Engine>, max_decoding: usize) -> SessionsServer<SessionsService> {
    SessionsServer::new(SessionsService { engine })
        .max_decoding_message_size(max_decoding)
        .max_encoding_message_size(usize::MAX)
}

impl SessionsService {
    /// Checks the payload size and converts the message, counting a rejection under `method`.
    fn parse<M: Message, T>(
        &self,
        ctx: &RequestCtx,
        method: &'static str,
        msg: &M,
        convert: impl FnOnce(&M) -> Result<T, dynaserve_api::FieldError>,
    ) -> Result<T, Status> {
        self.engine
            .check_payload(msg.encoded_len())
            .and_then(|()| convert(msg).map_err(ApiError::from))
            .map_err(|e| {
                with_request_id(
                    self.engine.reject(ctx, method, e).to_status(),
                    &ctx.request_id,
                )
            })
    }

    fn reply<T>(&self, ctx: &RequestCtx, r: Result<T, ApiError>) -> Result<Response<T>, Status> {
        let rid = ctx.request_id.clone();
        let mut resp = Response::new(r.map_err(|e| with_request_id(e.to_status(), &rid))?);
        insert(resp.metadata_mut(), "x-request-id", &rid);
        Ok(resp)
    }
}

/// The error of a client stream that failed: a later message that does not decode, or that
/// did not arrive within `--body-deadline-s`, is the client's fault like a bad first message
/// (INVALID_ARGUMENT naming `request`); anything else means the client went away.
fn client_stream_error(s: &Status) -> ApiError {
    if let Some(e) = super::undecodable(s.code(), s.message()) {
        return e;
    }
    if s.code() == tonic::Code::InvalidArgument {
        let m = s.message();
        return ApiError::invalid("request", m.strip_prefix("request: ").unwrap_or(m));
    }
    ApiError::cancelled(format!("client stream failed: {}", s.message()))
}

/// The timing metadata of a planner call's answer: `x-dynaserve-queue-ms`,
/// `x-dynaserve-forward-ms`, `x-dynaserve-total-ms`.
pub(super) fn insert_timing(m: &mut MetadataMap, t: &Timing) {
    insert(
        m,
        "x-dynaserve-queue-ms",
        &format!("{:.3}", millis(t.queue)),
    );
    insert(
        m,
        "x-dynaserve-forward-ms",
        &format!("{:.3}", millis(t.forward)),
    );
    insert(
        m,
        "x-dynaserve-total-ms",
        &format!("{:.3}", millis(t.total)),
    );
}

fn frames(rx: tokio::sync::mpsc::Receiver<Result<Frame, ApiError>>) -> FrameStream {
    Box::pin(
        ReceiverStream::new(rx).map(|r| r.map(|f: Frame| f.to_v1()).map_err(|e| e.to_status())),
    )
}

#[tonic::async_trait]
impl SessionsApi for SessionsService {
    type StepStream = FrameStream;
    type InteractStream = FrameStream;

    async fn create_session(
        &self,
        request: Request<v1::CreateSessionRequest>,
    ) -> Result<Response<v1::SessionInfo>, Status> {
        let ctx = ctx_of(&request);
        let req = request.into_inner();
        let spec = self.parse(&ctx, "create_session", &req, |r| {
            CreateSessionSpec::from_v1(r, "")
        })?;
        let r = self.engine.create_session(spec, ctx.clone()).await;
        let (info, warnings) = match r {
            Ok((info, w)) => (Ok(info.to_v1()), w),
            Err(e) => (Err(e), Vec::new()),
        };
        let mut resp = self.reply(&ctx, info)?;
        insert_warnings(resp.metadata_mut(), &warnings);
        Ok(resp)
    }

    async fn step(
        &self,
        request: Request<v1::StepRequest>,
    ) -> Result<Response<Self::StepStream>, Status> {
        let ctx = ctx_of(&request);
        let req = request.into_inner();
        let spec = self.parse(&ctx, "session_step", &req, StepSpec::from_v1)?;
        let r = self.engine.session_step(spec, ctx.clone()).await;
        let handle = r.map_err(|e| with_request_id(e.to_status(), &ctx.request_id))?;
        let mut resp = Response::new(frames(handle.frames));
        insert(resp.metadata_mut(), "x-request-id", &ctx.request_id);
        insert(resp.metadata_mut(), "x-dynaserve-model", &handle.model);
        Ok(resp)
    }

    async fn set_state(
        &self,
        request: Request<v1::SetStateRequest>,
    ) -> Result<Response<v1::SessionState>, Status> {
        let ctx = ctx_of(&request);
        let req = request.into_inner();
        let spec = self.parse(&ctx, "set_state", &req, SetStateSpec::from_v1)?;
        let r = self.engine.set_session_state(spec, ctx.clone()).await;
        self.reply(&ctx, r.map(|s| s.to_v1()))
    }

    async fn get_state(
        &self,
        request: Request<v1::GetStateRequest>,
    ) -> Result<Response<v1::SessionState>, Status> {
        let ctx = ctx_of(&request);
        let id = request.into_inner().session_id;
        let r = self.engine.session_state(&id, ctx.clone()).await;
        self.reply(&ctx, r.map(|s| s.to_v1()))
    }

    async fn fork(
        &self,
        request: Request<v1::ForkRequest>,
    ) -> Result<Response<v1::SessionInfo>, Status> {
        let ctx = ctx_of(&request);
        let id = request.into_inner().session_id;
        let r = self.engine.fork_session(&id, ctx.clone()).await;
        self.reply(&ctx, r.map(|i| i.to_v1()))
    }

    async fn delete_session(
        &self,
        request: Request<v1::DeleteSessionRequest>,
    ) -> Result<Response<v1::DeleteSessionResponse>, Status> {
        let ctx = ctx_of(&request);
        let id = request.into_inner().session_id;
        let r = self.engine.delete_session(&id, ctx.clone()).await;
        self.reply(&ctx, r.map(|()| v1::DeleteSessionResponse {}))
    }

    async fn predict(
        &self,
        request: Request<v1::SessionPredictRequest>,
    ) -> Result<Response<v1::PredictResponse>, Status> {
        let ctx = ctx_of(&request);
        let req = request.into_inner();
        let spec = self.parse(&ctx, "session_predict", &req, SessionPredictSpec::from_v1)?;
        let r = self.engine.session_predict(spec, ctx.clone()).await;
        self.reply(&ctx, r.map(|p| p.to_v1()))
    }

    async fn gradient(
        &self,
        request: Request<v1::SessionGradientRequest>,
    ) -> Result<Response<v1::GradientResponse>, Status> {
        let ctx = ctx_of(&request);
        let req = request.into_inner();
        let spec = self.parse(&ctx, "session_gradient", &req, SessionGradientSpec::from_v1)?;
        let r = self.engine.session_gradient(spec, ctx.clone()).await;
        let timing = r.as_ref().map(|g| g.timing).ok();
        let mut resp = self.reply(&ctx, r.map(|g| g.to_v1()))?;
        if let Some(t) = timing {
            insert_timing(resp.metadata_mut(), &t);
        }
        Ok(resp)
    }

    async fn interact(
        &self,
        request: Request<Streaming<v1::InteractRequest>>,
    ) -> Result<Response<Self::InteractStream>, Status> {
        let ctx = ctx_of(&request);
        let mut input = request.into_inner();
        let first = match input.message().await {
            Ok(Some(m)) => m,
            Ok(None) => {
                let e =
                    ApiError::invalid("session_id", "the stream ended before its first message");
                return Err(self.engine.reject(&ctx, "interact", e).to_status());
            }
            Err(s) => return Err(s),
        };
        let open = self.parse(&ctx, "interact", &first, InteractOpen::from_v1)?;
        let engine = self.engine.clone();
        let steps = input.map(move |m| match m {
            Ok(m) => engine
                .check_payload(m.encoded_len())
                .and_then(|()| InteractStep::from_v1(&m).map_err(ApiError::from)),
            Err(s) => Err(client_stream_error(&s)),
        });
        let r = self
            .engine
            .interact(open, Box::pin(steps), ctx.clone())
            .await;
        let handle = r.map_err(|e| with_request_id(e.to_status(), &ctx.request_id))?;
        let mut resp = Response::new(frames(handle.frames));
        insert(resp.metadata_mut(), "x-request-id", &ctx.request_id);
        insert(resp.metadata_mut(), "x-dynaserve-model", &handle.model);
        insert(
            resp.metadata_mut(),
            "x-dynaserve-session",
            &handle.session_id,
        );
        insert_warnings(resp.metadata_mut(), &handle.warnings);
        Ok(resp)
    }
}
