//! Server configuration: command-line flags, each with an environment variable.
//!
//! With no flags the server loads every model directory under `models/` and listens for gRPC
//! on `127.0.0.1:50051` and HTTP on `127.0.0.1:8080`, without authentication. Binding another
//! address needs bearer tokens (`--auth-token-file` or `DYNASERVE_AUTH_TOKENS`) or an explicit
//! `--allow-unauthenticated`.
//!
//! The flag groups that [`ServeConfig`] gathers live beside it: [`ConnectionConfig`] (the
//! listeners' limits and timeouts) and [`SessionConfig`] (the session store's caps); the
//! authentication and TLS flags are `security::SecurityConfig`.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use dynaserve_api::limits::{Caps, GenerateCaps};

mod connections;
mod scheduling;
mod seconds;
pub mod security;
mod sessions;

pub use connections::ConnectionConfig;
pub use scheduling::SchedulingConfig;
pub(crate) use seconds::secs;
pub use sessions::SessionConfig;

/// Default gRPC listen address.
pub const DEFAULT_GRPC_ADDR: &str = "127.0.0.1:50051";
/// Default HTTP listen address.
pub const DEFAULT_HTTP_ADDR: &str = "127.0.0.1:8080";

/// Log output format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    /// Human-readable lines.
    Plain,
    /// One JSON object per line.
    Json,
}

/// Flags of `dynaserve serve`.
#[derive(Clone, Debug, clap::Args)]
pub struct ServeConfig {
    /// Model checkpoint directories to serve (each with config.json and model.safetensors),
    /// a RigidFormer, a PhysiFormer or the rapier simulator (`models/simulators/rapier`): the
    /// family is read from config.json's `architecture`.
    /// Repeatable. When none is given, every such directory under --models-dir is served.
    #[arg(long = "model", env = "DYNASERVE_MODELS", value_delimiter = ',')]
    pub models: Vec<PathBuf>,
    /// Directory scanned for model directories when no --model is given.
    #[arg(long, env = "DYNASERVE_MODELS_DIR", default_value = "models")]
    pub models_dir: PathBuf,
    /// gRPC listen address (port 0 picks a free port; the bound address is printed).
    #[arg(long, env = "DYNASERVE_GRPC_ADDR", default_value = DEFAULT_GRPC_ADDR)]
    pub grpc_addr: SocketAddr,
    /// HTTP listen address (port 0 picks a free port; the bound address is printed).
    #[arg(long, env = "DYNASERVE_HTTP_ADDR", default_value = DEFAULT_HTTP_ADDR)]
    pub http_addr: SocketAddr,

    /// Most scenes in one batched forward pass (1 disables batching).
    #[arg(long, env = "DYNASERVE_MAX_BATCH_SCENES", default_value_t = 64)]
    pub max_batch_scenes: usize,
    /// Most objects in one batched pass (a larger single scene still runs alone); a model that
    /// computes a pass in forwards of a fixed size gets whole forwards (RigidFormer: multiples
    /// of 160 objects, 1920 by default).
    #[arg(long, env = "DYNASERVE_MAX_BATCH_OBJECTS", default_value_t = 2048)]
    pub max_batch_objects: usize,
    /// Longest time, in milliseconds, a queued step waits for batch-mates that are expected
    /// back (streams whose previous step just finished) before its batch starts anyway.
    #[arg(long, env = "DYNASERVE_MAX_QUEUE_DELAY_MS", default_value_t = 2.0)]
    pub max_queue_delay_ms: f64,

    /// Most concurrently active rollouts (streams) over all models; more get
    /// RESOURCE_EXHAUSTED / HTTP 429.
    #[arg(long, env = "DYNASERVE_MAX_ACTIVE_ROLLOUTS", default_value_t = 256)]
    pub max_active_rollouts: usize,
    /// Most scene variants of Predict calls in flight over all models (a Gradient call's
    /// candidates count too); a call that would go past it gets RESOURCE_EXHAUSTED / HTTP 429.
    #[arg(long, env = "DYNASERVE_MAX_PREDICT_VARIANTS", default_value_t = 1024)]
    pub max_predict_variants: usize,
    /// Most Generate samples in flight over all PhysiFormer models (a call counts one per
    /// sample); a call that would go past it gets RESOURCE_EXHAUSTED / HTTP 429.
    #[arg(long, env = "DYNASERVE_MAX_GENERATE_SAMPLES", default_value_t = 64)]
    pub max_generate_samples: usize,
    /// Most denoising steps per Generate call (also capped at 1000).
    #[arg(long, env = "DYNASERVE_MAX_DENOISE_STEPS", default_value_t = GenerateCaps::DEFAULT.max_denoise_steps)]
    pub max_denoise_steps: u32,
    /// Most samples per Generate call.
    #[arg(long, env = "DYNASERVE_MAX_SAMPLES", default_value_t = GenerateCaps::DEFAULT.max_samples)]
    pub max_samples: u32,
    /// Largest cost of one Generate call in vertex-frame evaluations: vertices x frames x
    /// network evaluations (2 x denoise steps - 1 with Heun, denoise steps with Euler) x
    /// samples. A call above it is refused with INVALID_ARGUMENT / 422 naming `denoise_steps`.
    /// The default is about 4.4 minutes of the bundled small model on a 2-core machine.
    #[arg(long, env = "DYNASERVE_MAX_GENERATE_COST", default_value_t = GenerateCaps::DEFAULT.max_cost)]
    pub max_generate_cost: u64,
    /// Retry hint sent with RESOURCE_EXHAUSTED / 429, milliseconds.
    #[arg(long, env = "DYNASERVE_RETRY_AFTER_MS", default_value_t = 1000)]
    pub retry_after_ms: u64,
    /// Frames buffered per stream before a slow reader pauses its own rollout.
    #[arg(long, env = "DYNASERVE_STREAM_BUFFER", default_value_t = 8)]
    pub stream_buffer: usize,

