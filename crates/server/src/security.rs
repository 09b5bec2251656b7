//! Who may talk to the server: bearer-token authentication on both protocols, TLS for both
//! listeners, and the browser policy (CORS allow-list, JSON-only bodies).
//!
//! - Tokens come from `--auth-token-file` (one per line, `#` comments) and/or
//!   `DYNASERVE_AUTH_TOKENS` (comma-separated). With none, authentication is off, which is
//!   allowed only when both listeners are on loopback addresses or `--allow-unauthenticated`
//!   is given. A request carries `authorization: Bearer <token>` (HTTP header or gRPC
//!   metadata); tokens are compared in constant time. Probes (`/health`, `/ready`, gRPC
//!   health) are open unless `--auth-probes`; `/metrics` is open only with
//!   `--auth-exempt-metrics`.
//! - TLS: `--tls-cert` and `--tls-key` (PEM) serve both ports over TLS 1.2/1.3 (rustls),
//!   offering `h2` and `http/1.1` by ALPN.
//! - CORS: off unless `--cors-origin` names allowed origins, which may use every method the
//!   API serves (GET, POST, PUT, DELETE); POST and PUT bodies must be `application/json` (415
//!   otherwise), so a page cannot make a browser send a "simple" cross-origin `text/plain`
//!   request.

use std::sync::Arc;

use axum::body::Body;
use axum::extract::Request;
use axum::http::{HeaderMap, HeaderValue, Method, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use subtle::{ConditionallySelectable, ConstantTimeEq};

use crate::error::ApiError;

pub use crate::config::security::{MIN_TOKEN_LEN, SecurityConfig, tls_acceptor};

/// Whom a request is attributed to for session ownership and per-caller quotas (the
/// `identity` of `crate::engine::RequestCtx`): with authentication on, the token it
/// authenticated with; otherwise its peer's IP address. The key is an opaque per-process hash,
/// so it reveals neither.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Caller(pub u64);

impl Caller {
    /// A request whose origin is unknown (no listener in front of the router).
    pub const UNKNOWN: Caller = Caller(0);

    fn key(kind: u8, id: &[u8]) -> Caller {
        use std::hash::BuildHasher;
        static KEYS: std::sync::OnceLock<std::collections::hash_map::RandomState> =
            std::sync::OnceLock::new();
        // 0 stays reserved for UNKNOWN.
        Caller(KEYS.get_or_init(Default::default).hash_one((kind, id)) | 1)
    }

    /// The caller of the `index`-th configured token.
    fn of_token(index: usize) -> Caller {
        Caller::key(0, &index.to_le_bytes())
    }

    /// The caller of an unauthenticated request from `ip`.
    pub fn of_peer(ip: std::net::IpAddr) -> Caller {
        match ip {
            std::net::IpAddr::V4(a) => Caller::key(4, &a.octets()),
            std::net::IpAddr::V6(a) => Caller::key(6, &a.octets()),
        }
    }

    /// The caller of a request from its extensions: the token's (set by [`Auth`]), else the
    /// peer's (set by the listener), else [`Caller::UNKNOWN`].
    pub fn of(extensions: &axum::http::Extensions) -> Caller {
        if let Some(c) = extensions.get::<Caller>() {
            return *c;
        }
        extensions
            .get::<crate::listener::Peer>()
            .map_or(Caller::UNKNOWN, |p| Caller::of_peer(p.0.ip()))
    }
}

impl<S: Send + Sync> axum::extract::FromRequestParts<S> for Caller {
    type Rejection = std::convert::Infallible;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        _state: &S,
    ) -> Result<Self, Self::Rejection> {
        Ok(Caller::of(&parts.extensions))
    }
}

/// The accepted tokens and which paths are open; shared by both listeners' middleware.
#[derive(Clone, Debug)]
pub struct Auth {
    tokens: Arc<Vec<Vec<u8>>>,
    probes_open: bool,
    metrics_open: bool,
}

/// Which protocol a listener speaks, for the form of the refusal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wire {
    /// gRPC: refusals are `UNAUTHENTICATED` statuses.
    Grpc,
    /// HTTP/JSON: refusals are 401 with `WWW-Authenticate: Bearer`.
    Http,
}

