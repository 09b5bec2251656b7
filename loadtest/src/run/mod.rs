//! The driver that runs a load (`load`: its modes, scenes and target) against one side (a
//! server over gRPC or HTTP, or the model in-process), scraping the server's `/metrics` around
//! every level. The callers that keep a level busy (streams, planner calls, Poisson arrivals)
//! are in `workers`, the soak in `soak`.

mod load;
mod remote;
mod soak;
mod workers;

pub use crate::report::{SoakCounts, SoakReport};
pub use load::{Load, Mode, Target, Transport};
use remote::{Remote, connect};
pub use soak::{DRAIN_LIMIT, REGION_SPACING_M, RolloutCheck, SoakPlan, StreamIdentity, soak_scene};
use workers::{poisson, predict_worker, stream_worker};

use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use dynaserve_api::json;
use tokio::sync::watch;

use crate::inprocess::InProcess;
use crate::recorder::Recorder;
use crate::report::{Report, ServerStats, SideReport};
use crate::rss::RssSource;
use crate::transport::{CallError, http_get};

/// Cloneable "stop now" signal (Ctrl-C).
#[derive(Clone, Debug)]
pub struct Stop(watch::Receiver<bool>);

impl Stop {
    /// A signal and the sender that raises it.
    pub fn new() -> (watch::Sender<bool>, Stop) {
        let (tx, rx) = watch::channel(false);
        (tx, Stop(rx))
    }

    /// True once raised.
    pub fn is_set(&self) -> bool {
        *self.0.borrow()
    }

    /// Resolves when raised (never, if the sender is dropped unraised).
    pub async fn wait(&self) {
        let mut rx = self.0.clone();
        if rx.wait_for(|v| *v).await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

async fn sleep_until_opt(deadline: Option<Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d.into()).await,
        None => std::future::pending().await,
    }
}

/// Progress lines on stderr while a level runs.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Print nothing.
    pub quiet: bool,
}

fn progress_task(
    rec: Arc<Mutex<Recorder>>,
    what: String,
    progress: Progress,
) -> Option<tokio::task::JoinHandle<()>> {
    if progress.quiet {
        return None;
    }
    let tty = std::io::stderr().is_terminal();
    Some(tokio::spawn(async move {
        let start = Instant::now();
        let mut last = (0u64, start);
        let mut tick = 0u64;
        loop {
            tokio::time::sleep(Duration::from_secs(1)).await;
            tick += 1;
            let (frames, ok, failed) = lock(&rec).progress();
            let now = Instant::now();
            let rate = (frames - last.0) as f64 / (now - last.1).as_secs_f64().max(1e-9);
            last = (frames, now);
            let line = format!(
                "[{what}] {:>5.1} s  frames {frames}  ok {ok}  failed {failed}  {rate:.0} frames/s",
                (now - start).as_secs_f64()
            );
            if tty {
                eprint!("\r\x1b[2K{line}");
            } else if tick.is_multiple_of(5) {
                eprintln!("{line}");
            }
        }
    }))
}

