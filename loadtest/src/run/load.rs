//! What a load is: its protocol ([`Transport`]), its shape ([`Mode`]), what it sends
//! ([`Load`]) and where it goes ([`Target`]).

use std::path::PathBuf;
use std::time::Duration;

use dynaserve_api::json;

use super::soak::SoakPlan;
use crate::scenes::SceneSource;

/// How requests reach the model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Transport {
    /// The gRPC API (dynaserve.v1.WorldModel).
    Grpc,
    /// The HTTP JSON API; rollouts as Server-Sent Events.
    Http,
    /// No server: the model loaded in this process, batched like the server.
    Inprocess,
}

impl Transport {
    /// Lower-case name.
    pub fn as_str(self) -> &'static str {
        match self {
            Transport::Grpc => "grpc",
            Transport::Http => "http",
            Transport::Inprocess => "inprocess",
        }
    }
}

/// The shape of the load.
#[derive(Clone, Debug, PartialEq)]
pub enum Mode {
    /// `n` concurrent streamed rollouts for each `n` in `levels`. Without `duration` every
    /// stream runs one rollout; with it, streams start new rollouts until it passes (rollouts
    /// running then are cut).
    Streams {
        /// Concurrency levels, run in order.
        levels: Vec<usize>,
        /// Length of each level, if timed.
        duration: Option<Duration>,
    },
    /// `calls` Predict calls of `variants` scene variants, `concurrency` at a time.
    Predict {
        /// Variants per call.
        variants: usize,
        /// Calls in all.
        calls: usize,
        /// Callers at once.
        concurrency: usize,
        /// `PredictRequest.every` (0: final poses only).
        every: u32,
    },
    /// Open loop: rollouts arrive as a Poisson process of `rate` per second for `duration`.
    Poisson {
        /// Mean arrivals per second.
        rate: f64,
        /// Arrival window.
        duration: Duration,
        /// Seed of the arrival times.
        seed: u64,
        /// Arrivals beyond this many running rollouts are skipped (and counted).
        max_in_flight: usize,
    },
    /// Closed-loop streams at `start`, `start * factor`, ... up to `max`, each level timed,
    /// until the p99 step latency exceeds `p99_bound_ms`.
    Ramp {
        /// First concurrency.
        start: usize,
        /// Growth factor between levels (at least 2).
        factor: usize,
        /// Largest concurrency.
        max: usize,
        /// Stop after the first level whose p99 step latency exceeds this, ms.
        p99_bound_ms: f64,
        /// Length of each level.
        level_duration: Duration,
    },
    /// Many streams for a long time, clients dropping rollouts at random and reconnecting,
    /// every frame checked for its stream and its order, the server's memory sampled.
    Soak(SoakPlan),
}

impl Mode {
    /// Mode name.
    pub fn name(&self) -> &'static str {
        match self {
            Mode::Streams { .. } => "streams",
            Mode::Predict { .. } => "predict",
            Mode::Poisson { .. } => "poisson",
            Mode::Ramp { .. } => "ramp",
            Mode::Soak(_) => "soak",
        }
    }
}

/// What to send.
#[derive(Clone, Debug)]
pub struct Load {
    /// Mode and its parameters.
    pub mode: Mode,
    /// Scenes.
    pub scenes: SceneSource,
    /// Steps per rollout or Predict call.
    pub steps: u32,
    /// Frames per step.
    pub dt_steps: u32,
    /// Model name (empty: the server's only model).
    pub model: String,
    /// Request deadline sent with every request, ms (0: none).
    pub timeout_ms: u32,
    /// Time at the start of every level whose samples are discarded.
    pub warmup: Duration,
}

impl Load {
    /// One-line description for reports.
    pub fn describe(&self) -> String {
        let m = match &self.mode {
            Mode::Streams { levels, duration } => format!(
                "streams {} x {} steps{}",
                levels
                    .iter()
                    .map(|l| l.to_string())
                    .collect::<Vec<_>>()
                    .join(","),
                self.steps,
                duration
                    .map(|d| format!(", repeated for {:.0} s", d.as_secs_f64()))
                    .unwrap_or_default()
            ),
            Mode::Predict {
                variants,
                calls,
                concurrency,
                every,
            } => format!(
                "predict {calls} calls x {variants} variants x {} steps, {concurrency} at a time, every {every}",
                self.steps
            ),
            Mode::Poisson { rate, duration, .. } => format!(
                "poisson {rate} rollouts/s for {:.0} s, {} steps each",
                duration.as_secs_f64(),
                self.steps
            ),
            Mode::Ramp {
                start,
                factor,
                max,
                p99_bound_ms,
                level_duration,
            } => format!(
                "ramp {start}..{max} (x{factor}) streams x {} steps, {:.0} s per level, until p99 step > {p99_bound_ms} ms",
                self.steps,
                level_duration.as_secs_f64()
            ),
            Mode::Soak(p) => format!(
                "soak {} streams x {} steps for {:.0} s, drop probability {}",
                p.streams,
                self.steps,
                p.duration.as_secs_f64(),
                p.drop_probability
            ),
        };
        format!(
            "{m}, dt_steps {}, {}{}",
            self.dt_steps,
            self.scenes.describe(),
            if self.warmup.is_zero() {
                String::new()
            } else {
                format!(", warm-up {:.1} s", self.warmup.as_secs_f64())
            }
        )
    }

    /// A streamed rollout request of `scene` with this load's steps, step size, model and
    /// deadline.
    pub(super) fn rollout(&self, scene: json::Scene) -> json::RolloutRequest {
        json::RolloutRequest {
            model: self.model.clone(),
            scene,
            steps: self.steps,
            dt_steps: self.dt_steps,
            timeout_ms: self.timeout_ms,
            stream: true,
        }
    }
}

/// Where the load goes.
#[derive(Clone, Debug)]
pub struct Target {
    /// Name in reports.
    pub label: String,
    /// Protocol.
    pub transport: Transport,
    /// gRPC URL (`http://host:50051`) or HTTP base URL (`http://host:8080`); unused in-process.
    pub url: String,
    /// Prometheus endpoint (`http://host:8080/metrics`); `None` skips the scrape.
    pub metrics_url: Option<String>,
    /// gRPC connections shared round-robin by the callers.
    pub connections: usize,
    /// Checkpoint directory for in-process runs.
    pub model_dir: PathBuf,
    /// Scene cap of in-process batches.
    pub max_batch_scenes: usize,
    /// Object budget of in-process batches.
    pub max_batch_objects: usize,
    /// The command that launched the server, if this run launched it.
    pub spawned: Option<String>,
    /// Process id of the server when it runs on this machine (spawned, or `--pid`): its
    /// resident memory is read from `/proc` during a soak.
    pub pid: Option<u32>,
}
