//! gRPC front end (tonic): the `dynaserve.v1.WorldModel` and `dynaserve.v1.Sessions`
//! (`sessions`) services, standard health checking and server reflection, served as an axum
//! router on the gRPC port.
//!
//! Deadlines: the `grpc-timeout` header is read here and enforced by the engine, which answers
//! DEADLINE_EXCEEDED on time (also for work still queued). tonic's own server timeout layer is
//! not used because it answers CANCELLED.

use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use dynaserve_api::spec::sampling::GenerateSpec;
use dynaserve_api::spec::{Frame, PredictSpec, RolloutSpec};
use dynaserve_api::v1;
use dynaserve_api::v1::world_model_server::{WorldModel as WorldModelApi, WorldModelServer};
use futures::{Stream, StreamExt};
use prost::Message;
use tokio_stream::wrappers::ReceiverStream;
use tonic::metadata::{MetadataMap, MetadataValue};
use tonic::{Request, Response, Status};
use tonic_health::server::HealthReporter;

use crate::engine::{Engine, Protocol, RequestCtx};
use crate::error::ApiError;
use crate::listener::{BodyLimit, with_body_deadline};
use crate::security::Caller;

mod prefetch;
mod sessions;

/// Parses a `grpc-timeout` header value (`<digits><unit>`, unit one of H M S m u n).
pub fn parse_grpc_timeout(value: &str) -> Option<Duration> {
    if value.len() < 2 || value.len() > 9 {
        return None;
    }
    let (digits, unit) = value.split_at(value.len() - 1);
    let n: u64 = digits.parse().ok()?;
    Some(match unit {
        "H" => Duration::from_secs(n.checked_mul(3600)?),
        "M" => Duration::from_secs(n.checked_mul(60)?),
        "S" => Duration::from_secs(n),
        "m" => Duration::from_millis(n),
        "u" => Duration::from_micros(n),
        "n" => Duration::from_nanos(n),
        _ => return None,
    })
}

/// The context of a gRPC request, attributed to its [`Caller`] (token or peer).
fn ctx_of<T>(request: &Request<T>) -> RequestCtx {
    let meta = request.metadata();
    let rid = meta.get("x-request-id").and_then(|v| v.to_str().ok());
    let timeout = meta
        .get("grpc-timeout")
        .and_then(|v| v.to_str().ok())
        .and_then(parse_grpc_timeout);
    RequestCtx::new(Protocol::Grpc, rid, timeout).with_identity(Caller::of(request.extensions()).0)
}

/// Appends one `x-dynaserve-warning` entry per warning (object parameters outside the model's
/// trained range).
fn insert_warnings(meta: &mut MetadataMap, warnings: &[String]) {
    for w in warnings {
        if let Ok(v) = MetadataValue::try_from(w.as_str()) {
            meta.append(dynaserve_api::WARNING_HEADER, v);
        }
    }
}

fn insert(meta: &mut MetadataMap, key: &'static str, value: &str) {
    if let Ok(v) = MetadataValue::try_from(value) {
        meta.insert(key, v);
    }
}

/// Implementation of the generated `WorldModel` service trait.
pub struct GrpcService {
    engine: Arc<Engine>,
}

type FrameStream = Pin<Box<dyn Stream<Item = Result<v1::StepFrame, Status>> + Send>>;
type GenerateEventStream = Pin<Box<dyn Stream<Item = Result<v1::GenerateEvent, Status>> + Send>>;

#[tonic::async_trait]
impl WorldModelApi for GrpcService {
    type RolloutStream = FrameStream;

    async fn rollout(
        &self,
        request: Request<v1::RolloutRequest>,
    ) -> Result<Response<Self::RolloutStream>, Status> {
        let ctx = ctx_of(&request);
        let req = request.into_inner();
        let parsed = self
            .engine
            .check_payload(req.encoded_len())
            .and_then(|()| RolloutSpec::from_v1(&req).map_err(ApiError::from));
        let rid = ctx.request_id.clone();
        let parsed = parsed.and_then(|r| Ok((r, self.engine.stream_quota(&ctx)?)));
        let (handle, quota) = match parsed {
            Ok((r, quota)) => self.engine.start_rollout(r, ctx).await.map(|h| (h, quota)),
            Err(e) => Err(self.engine.reject(&ctx, "rollout", e)),
        }
        .map_err(|e| with_request_id(e.to_status(), &rid))?;
        // The caller's stream quota is held as long as the response stream.
        let stream = ReceiverStream::new(handle.frames).map(move |r| {
            let _ = &quota;
            r.map(|f: Frame| f.to_v1()).map_err(|e| e.to_status())
        });
        let mut resp = Response::new(Box::pin(stream) as FrameStream);
        insert(resp.metadata_mut(), "x-request-id", &handle.request_id);
        insert(resp.metadata_mut(), "x-dynaserve-model", &handle.model);
        insert_warnings(resp.metadata_mut(), &handle.warnings);
        Ok(resp)
    }