    /// Most objects per scene (also capped by the model's own limit).
    #[arg(long, env = "DYNASERVE_MAX_OBJECTS", default_value_t = Caps::DEFAULT.max_objects)]
    pub max_objects: usize,
    /// Most reference points (or mesh samples) per object (also capped by the model's limit).
    #[arg(long, env = "DYNASERVE_MAX_POINTS_PER_OBJECT", default_value_t = Caps::DEFAULT.max_points_per_object)]
    pub max_points_per_object: usize,
    /// Most points per scene, summed over its objects.
    #[arg(long, env = "DYNASERVE_MAX_SCENE_POINTS", default_value_t = Caps::DEFAULT.max_scene_points)]
    pub max_scene_points: usize,
    /// Most steps per request.
    #[arg(long, env = "DYNASERVE_MAX_STEPS", default_value_t = Caps::DEFAULT.max_steps)]
    pub max_steps: u32,
    /// Largest step size in frames.
    #[arg(long, env = "DYNASERVE_MAX_DT_STEPS", default_value_t = Caps::DEFAULT.max_dt_steps)]
    pub max_dt_steps: u32,
    /// Most scene variants per Predict call.
    #[arg(long, env = "DYNASERVE_MAX_VARIANTS", default_value_t = Caps::DEFAULT.max_variants)]
    pub max_variants: usize,
    /// Largest cost of one RigidFormer request (Rollout, Predict, a session's Step or Predict)
    /// in object-steps: objects x steps, summed over a Predict's variants. A request above it
    /// is refused with INVALID_ARGUMENT / 422 naming `steps`. The default is about 4 minutes
    /// of a 2-core machine on 256-object scenes.
    #[arg(long, env = "DYNASERVE_MAX_REQUEST_COST", default_value_t = Caps::DEFAULT.max_request_cost)]
    pub max_request_cost: u64,
    /// Most work of one Gradient call (a session's Gradient) in scene-steps: candidates x
    /// steps. Also the most work of one gradient pass, which serves concurrent calls together
    /// (a larger call runs alone). The backward pass keeps every step's activations of every
    /// candidate, so its memory grows in proportion to this (and to the scene's objects and
    /// points: about 2 GiB for 480 scene-steps of a box and a pusher), and other models'
    /// steps wait for a pass to end. A call above it is refused with INVALID_ARGUMENT / 422
    /// naming `candidates`.
    #[arg(long, env = "DYNASERVE_MAX_GRADIENT_WORK", default_value_t = Caps::DEFAULT.max_gradient_work)]
    pub max_gradient_work: u64,
    /// Largest request payload in bytes (gRPC message or HTTP body); larger ones are rejected
    /// with INVALID_ARGUMENT / 422 naming `request`.
    #[arg(long, env = "DYNASERVE_MAX_REQUEST_BYTES", default_value_t = 16 << 20)]
    pub max_request_bytes: usize,

    /// A stream whose client has read nothing for this long, seconds, is ended and its rollout
    /// slot freed (`dynaserve_stalled_streams_total`); 0 disables.
    #[arg(long, env = "DYNASERVE_STREAM_STALL_TIMEOUT_S", default_value_t = 30.0)]
    pub stream_stall_timeout_s: f64,

    /// Deadline of a Rollout, Predict, session Step or Predict, or Generate that names none
    /// (no `grpc-timeout`, `timeout_ms` 0), seconds after arrival; 0 disables.
    #[arg(long, env = "DYNASERVE_DEFAULT_TIMEOUT_S", default_value_t = 900.0)]
    pub default_timeout_s: f64,

