//! The soak: many streams for a long time, clients dropping their rollouts at random and
//! reconnecting, every frame checked.
//!
//! Stream `i` owns a scene no other stream has: its own object count (`1 + i % objects`) and
//! its objects moved to their own square region of the ground plane, [`REGION_SPACING_M`]
//! metres apart on a grid. A frame belongs to its stream when it carries that many poses and
//! every pose lies inside the stream's region (a frame of another stream would lie in another
//! region). The frames of a rollout must come with steps 1, 2, 3, ...; a rollout its client
//! keeps must bring every step and end cleanly. Each stream owns its connection; after a drop
//! it opens a new one.

mod check;

pub use check::{REGION_SPACING_M, RolloutCheck, SoakTally, StreamIdentity, soak_scene};

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use dynaserve_api::json;
use rand::{Rng, SeedableRng};
use tokio::sync::Notify;

use super::{Load, Remote, Stop, lock};
use crate::recorder::{Recorder, RequestClock, ServerTiming};
use crate::report::SoakReport;
use crate::rss::{RssRecord, RssSource};
use crate::transport::{CallError, Conn};

/// How long streams may take to finish their last rollout after the soak's duration.
pub const DRAIN_LIMIT: Duration = Duration::from_secs(120);

/// What one stream of the soak does.
pub(super) struct SoakStream {
    pub(super) index: usize,
    pub(super) request: json::RolloutRequest,
    pub(super) identity: StreamIdentity,
    pub(super) drop_probability: f64,
    pub(super) seed: u64,
}

fn is_refusal(e: &CallError) -> bool {
    e.code.contains("RESOURCE_EXHAUSTED") || e.code.starts_with("http 429")
}

enum Outcome {
    Complete,
    Dropped,
    Refused(CallError),
    Failed(CallError),
    Cut,
}

/// Runs stream `s` until `end` (then finishes its rollout, up to `drain_end`), recording
/// frames in `rec` and checks in `tally`.
pub(super) async fn soak_stream(
    s: SoakStream,
    remote: Arc<Remote>,
    rec: Arc<Mutex<Recorder>>,
    tally: Arc<Mutex<SoakTally>>,
    end: Instant,
    drain_end: Instant,
    stop: Stop,
) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(s.seed ^ (s.index as u64) << 20);
    let steps = s.request.steps;
    let Some(mut conn) = connect(&remote, &s, &tally, end, &stop).await else {
        return;
    };
    let mut rollout = 0u64;
    while !stop.is_set() && Instant::now() < end {
        let drop_after = (steps >= 2 && rng.random_bool(s.drop_probability.clamp(0.0, 1.0)))
            .then(|| rng.random_range(1..steps));
        rollout += 1;
        let mut check = RolloutCheck::new();
        let outcome = tokio::select! {
            o = run_one(&mut conn, &s, &mut check, drop_after, &rec, &tally, rollout) => o,
            _ = tokio::time::sleep_until(drain_end.into()) => Outcome::Cut,
            _ = stop.wait() => Outcome::Cut,
        };
        let who = format!("stream {} rollout {rollout}", s.index);
        let mut new_connection = false;
        let mut wait = None;
        {
            let mut t = lock(&tally);
            match outcome {
                Outcome::Complete => {
                    check.finish(steps);
                    t.counts.kept_complete += 1;
                }
                Outcome::Dropped => {
                    t.counts.dropped += 1;
                    new_connection = true;
                }
                Outcome::Refused(e) => {
                    t.counts.refused += 1;
                    wait = Some(Duration::from_millis(
                        e.retry_after_ms.unwrap_or(100).clamp(10, 1000),
                    ));
                }
                Outcome::Failed(e) => {
                    check.finish(steps);
                    t.counts.failed += 1;
                    t.note(format!(
                        "{who}: failed after {} frames: {e}",
                        check.received
                    ));
                    new_connection = true;
                    wait = Some(Duration::from_millis(100));
                }
                Outcome::Cut => {
                    t.counts.cut += 1;
                    if !stop.is_set() {
                        t.counts.stalled += 1;
                        t.note(format!(
                            "{who}: still running {} s after the soak's end ({} frames)",
                            DRAIN_LIMIT.as_secs(),
                            check.received
                        ));
                    }
                }
            }
            t.add(&check);
        }
        if stop.is_set() || Instant::now() >= drain_end {
            return;
        }
        if let Some(w) = wait {
            tokio::select! {
                _ = tokio::time::sleep(w) => {}
                _ = stop.wait() => return,
            }
        }
        if new_connection && Instant::now() < end {
            // The client went away mid-rollout: it comes back on a new connection.
            let Some(c) = connect(&remote, &s, &tally, end, &stop).await else {
                return;
            };
            conn = c;
            lock(&tally).counts.reconnects += 1;
        }
    }
}

