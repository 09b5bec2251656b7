//! Flags of the session store (how many sessions, how much memory, how long they live idle)
//! and the per-caller quotas beside its global caps.

use std::time::Duration;

/// Flags of the session store.
#[derive(Clone, Debug, clap::Args)]
pub struct SessionConfig {
    /// Most sessions held at once over all models; creating or forking past it answers
    /// RESOURCE_EXHAUSTED / HTTP 429.
    #[arg(long, env = "DYNASERVE_MAX_SESSIONS", default_value_t = 4096)]
    pub max_sessions: usize,
    /// Most memory held by sessions (prepared scenes and states), MiB; past it creating or
    /// forking answers RESOURCE_EXHAUSTED / HTTP 429.
    #[arg(long, env = "DYNASERVE_MAX_SESSION_MIB", default_value_t = 1024)]
    pub max_session_mib: usize,
    /// A session not used for this long, seconds, is deleted.
    #[arg(long, env = "DYNASERVE_SESSION_TTL_S", default_value_t = 300.0)]
    pub session_ttl_s: f64,
    /// Most sessions one caller (a bearer token, or a peer IP address without authentication)
    /// holds at once; past it its creating or forking answers RESOURCE_EXHAUSTED / HTTP 429.
    #[arg(
        long,
        env = "DYNASERVE_MAX_SESSIONS_PER_CALLER",
        default_value_t = 1024
    )]
    pub max_sessions_per_caller: usize,
    /// Most session memory one caller holds, MiB (its prepared scenes and states).
    #[arg(
        long,
        env = "DYNASERVE_MAX_SESSION_MIB_PER_CALLER",
        default_value_t = 256
    )]
    pub max_session_mib_per_caller: usize,
    /// Most streams one caller has open at once (Rollout, Generate, a session's Step,
    /// Interact); past it a new one answers RESOURCE_EXHAUSTED / HTTP 429.
    #[arg(long, env = "DYNASERVE_MAX_STREAMS_PER_CALLER", default_value_t = 64)]
    pub max_streams_per_caller: usize,
}

impl SessionConfig {
    /// The idle TTL (at least 1 ms).
    pub fn ttl(&self) -> Duration {
        let s = if self.session_ttl_s.is_finite() {
            self.session_ttl_s.clamp(0.001, 30.0 * 86_400.0)
        } else {
            300.0
        };
        Duration::from_secs_f64(s)
    }

    /// Checks the flags for values that cannot work.
    pub fn validate(&self) -> Result<(), String> {
        if self.max_sessions == 0 || self.max_session_mib == 0 {
            return Err("--max-sessions and --max-session-mib must be at least 1".into());
        }
        if self.max_sessions_per_caller == 0
            || self.max_session_mib_per_caller == 0
            || self.max_streams_per_caller == 0
        {
            return Err(
                "--max-sessions-per-caller, --max-session-mib-per-caller and \
                 --max-streams-per-caller must be at least 1"
                    .into(),
            );
        }
        if !self.session_ttl_s.is_finite() || self.session_ttl_s <= 0.0 {
            return Err("--session-ttl-s must be a finite number > 0".into());
        }
        Ok(())
    }
}

impl Default for SessionConfig {
    fn default() -> Self {
        SessionConfig {
            max_sessions: 4096,
            max_session_mib: 1024,
            session_ttl_s: 300.0,
            max_sessions_per_caller: 1024,
            max_session_mib_per_caller: 256,
            max_streams_per_caller: 64,
        }
    }
}
