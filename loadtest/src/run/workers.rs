//! The callers of one level: stream workers (one rollout after another), planner-call workers
//! and the Poisson arrival process, each recording into the level's [`Recorder`].

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use dynaserve_api::json;
use rand::SeedableRng;
use rand_distr::{Distribution, Exp};

use super::{Load, Remote, Stop, lock, sleep_until_opt};
use crate::recorder::{Recorder, RequestClock, ServerTiming};
use crate::transport::{CallError, Conn};

/// One rollout on `conn`, recorded in `rec`; `None` when cut by `stop` or `deadline`.
pub(super) async fn one_rollout(
    conn: &mut Conn,
    req: &json::RolloutRequest,
    rec: &Mutex<Recorder>,
    deadline: Option<Instant>,
    stop: &Stop,
) -> Option<Result<(), CallError>> {
    lock(rec).started();
    let mut clock = RequestClock::start();
    let mut on_frame = |at: Instant, f: &json::StepFrame| {
        let timing = f.timing.map(|t| ServerTiming {
            queue_ms: f64::from(t.queue_ms),
            forward_ms: f64::from(t.forward_ms),
            batch_scenes: t.batch_scenes,
        });
        lock(rec).frame(&mut clock, at, f.poses.len(), timing);
    };
    let result = tokio::select! {
        r = conn.rollout(req, &mut on_frame) => Some(r),
        _ = stop.wait() => None,
        _ = sleep_until_opt(deadline) => None,
    };
    match result {
        Some(Ok(_)) => {
            lock(rec).rollout_ok(&clock, Instant::now());
            Some(Ok(()))
        }
        Some(Err(e)) => {
            lock(rec).failed(&e);
            Some(Err(e))
        }
        None => None,
    }
}

async fn backoff(e: &CallError, deadline: Option<Instant>, stop: &Stop) {
    let wait = Duration::from_millis(e.retry_after_ms.unwrap_or(100).clamp(10, 1000));
    tokio::select! {
        _ = tokio::time::sleep(wait) => {}
        _ = stop.wait() => {}
        _ = sleep_until_opt(deadline) => {}
    }
}

pub(super) async fn stream_worker(
    mut conn: Conn,
    req: json::RolloutRequest,
    rec: Arc<Mutex<Recorder>>,
    deadline: Option<Instant>,
    stop: Stop,
) {
    loop {
        if stop.is_set() || deadline.is_some_and(|d| Instant::now() >= d) {
            return;
        }
        match one_rollout(&mut conn, &req, &rec, deadline, &stop).await {
            None => return,
            Some(r) => {
                if deadline.is_none() {
                    return;
                }
                if let Err(e) = r {
                    backoff(&e, deadline, &stop).await;
                }
            }
        }
    }
}

pub(super) async fn predict_worker(
    mut conn: Conn,
    req: Arc<json::PredictRequest>,
    rec: Arc<Mutex<Recorder>>,
    remaining: Arc<AtomicUsize>,
    stop: Stop,
) {
    let objects: u64 = req.variants.iter().map(|v| v.objects.len() as u64).sum();
    let steps = u64::from(req.steps);
    while remaining
        .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |r| r.checked_sub(1))
        .is_ok()
    {
        if stop.is_set() {
            return;
        }
        lock(&rec).started();
        let clock = RequestClock::start();
        let r = tokio::select! {
            r = conn.predict(&req) => r,
            _ = stop.wait() => return,
        };
        let at = Instant::now();
        let r = r.and_then(|resp| {
            if resp.trajectories.len() == req.variants.len() {
                Ok(resp)
            } else {
                Err(CallError::new(
                    "incomplete",
                    format!(
                        "{} trajectories for {} variants",
                        resp.trajectories.len(),
                        req.variants.len()
                    ),
                ))
            }
        });
        match r {
            Ok(resp) => {
                let frames: u64 = resp
                    .trajectories
                    .iter()
                    .map(|t| t.frames.len() as u64)
                    .sum();
                lock(&rec).predict_ok(
                    &clock,
                    at,
                    frames,
                    req.variants.len() as u64 * steps,
                    objects * steps,
                    ServerTiming {
                        queue_ms: resp.timing.queue_ms,
                        forward_ms: resp.timing.forward_ms,
                        batch_scenes: 0,
                    },
                );
            }
            Err(e) => lock(&rec).failed(&e),
        }
    }
}

#[allow(clippy::too_many_arguments)]
pub(super) async fn poisson(
    load: &Arc<Load>,
    remote: &Arc<Remote>,
    rate: f64,
    arrivals_end: Instant,
    seed: u64,
    max_in_flight: usize,
    rec: &Arc<Mutex<Recorder>>,
    stop: &Stop,
) {
    let Ok(exp) = Exp::new(rate.max(1e-9)) else {
        return;
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let in_flight = Arc::new(AtomicUsize::new(0));
    let mut tasks = tokio::task::JoinSet::new();
    let mut next = Instant::now();
    let mut k = 0usize;
    loop {
        next += Duration::from_secs_f64(exp.sample(&mut rng));
        if next >= arrivals_end {
            break;
        }
        tokio::select! {
            _ = tokio::time::sleep_until(next.into()) => {}
            _ = stop.wait() => break,
        }
        // Reap finished tasks so the set stays small.
        while tasks.try_join_next().is_some() {}
        if in_flight.load(Ordering::SeqCst) >= max_in_flight {
            lock(rec).skipped();
            continue;
        }
        in_flight.fetch_add(1, Ordering::SeqCst);
        let req = load.rollout(load.scenes.scene(k));
        let (mut conn, rec, stop, in_flight) =
            (remote.conn(k), rec.clone(), stop.clone(), in_flight.clone());
        k += 1;
        tasks.spawn(async move {
            let _ = one_rollout(&mut conn, &req, &rec, None, &stop).await;
            in_flight.fetch_sub(1, Ordering::SeqCst);
        });
    }
    while tasks.join_next().await.is_some() {}
}
