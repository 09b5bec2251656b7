//! Sessions: scenes prepared once and kept with their state between calls, for planners.
//!
//! - this module: the store (ids, caps on count and memory, idle TTL and reaping, metrics,
//!   ownership) and the calls that do not step (create, fork, get, set, delete);
//! - `ledger`: per-caller quotas (sessions, session memory, open streams);
//! - `driven`: a `super::stepper::Stepper` whose kinematic objects follow given poses, and
//!   the `Step` call;
//! - `predict`: Predict from a session (variants of its state with their own actions);
//! - `interact`: the closed loop, one step per client message;
//! - `gradient`: Gradient from a session (candidate paths of its kinematic objects scored and
//!   differentiated from its state, in a gradient pass of its model).
//!
//! Steps of a session go through the model's scheduler like any rollout step (interactive
//! priority; Predict variants bulk), so they share its batches. One call at a time holds a
//! session's state (an async mutex); a reaper removes sessions idle for longer than the TTL
//! unless a call holds them.
//!
//! Ownership: a session belongs to the caller that created it (its bearer token, or without
//! authentication its peer IP address; see `crate::security::Caller`). For any other caller it
//! does not exist: every call naming it answers NOT_FOUND, exactly as for an unknown id, so ids
//! cannot be probed. A session created with `shared` may be used (stepped, read, set, forked,
//! driven by Interact) by every caller; only its owner may delete it (others: PERMISSION_DENIED).
//! Its session count and memory are charged to its owner; a fork belongs to (and is charged
//! to) the caller that forked it.

mod driven;
mod gradient;
pub mod input;
mod interact;
mod ledger;
mod predict;

use std::collections::HashMap;
use std::hash::{BuildHasher, Hasher};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use dynaserve_api::spec::session::{
    CreateSessionSpec, SessionInfo, SessionStateView, SetStateSpec,
};
use dynaserve_model::SceneState;

pub use driven::StepHandle;
pub use interact::InteractHandle;

use super::Engine;
use super::admission::check_steps;
use super::registry::ModelEntry;
use super::request::{Call, RequestCtx};
use crate::config::SessionConfig;
use crate::error::ApiError;
use crate::families::contract::SteppedScene;
use crate::metrics::Metrics;
use input::{apply_states, kinematic_mask};
use ledger::{Charge, Ledger, Usage};

/// A prepared scene held by sessions, counted once in the store's memory however many forks
/// share it; its bytes are released when the last holder goes.
struct HeldScene {
    scene: Arc<dyn SteppedScene>,
    bytes: usize,
    total: Arc<AtomicUsize>,
    /// Its bytes in its creator's quota.
    _charge: Charge,
}

impl Drop for HeldScene {
    fn drop(&mut self) {
        self.total.fetch_sub(self.bytes, Ordering::Relaxed);
    }
}

/// Bytes of one session's own state (three poses per object: the step before, previous and
/// current; and bookkeeping).
fn state_bytes(objects: usize) -> usize {
    objects * 3 * std::mem::size_of::<dynaserve_model::Pose>() + 512
}

/// What a call holding a session may change.
#[derive(Clone, Debug)]
pub(crate) struct Progress {
    /// Previous and current poses.
    pub state: SceneState,
    /// Steps taken since creation.
    pub step: u32,
}

/// One session.
pub(crate) struct Session {
    pub id: String,
    pub entry: Arc<ModelEntry>,
    held: Arc<HeldScene>,
    /// Kinematic mask `[objects]`.
    pub kinematic: Arc<[bool]>,
    /// Frames per step.
    pub dt_steps: u32,
    /// The state, held by one call at a time.
    pub progress: Arc<tokio::sync::Mutex<Progress>>,
    /// Set once the session leaves the store (deleted or reaped): a stream still holding it
    /// (Interact) must stop stepping it at its next message.
    removed: AtomicBool,
    /// The caller it belongs to (`RequestCtx::identity`).
    owner: u64,
    /// Usable by every caller (not only its owner).
    shared: bool,
    /// The session and its state in its owner's quota.
    _charge: Charge,
    last_used: Mutex<Instant>,
    own_bytes: usize,
    total: Arc<AtomicUsize>,
    open: prometheus::IntGauge,
}

impl Session {
    /// The prepared scene.
    pub fn scene(&self) -> &Arc<dyn SteppedScene> {
        &self.held.scene
    }

