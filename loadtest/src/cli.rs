//! Command line of `dynaserve-loadtest`.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use clap::{Args, Parser, Subcommand};

use crate::report::{RunReport, to_html};
use crate::run::{Load, Mode, Progress, SoakPlan, Stop, Target, Transport, run_target};
use crate::scenes::SceneSource;
use crate::spawn::SpawnedServer;

/// Load generator for Dynaserve: streamed rollouts, planner Predict calls, Poisson arrivals
/// and concurrency ramps against the real gRPC or HTTP API (or the model in-process), with
/// throughput, latency, error and server batching reports.
#[derive(Parser, Debug)]
#[command(name = "dynaserve-loadtest", version, about)]
pub struct Cli {
    /// The load shape.
    #[command(subcommand)]
    pub mode: ModeCmd,
}

/// Load shapes.
#[derive(Subcommand, Debug)]
pub enum ModeCmd {
    /// N concurrent streamed rollouts of S steps (a list of N runs one level each).
    Streams(StreamsArgs),
    /// Planner Predict calls of K variants x S steps, R calls, C at a time.
    Predict(PredictArgs),
    /// Open loop: rollouts arriving as a Poisson process of a given rate.
    Poisson(PoissonArgs),
    /// Concurrency 1, 2, 4, ... until the p99 step latency crosses a bound.
    Ramp(RampArgs),
    /// Many streams for a long time, clients dropping and reconnecting at random; every frame
    /// is checked for its stream and order, the server's memory sampled. Exit code 1 when a
    /// frame was lost, misrouted or out of order, or a kept rollout failed.
    Soak(SoakArgs),
    /// Closed-loop Generate calls (PhysiFormer) at each concurrency level: samples and
    /// denoising steps per second, gain over the first level, latency.
    Generate(crate::generate::GenerateArgs),
}

/// Flags of `soak`.
#[derive(Args, Debug)]
pub struct SoakArgs {
    /// Concurrent streams, each on its own connection.
    #[arg(long, default_value_t = 64)]
    pub streams: usize,
    /// How long new rollouts are started: seconds, or with a unit (`90s`, `10m`, `1h`).
    /// Streams then finish the rollout they are in.
    #[arg(long, default_value = "10m")]
    pub duration: String,
    /// Chance that a client drops a rollout at a random frame and reconnects on a new
    /// connection.
    #[arg(long, default_value_t = 0.3)]
    pub drop_probability: f64,
    /// Process id of the server, to read its resident memory from /proc (a spawned server's
    /// is known; otherwise the server's /metrics is tried).
    #[arg(long)]
    pub pid: Option<u32>,
    /// Seconds between two readings of the server's resident memory.
    #[arg(long, default_value_t = 10.0)]
    pub rss_interval_s: f64,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub common: Common,
}

/// Parses a duration: a number of seconds, or a number followed by `ms`, `s`, `m` or `h`.
pub fn parse_duration(text: &str) -> anyhow::Result<Duration> {
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let value: f64 = number
        .parse()
        .map_err(|_| anyhow::anyhow!("{text:?} is not a duration (e.g. 600, 90s, 10m, 1h)"))?;
    let scale = match unit.trim() {
        "" | "s" => 1.0,
        "ms" => 1e-3,
        "m" | "min" => 60.0,
        "h" => 3600.0,
        u => anyhow::bail!("{text:?}: unknown unit {u:?} (use ms, s, m or h)"),
    };
    seconds("--duration", value * scale)
}

/// Flags of `streams`.
#[derive(Args, Debug)]
pub struct StreamsArgs {
    /// Concurrent streams; a comma-separated list runs one level per value (a sweep).
    #[arg(long, value_delimiter = ',', default_value = "8")]
    pub streams: Vec<usize>,
    /// Keep every stream busy for this long (new rollouts as old ones end; rollouts running at
    /// the end are cut). Without it each stream runs exactly one rollout.
    #[arg(long)]
    pub duration_s: Option<f64>,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub common: Common,
}

