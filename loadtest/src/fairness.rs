//! `fairness` mode: how much bulk work slows interactive streams. Over gRPC it measures the
//! step latency (time between consecutive frames of one stream) of `--streams` streamed
//! rollouts twice: alone, then while `--bulk-predicts` Predict calls and `--generates`
//! Generate calls at the server's limits run beside them (each restarted when it ends, all
//! cancelled after the window). It prints the p50 and p99 step latency of both windows and
//! their ratios, and how much bulk work the server did during the second window (from
//! `/metrics`: scene-steps of the rigid model beyond the streams' own, and network evaluations
//! of the PhysiFormer model), so a server that simply starved the bulk work would show it.
//!
//! The bulk calls are sized from `ListModels`: a Predict of the model's `max_variants` scenes
//! of `--objects` objects with as many steps as `max_request_cost` allows (at most
//! `max_steps`), and a Generate of the scene file with `max_samples` samples and as many
//! denoising steps as the cost cap allows (at most `max_denoise_steps`).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use dynaserve_api::json;
use dynaserve_api::v1;
use dynaserve_client::Client;
use dynaserve_client::random_scene::generate;
use futures::StreamExt;

use crate::spawn::SpawnedServer;
use crate::stats::percentile_sorted;
use crate::transport::http_get;

/// Flags of `fairness`.
#[derive(Args, Debug)]
pub struct FairnessArgs {
    /// gRPC URL of the server (ignored with --spawn).
    #[arg(long, default_value = "http://127.0.0.1:50051")]
    pub target: String,
    /// Prometheus endpoint (default: port 8080 of the target's host, or the spawned server's).
    #[arg(long)]
    pub metrics_url: Option<String>,
    /// Launch the server for the run (a shell command, as for the other modes).
    #[arg(long)]
    pub spawn: Option<String>,
    /// Interactive streams.
    #[arg(long, default_value_t = 8)]
    pub streams: usize,
    /// Objects per scene (streams and Predict variants).
    #[arg(long, default_value_t = 10)]
    pub objects: usize,
    /// Surface points per object of the streams' scenes.
    #[arg(long, default_value_t = 512)]
    pub points: usize,
    /// Surface points per object of the Predict variants (the largest Predict must fit the
    /// server's request size limit).
    #[arg(long, default_value_t = 128)]
    pub bulk_points: usize,
    /// Steps per rollout (a stream starts a new rollout when one ends).
    #[arg(long, default_value_t = 200)]
    pub steps: u32,
    /// Concurrent Predict calls at the limits.
    #[arg(long, default_value_t = 2)]
    pub bulk_predicts: usize,
    /// Concurrent Generate calls at the limits (needs a PhysiFormer model).
    #[arg(long, default_value_t = 2)]
    pub generates: usize,
    /// The Generate body (JSON) whose scene the Generate calls sample.
    #[arg(long, default_value = "examples/scenes/generate/elastic_drop.json")]
    pub generate_scene: PathBuf,
    /// Seconds measured in each window.
    #[arg(long, default_value_t = 10.0)]
    pub duration_s: f64,
    /// Seconds at the start of each window that are not measured (streams starting; the bulk
    /// calls being admitted and prepared).
    #[arg(long, default_value_t = 3.0)]
    pub warmup_s: f64,
    /// Seconds to wait for a spawned server to become ready.
    #[arg(long, default_value_t = 300.0)]
    pub spawn_timeout_s: f64,
}

/// Step latencies of one window.
struct Window {
    /// Sorted step latencies, seconds.
    steps: Vec<f64>,
    /// Frames the streams received in the measured part.
    frames: u64,
    /// Length of the measured part.
    seconds: f64,
    /// Failed rollouts.
    errors: u64,
}

impl Window {
    fn p(&self, q: f64) -> f64 {
        1e3 * percentile_sorted(&self.steps, q)
    }
}

