//! `dynaserve rollout SCENE.json`: runs a scene file on a server and prints or saves the
//! trajectory.

use std::io::Write;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use dynaserve_api::json;
use futures::StreamExt;

use crate::client::Client;
use crate::scene_file;

/// Flags of `dynaserve rollout`.
#[derive(Clone, Debug, clap::Args)]
pub struct RolloutArgs {
    /// Scene file (JSON, the body of POST /v1/rollout; see examples/scenes/).
    pub scene: PathBuf,
    /// gRPC server URL.
    #[arg(
        long,
        env = "DYNASERVE_SERVER",
        default_value = "http://127.0.0.1:50051"
    )]
    pub server: String,
    /// Write the whole trajectory as one JSON document (`model`, `request_id`, `frames`,
    /// `timing`) to this file instead of printing one JSON frame per line.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Model name (overrides the scene file's `model`).
    #[arg(long)]
    pub model: Option<String>,
    /// Steps (overrides the scene file's `steps`).
    #[arg(long)]
    pub steps: Option<u32>,
    /// Frames per step (overrides the scene file's `dt_steps`).
    #[arg(long)]
    pub dt_steps: Option<u32>,
    /// Deadline for the whole rollout, milliseconds.
    #[arg(long)]
    pub timeout_ms: Option<u64>,
}

/// Runs the `rollout` subcommand.
pub fn run(args: RolloutArgs) -> anyhow::Result<()> {
    let mut request = scene_file::load(&args.scene)?;
    if let Some(m) = args.model {
        request.model = m;
    }
    if let Some(s) = args.steps {
        request.steps = s;
    }
    if let Some(d) = args.dt_steps {
        request.dt_steps = d;
    }
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async move {
        let start = Instant::now();
        let mut client = Client::connect(&args.server)
            .await?
            .with_timeout(args.timeout_ms.map(Duration::from_millis));
        let mut rollout = client.rollout(&request).await?;
        for w in &rollout.warnings {
            eprintln!("warning: {w}");
        }
        let mut frames = Vec::new();
        let stdout = std::io::stdout();
        while let Some(frame) = rollout.frames.next().await {
            let frame = frame?;
            if args.out.is_none() {
                let mut out = stdout.lock();
                serde_json::to_writer(&mut out, &frame)?;
                writeln!(out)?;
            } else {
                frames.push(frame);
            }
        }
        let total_ms = start.elapsed().as_secs_f64() * 1e3;
        if let Some(path) = args.out {
            let mut timing = json::RequestTiming {
                total_ms,
                ..Default::default()
            };
            for t in frames.iter().filter_map(|f| f.timing) {
                timing.queue_ms += f64::from(t.queue_ms);
                timing.forward_ms += f64::from(t.forward_ms);
            }
            let n = frames.len();
            let doc = json::RolloutResponse {
                model: rollout.model.clone(),
                request_id: rollout.request_id.clone(),
                frames,
                timing,
            };
            let text = serde_json::to_string_pretty(&doc)?;
            std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
            eprintln!(
                "{n} frames from {} (request {}) in {total_ms:.1} ms -> {}",
                rollout.model,
                rollout.request_id,
                path.display()
            );
        }
        Ok(())
    })
}
