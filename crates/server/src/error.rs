//! One error type for both front ends, mapped to a gRPC status or an HTTP response.

use std::time::Duration;

use axum::http::{HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use dynaserve_api::FieldError;
use dynaserve_api::json::{ErrorDetail, ErrorResponse};
use tonic::Code;

/// gRPC metadata key of the retry hint (milliseconds), as understood by gRPC retry policies.
pub const RETRY_PUSHBACK_KEY: &str = "grpc-retry-pushback-ms";

/// A request failure: gRPC code, message, the offending field for invalid input and a retry
/// hint for overload.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{code:?}: {message}")]
pub struct ApiError {
    /// gRPC status code (the HTTP status is derived from it).
    pub code: Code,
    /// Message; for invalid input it starts with the field path.
    pub message: String,
    /// Offending field path for invalid input.
    pub field: Option<String>,
    /// Suggested wait before retrying (overload only).
    pub retry_after: Option<Duration>,
    /// HTTP status when it is not the one derived from `code` (415, 408).
    pub http_override: Option<StatusCode>,
}

impl ApiError {
    fn new(code: Code, message: impl Into<String>) -> ApiError {
        ApiError {
            code,
            message: message.into(),
            field: None,
            retry_after: None,
            http_override: None,
        }
    }

    /// INVALID_ARGUMENT naming `field`; the message reads `"{field}: {message}"`.
    pub fn invalid(field: impl Into<String>, message: impl std::fmt::Display) -> ApiError {
        let field = field.into();
        ApiError {
            code: Code::InvalidArgument,
            message: format!("{field}: {message}"),
            field: Some(field),
            retry_after: None,
            http_override: None,
        }
    }

    /// RESOURCE_EXHAUSTED with a retry hint.
    pub fn exhausted(message: impl Into<String>, retry_after: Duration) -> ApiError {
        ApiError {
            retry_after: Some(retry_after),
            ..ApiError::new(Code::ResourceExhausted, message)
        }
    }

    /// DEADLINE_EXCEEDED.
    pub fn deadline(message: impl Into<String>) -> ApiError {
        ApiError::new(Code::DeadlineExceeded, message)
    }

    /// UNAVAILABLE.
    pub fn unavailable(message: impl Into<String>) -> ApiError {
        ApiError::new(Code::Unavailable, message)
    }

    /// CANCELLED (the client went away).
    pub fn cancelled(message: impl Into<String>) -> ApiError {
        ApiError::new(Code::Cancelled, message)
    }

    /// FAILED_PRECONDITION (HTTP 400): the request is well formed but what it names cannot
    /// do it (a Gradient call on a model that computes no gradients).
    pub fn failed_precondition(message: impl Into<String>) -> ApiError {
        ApiError::new(Code::FailedPrecondition, message)
    }

    /// PERMISSION_DENIED (HTTP 403): the caller may not do this to the resource.
    pub fn permission_denied(message: impl Into<String>) -> ApiError {
        ApiError::new(Code::PermissionDenied, message)
    }

    /// UNAUTHENTICATED (HTTP 401): missing or rejected credentials.
    pub fn unauthenticated(message: impl Into<String>) -> ApiError {
        ApiError::new(Code::Unauthenticated, message)
    }

    /// INVALID_ARGUMENT naming `request`, answered over HTTP as 415 Unsupported Media Type.
    pub fn unsupported_media_type(message: impl Into<String>) -> ApiError {
        ApiError {
            http_override: Some(StatusCode::UNSUPPORTED_MEDIA_TYPE),
            ..ApiError::invalid("request", message.into())
        }
    }

    /// INVALID_ARGUMENT naming `request` for a body that stopped arriving, answered over HTTP as
    /// 408 Request Timeout.
    pub fn body_timeout(message: impl Into<String>) -> ApiError {
        ApiError {
            http_override: Some(StatusCode::REQUEST_TIMEOUT),
            ..ApiError::invalid("request", message.into())
        }
    }

    /// INTERNAL.
    pub fn internal(message: impl Into<String>) -> ApiError {
        ApiError::new(Code::Internal, message)
    }

    /// The `reason` label of `dynaserve_request_failures_total`.
    pub fn reason(&self) -> &'static str {
        match self.code {
            Code::InvalidArgument
            | Code::NotFound
            | Code::OutOfRange
            | Code::PermissionDenied
            | Code::FailedPrecondition => "invalid_argument",
            Code::ResourceExhausted => "resource_exhausted",
            Code::DeadlineExceeded => "deadline_exceeded",
            Code::Cancelled => "cancelled",
            Code::Unavailable => "unavailable",
            _ => "internal",
        }
    }

    /// The gRPC code name, e.g. `INVALID_ARGUMENT`.
    pub fn code_name(&self) -> &'static str {
        dynaserve_api::code_name(self.code)
    }

    /// The HTTP status of this error (422 invalid input, 415 non-JSON body, 408 body not
    /// received in time, 400 failed precondition, 401 unauthenticated, 403 forbidden, 429
    /// overload, 504 deadline, 503 unavailable, 499 cancelled, 500 otherwise).
    pub fn http_status(&self) -> StatusCode {
        if let Some(s) = self.http_override {
            return s;
        }
        match self.code {
            Code::Unauthenticated => StatusCode::UNAUTHORIZED,
            Code::InvalidArgument | Code::OutOfRange => StatusCode::UNPROCESSABLE_ENTITY,
            Code::NotFound => StatusCode::NOT_FOUND,
            Code::FailedPrecondition => StatusCode::BAD_REQUEST,
            Code::PermissionDenied => StatusCode::FORBIDDEN,
            Code::ResourceExhausted => StatusCode::TOO_MANY_REQUESTS,
            Code::DeadlineExceeded => StatusCode::GATEWAY_TIMEOUT,
            Code::Unavailable => StatusCode::SERVICE_UNAVAILABLE,
            Code::Cancelled => StatusCode::from_u16(499).unwrap_or(StatusCode::BAD_REQUEST),
            _ => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    /// The JSON error document. Its `code` is the gRPC code name, except for the two HTTP
    /// conditions gRPC has no code for: `UNSUPPORTED_MEDIA_TYPE` (415) and `REQUEST_TIMEOUT`
    /// (408).
    pub fn body(&self) -> ErrorResponse {
        let code = match self.http_override {
            Some(StatusCode::UNSUPPORTED_MEDIA_TYPE) => "UNSUPPORTED_MEDIA_TYPE",
            Some(StatusCode::REQUEST_TIMEOUT) => "REQUEST_TIMEOUT",
            _ => self.code_name(),
        };
        ErrorResponse {
            error: ErrorDetail {
                code: code.to_string(),
                message: self.message.clone(),
                field: self.field.clone(),
                retry_after_ms: self.retry_after.map(|d| d.as_millis() as u64),
            },
        }
    }

    /// The gRPC status, with `grpc-retry-pushback-ms` and `retry-after-ms` for overload and a
    /// `google.rpc.BadRequest` detail naming the field for invalid input.
    pub fn to_status(&self) -> tonic::Status {
        let mut status = match &self.field {
            Some(field) => {
                use tonic_types::{ErrorDetails, StatusExt};
                let description = self
                    .message
                    .strip_prefix(&format!("{field}: "))
                    .unwrap_or(&self.message);
                tonic::Status::with_error_details(
                    self.code,
                    self.message.clone(),
                    ErrorDetails::with_bad_request_violation(field.clone(), description),
                )
            }
            None => tonic::Status::new(self.code, self.message.clone()),
        };
        if let Some(d) = self.retry_after {
            let ms = d.as_millis().to_string();
            if let Ok(v) = ms.parse() {
                status.metadata_mut().insert(RETRY_PUSHBACK_KEY, v);
            }
            if let Ok(v) = ms.parse() {
                status.metadata_mut().insert("retry-after-ms", v);
            }
        }
        status
    }
}

/// `n` and the word for one or for many, as messages count what a request asks for: `1 step`,
/// `3 steps`.
pub(crate) fn count(n: u64, one: &str, many: &str) -> String {
    if n == 1 {
        format!("{n} {one}")
    } else {
        format!("{n} {many}")
    }
}

impl From<FieldError> for ApiError {
    fn from(e: FieldError) -> ApiError {
        ApiError::invalid(e.field, e.message)
    }
}

impl From<ApiError> for tonic::Status {
    fn from(e: ApiError) -> tonic::Status {
        e.to_status()
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let mut resp = (self.http_status(), axum::Json(self.body())).into_response();
        if let Some(d) = self.retry_after {
            // Retry-After is in whole seconds; round up so clients never retry early.
            let secs = d.as_millis().div_ceil(1000).max(1);
            if let Ok(v) = HeaderValue::from_str(&secs.to_string()) {
                resp.headers_mut()
                    .insert(axum::http::header::RETRY_AFTER, v);
            }
        }
        resp
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mappings() {
        let e = ApiError::invalid("scene.objects[1].mass", "must be > 0");
        assert_eq!(e.message, "scene.objects[1].mass: must be > 0");
        assert_eq!(e.http_status(), StatusCode::UNPROCESSABLE_ENTITY);
        assert_eq!(e.to_status().code(), Code::InvalidArgument);
        use tonic_types::StatusExt;
        let details = e.to_status().get_error_details();
        let v = &details.bad_request().unwrap().field_violations[0];
        assert_eq!(
            (v.field.as_str(), v.description.as_str()),
            ("scene.objects[1].mass", "must be > 0")
        );
        assert_eq!(
            ApiError::unsupported_media_type("x").http_status(),
            StatusCode::UNSUPPORTED_MEDIA_TYPE
        );
        assert_eq!(
            ApiError::unauthenticated("x").http_status(),
            StatusCode::UNAUTHORIZED
        );
        let o = ApiError::exhausted("full", Duration::from_millis(1500));
        let s = o.to_status();
        assert_eq!(s.metadata().get(RETRY_PUSHBACK_KEY).unwrap(), "1500");
        let r = o.into_response();
        assert_eq!(r.status(), StatusCode::TOO_MANY_REQUESTS);
        assert_eq!(r.headers()["retry-after"], "2");
    }
}