    /// Connection limits and timeouts of both listeners.
    #[command(flatten)]
    pub connections: ConnectionConfig,
    /// Authentication, TLS and the browser (CORS) policy.
    #[command(flatten)]
    pub security: security::SecurityConfig,

    /// Sessions: how many, how much memory, how long they live idle.
    #[command(flatten)]
    pub sessions: SessionConfig,
    /// Scheduling classes: which requests are bulk work and its share of the passes.
    #[command(flatten)]
    pub scheduling: SchedulingConfig,

    /// On SIGTERM or Ctrl-C: how long running rollouts may continue, seconds, before they are
    /// closed with UNAVAILABLE.
    #[arg(long, env = "DYNASERVE_DRAIN_TIMEOUT_S", default_value_t = 30.0)]
    pub drain_timeout_s: f64,
    /// Skip the warm-up step at start-up (readiness is then reported right after loading).
    #[arg(long, env = "DYNASERVE_NO_WARMUP")]
    pub no_warmup: bool,
    /// Device the models run on: `cpu`, `cuda` or `cuda:N` (CUDA needs a build with
    /// `--features cuda`).
    #[arg(long, env = "DYNASERVE_DEVICE", default_value = "cpu")]
    pub device: String,

    /// Log format.
    #[arg(long, env = "DYNASERVE_LOG_FORMAT", value_enum, default_value_t = LogFormat::Plain)]
    pub log_format: LogFormat,
    /// Log filter (tracing `EnvFilter` syntax, e.g. `info,dynaserve_server=debug`).
    #[arg(long, env = "DYNASERVE_LOG", default_value = "info")]
    pub log: String,
    /// Print the exported metric names, types, labels and help texts, then exit.
    #[arg(long)]
    pub print_metrics: bool,
}

impl Default for ServeConfig {
    fn default() -> Self {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Wrapper {
            #[command(flatten)]
            config: ServeConfig,
        }
        // Parsing an empty command line yields the documented defaults.
        Wrapper::parse_from(["serve"]).config
    }
}

impl ServeConfig {
    /// A configuration for tests and embedding: both listeners on 127.0.0.1 with free ports,
    /// the given model directories, other settings at their defaults.
    pub fn local(models: Vec<PathBuf>) -> ServeConfig {
        ServeConfig {
            models,
            grpc_addr: ([127, 0, 0, 1], 0).into(),
            http_addr: ([127, 0, 0, 1], 0).into(),
            ..ServeConfig::default()
        }
    }

    /// The request caps set by the flags (each model caps them again with its own limits).
    pub fn caps(&self) -> Caps {
        Caps {
            max_objects: self.max_objects,
            max_points_per_object: self.max_points_per_object,
            max_scene_points: self.max_scene_points,
            max_steps: self.max_steps,
            max_dt_steps: self.max_dt_steps,
            // A Predict call above the in-flight cap could never be admitted, so the cap on one
            // call (reported by ListModels) is the smaller of the two.
            max_variants: self.max_variants.min(self.max_predict_variants),
            max_request_cost: self.max_request_cost,
            max_gradient_work: self.max_gradient_work,
        }
    }

    /// The Generate caps set by the flags (each PhysiFormer model caps them again). A call
    /// with more samples than the in-flight cap could never be admitted, so the per-call cap
    /// is the smaller of the two.
    pub fn generate_caps(&self) -> GenerateCaps {
        GenerateCaps {
            max_denoise_steps: self.max_denoise_steps,
            max_samples: self
                .max_samples
                .min(u32::try_from(self.max_generate_samples).unwrap_or(u32::MAX)),
            max_cost: self.max_generate_cost,
        }
    }

    /// `default_timeout_s` as a duration; `None` when 0 (disabled).
    pub fn default_timeout(&self) -> Option<Duration> {
        secs(self.default_timeout_s)
    }

    /// `stream_stall_timeout_s` as a duration; `None` when 0 (disabled).
    pub fn stream_stall_timeout(&self) -> Option<Duration> {
        secs(self.stream_stall_timeout_s)
    }

    /// `max_queue_delay_ms` as a duration (negative or non-finite values mean zero).
    pub fn max_queue_delay(&self) -> Duration {
        let ms = if self.max_queue_delay_ms.is_finite() {
            self.max_queue_delay_ms.clamp(0.0, 60_000.0)
        } else {
            0.0
        };
        Duration::from_secs_f64(ms / 1000.0)
    }

    /// `drain_timeout_s` as a duration.
    pub fn drain_timeout(&self) -> Duration {
        let s = if self.drain_timeout_s.is_finite() {
            self.drain_timeout_s.clamp(0.0, 86_400.0)
        } else {
            0.0
        };
        Duration::from_secs_f64(s)
    }