fn end_progress(h: Option<tokio::task::JoinHandle<()>>) {
    if let Some(h) = h {
        h.abort();
        if std::io::stderr().is_terminal() {
            eprint!("\r\x1b[2K");
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Runs every level of `load` against `target` and returns the side's report. Errors of
/// individual requests are counted in the report; only an unreachable target (or an
/// unloadable in-process model) is an `Err`.
pub async fn run_target(
    load: &Load,
    target: &Target,
    stop: &Stop,
    progress: Progress,
) -> anyhow::Result<SideReport> {
    let load = Arc::new(load.clone());
    let mut side = SideReport {
        label: target.label.clone(),
        transport: target.transport.as_str().to_string(),
        target: match target.transport {
            Transport::Inprocess => target.model_dir.display().to_string(),
            _ => target.url.clone(),
        },
        spawned: target.spawned.clone(),
        ..SideReport::default()
    };
    let exec = match target.transport {
        Transport::Inprocess => {
            anyhow::ensure!(
                !matches!(load.mode, Mode::Poisson { .. }),
                "the poisson mode needs a server (open-loop arrivals are scheduled by it); \
                 use streams, predict or ramp in-process"
            );
            anyhow::ensure!(
                !matches!(load.mode, Mode::Soak(_)),
                "the soak checks a server's streams: it needs --transport grpc or http"
            );
            let dir = target.model_dir.clone();
            let (s, o) = (target.max_batch_scenes, target.max_batch_objects);
            let ip = tokio::task::spawn_blocking(move || InProcess::load(&dir, s, o))
                .await
                .context("loading the model")??;
            side.model = ip.name().to_string();
            Exec::InProcess(Arc::new(ip))
        }
        _ => {
            let remote = connect(target, &load).await?;
            side.model = remote.model.clone();
            Exec::Remote(Arc::new(remote))
        }
    };
    let level_list: Vec<(usize, Option<Duration>)> = match &load.mode {
        Mode::Streams { levels, duration } => levels.iter().map(|&l| (l, *duration)).collect(),
        Mode::Predict { concurrency, .. } => vec![(*concurrency, None)],
        Mode::Poisson { rate, .. } => vec![(rate.round().max(1.0) as usize, None)],
        Mode::Soak(p) => vec![(p.streams, None)],
        Mode::Ramp {
            start,
            factor,
            max,
            level_duration,
            ..
        } => {
            let mut v = Vec::new();
            let mut c = (*start).max(1);
            while c <= *max {
                v.push((c, Some(*level_duration)));
                c = c.saturating_mul((*factor).max(2));
            }
            if v.last().is_some_and(|l| l.0 < *max) {
                v.push((*max, Some(*level_duration)));
            }
            v
        }
    };
    for (concurrency, duration) in level_list {
        if stop.is_set() {
            break;
        }
        let before = match &target.metrics_url {
            Some(u) if !matches!(exec, Exec::InProcess(_)) => Some(http_get(u).await),
            _ => None,
        };
        let rss = match (target.pid, &target.metrics_url) {
            (Some(pid), _) => Some(RssSource::Proc(pid)),
            (None, Some(url)) => Some(RssSource::Metrics(url.clone())),
            (None, None) => None,
        };
        let mut report = run_level(&load, &exec, concurrency, duration, rss, stop, progress).await;
        match before {
            Some(Ok(b)) => {
                let url = target.metrics_url.as_deref().unwrap_or_default();
                // Let the server record the last batches before the second scrape.
                tokio::time::sleep(Duration::from_millis(50)).await;
                match http_get(url).await {
                    Ok(a) => match ServerStats::from_scrapes(&b, &a) {
                        Ok(s) => report.server = Some(s),
                        Err(e) => report.server_metrics_error = Some(e),
                    },
                    Err(e) => report.server_metrics_error = Some(e),
                }
            }
            Some(Err(e)) => report.server_metrics_error = Some(e),
            None => {}
        }
        if !progress.quiet {
            eprintln!(
                "[{} {} {concurrency}] {:.1} scene-steps/s, step p50 {:.2} ms p99 {:.2} ms, {} ok, {} failed",
                side.label,
                load.mode.name(),
                report.throughput.scene_steps_per_s,
                report.step_latency_ms.p50,
                report.step_latency_ms.p99,
                report.requests.ok,
                report.requests.failed
            );
        }
        let p99 = report.step_latency_ms.p99;
        let interrupted = report.interrupted;
        side.levels.push(report);
        if interrupted {
            side.notes
                .push("interrupted by Ctrl-C: partial report".into());
            break;
        }
        if let Mode::Ramp { p99_bound_ms, .. } = load.mode
            && p99 > p99_bound_ms
        {
            side.notes.push(format!(
                "ramp stopped at {concurrency} streams: p99 step latency {p99:.2} ms > bound {p99_bound_ms} ms"
            ));
            break;
        }
    }
    if let Mode::Ramp { max, .. } = load.mode
        && side.notes.is_empty()
    {
        side.notes.push(format!(
            "ramp reached the maximum of {max} streams without crossing the p99 bound"
        ));
    }
    Ok(side)
}

enum Exec {
    Remote(Arc<Remote>),
    InProcess(Arc<InProcess>),
}

async fn run_level(
    load: &Arc<Load>,
    exec: &Exec,
    concurrency: usize,
    duration: Option<Duration>,
    rss: Option<RssSource>,
    stop: &Stop,
    progress: Progress,
) -> Report {
    let start = Instant::now();
    let measure_from = start + load.warmup;
    let rec = Arc::new(Mutex::new(Recorder::new(measure_from)));
    let what = format!("{} {concurrency}", load.mode.name());
    let bar = progress_task(rec.clone(), what, progress);
    let deadline = duration.map(|d| measure_from + d);
    let (mut expected, mut offered, mut soaked) = (None, None, None);
    match (exec, &load.mode) {
        (Exec::InProcess(ip), mode) => {
            let flag = Arc::new(AtomicBool::new(false));
            let watcher = {
                let (flag, stop) = (flag.clone(), stop.clone());
                tokio::spawn(async move {
                    stop.wait().await;
                    flag.store(true, Ordering::SeqCst);
                })
            };
            let (ip, rec2, load2, flag2) = (ip.clone(), rec.clone(), load.clone(), flag.clone());
            let mode = mode.clone();
            if duration.is_none()
                && let Mode::Streams { .. } = mode
            {
                expected = Some(concurrency as u64 * u64::from(load.steps));
            }
            let r = tokio::task::spawn_blocking(move || match mode {
                Mode::Predict {
                    variants,
                    calls,
                    every,
                    ..
                } => {
                    let v: Vec<json::Scene> =
                        (0..variants).map(|k| load2.scenes.scene(k)).collect();
                    ip.run_predict(&v, load2.steps, load2.dt_steps, every, calls, &flag2, &rec2)
                }
                _ => {
                    let s: Vec<json::Scene> =
                        (0..concurrency).map(|k| load2.scenes.scene(k)).collect();
                    ip.run_streams(&s, load2.steps, load2.dt_steps, deadline, &flag2, &rec2)
                }
            })
            .await;
            watcher.abort();
            if let Err(e) = r {
                lock(&rec).failed(&CallError::new("inprocess panic", e.to_string()));
            }
        }
        (
            Exec::Remote(remote),
            Mode::Predict {
                variants,
                calls,
                every,
                ..
            },
        ) => {
            let req = Arc::new(json::PredictRequest {
                model: load.model.clone(),
                variants: (0..*variants).map(|k| load.scenes.scene(k)).collect(),
                steps: load.steps,
                dt_steps: load.dt_steps,
                every: *every,
                timeout_ms: load.timeout_ms,
            });
            let remaining = Arc::new(AtomicUsize::new(*calls));
            let mut tasks = tokio::task::JoinSet::new();
            for i in 0..concurrency.max(1) {
                let (conn, req, rec, remaining, stop) = (
                    remote.conn(i),
                    req.clone(),
                    rec.clone(),
                    remaining.clone(),
                    stop.clone(),
                );
                tasks.spawn(predict_worker(conn, req, rec, remaining, stop));
            }
            while tasks.join_next().await.is_some() {}
        }
        (
            Exec::Remote(remote),
            Mode::Poisson {
                rate,
                duration,
                seed,
                max_in_flight,
            },
        ) => {
            offered = Some(*rate);
            let arrivals_end = start + *duration;
            poisson(
                load,
                remote,
                *rate,
                arrivals_end,
                *seed,
                *max_in_flight,
                &rec,
                stop,
            )
            .await;
        }
        (Exec::Remote(remote), Mode::Soak(plan)) => {
            soaked = Some(soak::run_soak(load, remote, plan, rss, &rec, stop).await);
        }
        (Exec::Remote(remote), _) => {
            if duration.is_none() {
                expected = Some(concurrency as u64 * u64::from(load.steps));
            }
            let mut tasks = tokio::task::JoinSet::new();
            for i in 0..concurrency {
                let req = load.rollout(load.scenes.scene(i));
                let (conn, rec, stop) = (remote.conn(i), rec.clone(), stop.clone());
                tasks.spawn(stream_worker(conn, req, rec, deadline, stop));
            }
            while tasks.join_next().await.is_some() {}
        }
    }
    end_progress(bar);
    let interrupted = stop.is_set();
    let r = lock(&rec);
    let end = match deadline {
        Some(d) if !interrupted => d.min(Instant::now()),
        _ => r.last_event().unwrap_or_else(Instant::now),
    };
    let mut report = r.report(concurrency, end.max(measure_from), interrupted);
    report.expected_frames = expected;
    report.offered_rate = offered;
    report.soak = soaked;
    report
}