/// Flags of `predict`.
#[derive(Args, Debug)]
pub struct PredictArgs {
    /// Scene variants per call.
    #[arg(long, default_value_t = 64)]
    pub variants: usize,
    /// Calls in all.
    #[arg(long, default_value_t = 5)]
    pub calls: usize,
    /// Calls in flight at once.
    #[arg(long, default_value_t = 1)]
    pub concurrency: usize,
    /// Return every k-th frame (0: final poses only).
    #[arg(long, default_value_t = 0)]
    pub every: u32,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub common: Common,
}

/// Flags of `poisson`.
#[derive(Args, Debug)]
pub struct PoissonArgs {
    /// Mean arrivals per second.
    #[arg(long)]
    pub rate: f64,
    /// Arrival window, seconds (the run then waits for the rollouts still running).
    #[arg(long, default_value_t = 30.0)]
    pub duration_s: f64,
    /// Arrivals while this many rollouts are running are skipped and counted.
    #[arg(long, default_value_t = 1024)]
    pub max_in_flight: usize,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub common: Common,
}

/// Flags of `ramp`.
#[derive(Args, Debug)]
pub struct RampArgs {
    /// First concurrency.
    #[arg(long, default_value_t = 1)]
    pub start: usize,
    /// Growth factor between levels.
    #[arg(long, default_value_t = 2)]
    pub factor: usize,
    /// Largest concurrency.
    #[arg(long, default_value_t = 256)]
    pub max_concurrency: usize,
    /// Stop after the first level whose p99 step latency exceeds this, ms.
    #[arg(long, default_value_t = 100.0)]
    pub p99_bound_ms: f64,
    /// Seconds per level.
    #[arg(long, default_value_t = 10.0)]
    pub level_duration_s: f64,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub common: Common,
}

/// Flags shared by every mode. Flags marked "per side" may be given twice with `--compare`
/// (first for side A, second for B); given once they apply to both.
#[derive(Args, Debug, Clone)]
pub struct Common {
    /// Protocol, per side: grpc, http, or inprocess (no server; the model runs in this process
    /// with the server's batching rule).
    #[arg(long, value_enum)]
    pub transport: Vec<Transport>,
    /// Server URL, per side: the gRPC URL (default http://127.0.0.1:50051) or, with
    /// `--transport http`, the HTTP base URL (default http://127.0.0.1:8080).
    #[arg(long)]
    pub target: Vec<String>,
    /// Prometheus endpoint, per side (default: the HTTP port's /metrics; for gRPC targets the
    /// same host on port 8080).
    #[arg(long)]
    pub metrics_url: Vec<String>,
    /// Do not scrape /metrics.
    #[arg(long)]
    pub no_metrics: bool,
    /// Launch the server for the run, per side: a shell command such as
    /// "target/release/dynaserve serve --model models/rigidformer-small". Free loopback ports
    /// are appended unless the command sets --grpc-addr/--http-addr; the server is stopped
    /// after its side has run.
    #[arg(long)]
    pub spawn: Vec<String>,
    /// Seconds to wait for a spawned server to become ready.
    #[arg(long, default_value_t = 300.0)]
    pub spawn_timeout_s: f64,
    /// Side names, per side (default A, B).
    #[arg(long)]
    pub label: Vec<String>,
    /// Run the load against two sides (A, then B) and report B/A ratios.
    #[arg(long)]
    pub compare: bool,
    /// Model name on the server (default: its only model).
    #[arg(long, default_value = "")]
    pub model: String,
    /// Checkpoint directory for `--transport inprocess`.
    #[arg(long, default_value = "models/rigidformer-small")]
    pub model_dir: PathBuf,
    /// Scene cap per forward pass for `--transport inprocess` (the server's --max-batch-scenes).
    #[arg(long, default_value_t = 64)]
    pub max_batch_scenes: usize,
    /// Object budget per forward pass for `--transport inprocess` (the server's
    /// --max-batch-objects).
    #[arg(long, default_value_t = 2048)]
    pub max_batch_objects: usize,
    /// Scene file(s) (JSON, the body of POST /v1/rollout, e.g. examples/scenes/*.json), used
    /// in turn. Without it scenes are generated.
    #[arg(long)]
    pub scene: Vec<PathBuf>,
    /// Objects per generated scene.
    #[arg(long, default_value_t = 10)]
    pub objects: usize,
    /// Surface points per generated object.
    #[arg(long, default_value_t = 512)]
    pub points: usize,
    /// Seed of generated scenes and Poisson arrivals.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Steps per rollout or call (default: the scene file's `steps`, else 50).
    #[arg(long)]
    pub steps: Option<u32>,
    /// Frames per step (default: the scene file's `dt_steps`, else 1).
    #[arg(long)]
    pub dt_steps: Option<u32>,
    /// gRPC connections shared by the callers (HTTP uses one connection per caller).
    #[arg(long, default_value_t = 4)]
    pub connections: usize,
    /// Deadline sent with every request, ms (0: none).
    #[arg(long, default_value_t = 0)]
    pub timeout_ms: u32,
    /// Seconds at the start of every level whose samples are discarded.
    #[arg(long, default_value_t = 0.0)]
    pub warmup_s: f64,
    /// Write the report as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write a self-contained HTML page with throughput and p99 charts to this file.
    #[arg(long)]
    pub html: Option<PathBuf>,
    /// No progress lines on stderr.
    #[arg(long)]
    pub quiet: bool,
}