impl Auth {
    /// Authentication for `config`; `None` when no token is configured (authentication off).
    pub fn from_config(config: &SecurityConfig) -> Result<Option<Auth>, String> {
        let tokens = config.load_tokens()?;
        if tokens.is_empty() {
            return Ok(None);
        }
        Ok(Some(Auth {
            tokens: Arc::new(tokens.into_iter().map(String::into_bytes).collect()),
            probes_open: !config.auth_probes,
            metrics_open: config.auth_exempt_metrics,
        }))
    }

    /// True when `path` needs no token.
    fn is_open(&self, path: &str) -> bool {
        match path {
            "/health"
            | "/ready"
            | "/grpc.health.v1.Health/Check"
            | "/grpc.health.v1.Health/Watch" => self.probes_open,
            "/metrics" => self.metrics_open,
            // The viewer's static page and assets carry no data; its API calls send the token.
            "/" | "/dashboard" => true,
            p => p.starts_with("/viewer/"),
        }
    }

    /// True when `headers` carry one of the tokens (see `Auth::token_of`).
    pub fn accepts(&self, headers: &HeaderMap) -> bool {
        self.token_of(headers).is_some()
    }

    /// The index of the token `headers` carry, if they carry one. Every token is compared,
    /// each in constant time, so timing does not tell which one (or how much of one) matched.
    fn token_of(&self, headers: &HeaderMap) -> Option<usize> {
        let given = headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            // The scheme name is case-insensitive (RFC 7235).
            .and_then(|v| {
                v.split_once(' ')
                    .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
                    .map(|(_, token)| token)
            })
            .map(str::trim)?;
        let mut ok = subtle::Choice::from(0u8);
        let mut index = 0u64;
        for (i, t) in self.tokens.iter().enumerate() {
            let eq = t.as_slice().ct_eq(given.as_bytes());
            index = u64::conditional_select(&index, &(i as u64), eq);
            ok |= eq;
        }
        bool::from(ok).then_some(index as usize)
    }

    /// `router` behind this authentication; refusals take the form of `wire`.
    pub fn protect(&self, router: axum::Router, wire: Wire) -> axum::Router {
        let auth = self.clone();
        router.layer(axum::middleware::from_fn(
            move |req: Request, next: Next| auth.clone().check(wire, req, next),
        ))
    }

    /// The middleware: passes authorised (or open) requests on, answers the others.
    async fn check(self, wire: Wire, mut req: Request, next: Next) -> Response {
        if let Some(i) = self.token_of(req.headers()) {
            req.extensions_mut().insert(Caller::of_token(i));
            return next.run(req).await;
        }
        if self.is_open(req.uri().path()) || req.method() == Method::OPTIONS {
            return next.run(req).await;
        }
        let missing = !req.headers().contains_key(header::AUTHORIZATION);
        let msg = if missing {
            "missing credentials: send `authorization: Bearer <token>`"
        } else {
            "invalid credentials: the bearer token is not accepted"
        };
        match wire {
            Wire::Grpc => tonic::Status::unauthenticated(msg).into_http::<Body>(),
            Wire::Http => {
                let mut r = ApiError::unauthenticated(msg).into_response();
                r.headers_mut().insert(
                    header::WWW_AUTHENTICATE,
                    HeaderValue::from_static("Bearer realm=\"dynaserve\""),
                );
                r
            }
        }
    }
}

