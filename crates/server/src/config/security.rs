//! The flags of authentication, TLS and CORS (`SecurityConfig`) and what they build: the
//! token list, the TLS acceptor and the CORS layer. `crate::security` applies them to
//! requests.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

use axum::http::{HeaderValue, Method, header};
use tokio_rustls::TlsAcceptor;
use tokio_rustls::rustls;
use tower_http::cors::{AllowOrigin, CorsLayer};

/// Shortest accepted token, bytes (a guessable token is no protection).
pub const MIN_TOKEN_LEN: usize = 16;

/// Flags of authentication, TLS and CORS.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct SecurityConfig {
    /// File of bearer tokens, one per line (blank lines and `#` comments ignored). A request
    /// must send `authorization: Bearer <token>` with one of them.
    #[arg(long, env = "DYNASERVE_AUTH_TOKEN_FILE")]
    pub auth_token_file: Option<PathBuf>,
    /// Bearer tokens, comma-separated (environment only, so they stay out of `ps`).
    #[arg(skip)]
    pub auth_tokens: Vec<String>,
    /// Serve a non-loopback address without any token (e.g. behind an authenticating proxy).
    #[arg(long, env = "DYNASERVE_ALLOW_UNAUTHENTICATED")]
    pub allow_unauthenticated: bool,
    /// Require a token on the probes too (`/health`, `/ready`, grpc.health.v1.Health).
    #[arg(long, env = "DYNASERVE_AUTH_PROBES")]
    pub auth_probes: bool,
    /// Serve `/metrics` without a token (for a scraper inside a trusted network).
    #[arg(long, env = "DYNASERVE_AUTH_EXEMPT_METRICS")]
    pub auth_exempt_metrics: bool,
    /// PEM certificate chain; with --tls-key, both listeners speak TLS.
    #[arg(long, env = "DYNASERVE_TLS_CERT", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// PEM private key of --tls-cert.
    #[arg(long, env = "DYNASERVE_TLS_KEY", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Origins allowed to call the HTTP API from a browser (CORS), e.g.
    /// `https://viewer.example.com`. Repeatable or comma-separated; none (the default) sends no
    /// CORS headers, so browsers refuse cross-origin calls.
    #[arg(
        long = "cors-origin",
        env = "DYNASERVE_CORS_ORIGINS",
        value_delimiter = ','
    )]
    pub cors_origins: Vec<String>,
}

impl SecurityConfig {
    /// Every configured token: `auth_tokens`, `DYNASERVE_AUTH_TOKENS` and the token file.
    pub fn load_tokens(&self) -> Result<Vec<String>, String> {
        let mut tokens: Vec<String> = self.auth_tokens.clone();
        if let Ok(env) = std::env::var("DYNASERVE_AUTH_TOKENS") {
            tokens.extend(env.split(',').map(|t| t.trim().to_string()));
        }
        if let Some(path) = &self.auth_token_file {
            let text = std::fs::read_to_string(path)
                .map_err(|e| format!("--auth-token-file {}: cannot read: {e}", path.display()))?;
            tokens.extend(
                text.lines()
                    .map(str::trim)
                    .filter(|l| !l.is_empty() && !l.starts_with('#'))
                    .map(str::to_string),
            );
        }
        tokens.retain(|t| !t.is_empty());
        if let Some(t) = tokens.iter().find(|t| t.len() < MIN_TOKEN_LEN) {
            return Err(format!(
                "an authentication token of {} bytes is too short; at least {MIN_TOKEN_LEN}",
                t.len()
            ));
        }
        if let Some(t) = tokens
            .iter()
            .find(|t| !t.bytes().all(|b| b.is_ascii_graphic()))
        {
            return Err(format!(
                "an authentication token of {} bytes has spaces or non-ASCII characters",
                t.len()
            ));
        }
        tokens.sort();
        tokens.dedup();
        Ok(tokens)
    }