fn seconds(name: &str, s: f64) -> anyhow::Result<Duration> {
    anyhow::ensure!(
        s.is_finite() && s >= 0.0,
        "{name} must be a number of seconds >= 0"
    );
    Ok(Duration::from_secs_f64(s))
}

fn pick<T: Clone>(list: &[T], i: usize) -> Option<T> {
    list.get(i).or(list.first()).cloned()
}

/// A side before its server is (optionally) launched.
#[derive(Clone, Debug)]
pub struct SidePlan {
    /// Target template (URL filled in from the spawned server when `spawn` is set).
    pub target: Target,
    /// Command to launch, for remote sides.
    pub spawn: Option<String>,
}

/// Default metrics URL of a target: HTTP targets' own `/metrics`, gRPC targets' host on 8080.
pub fn default_metrics_url(transport: Transport, url: &str) -> Option<String> {
    match transport {
        Transport::Http => Some(format!("{}/metrics", url.trim_end_matches('/'))),
        Transport::Grpc => {
            let base = dynaserve_client::http::HttpBase::parse(url).ok()?;
            let host = dynaserve_client::http::HttpBase {
                host: base.host,
                port: 8080,
            };
            Some(format!("http://{}/metrics", host.authority()))
        }
        Transport::Inprocess => None,
    }
}

/// Splits the per-side flags into one or two side plans.
pub fn plan_sides(c: &Common) -> anyhow::Result<Vec<SidePlan>> {
    let most = [
        c.transport.len(),
        c.target.len(),
        c.metrics_url.len(),
        c.spawn.len(),
        c.label.len(),
    ]
    .into_iter()
    .max()
    .unwrap_or(0);
    anyhow::ensure!(
        most <= 2,
        "per-side flags (--transport, --target, --metrics-url, --spawn, --label) may be given at most twice"
    );
    let n = if c.compare { 2 } else { 1 };
    anyhow::ensure!(
        c.compare || most <= 1,
        "a per-side flag was given twice: add --compare to run two sides"
    );
    anyhow::ensure!(
        !c.compare || most == 2 || c.transport.len() == 1 || !c.spawn.is_empty(),
        "--compare needs two sides: give --target, --transport or --spawn twice"
    );
    anyhow::ensure!(c.connections >= 1, "--connections must be at least 1");
    let mut out = Vec::new();
    for i in 0..n {
        let transport = pick(&c.transport, i).unwrap_or(Transport::Grpc);
        let spawn = match transport {
            Transport::Inprocess => None,
            _ => pick(&c.spawn, i),
        };
        let url = pick(&c.target, i).unwrap_or_else(|| match transport {
            Transport::Http => "http://127.0.0.1:8080".into(),
            _ => "http://127.0.0.1:50051".into(),
        });
        let metrics_url = if c.no_metrics {
            None
        } else {
            pick(&c.metrics_url, i).or_else(|| default_metrics_url(transport, &url))
        };
        out.push(SidePlan {
            target: Target {
                label: c
                    .label
                    .get(i)
                    .cloned()
                    .unwrap_or_else(|| ["A", "B"][i].to_string()),
                transport,
                url,
                metrics_url,
                connections: c.connections,
                model_dir: c.model_dir.clone(),
                max_batch_scenes: c.max_batch_scenes,
                max_batch_objects: c.max_batch_objects,
                spawned: None,
                pid: None,
            },
            spawn,
        });
    }
    if n == 2 {
        let (a, b) = (&out[0], &out[1]);
        anyhow::ensure!(
            a.target.transport != b.target.transport
                || a.target.url != b.target.url
                || a.spawn != b.spawn
                || a.spawn.is_some(),
            "--compare: both sides are the same; give two targets, transports or spawn commands"
        );
    }
    Ok(out)
}