/// Runs `n` streams until `until`, recording the step latencies of frames after `from`.
async fn streams(client: &Client, a: &FairnessArgs, from: Instant, until: Instant) -> Window {
    let tasks: Vec<_> = (0..a.streams)
        .map(|i| {
            let mut c = client.clone();
            let req = json::RolloutRequest {
                model: String::new(),
                scene: generate(i as u64, a.objects, a.points),
                steps: a.steps,
                dt_steps: 1,
                timeout_ms: 0,
                stream: false,
            };
            tokio::spawn(async move {
                let (mut steps, mut frames, mut errors) = (Vec::new(), 0u64, 0u64);
                'outer: while Instant::now() < until {
                    let mut r = match c.rollout(&req).await {
                        Ok(r) => r,
                        Err(e) => {
                            if errors == 0 {
                                eprintln!("rollout failed: {e}");
                            }
                            errors += 1;
                            tokio::time::sleep(Duration::from_millis(100)).await;
                            continue;
                        }
                    };
                    let mut last: Option<Instant> = None;
                    while let Some(f) = r.frames.next().await {
                        let now = Instant::now();
                        if now >= until {
                            break 'outer;
                        }
                        if f.is_err() {
                            errors += 1;
                            continue 'outer;
                        }
                        if now >= from {
                            frames += 1;
                            if let Some(prev) = last.filter(|p| *p >= from) {
                                steps.push((now - prev).as_secs_f64());
                            }
                        }
                        last = Some(now);
                    }
                }
                (steps, frames, errors)
            })
        })
        .collect();
    let mut w = Window {
        steps: Vec::new(),
        frames: 0,
        seconds: until.saturating_duration_since(from).as_secs_f64(),
        errors: 0,
    };
    for t in tasks {
        if let Ok((s, f, e)) = t.await {
            w.steps.extend(s);
            w.frames += f;
            w.errors += e;
        }
    }
    w.steps.sort_by(f64::total_cmp);
    w
}

/// The rigid and the PhysiFormer model of the server (the first of each).
fn pick_models(models: &[v1::ModelInfo]) -> (Option<&v1::ModelInfo>, Option<&v1::ModelInfo>) {
    let physi = |m: &&v1::ModelInfo| m.max_samples > 0;
    (
        models.iter().find(|m| !physi(m) && m.max_variants > 0),
        models.iter().find(physi),
    )
}

/// A Predict at `m`'s limits: `max_variants` scenes, as many steps as the cost cap allows.
fn bulk_predict(m: &v1::ModelInfo, a: &FairnessArgs, seed: u64) -> json::PredictRequest {
    let variants = (m.max_variants as usize).max(1);
    let per_step = (variants * a.objects.max(1)) as u64;
    let steps = (m.max_request_cost / per_step).clamp(1, u64::from(m.max_steps.max(1))) as u32;
    json::PredictRequest {
        model: m.name.clone(),
        variants: (0..variants)
            .map(|i| generate(seed + i as u64, a.objects, a.bulk_points))
            .collect(),
        steps,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    }
}

/// A Generate of `body`'s scene at `m`'s limits: `max_samples` samples and as many denoising
/// steps as the cost cap allows.
fn bulk_generate(m: &v1::ModelInfo, mut body: json::GenerateRequest) -> json::GenerateRequest {
    let vertices: u64 = body
        .scene
        .objects
        .iter()
        .map(|o| o.vertices.len() as u64)
        .sum();
    let frames = if body.frames == 0 {
        m.max_frames
    } else {
        body.frames
    };
    let samples = m.max_samples.max(1);
    let evaluations = |s: u32| match body.sampler {
        json::Sampler::Heun => (2 * u64::from(s)).saturating_sub(1),
        json::Sampler::Euler => u64::from(s),
    };
    let mut steps = m.max_denoise_steps.max(1);
    while steps > 1
        && vertices * u64::from(frames) * evaluations(steps) * u64::from(samples)
            > m.max_request_cost
    {
        steps -= 1;
    }
    body.model = m.name.clone();
    body.frames = frames;
    body.samples = samples;
    body.denoise_steps = steps;
    body.noise = None;
    body
}

/// Progress of the bulk calls, counted by their tasks.
#[derive(Default)]
struct BulkTally {
    predicts_done: AtomicU64,
    denoise_steps: AtomicU64,
    errors: AtomicU64,
}