/// The HTTP router with its policy around it, outermost first: CORS (when origins are allowed),
/// authentication (when tokens are configured), JSON-only POST and PUT bodies, the body read
/// timeout (between chunks) and the body deadline (the whole body).
pub fn http_policy(
    router: axum::Router,
    config: &crate::ServeConfig,
    auth: Option<&Auth>,
) -> axum::Router {
    let mut router = router.layer(axum::middleware::from_fn(require_json));
    if let Some(t) = config.connections.body_read_timeout() {
        router = router.layer(axum::middleware::map_request(
            move |req: Request| async move {
                req.map(|b| Body::new(tower_http::timeout::TimeoutBody::new(t, b)))
            },
        ));
    }
    if let Some(d) = config.connections.body_deadline() {
        router = router.layer(axum::middleware::map_request(
            move |req: Request| async move {
                crate::listener::with_body_deadline(
                    req,
                    Some(d),
                    None,
                    crate::listener::BodyLimit::Whole,
                    false,
                )
            },
        ));
    }
    if let Some(a) = auth {
        router = a.protect(router, Wire::Http);
    }
    if let Some(cors) = config.security.cors_layer() {
        router = router.layer(cors);
    }
    router
}

/// Middleware of the HTTP API: POST and PUT bodies must be JSON (`application/json` or
/// `+json`), otherwise 415 naming the content type received. A request without a body (no
/// content type, and `Content-Length: 0` or neither a length nor a chunked encoding, as
/// `curl -X POST` sends it) passes: there is nothing to be JSON.
pub async fn require_json(req: Request, next: Next) -> Response {
    if req.method() == Method::POST || req.method() == Method::PUT {
        let h = req.headers();
        let ct = h
            .get(header::CONTENT_TYPE)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("");
        let bodiless = ct.is_empty()
            && !h.contains_key(header::TRANSFER_ENCODING)
            && h.get(header::CONTENT_LENGTH)
                .is_none_or(|v| v.to_str().is_ok_and(|s| s.trim() == "0"));
        if bodiless {
            return next.run(req).await;
        }
        let essence = ct
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_lowercase();
        if essence != "application/json" && !essence.ends_with("+json") {
            let shown = if ct.is_empty() { "none" } else { ct };
            let e = ApiError::unsupported_media_type(format!(
                "content-type must be application/json, got {shown}"
            ));
            return e.into_response();
        }
    }
    next.run(req).await
}

/// True when `e` (from reading a request body) is the body read timeout.
pub fn is_body_timeout(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut cur = Some(e);
    while let Some(err) = cur {
        if err.is::<tower_http::timeout::TimeoutError>() {
            return true;
        }
        cur = err.source();
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::security::cors_origin;

    fn auth(tokens: &[&str]) -> Auth {
        Auth::from_config(&SecurityConfig {
            auth_tokens: tokens.iter().map(|t| t.to_string()).collect(),
            ..SecurityConfig::default()
        })
        .unwrap()
        .unwrap()
    }

    fn with(v: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(header::AUTHORIZATION, HeaderValue::from_str(v).unwrap());
        h
    }

    #[test]
    fn tokens_match_exactly() {
        let a = auth(&["0123456789abcdef", "fedcba9876543210xyz"]);
        assert!(a.accepts(&with("Bearer 0123456789abcdef")));
        assert!(a.accepts(&with("Bearer fedcba9876543210xyz")));
        assert!(!a.accepts(&with("Bearer 0123456789abcde")));
        assert!(!a.accepts(&with("Bearer 0123456789abcdefg")));
        assert!(!a.accepts(&with("Basic 0123456789abcdef")));
        assert!(a.accepts(&with("BEARER 0123456789abcdef")));
        assert!(!a.accepts(&HeaderMap::new()));
        assert!(a.is_open("/health") && !a.is_open("/metrics") && !a.is_open("/v1/rollout"));
        // The viewer's page and assets load without a token; its data calls still need one.
        assert!(a.is_open("/") && a.is_open("/dashboard") && a.is_open("/viewer/viewer.js"));
        assert!(!a.is_open("/v1/examples") && !a.is_open("/viewerx"));
    }

    #[test]
    fn short_tokens_and_bad_origins_are_refused() {
        let c = SecurityConfig {
            auth_tokens: vec!["short".into()],
            ..SecurityConfig::default()
        };
        assert!(c.load_tokens().unwrap_err().contains("too short"));
        for bad in ["*", "example.com", "https://a.example/path", "https://"] {
            assert!(cors_origin(bad).is_err(), "{bad}");
        }
        assert!(cors_origin("http://localhost:3000").is_ok());
    }
}