/// Builds the load description from the parsed command line.
pub fn build_load(cli: &Cli) -> anyhow::Result<(Load, Common)> {
    let (mode, common) = match &cli.mode {
        ModeCmd::Generate(_) => anyhow::bail!("generate runs on its own (generate::run)"),
        ModeCmd::Streams(a) => {
            anyhow::ensure!(
                !a.streams.is_empty() && a.streams.iter().all(|&s| s >= 1),
                "--streams must list counts >= 1"
            );
            (
                Mode::Streams {
                    levels: a.streams.clone(),
                    duration: a
                        .duration_s
                        .map(|d| seconds("--duration-s", d))
                        .transpose()?,
                },
                a.common.clone(),
            )
        }
        ModeCmd::Predict(a) => {
            anyhow::ensure!(
                a.variants >= 1 && a.calls >= 1 && a.concurrency >= 1,
                "--variants, --calls and --concurrency must be at least 1"
            );
            (
                Mode::Predict {
                    variants: a.variants,
                    calls: a.calls,
                    concurrency: a.concurrency,
                    every: a.every,
                },
                a.common.clone(),
            )
        }
        ModeCmd::Poisson(a) => {
            anyhow::ensure!(
                a.rate.is_finite() && a.rate > 0.0,
                "--rate must be a positive number of arrivals per second"
            );
            (
                Mode::Poisson {
                    rate: a.rate,
                    duration: seconds("--duration-s", a.duration_s)?,
                    seed: a.common.seed,
                    max_in_flight: a.max_in_flight.max(1),
                },
                a.common.clone(),
            )
        }
        ModeCmd::Ramp(a) => {
            anyhow::ensure!(
                a.start >= 1 && a.max_concurrency >= a.start && a.factor >= 2,
                "ramp needs 1 <= --start <= --max-concurrency and --factor >= 2"
            );
            (
                Mode::Ramp {
                    start: a.start,
                    factor: a.factor,
                    max: a.max_concurrency,
                    p99_bound_ms: a.p99_bound_ms,
                    level_duration: seconds("--level-duration-s", a.level_duration_s)?,
                },
                a.common.clone(),
            )
        }
        ModeCmd::Soak(a) => {
            anyhow::ensure!(a.streams >= 1, "--streams must be at least 1");
            anyhow::ensure!(
                (0.0..=1.0).contains(&a.drop_probability),
                "--drop-probability must be in [0, 1]"
            );
            let rss_interval = seconds("--rss-interval-s", a.rss_interval_s)?;
            anyhow::ensure!(
                rss_interval >= Duration::from_millis(100),
                "--rss-interval-s must be at least 0.1"
            );
            (
                Mode::Soak(SoakPlan {
                    streams: a.streams,
                    duration: parse_duration(&a.duration)?,
                    drop_probability: a.drop_probability,
                    rss_interval,
                    seed: a.common.seed,
                }),
                a.common.clone(),
            )
        }
    };
    if let Mode::Soak(_) = mode {
        anyhow::ensure!(
            !common.compare,
            "soak runs against one server: --compare does not apply"
        );
        anyhow::ensure!(
            !common.transport.contains(&Transport::Inprocess),
            "the soak checks a server's streams: use --transport grpc or http"
        );
    }
    let scenes = if common.scene.is_empty() {
        anyhow::ensure!(
            common.objects >= 1 && common.points >= 1,
            "--objects and --points must be at least 1"
        );
        SceneSource::Generated {
            objects: common.objects,
            points: common.points,
            seed: common.seed,
        }
    } else {
        SceneSource::from_files(&common.scene)?
    };
    let file = scenes.file_steps();
    let steps = common.steps.or(file.map(|f| f.0)).unwrap_or(50);
    let dt_steps = common.dt_steps.or(file.map(|f| f.1)).unwrap_or(1);
    anyhow::ensure!(steps >= 1, "--steps must be at least 1");
    Ok((
        Load {
            mode,
            scenes,
            steps,
            dt_steps: dt_steps.max(1),
            model: common.model.clone(),
            timeout_ms: common.timeout_ms,
            warmup: seconds("--warmup-s", common.warmup_s)?,
        },
        common,
    ))
}

