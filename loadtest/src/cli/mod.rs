//! Command line of `dynaserve-loadtest`: the flags (`args`), their checks and the run they
//! describe (`plan`), and [`main`], which runs the sides in turn and writes the reports.

mod args;
mod plan;

pub use args::{Cli, Common, ModeCmd, PoissonArgs, PredictArgs, RampArgs, SoakArgs, StreamsArgs};
pub use plan::{SidePlan, build_load, default_metrics_url, parse_duration, plan_sides};

use anyhow::Context;
use clap::Parser;

use crate::report::{RunReport, to_html};
use crate::run::{Progress, Stop, Transport, run_target};
use crate::spawn::SpawnedServer;
use plan::seconds;

/// Runs the load tester; returns the process exit code (0, or 130 after Ctrl-C).
pub fn main() -> anyhow::Result<i32> {
    let cli = Cli::parse();
    if let ModeCmd::Generate(a) = &cli.mode {
        return crate::generate_mode::run(a);
    }
    if let ModeCmd::Fairness(a) = &cli.mode {
        return crate::fairness::run(a);
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
