//! The command line as `clap` parses it: one subcommand per load shape, each with its own flags
//! and the flags every shape shares ([`Common`]).

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

use crate::run::Transport;

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
    Generate(crate::generate_mode::GenerateArgs),
    /// Step latency of interactive streams alone and beside bulk Predict and Generate calls
    /// at the server's limits, with the ratio (how well the scheduler isolates them).
    Fairness(crate::fairness::FairnessArgs),
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