    /// Seconds per step.
    pub fn dt_seconds(&self) -> f32 {
        (f64::from(self.dt_steps) * self.entry.dt_frame) as f32
    }

    fn touch(&self) {
        if let Ok(mut t) = self.last_used.lock() {
            *t = Instant::now();
        }
    }

    fn idle_since(&self) -> Instant {
        self.last_used
            .lock()
            .map_or_else(|_| Instant::now(), |t| *t)
    }

    /// True once the session has been deleted or reaped.
    pub(crate) fn is_removed(&self) -> bool {
        self.removed.load(Ordering::Acquire)
    }

    /// True when `caller` may use the session: its owner, or anyone when it is shared.
    fn visible_to(&self, caller: u64) -> bool {
        self.shared || self.owner == caller
    }

    fn kinematic_indices(&self) -> Vec<u32> {
        self.kinematic
            .iter()
            .enumerate()
            .filter(|(_, k)| **k)
            .map(|(j, _)| j as u32)
            .collect()
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        self.total.fetch_sub(self.own_bytes, Ordering::Relaxed);
        self.open.dec();
    }
}

/// Every session of the engine.
pub(crate) struct SessionStore {
    config: SessionConfig,
    map: Mutex<HashMap<String, Arc<Session>>>,
    bytes: Arc<AtomicUsize>,
    /// Per-caller quotas (sessions, memory, streams).
    ledger: Arc<Ledger>,
    reaper_started: std::sync::Once,
    metrics: Metrics,
}

