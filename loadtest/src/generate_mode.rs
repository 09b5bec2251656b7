//! `generate` mode: closed-loop Generate calls (PhysiFormer) over gRPC at each concurrency
//! level, each worker sending the next call when its last one has finished, for a fixed time
//! per level. Prints per level the calls, samples per second, denoising steps per second, the
//! gain over the first level (what batching denoising steps of concurrent calls buys), the
//! call latency quantiles and the mean of the widest pass each denoising step ran in.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use dynaserve_api::json;
use dynaserve_api::v1;
use dynaserve_client::{Client, ClientError};
use futures::StreamExt;

/// Flags of `generate`.
#[derive(Args, Debug)]
pub struct GenerateArgs {
    /// gRPC URL of the server.
    #[arg(long, default_value = "http://127.0.0.1:50051")]
    pub target: String,
    /// A `POST /v1/generate` body (JSON) sent by every call.
    #[arg(long, default_value = "examples/scenes/generate/elastic_drop.json")]
    pub scene: PathBuf,
    /// Concurrency levels, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,8")]
    pub concurrency: Vec<usize>,
    /// Seconds per level during which new calls start (calls then finish).
    #[arg(long, default_value_t = 10.0)]
    pub duration_s: f64,
    /// Frames per call, replacing the file's.
    #[arg(long)]
    pub frames: Option<u32>,
    /// Denoising steps per call, replacing the file's.
    #[arg(long)]
    pub denoise_steps: Option<u32>,
    /// Samples per call, replacing the file's.
    #[arg(long)]
    pub samples: Option<u32>,
}

/// What one worker measured.
#[derive(Default)]
struct Tally {
    calls: u64,
    samples: u64,
    steps: u64,
    widest_sum: f64,
    latencies: Vec<f64>,
    errors: u64,
}

async fn one_call(
    client: &mut Client,
    req: &v1::GenerateRequest,
    t: &mut Tally,
) -> Result<(), ClientError> {
    let start = Instant::now();
    let mut generation = client.generate(req.clone()).await?;
    let (mut samples, mut steps, mut widest) = (0u64, 0u64, 0f64);
    while let Some(ev) = generation.events.next().await {
        match ev?.event {
            Some(v1::generate_event::Event::Progress(p)) => {
                steps += 1;
                widest += f64::from(p.timing.map_or(0, |t| t.batch_scenes));
            }
            Some(v1::generate_event::Event::Sample(_)) => samples += 1,
            None => {}
        }
    }
    t.calls += 1;
    t.samples += samples;
    t.steps += steps * samples;
    t.widest_sum += widest;
    t.latencies.push(start.elapsed().as_secs_f64());
    Ok(())
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Runs the levels and prints the table; returns the exit code (1 if any call failed).
pub fn run(a: &GenerateArgs) -> anyhow::Result<i32> {
    let text = std::fs::read_to_string(&a.scene)
        .with_context(|| format!("reading {}", a.scene.display()))?;
    let mut body: json::GenerateRequest = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a Generate body", a.scene.display()))?;
    body.frames = a.frames.unwrap_or(body.frames);
    body.denoise_steps = a.denoise_steps.unwrap_or(body.denoise_steps);
    body.samples = a.samples.unwrap_or(body.samples);
    anyhow::ensure!(
        a.duration_s.is_finite() && a.duration_s > 0.0,
        "--duration-s must be positive"
    );
    anyhow::ensure!(
        !a.concurrency.is_empty() && a.concurrency.iter().all(|&c| c > 0),
        "--concurrency needs levels of at least 1"
    );
    let req = body.to_proto();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async move {
        let client = Client::connect(&a.target)
            .await
            .with_context(|| format!("cannot reach the gRPC server at {}", a.target))?;
        println!(
            "generate: {} ({} frames, {} denoising steps, {} samples per call), {} s per level",
            a.scene.display(),
            body.frames,
            body.denoise_steps,
            body.samples.max(1),
            a.duration_s
        );
        println!(
            "{:>11} {:>6} {:>10} {:>13} {:>9} {:>9} {:>9} {:>12}",
            "concurrency",
            "calls",
            "samples/s",
            "den.steps/s",
            "gain",
            "p50 ms",
            "p99 ms",
            "mean widest"
        );
        let mut base: Option<f64> = None;
        let mut failed = false;
        for &c in &a.concurrency {
            let until = Instant::now() + Duration::from_secs_f64(a.duration_s);
            let start = Instant::now();
            let workers: Vec<_> = (0..c)
                .map(|_| {
                    let mut client = client.clone();
                    let req = req.clone();
                    tokio::spawn(async move {
                        let mut t = Tally::default();
                        while Instant::now() < until {
                            if let Err(e) = one_call(&mut client, &req, &mut t).await {
                                if t.errors == 0 {
                                    eprintln!("call failed: {e}");
                                }
                                t.errors += 1;
                            }
                        }
                        t
                    })
                })
                .collect();
            let mut all = Tally::default();
            for w in workers {
                let t = w.await.context("worker panicked")?;
                all.calls += t.calls;
                all.samples += t.samples;
                all.steps += t.steps;
                all.widest_sum += t.widest_sum;
                all.errors += t.errors;
                all.latencies.extend(t.latencies);
            }
            let wall = start.elapsed().as_secs_f64();
            all.latencies.sort_by(f64::total_cmp);
            let rate = all.samples as f64 / wall;
            let gain = rate / *base.get_or_insert(rate);
            let progress_events = all.steps as f64 / f64::from(body.samples.max(1));
            println!(
                "{:>11} {:>6} {:>10.2} {:>13.1} {:>8.2}x {:>9.0} {:>9.0} {:>12.2}",
                c,
                all.calls,
                rate,
                all.steps as f64 / wall,
                gain,
                1e3 * quantile(&all.latencies, 0.5),
                1e3 * quantile(&all.latencies, 0.99),
                all.widest_sum / progress_events.max(1.0)
            );
            if all.errors > 0 {
                eprintln!("concurrency {c}: {} calls failed", all.errors);
                failed = true;
            }
        }
        Ok(i32::from(failed))
    })
}
