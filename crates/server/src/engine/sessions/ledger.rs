//! Per-caller quotas: what each caller (see `crate::security::Caller`) holds of sessions,
//! session memory and open streams, under the caps of `crate::config::SessionConfig`. A
//! [`Charge`] is taken under one lock, checked against the caps, and given back when dropped.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::config::SessionConfig;
use crate::error::ApiError;

/// What one caller holds (or a change of it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Usage {
    /// Sessions.
    pub sessions: usize,
    /// Bytes of session memory.
    pub bytes: usize,
    /// Open streams.
    pub streams: usize,
}

/// Every caller's usage; callers that hold nothing are not kept.
pub(crate) struct Ledger {
    caps: Usage,
    held: Mutex<HashMap<u64, Usage>>,
}

/// A caller's share of the ledger, given back when dropped.
pub(crate) struct Charge {
    ledger: Arc<Ledger>,
    caller: u64,
    usage: Usage,
}

impl std::fmt::Debug for Charge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Charge")
            .field("usage", &self.usage)
            .finish()
    }
}

impl Ledger {
    /// A ledger under the per-caller caps of `config`.
    pub(crate) fn new(config: &SessionConfig) -> Ledger {
        Ledger {
            caps: Usage {
                sessions: config.max_sessions_per_caller,
                bytes: config.max_session_mib_per_caller.saturating_mul(1 << 20),
                streams: config.max_streams_per_caller,
            },
            held: Mutex::new(HashMap::new()),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<u64, Usage>> {
        self.held.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The per-caller cap on session memory, bytes.
    pub(crate) fn max_bytes(&self) -> usize {
        self.caps.bytes
    }

    /// What `caller` holds now.
    #[cfg(test)]
    fn usage(&self, caller: u64) -> Usage {
        self.lock().get(&caller).copied().unwrap_or_default()
    }

    /// Charges `add` to `caller` when it stays within every cap; RESOURCE_EXHAUSTED naming the
    /// cap and its flag otherwise (nothing charged).
    pub(crate) fn charge(
        self: &Arc<Self>,
        caller: u64,
        add: Usage,
        retry: Duration,
    ) -> Result<Charge, ApiError> {
        let mut held = self.lock();
        let now = held.get(&caller).copied().unwrap_or_default();
        let over = |have: usize, more: usize, cap: usize| more > 0 && have + more > cap;
        let refusal = if over(now.sessions, add.sessions, self.caps.sessions) {
            Some(format!(
                "you hold {} sessions, the limit per caller (--max-sessions-per-caller); \
                 delete some or retry later",
                now.sessions
            ))
        } else if over(now.bytes, add.bytes, self.caps.bytes) {
            Some(format!(
                "your sessions hold {} bytes; {} more would exceed the limit per caller of {} \
                 MiB (--max-session-mib-per-caller); delete some or retry later",
                now.bytes,
                add.bytes,
                self.caps.bytes >> 20
            ))
        } else if over(now.streams, add.streams, self.caps.streams) {
            Some(format!(
                "you have {} streams open, the limit per caller (--max-streams-per-caller); \
                 retry when one ends",
                now.streams
            ))
        } else {
            None
        };
        if let Some(m) = refusal {
            return Err(ApiError::exhausted(m, retry));
        }
        let e = held.entry(caller).or_default();
        e.sessions += add.sessions;
        e.bytes += add.bytes;
        e.streams += add.streams;
        Ok(Charge {
            ledger: self.clone(),
            caller,
            usage: add,
        })
    }
}

impl Drop for Charge {
    fn drop(&mut self) {
        let mut held = self.ledger.lock();
        if let Some(e) = held.get_mut(&self.caller) {
            e.sessions = e.sessions.saturating_sub(self.usage.sessions);
            e.bytes = e.bytes.saturating_sub(self.usage.bytes);
            e.streams = e.streams.saturating_sub(self.usage.streams);
            if *e == Usage::default() {
                held.remove(&self.caller);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn charges_stay_under_each_cap_and_come_back_when_dropped() {
        let ledger = Arc::new(Ledger::new(&SessionConfig {
            max_sessions_per_caller: 2,
            max_session_mib_per_caller: 1,
            max_streams_per_caller: 1,
            ..SessionConfig::default()
        }));
        let retry = Duration::from_secs(1);
        let one = Usage {
            sessions: 1,
            bytes: 1000,
            streams: 0,
        };
        let a = ledger.charge(7, one, retry).unwrap();
        let b = ledger.charge(7, one, retry).unwrap();
        let e = ledger.charge(7, one, retry).unwrap_err();
        assert!(
            e.message.contains("--max-sessions-per-caller"),
            "{}",
            e.message
        );
        // Another caller has its own quota.
        let other = ledger.charge(8, one, retry).unwrap();
        let big = Usage {
            bytes: 2 << 20,
            ..Usage::default()
        };
        let e = ledger.charge(8, big, retry).unwrap_err();
        assert!(
            e.message.contains("--max-session-mib-per-caller"),
            "{}",
            e.message
        );
        let stream = Usage {
            streams: 1,
            ..Usage::default()
        };
        let s = ledger.charge(7, stream, retry).unwrap();
        assert!(ledger.charge(7, stream, retry).is_err());
        drop((a, s));
        assert_eq!(ledger.usage(7), one);
        ledger.charge(7, one, retry).unwrap();
        drop((b, other));
        assert_eq!(ledger.usage(7), Usage::default());
        assert!(
            ledger.lock().is_empty(),
            "callers holding nothing are not kept"
        );
    }
}