/// Milliseconds since the Unix epoch at `at`.
fn unix_ms(at: Instant) -> u64 {
    let now = Instant::now();
    let wall = SystemTime::now();
    let t = if at >= now {
        wall + (at - now)
    } else {
        wall - (now - at)
    };
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// A new session id: 32 hex digits from two independently keyed hashes of a counter and the
/// clock (std's randomly keyed SipHash), so ids neither repeat nor follow a pattern.
fn new_session_id() -> String {
    static N: AtomicU64 = AtomicU64::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    let nanos = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    let part = |salt: u64| {
        let mut h = std::collections::hash_map::RandomState::new().build_hasher();
        h.write_u64(n);
        h.write_u64(nanos);
        h.write_u64(salt);
        h.finish()
    };
    format!("{:016x}{:016x}", part(1), part(2))
}

/// NOT_FOUND for an unknown or expired session.
pub(crate) fn not_found(id: &str) -> ApiError {
    ApiError {
        code: tonic::Code::NotFound,
        message: format!("session_id: no session {id:?} (unknown, deleted or expired)"),
        field: Some("session_id".into()),
        ..ApiError::internal(String::new())
    }
}

impl SessionStore {
    pub(crate) fn new(config: SessionConfig, metrics: Metrics) -> SessionStore {
        SessionStore {
            ledger: Arc::new(Ledger::new(&config)),
            config,
            map: Mutex::new(HashMap::new()),
            bytes: Arc::new(AtomicUsize::new(0)),
            reaper_started: std::sync::Once::new(),
            metrics,
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, Arc<Session>>> {
        self.map.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Number of sessions held.
    pub(crate) fn len(&self) -> usize {
        self.lock().len()
    }

    /// Looks up a session `caller` may use (NOT_FOUND for another caller's, as for an unknown
    /// id) and renews its TTL.
    pub(crate) fn get(&self, id: &str, caller: u64) -> Result<Arc<Session>, ApiError> {
        let s = self
            .lock()
            .get(id)
            .filter(|s| s.visible_to(caller))
            .cloned()
            .ok_or_else(|| not_found(id))?;
        s.touch();
        Ok(s)
    }

    fn expires_at(&self, s: &Session) -> u64 {
        unix_ms(s.idle_since() + self.config.ttl())
    }

    fn info(&self, s: &Session) -> SessionInfo {
        SessionInfo {
            session_id: s.id.clone(),
            model: s.entry.name.clone(),
            expires_at_unix_ms: self.expires_at(s),
            objects: s.scene().len() as u32,
            dt_steps: s.dt_steps,
            kinematic: s.kinematic_indices(),
            shared: s.shared,
        }
    }

    /// Refuses, with INVALID_ARGUMENT naming `scene`, a session of `bytes` that could never
    /// be held (more than the server's or one caller's session memory with nothing else held),
    /// rather than a RESOURCE_EXHAUSTED that retrying cannot cure.
    fn check_fits(&self, bytes: usize) -> Result<(), ApiError> {
        let server = self.config.max_session_mib << 20;
        let caller = self.ledger.max_bytes();
        let (cap, flag) = if server <= caller {
            (server, "--max-session-mib")
        } else {
            (caller, "--max-session-mib-per-caller")
        };
        if bytes > cap {
            return Err(ApiError::invalid(
                "scene",
                format!(
                    "the session needs {bytes} bytes, more than the {} MiB the server ever \
                     holds for {} ({flag}); use fewer objects or points",
                    cap >> 20,
                    if flag == "--max-session-mib" {
                        "all sessions"
                    } else {
                        "one caller's sessions"
                    }
                ),
            ));
        }
        Ok(())
    }

    /// Charges `add` to `caller`'s quota (RESOURCE_EXHAUSTED past a per-caller cap).
    fn charge(&self, caller: u64, add: Usage, retry: Duration) -> Result<Charge, ApiError> {
        self.ledger.charge(caller, add, retry)
    }

    /// Checks the caps for `extra` more bytes and one more session.
    fn admit(&self, extra: usize, retry: Duration) -> Result<(), ApiError> {
        let n = self.len();
        if n >= self.config.max_sessions {
            return Err(ApiError::exhausted(
                format!("{n} sessions are open, the server's limit; delete some or retry later"),
                retry,
            ));
        }
        let cap = self.config.max_session_mib << 20;
        let used = self.bytes.load(Ordering::Relaxed);
        if used + extra > cap {
            return Err(ApiError::exhausted(
                format!(
                    "sessions hold {used} bytes; {extra} more would exceed the server's limit \
                     of {} MiB; delete some or retry later",
                    self.config.max_session_mib
                ),
                retry,
            ));
        }
        Ok(())
    }

    /// Keeps a new session owned by `owner`, its count and state charged to `charge`.
    #[allow(clippy::too_many_arguments)]
    fn insert(
        &self,
        entry: Arc<ModelEntry>,
        held: Arc<HeldScene>,
        kinematic: Arc<[bool]>,
        dt_steps: u32,
        progress: Progress,
        owner: u64,
        shared: bool,
        charge: Charge,
    ) -> Arc<Session> {
        let own_bytes = state_bytes(progress.state.len());
        self.bytes.fetch_add(own_bytes, Ordering::Relaxed);
        let open = self
            .metrics
            .sessions_open
            .with_label_values(&[entry.name.as_str()]);
        open.inc();
        let s = Arc::new(Session {
            id: new_session_id(),
            entry,
            held,
            kinematic,
            dt_steps,
            progress: Arc::new(tokio::sync::Mutex::new(progress)),
            removed: AtomicBool::new(false),
            owner,
            shared,
            _charge: charge,
            last_used: Mutex::new(Instant::now()),
            own_bytes,
            total: self.bytes.clone(),
            open,
        });
        self.lock().insert(s.id.clone(), s.clone());
        s
    }

    /// Removes a session for `caller`: NOT_FOUND when it does not exist for that caller,
    /// PERMISSION_DENIED when it is another caller's shared session.
    fn remove_for(&self, id: &str, caller: u64) -> Result<(), ApiError> {
        let mut map = self.lock();
        match map.get(id) {
            Some(s) if s.owner == caller => {}
            Some(s) if s.shared => {
                return Err(ApiError::permission_denied(format!(
                    "session_id: session {id:?} is shared by another caller; only its owner \
                     may delete it"
                )));
            }
            _ => return Err(not_found(id)),
        }
        if let Some(s) = map.remove(id) {
            s.removed.store(true, Ordering::Release);
        }
        Ok(())
    }

    /// Removes a session, marking it removed for any stream still holding it; false if it
    /// was not there.
    pub(crate) fn remove(&self, id: &str) -> bool {
        let removed = self.lock().remove(id);
        if let Some(s) = &removed {
            s.removed.store(true, Ordering::Release);
        }
        removed.is_some()
    }

    /// Starts the reaper once (on the current runtime); it stops when the store is dropped.
    fn start_reaper(self: &Arc<Self>) {
        self.reaper_started.call_once(|| {
            let weak: Weak<SessionStore> = Arc::downgrade(self);
            let period =
                (self.config.ttl() / 4).clamp(Duration::from_millis(20), Duration::from_secs(10));
            tokio::spawn(async move {
                let mut tick = tokio::time::interval(period);
                tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
                loop {
                    tick.tick().await;
                    let Some(store) = weak.upgrade() else { return };
                    store.reap(Instant::now());
                }
            });
        });
    }

    /// Removes the sessions idle for longer than the TTL at `now` that no call holds.
    fn reap(&self, now: Instant) {
        let ttl = self.config.ttl();
        let mut reaped = Vec::new();
        {
            let mut map = self.lock();
            map.retain(|_, s| {
                let expired = now.saturating_duration_since(s.idle_since()) > ttl;
                // A session in use (its state held by a call) is not idle, whatever its clock.
                let busy = s.progress.try_lock().is_err();
                if expired && !busy {
                    reaped.push(s.clone());
                    false
                } else {
                    true
                }
            });
        }
        for s in reaped {
            s.removed.store(true, Ordering::Release);
            tracing::info!(session = %s.id, model = %s.entry.name, "session expired");
            self.metrics
                .sessions_reaped
                .with_label_values(&[s.entry.name.as_str()])
                .inc();
        }
    }
}

impl Engine {
    /// Runs a session call that answers at once (no steps): admission, then `call`, counted
    /// under `method` in the request metrics and logged in its span.
    async fn session_call<T>(
        &self,
        ctx: &RequestCtx,
        method: &'static str,
        call: impl Future<Output = Result<T, ApiError>>,
    ) -> Result<T, ApiError> {
        let span = tracing::info_span!("session", request_id = %ctx.request_id, method);
        Call::new(&self.metrics, ctx, method, span)
            .answer(async {
                self.admit_check()?;
                call.await
            })
            .await
    }

    /// Number of sessions held.
    pub fn sessions_open(&self) -> usize {
        self.sessions.len()
    }

    /// Validates and prepares a scene and keeps it as a new session; with the session, one
    /// warning per object parameter outside the model's trained range.
    pub async fn create_session(
        self: &Arc<Self>,
        req: CreateSessionSpec,
        ctx: RequestCtx,
    ) -> Result<(SessionInfo, Vec<String>), ApiError> {
        self.session_call(&ctx, "create_session", async {
            let (s, warnings) = self.create_session_inner(req, ctx.identity).await?;
            Ok((self.sessions.info(&s), warnings))
        })
        .await
    }

    /// Creates a session owned by `owner` (the caller has checked admission and records the
    /// call); with it, the warnings of its scene (see [`Engine::range_warnings`]).
    pub(crate) async fn create_session_inner(
        self: &Arc<Self>,
        req: CreateSessionSpec,
        owner: u64,
    ) -> Result<(Arc<Session>, Vec<String>), ApiError> {
        let shared = req.shared;
        let entry = self.resolve(&req.model)?;
        let dt_steps = check_steps(1, req.dt_steps, &entry.limits)?;
        let kinematic: Arc<[bool]> =
            kinematic_mask(&req.kinematic, req.scene.objects.len())?.into();
        // The count cap first, before preparing anything.
        self.sessions.admit(0, self.retry_after())?;
        let (scene, state, warnings) = self
            .prepare_one(&entry, req.scene, dt_steps, kinematic.clone())
            .await?;
        let bytes = scene.bytes();
        let own = state_bytes(state.len());
        self.sessions.check_fits(bytes + own)?;
        self.sessions.admit(bytes + own, self.retry_after())?;
        let retry = self.retry_after();
        let scene_charge = self.sessions.charge(
            owner,
            Usage {
                bytes,
                ..Usage::default()
            },
            retry,
        )?;
        let session_charge = self.sessions.charge(
            owner,
            Usage {
                sessions: 1,
                bytes: own,
                streams: 0,
            },
            retry,
        )?;
        self.sessions.bytes.fetch_add(bytes, Ordering::Relaxed);
        let held = Arc::new(HeldScene {
            scene,
            bytes,
            total: self.sessions.bytes.clone(),
            _charge: scene_charge,
        });
        let s = self.sessions.insert(
            entry,
            held,
            kinematic,
            dt_steps,
            Progress { state, step: 0 },
            owner,
            shared,
            session_charge,
        );
        self.sessions.start_reaper();
        self.metrics
            .sessions_created
            .with_label_values(&[s.entry.name.as_str()])
            .inc();
        tracing::info!(session = %s.id, objects = s.scene().len(), "session created");
        Ok((s, warnings))
    }

    /// Copies a session's state under a new id (the prepared scene is shared).
    pub async fn fork_session(&self, id: &str, ctx: RequestCtx) -> Result<SessionInfo, ApiError> {
        self.session_call(&ctx, "fork_session", async {
            let s = self.sessions.get(id, ctx.identity)?;
            let progress = s.progress.lock().await.clone();
            let own = state_bytes(progress.state.len());
            self.sessions.admit(own, self.retry_after())?;
            let charge = self.sessions.charge(
                ctx.identity,
                Usage {
                    sessions: 1,
                    bytes: own,
                    streams: 0,
                },
                self.retry_after(),
            )?;
            // The fork is its forker's own, not shared.
            let f = self.sessions.insert(
                s.entry.clone(),
                s.held.clone(),
                s.kinematic.clone(),
                s.dt_steps,
                progress,
                ctx.identity,
                false,
                charge,
            );
            self.metrics
                .session_forks
                .with_label_values(&[s.entry.name.as_str()])
                .inc();
            Ok(self.sessions.info(&f))
        })
        .await
    }

    fn view(&self, s: &Session, p: &Progress) -> SessionStateView {
        SessionStateView {
            session_id: s.id.clone(),
            step: p.step,
            time: s.entry.time_at(p.step, s.dt_steps),
            state: p.state.clone(),
            expires_at_unix_ms: self.sessions.expires_at(s),
        }
    }

    /// A session's current state (waits for a running call on it to finish).
    pub async fn session_state(
        &self,
        id: &str,
        ctx: RequestCtx,
    ) -> Result<SessionStateView, ApiError> {
        self.session_call(&ctx, "get_state", async {
            let s = self.sessions.get(id, ctx.identity)?;
            let p = s.progress.lock().await;
            Ok(self.view(&s, &p))
        })
        .await
    }

    /// Overwrites some objects' states (waits for a running call on the session to finish).
    pub async fn set_session_state(
        &self,
        req: SetStateSpec,
        ctx: RequestCtx,
    ) -> Result<SessionStateView, ApiError> {
        self.session_call(&ctx, "set_state", async {
            let s = self.sessions.get(&req.session_id, ctx.identity)?;
            let mut p = s.progress.lock().await;
            apply_states(&mut p.state, &req.objects, s.dt_seconds(), "objects")?;
            Ok(self.view(&s, &p))
        })
        .await
    }

    /// Deletes a session of the caller's. A call running on it finishes first; an Interact
    /// stream on it ends at its next message with NOT_FOUND instead of stepping it further.
    pub async fn delete_session(&self, id: &str, ctx: RequestCtx) -> Result<(), ApiError> {
        self.session_call(&ctx, "delete_session", async {
            self.sessions.remove_for(id, ctx.identity)
        })
        .await
    }

    /// One stream of `ctx`'s caller (Rollout, Generate, a session's Step, Interact) in its
    /// quota, given back when dropped; RESOURCE_EXHAUSTED when the caller has
    /// `--max-streams-per-caller` open.
    pub fn stream_quota(&self, ctx: &RequestCtx) -> Result<StreamQuota, ApiError> {
        self.sessions
            .charge(
                ctx.identity,
                Usage {
                    streams: 1,
                    ..Usage::default()
                },
                self.retry_after(),
            )
            .map(|c| StreamQuota { _charge: c })
    }
}

/// One open stream in its caller's quota (see [`Engine::stream_quota`]); dropping it ends
/// the stream's share.
#[derive(Debug)]
pub struct StreamQuota {
    _charge: Charge,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_32_hex_digits_and_distinct() {
        let a = new_session_id();
        let b = new_session_id();
        assert_eq!(a.len(), 32);
        assert!(a.bytes().all(|c| c.is_ascii_hexdigit()));
        assert_ne!(a, b);
    }

    #[test]
    fn expiry_is_in_the_future_by_the_ttl() {
        let now_ms = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap()
            .as_millis() as u64;
        let at = unix_ms(Instant::now() + Duration::from_secs(10));
        assert!(
            at >= now_ms + 9_000 && at <= now_ms + 11_000,
            "{at} vs {now_ms}"
        );
    }
}