    async fn predict(
        &self,
        request: Request<v1::PredictRequest>,
    ) -> Result<Response<v1::PredictResponse>, Status> {
        let ctx = ctx_of(&request);
        let req = request.into_inner();
        let rid = ctx.request_id.clone();
        let parsed = self
            .engine
            .check_payload(req.encoded_len())
            .and_then(|()| PredictSpec::from_v1(&req).map_err(ApiError::from));
        let out = match parsed {
            Ok(r) => self.engine.predict(r, ctx).await,
            Err(e) => Err(self.engine.reject(&ctx, "predict", e)),
        }
        .map_err(|e| with_request_id(e.to_status(), &rid))?;
        let mut resp = Response::new(out.to_v1());
        let m = resp.metadata_mut();
        insert(m, "x-request-id", &rid);
        insert_warnings(m, &out.warnings);
        sessions::insert_timing(m, &out.timing);
        Ok(resp)
    }

    type GenerateStream = GenerateEventStream;

    async fn generate(
        &self,
        request: Request<v1::GenerateRequest>,
    ) -> Result<Response<Self::GenerateStream>, Status> {
        let ctx = ctx_of(&request);
        let req = request.into_inner();
        let parsed = self
            .engine
            .check_payload(req.encoded_len())
            .and_then(|()| GenerateSpec::from_v1(&req).map_err(ApiError::from));
        let rid = ctx.request_id.clone();
        let parsed = parsed.and_then(|r| Ok((r, self.engine.stream_quota(&ctx)?)));
        let (handle, quota) = match parsed {
            Ok((r, quota)) => self.engine.start_generate(r, ctx).await.map(|h| (h, quota)),
            Err(e) => Err(self.engine.reject(&ctx, "generate", e)),
        }
        .map_err(|e| with_request_id(e.to_status(), &rid))?;
        let stream = ReceiverStream::new(handle.events).map(move |r| {
            let _ = &quota;
            r.map(|e| e.to_v1()).map_err(|e| e.to_status())
        });
        let mut resp = Response::new(Box::pin(stream) as GenerateEventStream);
        insert(resp.metadata_mut(), "x-request-id", &handle.request_id);
        insert(resp.metadata_mut(), "x-dynaserve-model", &handle.model);
        Ok(resp)
    }

    async fn list_models(
        &self,
        request: Request<v1::ListModelsRequest>,
    ) -> Result<Response<v1::ListModelsResponse>, Status> {
        let ctx = ctx_of(&request);
        let list = self.engine.list_models(&ctx);
        let mut resp = Response::new(v1::ListModelsResponse {
            models: list.iter().map(|m| m.to_v1()).collect(),
        });
        insert(resp.metadata_mut(), "x-request-id", &ctx.request_id);
        Ok(resp)
    }
}

fn with_request_id(mut s: Status, rid: &str) -> Status {
    insert(s.metadata_mut(), "x-request-id", rid);
    s
}

/// Name under which the WorldModel service reports health.
pub const SERVICE_NAME: &str = <WorldModelServer<GrpcService> as tonic::server::NamedService>::NAME;

/// Marks the overall server ("") and the WorldModel service as serving or not.
pub async fn set_health(reporter: &HealthReporter, serving: bool) {
    use tonic_health::ServingStatus;
    let status = if serving {
        ServingStatus::Serving
    } else {
        ServingStatus::NotServing
    };
    reporter.set_service_status("", status).await;
    reporter.set_service_status(SERVICE_NAME, status).await;
}