    /// Checks the flags for values that cannot work.
    pub fn validate(&self) -> Result<(), String> {
        let positive = [
            ("--max-batch-scenes", self.max_batch_scenes),
            ("--max-batch-objects", self.max_batch_objects),
            ("--max-active-rollouts", self.max_active_rollouts),
            ("--max-predict-variants", self.max_predict_variants),
            ("--max-generate-samples", self.max_generate_samples),
            ("--max-denoise-steps", self.max_denoise_steps as usize),
            ("--max-samples", self.max_samples as usize),
            ("--stream-buffer", self.stream_buffer),
            ("--max-objects", self.max_objects),
            ("--max-points-per-object", self.max_points_per_object),
            ("--max-scene-points", self.max_scene_points),
            ("--max-variants", self.max_variants),
            ("--max-request-bytes", self.max_request_bytes),
        ];
        for (name, v) in positive {
            if v == 0 {
                return Err(format!("{name} must be at least 1"));
            }
        }
        if self.max_request_cost == 0 {
            return Err("--max-request-cost must be at least 1".into());
        }
        if self.max_gradient_work == 0 {
            return Err("--max-gradient-work must be at least 1".into());
        }
        if self.max_generate_cost == 0 {
            return Err("--max-generate-cost must be at least 1".into());
        }
        if self.max_steps == 0 || self.max_dt_steps == 0 {
            return Err("--max-steps and --max-dt-steps must be at least 1".into());
        }
        if !self.max_queue_delay_ms.is_finite() || self.max_queue_delay_ms < 0.0 {
            return Err("--max-queue-delay-ms must be a finite number >= 0".into());
        }
        if !self.drain_timeout_s.is_finite() || self.drain_timeout_s < 0.0 {
            return Err("--drain-timeout-s must be a finite number >= 0".into());
        }
        if !self.stream_stall_timeout_s.is_finite() || self.stream_stall_timeout_s < 0.0 {
            return Err("--stream-stall-timeout-s must be a finite number >= 0".into());
        }
        if !self.default_timeout_s.is_finite() || self.default_timeout_s < 0.0 {
            return Err("--default-timeout-s must be a finite number >= 0".into());
        }
        dynaserve_model::check_device_name(&self.device).map_err(|e| format!("--device: {e}"))?;
        self.connections.validate()?;
        self.sessions.validate()?;
        self.scheduling.validate()?;
        self.security.validate(&[self.grpc_addr, self.http_addr])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_documented_ports_and_valid() {
        let c = ServeConfig::default();
        assert_eq!(c.grpc_addr.port(), 50051);
        assert!(c.grpc_addr.ip().is_loopback() && c.http_addr.ip().is_loopback());
        assert_eq!(c.http_addr.port(), 8080);
        assert_eq!(c.models_dir, PathBuf::from("models"));
        assert!(c.validate().is_ok());
        assert_eq!(c.caps(), Caps::DEFAULT);
        assert_eq!(c.generate_caps(), GenerateCaps::DEFAULT);
        let mut bad = c.clone();
        bad.max_batch_scenes = 0;
        assert!(bad.validate().unwrap_err().contains("--max-batch-scenes"));
        let mut bad = c.clone();
        bad.max_request_cost = 0;
        assert!(bad.validate().unwrap_err().contains("--max-request-cost"));
        let mut bad = c.clone();
        bad.max_generate_cost = 0;
        assert!(bad.validate().unwrap_err().contains("--max-generate-cost"));
    }

    #[test]
    fn the_device_must_be_known_and_built_in() {
        let mut c = ServeConfig::default();
        assert_eq!(c.device, "cpu");
        c.device = "tpu".into();
        assert!(c.validate().unwrap_err().contains("--device"));
        if !dynaserve_model::cuda_compiled() {
            c.device = "cuda".into();
            assert!(c.validate().unwrap_err().contains("--features cuda"));
        }
    }

    #[test]
    fn predict_cap_never_exceeds_the_in_flight_cap() {
        let c = ServeConfig {
            max_predict_variants: 10,
            ..ServeConfig::default()
        };
        assert_eq!(c.caps().max_variants, 10);
    }

    #[test]
    fn a_public_bind_needs_tokens_or_an_explicit_opt_out() {
        let mut c = ServeConfig {
            http_addr: "0.0.0.0:8080".parse().unwrap(),
            ..ServeConfig::default()
        };
        let e = c.validate().unwrap_err();
        assert!(e.contains("--allow-unauthenticated"), "{e}");
        c.security.auth_tokens = vec!["secret-token-0123".into()];
        assert!(c.validate().is_ok());
        c.security.auth_tokens.clear();
        c.security.allow_unauthenticated = true;
        assert!(c.validate().is_ok());
    }
}
