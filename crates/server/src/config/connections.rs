//! Flags of the listeners: the caps on open connections (in all and per peer address), the
//! connection and body timeouts (enforced by `crate::listener`) and the probe listener.

use std::net::SocketAddr;
use std::time::Duration;

use super::seconds::{check_secs, secs};

/// Connection limits and timeouts (flags of `dynaserve serve`).
#[derive(Clone, Debug, clap::Args)]
pub struct ConnectionConfig {
    /// Most open connections per listener; more are closed on accept.
    #[arg(long, env = "DYNASERVE_MAX_CONNECTIONS", default_value_t = 1024)]
    pub max_connections: usize,
    /// Most open connections per listener from one peer IP address; more from that address
    /// are closed on accept, so one host cannot fill a listener. 0 disables. Behind a proxy
    /// every client has the proxy's address: raise or disable it there.
    #[arg(long, env = "DYNASERVE_MAX_CONNECTIONS_PER_PEER", default_value_t = 64)]
    pub max_connections_per_peer: usize,
    /// Seconds a connection may take to send a request's headers (from accept, and for HTTP/1
    /// between requests: idle keep-alive connections close after it); 0 disables.
    #[arg(long, env = "DYNASERVE_HEADER_READ_TIMEOUT_S", default_value_t = 10.0)]
    pub header_read_timeout_s: f64,
    /// Seconds a request body may pause between two chunks before the request fails with 408
    /// (HTTP) and the connection closes, or, inside a gRPC message, with INVALID_ARGUMENT
    /// naming `request` (an Interact client may wait as long as it likes between messages);
    /// 0 disables.
    #[arg(long, env = "DYNASERVE_BODY_READ_TIMEOUT_S", default_value_t = 30.0)]
    pub body_read_timeout_s: f64,
    /// Seconds a request body may take in all, however steadily it trickles: an HTTP body from
    /// the request's headers to its end (else 408), a gRPC request's message from the request's
    /// start (for a client stream such as Interact: each later message from its first byte;
    /// the wait between messages is not bounded) (else INVALID_ARGUMENT naming `request`).
    /// 0 disables.
    #[arg(long, env = "DYNASERVE_BODY_DEADLINE_S", default_value_t = 60.0)]
    pub body_deadline_s: f64,
    /// Address of a listener of its own for the probes (`/health`, `/ready`) and `/metrics`
    /// over HTTP, with its own connection cap, so that a full API listener cannot lock them
    /// out. None (the default): the probes are served on the HTTP listener only.
    #[arg(long, env = "DYNASERVE_HEALTH_ADDR")]
    pub health_addr: Option<SocketAddr>,
    /// Seconds between HTTP/2 keep-alive pings; 0 disables.
    #[arg(
        long,
        env = "DYNASERVE_HTTP2_KEEPALIVE_INTERVAL_S",
        default_value_t = 30.0
    )]
    pub http2_keepalive_interval_s: f64,
    /// Seconds to wait for a keep-alive ping's answer before closing the connection.
    #[arg(
        long,
        env = "DYNASERVE_HTTP2_KEEPALIVE_TIMEOUT_S",
        default_value_t = 10.0
    )]
    pub http2_keepalive_timeout_s: f64,
}

impl ConnectionConfig {
    /// Checks the flags for values that cannot work.
    pub fn validate(&self) -> Result<(), String> {
        if self.max_connections == 0 {
            return Err("--max-connections must be at least 1".into());
        }
        check_secs("--header-read-timeout-s", self.header_read_timeout_s)?;
        check_secs("--body-read-timeout-s", self.body_read_timeout_s)?;
        check_secs("--body-deadline-s", self.body_deadline_s)?;
        check_secs(
            "--http2-keepalive-interval-s",
            self.http2_keepalive_interval_s,
        )?;
        check_secs(
            "--http2-keepalive-timeout-s",
            self.http2_keepalive_timeout_s,
        )
    }

    /// `body_read_timeout_s` as a duration; `None` when disabled.
    pub fn body_read_timeout(&self) -> Option<Duration> {
        secs(self.body_read_timeout_s)
    }

    /// `body_deadline_s` as a duration; `None` when disabled.
    pub fn body_deadline(&self) -> Option<Duration> {
        secs(self.body_deadline_s)
    }
}