/// Starts the bulk calls, each restarted when it ends; abort the returned tasks to cancel.
fn start_bulk(
    client: &Client,
    predict: Option<json::PredictRequest>,
    gen_req: Option<v1::GenerateRequest>,
    a: &FairnessArgs,
    tally: &Arc<BulkTally>,
) -> Vec<tokio::task::JoinHandle<()>> {
    let mut tasks = Vec::new();
    if let Some(p) = predict {
        for _ in 0..a.bulk_predicts {
            let (mut c, p, t) = (client.clone(), p.clone(), tally.clone());
            tasks.push(tokio::spawn(async move {
                loop {
                    match c.predict(&p).await {
                        Ok(_) => t.predicts_done.fetch_add(1, Ordering::Relaxed),
                        Err(e) => {
                            if t.errors.fetch_add(1, Ordering::Relaxed) == 0 {
                                eprintln!("bulk Predict failed: {e}");
                            }
                            tokio::time::sleep(Duration::from_millis(500)).await;
                            0
                        }
                    };
                }
            }));
        }
    }
    if let Some(g) = gen_req {
        for _ in 0..a.generates {
            let (mut c, g, t) = (client.clone(), g.clone(), tally.clone());
            tasks.push(tokio::spawn(async move {
                loop {
                    let r = async {
                        let mut generation = c.generate(g.clone()).await?;
                        while let Some(ev) = generation.events.next().await {
                            if let Some(v1::generate_event::Event::Progress(_)) = ev?.event {
                                t.denoise_steps.fetch_add(1, Ordering::Relaxed);
                            }
                        }
                        Ok::<(), dynaserve_client::ClientError>(())
                    }
                    .await;
                    if let Err(e) = r {
                        if t.errors.fetch_add(1, Ordering::Relaxed) == 0 {
                            eprintln!("bulk Generate failed: {e}");
                        }
                        tokio::time::sleep(Duration::from_millis(500)).await;
                    }
                }
            }));
        }
    }
    tasks
}

/// The rigid model's scene-steps so far, from `/metrics`.
async fn scene_steps(metrics_url: &str, model: &str) -> Option<f64> {
    let text = http_get(metrics_url).await.ok()?;
    dynaserve_client::prom::value(
        &text,
        &format!("dynaserve_scene_steps_total{{model=\"{model}\"}}"),
    )
}

fn seconds(name: &str, v: f64) -> anyhow::Result<Duration> {
    anyhow::ensure!(v.is_finite() && v >= 0.0, "{name} must be a number >= 0");
    Ok(Duration::from_secs_f64(v))
}

/// Runs both windows and prints the figures; returns the exit code (1 if a stream failed).
pub fn run(a: &FairnessArgs) -> anyhow::Result<i32> {
    let duration = seconds("--duration-s", a.duration_s)?;
    seconds("--warmup-s", a.warmup_s)?;
    anyhow::ensure!(duration > Duration::ZERO, "--duration-s must be positive");
    anyhow::ensure!(a.streams > 0, "--streams must be at least 1");
    let text = std::fs::read_to_string(&a.generate_scene)
        .with_context(|| format!("reading {}", a.generate_scene.display()))?;
    let gen_body: json::GenerateRequest = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a Generate body", a.generate_scene.display()))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async move {
        let server = match &a.spawn {
            Some(cmd) => {
                eprintln!("starting `{cmd}`");
                Some(
                    SpawnedServer::start(cmd, seconds("--spawn-timeout-s", a.spawn_timeout_s)?)
                        .await?,
                )
            }
            None => None,
        };
        let target = server
            .as_ref()
            .map_or(a.target.clone(), |s| s.grpc_url.clone());
        let metrics_url = a.metrics_url.clone().or_else(|| {
            server
                .as_ref()
                .map(|s| format!("{}/metrics", s.http_url))
                .or_else(|| {
                    let u: hyper::Uri = target.parse().ok()?;
                    Some(format!("http://{}:8080/metrics", u.host()?))
                })
        });
        let code = measure(a, &target, metrics_url.as_deref(), gen_body).await;
        if let Some(s) = server {
            s.stop().await;
        }
        code
    })
}