/// Builds the gRPC router: WorldModel, Sessions, grpc.health.v1.Health and server reflection
/// (v1 and v1alpha). The health status starts as NOT_SERVING.
pub async fn router(engine: Arc<Engine>) -> anyhow::Result<(axum::Router, HealthReporter)> {
    let (reporter, health) = tonic_health::server::health_reporter();
    set_health(&reporter, false).await;
    let reflection_v1 = tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(v1::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
        .build_v1()?;
    let reflection_v1alpha = tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(v1::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
        .build_v1alpha()?;
    // Messages up to 4x the configured limit are decoded so that the limit itself is reported
    // as INVALID_ARGUMENT naming `request`; beyond that tonic refuses to decode.
    let hard_cap = engine.config().max_request_bytes.saturating_mul(4);
    let body_deadline = engine.config().connections.body_deadline();
    // A pause inside a message: the HTTP listener's timeout between body chunks.
    let idle = engine.config().connections.body_read_timeout();
    let sessions = sessions::server(engine.clone(), hard_cap);
    let service = WorldModelServer::new(GrpcService { engine })
        .max_decoding_message_size(hard_cap)
        .max_encoding_message_size(usize::MAX);
    let routes = tonic::service::Routes::new(service)
        .add_service(sessions)
        .add_service(health)
        .add_service(reflection_v1)
        .add_service(reflection_v1alpha)
        .prepare();
    let router = routes
        .into_axum_router()
        .layer(axum::middleware::map_response(move |r| {
            client_faults_are_invalid(r, hard_cap)
        }))
        .layer(axum::middleware::map_request(
            move |req: axum::extract::Request| async move {
                if is_client_stream(req.uri().path()) {
                    let req = req.map(|b| axum::body::Body::new(prefetch::ReadAhead::new(b)));
                    with_body_deadline(req, body_deadline, idle, BodyLimit::EachMessage, true)
                } else {
                    with_body_deadline(req, body_deadline, idle, BodyLimit::Whole, true)
                }
            },
        ));
    Ok((router, reporter))
}

/// True for the methods whose client sends a stream of messages (Interact, server
/// reflection): `--body-deadline-s` bounds each of their messages, not the whole stream.
fn is_client_stream(path: &str) -> bool {
    path == "/dynaserve.v1.Sessions/Interact" || path.ends_with("/ServerReflectionInfo")
}

/// The start of tonic's text (prost's `DecodeError`) for a message whose bytes do not decode.
const DECODE_ERROR: &str = "failed to decode Protobuf message";

/// tonic's text for a message frame cut short by the end of the request body.
const TRUNCATED: &str = "Unexpected EOF decoding stream";

/// The refusal of a request message that did not decode, when `code` and `message` are
/// tonic's status for one: tonic's codec answers INTERNAL for every prost `DecodeError` (and
/// for a frame cut short), but the fault is the client's, so it is INVALID_ARGUMENT naming
/// `request` like every other malformed input.
pub(crate) fn undecodable(code: tonic::Code, message: &str) -> Option<ApiError> {
    (code == tonic::Code::Internal
        && (message.starts_with(DECODE_ERROR) || message.starts_with(TRUNCATED)))
    .then(|| {
        ApiError::invalid(
            "request",
            format!("the message is not valid protobuf: {message}"),
        )
    })
}

/// Rewrites tonic's own refusals of a request message (trailers-only responses, answered
/// before a handler runs or by a handler passing the stream's error on) into our contract,
/// INVALID_ARGUMENT naming `request`: a message above the decoding cap (tonic: OUT_OF_RANGE)
/// and one whose bytes do not decode (tonic: INTERNAL). Other statuses pass untouched.
async fn client_faults_are_invalid(
    mut r: axum::response::Response,
    hard_cap: usize,
) -> axum::response::Response {
    let h = r.headers();
    let Some(code) = h
        .get("grpc-status")
        .map(|v| tonic::Code::from_bytes(v.as_bytes()))
        .filter(|c| matches!(c, tonic::Code::OutOfRange | tonic::Code::Internal))
    else {
        return r;
    };
    let message = h
        .get("grpc-message")
        .map(|v| percent_decode(v.as_bytes()))
        .unwrap_or_default();
    let refusal = if code == tonic::Code::OutOfRange && message.contains("message length too large")
    {
        Some(ApiError::invalid(
            "request",
            format!("the message is larger than the server accepts ({hard_cap} bytes)"),
        ))
    } else {
        undecodable(code, &message)
    };
    if let Some(e) = refusal {
        let mut fresh = e.to_status().into_http::<axum::body::Body>();
        std::mem::swap(r.headers_mut(), fresh.headers_mut());
    }
    r
}

/// A `grpc-message` header value, percent-decoded (tonic encodes spaces and a few others).
fn percent_decode(v: &[u8]) -> String {
    percent_encoding::percent_decode(v)
        .decode_utf8_lossy()
        .into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grpc_timeout_units() {
        assert_eq!(parse_grpc_timeout("100m"), Some(Duration::from_millis(100)));
        assert_eq!(parse_grpc_timeout("2S"), Some(Duration::from_secs(2)));
        assert_eq!(parse_grpc_timeout("5u"), Some(Duration::from_micros(5)));
        assert_eq!(parse_grpc_timeout("1H"), Some(Duration::from_secs(3600)));
        assert_eq!(parse_grpc_timeout("m"), None);
        assert_eq!(parse_grpc_timeout("12x"), None);
        assert_eq!(parse_grpc_timeout("123456789S"), None);
    }

    #[test]
    fn undecodable_messages_are_invalid_naming_request() {
        assert_eq!(
            percent_decode(b"failed%20to%20decode%20Protobuf%20message:%20invalid%20varint%zz%"),
            "failed to decode Protobuf message: invalid varint%zz%"
        );
        let e = undecodable(
            tonic::Code::Internal,
            "failed to decode Protobuf message: invalid varint",
        )
        .unwrap()
        .to_status();
        assert_eq!(e.code(), tonic::Code::InvalidArgument);
        assert!(e.message().starts_with("request: "), "{}", e.message());
        assert!(undecodable(tonic::Code::Internal, "Unexpected EOF decoding stream.").is_some());
        assert!(undecodable(tonic::Code::Internal, "an engine fault").is_none());
        assert!(undecodable(tonic::Code::Unknown, DECODE_ERROR).is_none());
    }
}