/// Runs the load tester; returns the process exit code (0, or 130 after Ctrl-C).
pub fn main() -> anyhow::Result<i32> {
    let cli = Cli::parse();
    if let ModeCmd::Generate(a) = &cli.mode {
        return crate::generate::run(a);
    }
    let (load, common) = build_load(&cli)?;
    let mut sides = plan_sides(&common)?;
    if let ModeCmd::Soak(a) = &cli.mode {
        for side in &mut sides {
            side.target.pid = a.pid;
        }
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async move {
        let (stop_tx, stop) = Stop::new();
        tokio::spawn(async move {
            if tokio::signal::ctrl_c().await.is_ok() {
                eprintln!("\nCtrl-C: stopping, partial report follows (Ctrl-C again to quit now)");
                stop_tx.send_replace(true);
                if tokio::signal::ctrl_c().await.is_ok() {
                    std::process::exit(130);
                }
            }
        });
        let progress = Progress {
            quiet: common.quiet,
        };
        let mut run = RunReport {
            version: env!("CARGO_PKG_VERSION").to_string(),
            mode: load.mode.name().to_string(),
            load: load.describe(),
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            ..RunReport::default()
        };
        let spawn_timeout = seconds("--spawn-timeout-s", common.spawn_timeout_s)?;
        for plan in sides {
            if stop.is_set() {
                break;
            }
            let mut target = plan.target.clone();
            let server = match &plan.spawn {
                Some(cmd) => {
                    if !common.quiet {
                        eprintln!("[{}] starting `{cmd}`", target.label);
                    }
                    let s = tokio::select! {
                        s = SpawnedServer::start(cmd, spawn_timeout) => s?,
                        _ = stop.wait() => break,
                    };
                    target.url = match target.transport {
                        Transport::Http => s.http_url.clone(),
                        _ => s.grpc_url.clone(),
                    };
                    if !common.no_metrics && common.metrics_url.is_empty() {
                        target.metrics_url = Some(format!("{}/metrics", s.http_url));
                    }
                    target.spawned = Some(s.command.clone());
                    target.pid = s.pid();
                    Some(s)
                }
                None => None,
            };
            let result = run_target(&load, &target, &stop, progress).await;
            if let Some(s) = server {
                s.stop().await;
            }
            run.sides
                .push(result.with_context(|| format!("side {}", target.label))?);
        }
        run.compute_ratios();
        print!("{}", run.to_text());
        if let Some(path) = &common.json {
            let text = serde_json::to_string_pretty(&run)?;
            std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
            eprintln!("JSON report: {}", path.display());
        }
        if let Some(path) = &common.html {
            std::fs::write(path, to_html(&run))
                .with_context(|| format!("writing {}", path.display()))?;
            eprintln!("HTML chart: {}", path.display());
        }
        let soak_failed = run
            .sides
            .iter()
            .flat_map(|s| &s.levels)
            .filter_map(|l| l.soak.as_ref())
            .any(|s| !s.passed());
        Ok(if stop.is_set() {
            130
        } else if soak_failed {
            1
        } else {
            0
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(args: &[&str]) -> anyhow::Result<(Load, Vec<SidePlan>)> {
        let mut v = vec!["dynaserve-loadtest"];
        v.extend_from_slice(args);
        let cli = Cli::try_parse_from(v)?;
        let (load, common) = build_load(&cli)?;
        Ok((load, plan_sides(&common)?))
    }

    #[test]
    fn defaults_and_sides() {
        let (load, sides) = parse(&["streams", "--streams", "1,8", "--steps", "5"]).unwrap();
        assert_eq!(
            load.mode,
            Mode::Streams {
                levels: vec![1, 8],
                duration: None
            }
        );
        assert_eq!(load.steps, 5);
        assert_eq!(sides.len(), 1);
        assert_eq!(sides[0].target.url, "http://127.0.0.1:50051");
        assert_eq!(
            sides[0].target.metrics_url.as_deref(),
            Some("http://127.0.0.1:8080/metrics")
        );
        let (_, sides) = parse(&[
            "predict",
            "--compare",
            "--transport",
            "inprocess",
            "--transport",
            "grpc",
            "--spawn",
            "dynaserve serve",
        ])
        .unwrap();
        assert_eq!(sides[0].target.transport, Transport::Inprocess);
        assert!(sides[0].spawn.is_none());
        assert_eq!(sides[1].spawn.as_deref(), Some("dynaserve serve"));
        assert_eq!(sides[1].target.label, "B");
        let (_, sides) = parse(&["ramp", "--transport", "http", "--target", "http://h:9"]).unwrap();
        assert_eq!(
            sides[0].target.metrics_url.as_deref(),
            Some("http://h:9/metrics")
        );
    }

    #[test]
    fn soak_flags_and_durations() {
        let (load, sides) = parse(&["soak", "--duration", "90s", "--steps", "120"]).unwrap();
        let Mode::Soak(p) = &load.mode else {
            panic!("{:?}", load.mode)
        };
        assert_eq!(p.streams, 64);
        assert_eq!(p.duration, Duration::from_secs(90));
        assert_eq!(p.drop_probability, 0.3);
        assert_eq!(load.steps, 120);
        assert_eq!(sides.len(), 1);
        assert_eq!(parse_duration("10m").unwrap(), Duration::from_secs(600));
        assert_eq!(parse_duration("600").unwrap(), Duration::from_secs(600));
        assert_eq!(parse_duration("1.5h").unwrap(), Duration::from_secs(5400));
        assert_eq!(parse_duration("250ms").unwrap(), Duration::from_millis(250));
        assert!(parse_duration("m").is_err());
        assert!(parse_duration("-5s").is_err());
    }

    #[test]
    fn bad_flag_combinations_are_errors() {
        assert!(
            parse(&[
                "streams",
                "--target",
                "http://a:1",
                "--target",
                "http://b:1"
            ])
            .is_err()
        );
        assert!(parse(&["streams", "--compare"]).is_err());
        assert!(parse(&["streams", "--streams", "0"]).is_err());
        assert!(parse(&["poisson", "--rate", "-1"]).is_err());
        assert!(parse(&["ramp", "--start", "8", "--max-concurrency", "4"]).is_err());
        assert!(parse(&["streams", "--scene", "does-not-exist.json"]).is_err());
        assert!(parse(&["streams", "--warmup-s", "-2"]).is_err());
        assert!(parse(&["soak", "--drop-probability", "1.5"]).is_err());
        assert!(parse(&["soak", "--duration", "10 parsecs"]).is_err());
        assert!(parse(&["soak", "--transport", "inprocess"]).is_err());
        assert!(
            parse(&[
                "soak",
                "--compare",
                "--target",
                "http://a:1",
                "--target",
                "http://b:1"
            ])
            .is_err()
        );
    }
}