/// A new connection for stream `s`, retried every 200 ms (each failure counted) until `end`.
async fn connect(
    remote: &Remote,
    s: &SoakStream,
    tally: &Mutex<SoakTally>,
    end: Instant,
    stop: &Stop,
) -> Option<Conn> {
    loop {
        match remote.fresh_conn().await {
            Ok(c) => return Some(c),
            Err(e) => {
                let mut t = lock(tally);
                t.counts.connect_errors += 1;
                t.note(format!("stream {}: cannot connect: {e}", s.index));
            }
        }
        if stop.is_set() || Instant::now() >= end {
            return None;
        }
        tokio::select! {
            _ = tokio::time::sleep(Duration::from_millis(200)) => {}
            _ = stop.wait() => return None,
        }
    }
}

async fn run_one(
    conn: &mut Conn,
    s: &SoakStream,
    check: &mut RolloutCheck,
    drop_after: Option<u32>,
    rec: &Mutex<Recorder>,
    tally: &Mutex<SoakTally>,
    rollout: u64,
) -> Outcome {
    let leave = Notify::new();
    lock(rec).started();
    let mut clock = RequestClock::start();
    let result = {
        let mut on_frame = |at: Instant, f: &json::StepFrame| {
            let timing = f.timing.map(|t| ServerTiming {
                queue_ms: f64::from(t.queue_ms),
                forward_ms: f64::from(t.forward_ms),
                batch_scenes: t.batch_scenes,
            });
            lock(rec).frame(&mut clock, at, f.poses.len(), timing);
            if let Some(wrong) = check.frame(&s.identity, f) {
                lock(tally).note(format!("stream {} rollout {rollout}: {wrong}", s.index));
            }
            if drop_after == Some(check.received) {
                leave.notify_one();
            }
        };
        tokio::select! {
            r = conn.rollout(&s.request, &mut on_frame) => Some(r),
            _ = leave.notified() => None,
        }
    };
    match result {
        None => Outcome::Dropped,
        Some(Ok(_)) => {
            lock(rec).rollout_ok(&clock, Instant::now());
            Outcome::Complete
        }
        Some(Err(e)) => {
            lock(rec).failed(&e);
            if check.received == 0 && is_refusal(&e) {
                Outcome::Refused(e)
            } else {
                Outcome::Failed(e)
            }
        }
    }
}

/// Parameters of a soak.
#[derive(Clone, Debug, PartialEq)]
pub struct SoakPlan {
    /// Concurrent streams.
    pub streams: usize,
    /// Time new rollouts are started; streams then finish the rollout they are in.
    pub duration: Duration,
    /// Chance that a client drops a rollout at a random frame and reconnects.
    pub drop_probability: f64,
    /// Time between two readings of the server's resident memory.
    pub rss_interval: Duration,
    /// Seed of the drop decisions.
    pub seed: u64,
}

/// Runs the soak: every stream on its own connection until the duration ends, the server's
/// memory read at the start, every `rss_interval` and at the end.
pub(super) async fn run_soak(
    load: &Arc<Load>,
    remote: &Arc<Remote>,
    plan: &SoakPlan,
    rss_source: Option<RssSource>,
    rec: &Arc<Mutex<Recorder>>,
    stop: &Stop,
) -> SoakReport {
    let start = Instant::now();
    let mut rss = rss_source.as_ref().map(RssRecord::new);
    if let (Some(r), Some(src)) = (rss.as_mut(), rss_source.as_ref()) {
        r.sample(src, start).await;
    }
    let end = start + plan.duration;
    let drain_end = end + DRAIN_LIMIT;
    let tally = Arc::new(Mutex::new(SoakTally::default()));
    let mut tasks = tokio::task::JoinSet::new();
    for i in 0..plan.streams {
        let (scene, identity) = soak_scene(&load.scenes, i, plan.streams);
        let s = SoakStream {
            index: i,
            request: load.rollout(scene),
            identity,
            drop_probability: plan.drop_probability,
            seed: plan.seed,
        };
        tasks.spawn(soak_stream(
            s,
            remote.clone(),
            rec.clone(),
            tally.clone(),
            end,
            drain_end,
            stop.clone(),
        ));
    }
    let every = plan.rss_interval.max(Duration::from_millis(100));
    let mut tick = tokio::time::interval_at((start + every).into(), every);
    loop {
        tokio::select! {
            j = tasks.join_next() => if j.is_none() { break },
            _ = tick.tick(), if rss.is_some() => {
                if let (Some(r), Some(src)) = (rss.as_mut(), rss_source.as_ref()) {
                    r.sample(src, start).await;
                }
            }
        }
    }
    if let (Some(r), Some(src)) = (rss.as_mut(), rss_source.as_ref()) {
        r.sample(src, start).await;
    }
    let t = lock(&tally);
    SoakReport {
        streams: plan.streams,
        duration_s: plan.duration.as_secs_f64(),
        elapsed_s: start.elapsed().as_secs_f64(),
        drop_probability: plan.drop_probability,
        steps: load.steps,
        counts: t.counts,
        frames_per_s: t.counts.frames as f64 / start.elapsed().as_secs_f64().max(1e-9),
        rss,
        examples: t.examples.clone(),
    }
}