    /// Checks the flags: readable tokens, a loopback bind or tokens (or the explicit opt-out),
    /// valid CORS origins.
    pub fn validate(&self, binds: &[SocketAddr]) -> Result<(), String> {
        let tokens = self.load_tokens()?;
        if tokens.is_empty()
            && !self.allow_unauthenticated
            && let Some(a) = binds.iter().find(|a| !a.ip().is_loopback())
        {
            return Err(format!(
                "refusing to serve {a} without authentication: give tokens with \
                 --auth-token-file or DYNASERVE_AUTH_TOKENS, bind a loopback address, or \
                 pass --allow-unauthenticated"
            ));
        }
        for o in &self.cors_origins {
            cors_origin(o)?;
        }
        Ok(())
    }

    /// The TLS acceptor of `--tls-cert`/`--tls-key`, or `None` for plain TCP.
    pub fn tls_acceptor(&self) -> anyhow::Result<Option<TlsAcceptor>> {
        let (Some(cert), Some(key)) = (&self.tls_cert, &self.tls_key) else {
            return Ok(None);
        };
        Ok(Some(tls_acceptor(
            &std::fs::read(cert)
                .map_err(|e| anyhow::anyhow!("--tls-cert {}: {e}", cert.display()))?,
            &std::fs::read(key).map_err(|e| anyhow::anyhow!("--tls-key {}: {e}", key.display()))?,
        )?))
    }

    /// The CORS layer of the HTTP API, or `None` when no origin is allowed.
    pub fn cors_layer(&self) -> Option<CorsLayer> {
        if self.cors_origins.is_empty() {
            return None;
        }
        let origins: Vec<HeaderValue> = self
            .cors_origins
            .iter()
            .filter_map(|o| cors_origin(o).ok())
            .collect();
        Some(
            CorsLayer::new()
                .allow_origin(AllowOrigin::list(origins))
                // Exactly the methods the API serves (a session's state is PUT, a session
                // DELETEd).
                .allow_methods([Method::GET, Method::POST, Method::PUT, Method::DELETE])
                .allow_headers([
                    header::CONTENT_TYPE,
                    header::AUTHORIZATION,
                    header::ACCEPT,
                    header::HeaderName::from_static("x-request-id"),
                ])
                .expose_headers([
                    header::HeaderName::from_static("x-request-id"),
                    header::HeaderName::from_static("x-dynaserve-model"),
                    header::HeaderName::from_static(dynaserve_api::WARNING_HEADER),
                    header::RETRY_AFTER,
                ])
                .max_age(std::time::Duration::from_secs(600)),
        )
    }
}

/// An origin as browsers send it: `scheme://host[:port]`, no path.
pub(crate) fn cors_origin(o: &str) -> Result<HeaderValue, String> {
    let ok = (o.starts_with("http://") || o.starts_with("https://"))
        && !o
            .split_once("://")
            .is_some_and(|(_, rest)| rest.contains('/'))
        && !o.ends_with("://");
    if !ok {
        return Err(format!(
            "--cors-origin {o:?} is not an origin like https://viewer.example.com"
        ));
    }
    HeaderValue::from_str(o).map_err(|_| format!("--cors-origin {o:?} is not a valid header value"))
}

/// A rustls server configuration (ring provider, ALPN h2 and http/1.1) from PEM bytes.
pub fn tls_acceptor(cert_pem: &[u8], key_pem: &[u8]) -> anyhow::Result<TlsAcceptor> {
    use rustls::pki_types::pem::PemObject;
    use rustls::pki_types::{CertificateDer, PrivateKeyDer};
    let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_slice_iter(cert_pem)
        .collect::<Result<_, _>>()
        .map_err(|e| anyhow::anyhow!("TLS certificate: {e}"))?;
    if certs.is_empty() {
        anyhow::bail!("TLS certificate: no PEM certificate found");
    }
    let key = PrivateKeyDer::from_pem_slice(key_pem)
        .map_err(|e| anyhow::anyhow!("TLS key: no usable PEM private key: {e}"))?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut config = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| anyhow::anyhow!("TLS: {e}"))?
        .with_no_client_auth()
        .with_single_cert(certs, key)
        .map_err(|e| anyhow::anyhow!("TLS certificate and key: {e}"))?;
    config.alpn_protocols = vec![b"h2".to_vec(), b"http/1.1".to_vec()];
    Ok(TlsAcceptor::from(Arc::new(config)))
}