async fn measure(
    a: &FairnessArgs,
    target: &str,
    metrics_url: Option<&str>,
    gen_body: json::GenerateRequest,
) -> anyhow::Result<i32> {
    let client = Client::connect(target)
        .await
        .with_context(|| format!("cannot reach the gRPC server at {target}"))?;
    let models = client.clone().list_models().await?;
    let (rigid, physi) = pick_models(&models);
    let rigid = rigid.context("the server has no RigidFormer model")?;
    let predict = (a.bulk_predicts > 0).then(|| bulk_predict(rigid, a, 1000));
    let gen_req = match physi {
        Some(m) if a.generates > 0 => Some(bulk_generate(m, gen_body)),
        None if a.generates > 0 => {
            eprintln!("the server has no PhysiFormer model: no Generate calls");
            None
        }
        _ => None,
    };
    let duration = Duration::from_secs_f64(a.duration_s);
    let warmup = Duration::from_secs_f64(a.warmup_s);
    println!(
        "fairness: {} streams of {} objects x {} points, {} s measured per window after {} s",
        a.streams, a.objects, a.points, a.duration_s, a.warmup_s
    );
    if let Some(p) = &predict {
        println!(
            "  bulk: {} Predict calls of {} variants x {} objects x {} steps ({} object-steps each)",
            a.bulk_predicts,
            p.variants.len(),
            a.objects,
            p.steps,
            p.variants.len() as u64 * a.objects as u64 * u64::from(p.steps)
        );
    }
    if let Some(g) = &gen_req {
        println!(
            "  bulk: {} Generate calls of {} ({} samples x {} denoising steps, {} frames)",
            a.generates,
            a.generate_scene.display(),
            g.samples,
            g.denoise_steps,
            g.frames
        );
    }
    // Window 1: the streams alone.
    let start = Instant::now();
    let alone = streams(&client, a, start + warmup, start + warmup + duration).await;
    // Window 2: the same streams beside the bulk calls, which start first.
    let tally = Arc::new(BulkTally::default());
    let bulk = start_bulk(
        &client,
        predict,
        gen_req.as_ref().map(json::GenerateRequest::to_proto),
        a,
        &tally,
    );
    tokio::time::sleep(warmup).await;
    let start = Instant::now();
    let from = start + warmup;
    let physi_name = physi.map(|m| m.name.clone()).unwrap_or_default();
    let steps_task = {
        let url = metrics_url.map(str::to_string);
        let models = [rigid.name.clone(), physi_name.clone()];
        tokio::spawn(async move {
            tokio::time::sleep_until((start + warmup).into()).await;
            let u = url?;
            let r = scene_steps(&u, &models[0]).await?;
            let p = scene_steps(&u, &models[1]).await.unwrap_or(0.0);
            Some((u, r, p))
        })
    };
    let beside = streams(&client, a, from, from + duration).await;
    let bulk_done = match steps_task.await.ok().flatten() {
        Some((url, r0, p0)) => {
            let r = scene_steps(&url, &rigid.name).await;
            let p = scene_steps(&url, &physi_name).await.unwrap_or(0.0);
            r.map(|r| ((r - r0 - beside.frames as f64).max(0.0), p - p0))
        }
        None => None,
    };
    for t in &bulk {
        t.abort();
    }
    println!(
        "{:<22} {:>10} {:>10} {:>10} {:>8}",
        "", "step p50", "step p99", "step max", "frames"
    );
    for (name, w) in [("alone (ms)", &alone), ("beside bulk (ms)", &beside)] {
        println!(
            "{:<22} {:>10.2} {:>10.2} {:>10.2} {:>8}",
            name,
            w.p(50.0),
            w.p(99.0),
            w.p(100.0),
            w.frames
        );
    }
    println!(
        "{:<22} {:>9.2}x {:>9.2}x",
        "beside / alone",
        beside.p(50.0) / alone.p(50.0),
        beside.p(99.0) / alone.p(99.0)
    );
    let secs = beside.seconds.max(1e-9);
    let done = tally.predicts_done.load(Ordering::Relaxed);
    let errors = tally.errors.load(Ordering::Relaxed);
    let progress = tally.denoise_steps.load(Ordering::Relaxed);
    match bulk_done {
        Some((r, p)) => println!(
            "  bulk during the second window: {:.1} Predict scene-steps/s, {:.1} Generate network evaluations/s ({done} Predict calls and {progress} Generate denoising steps completed, {errors} bulk errors)",
            r / secs,
            p / secs,
        ),
        None => println!(
            "  bulk: no /metrics, so no bulk rates ({done} Predict calls and {progress} Generate denoising steps completed, {errors} bulk errors)"
        ),
    }
    let errors = alone.errors + beside.errors;
    if errors > 0 {
        eprintln!("{errors} rollouts failed");
    }
    Ok(i32::from(errors > 0))
}
