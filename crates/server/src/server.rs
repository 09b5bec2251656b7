//! Start-up, serving and graceful shutdown.
//!
//! Start-up: load every model, start one scheduler thread per model, bind both listeners
//! (liveness answers at once), warm each model up, then report ready (`/ready`, gRPC health).
//!
//! Shutdown (SIGTERM, Ctrl-C or [`RunningServer::shutdown`]): readiness turns off (`/ready`
//! answers 503 `draining`, gRPC health NOT_SERVING), new work gets UNAVAILABLE, while probes
//! and `/metrics` keep answering; running rollouts and Predict calls continue until they finish
//! or the drain deadline passes, then what is left is closed with UNAVAILABLE ("the drain
//! deadline passed"). Only then do the listeners stop accepting and open connections close;
//! the schedulers stop and the process exits.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio::task::JoinHandle;

use crate::config::{LogFormat, ServeConfig};
use crate::engine::{Engine, Models};
use crate::grpc;
use crate::http;
use crate::listener;
use crate::security::{Auth, Wire};
use crate::viewer::{self, Viewer};

/// Most open connections of the probe listener (`--health-addr`); half of them per peer at most.
const HEALTH_MAX_CONNECTIONS: usize = 64;

/// Extra time after the drain deadline for connections to close before serving stops anyway.
const CLOSE_GRACE: Duration = Duration::from_secs(5);

/// A server running on the current tokio runtime.
pub struct RunningServer {
    /// Bound gRPC address.
    pub grpc_addr: SocketAddr,
    /// Bound HTTP address.
    pub http_addr: SocketAddr,
    /// Bound address of the probe listener (`--health-addr`), if one was asked for.
    pub health_addr: Option<SocketAddr>,
    engine: Arc<Engine>,
    stop_tx: watch::Sender<bool>,
    ready_rx: watch::Receiver<Option<Result<(), String>>>,
    task: JoinHandle<anyhow::Result<()>>,
}

impl RunningServer {
    /// The engine (metrics, readiness).
    pub fn engine(&self) -> &Arc<Engine> {
        &self.engine
    }

    /// Begins a graceful shutdown (as SIGTERM does).
    pub fn shutdown(&self) {
        self.stop_tx.send_replace(true);
    }

    /// Waits until warm-up has finished (Ok) or failed (Err), at most `timeout`.
    pub async fn wait_ready(&self, timeout: Duration) -> anyhow::Result<()> {
        let mut rx = self.ready_rx.clone();
        let r = tokio::time::timeout(timeout, rx.wait_for(|v| v.is_some()))
            .await
            .context("timed out waiting for warm-up")?
            .context("server stopped during warm-up")?;
        match r.as_ref() {
            Some(Ok(())) => Ok(()),
            Some(Err(e)) => anyhow::bail!("warm-up failed: {e}"),
            None => anyhow::bail!("warm-up did not finish"),
        }
    }

    /// Waits until the server has stopped (after [`RunningServer::shutdown`]).
    pub async fn wait(self) -> anyhow::Result<()> {
        self.task.await.context("server task panicked")?
    }
}

/// Model directories to serve: `config.models`, or every directory under `config.models_dir`
/// that holds a `config.json`, sorted by name.
pub fn model_dirs(config: &ServeConfig) -> anyhow::Result<Vec<PathBuf>> {
    if !config.models.is_empty() {
        return Ok(config.models.clone());
    }
    let dir = &config.models_dir;
    let entries = std::fs::read_dir(dir).with_context(|| {
        format!(
            "cannot read the models directory {} (it is relative to the working directory; \
                 pass --models-dir DIR or --model DIR to name the models)",
            dir.display()
        )
    })?;
    let mut dirs: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.join(dynaserve_model::checkpoint::CONFIG_FILE).is_file())
        .collect();
    dirs.sort();
    if dirs.is_empty() {
        anyhow::bail!(
            "no model directories (with config.json) under {}; pass --model DIR",
            dir.display()
        );
    }
    Ok(dirs)
}

/// Loads every model directory on the CPU, each in the family its config.json's
/// `architecture` names ([`crate::families::registry`]).
pub fn load_all(dirs: &[PathBuf]) -> anyhow::Result<Models> {
    load_all_on(dirs, &candle_core::Device::Cpu)
}

/// [`load_all`] on `device`.
pub fn load_all_on(dirs: &[PathBuf], device: &candle_core::Device) -> anyhow::Result<Models> {
    let opts = crate::families::LoadOptions {
        device: device.clone(),
    };
    let mut models = Models::default();
    for d in dirs {
        models.push(crate::families::load_dir(d, &opts)?);
    }
    Ok(models)
}

async fn stop_signal(mut rx: watch::Receiver<bool>) {
    let _ = rx.wait_for(|s| *s).await;
}

/// Starts the server on the current tokio runtime with already loaded models and the built-in
/// viewer examples. Returns once both listeners are bound; warm-up continues in the background
/// (see [`RunningServer::wait_ready`]).
pub async fn start(
    config: ServeConfig,
    models: impl Into<Models>,
) -> anyhow::Result<RunningServer> {
    start_with_viewer(config, models, Viewer::builtin()).await
}

/// [`start`] with the scenes the browser viewer offers (`GET /v1/examples`).
pub async fn start_with_viewer(
    config: ServeConfig,
    models: impl Into<Models>,
    viewer: Viewer,
) -> anyhow::Result<RunningServer> {
    let engine = Arc::new(Engine::new(config.clone(), models)?);
    let grpc_listener = TcpListener::bind(config.grpc_addr)
        .await
        .with_context(|| format!("binding gRPC address {}", config.grpc_addr))?;
    let http_listener = TcpListener::bind(config.http_addr)
        .await
        .with_context(|| format!("binding HTTP address {}", config.http_addr))?;
    let health_listener = match config.connections.health_addr {
        Some(a) => Some(
            TcpListener::bind(a)
                .await
                .with_context(|| format!("binding the probe address {a} (--health-addr)"))?,
        ),
        None => None,
    };
    let grpc_addr = grpc_listener.local_addr()?;
    let http_addr = http_listener.local_addr()?;
    let health_addr = match &health_listener {
        Some(l) => Some(l.local_addr()?),
        None => None,
    };
    let tls = config.security.tls_acceptor()?;
    let auth = Auth::from_config(&config.security).map_err(anyhow::Error::msg)?;
    let (grpc_router, health) = grpc::router(engine.clone()).await?;
    let grpc_router = match &auth {
        Some(a) => a.protect(grpc_router, Wire::Grpc),
        None => grpc_router,
    };
    let http_router = crate::security::http_policy(
        http::router(engine.clone()).merge(viewer::router(viewer)),
        &config,
        auth.as_ref(),
    );

    let (stop_tx, stop_rx) = watch::channel(false);
    // Listeners stop accepting when `accept_rx` flips, at the end of a drain.
    let (accept_tx, accept_rx) = watch::channel(false);
    let grpc_task = tokio::spawn(listener::serve(
        "grpc",
        grpc_listener,
        grpc_router,
        tls.clone(),
        config.connections.clone(),
        engine.metrics().clone(),
        accept_rx.clone(),
    ));
    // The probe listener: the probes and `/metrics` (under the same authentication), its own
    // connection cap, so a full API listener does not lock the probes out.
    let health_task = health_listener.map(|l| {
        let router = http::probes_router(engine.clone());
        let router = match &auth {
            Some(a) => a.protect(router, Wire::Http),
            None => router,
        };
        let mut connections = config.connections.clone();
        connections.max_connections = HEALTH_MAX_CONNECTIONS;
        connections.max_connections_per_peer = connections
            .max_connections_per_peer
            .min(HEALTH_MAX_CONNECTIONS / 2);
        tokio::spawn(listener::serve(
            "health",
            l,
            router,
            tls.clone(),
            connections,
            engine.metrics().clone(),
            accept_rx.clone(),
        ))
    });
    let http_task = tokio::spawn(listener::serve(
        "http",
        http_listener,
        http_router,
        tls,
        config.connections.clone(),
        engine.metrics().clone(),
        accept_rx,
    ));

    let (ready_tx, ready_rx) = watch::channel(None);
    let warm_engine = engine.clone();
    let warm_health = health.clone();
    let no_warmup = config.no_warmup;
    let warm_task = tokio::spawn(async move {
        let r = if no_warmup {
            Ok(())
        } else {
            warm_engine.warm_up().await
        };
        match r {
            Ok(()) => {
                if !warm_engine.is_draining() {
                    warm_engine.mark_ready();
                    grpc::set_health(&warm_health, true).await;
                    tracing::info!("ready");
                }
                ready_tx.send_replace(Some(Ok(())));
            }
            Err(e) => {
                tracing::error!(error = %e.message, "warm-up failed; not ready");
                ready_tx.send_replace(Some(Err(e.message)));
            }
        }
    });

    let sup_engine = engine.clone();
    let drain = config.drain_timeout();
    let task = tokio::spawn(async move {
        stop_signal(stop_rx).await;
        let engine = sup_engine;
        let started = Instant::now();
        tracing::info!(
            running = engine.running(),
            drain_timeout_s = drain.as_secs_f64(),
            "shutting down: draining"
        );
        engine.start_drain();
        grpc::set_health(&health, false).await;
        warm_task.abort();
        // Let running work finish, up to the drain deadline.
        let deadline = started + drain;
        while engine.running() > 0 && Instant::now() < deadline {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        if engine.running() > 0 {
            tracing::warn!(
                running = engine.running(),
                "drain deadline passed; closing running work with UNAVAILABLE"
            );
            engine.close_running();
        }
        accept_tx.send_replace(true);
        let servers = async {
            let g = grpc_task.await;
            let h = http_task.await;
            if let Some(t) = health_task {
                let _ = t.await;
            }
            (g, h)
        };
        match tokio::time::timeout(CLOSE_GRACE, servers).await {
            Ok((g, h)) => {
                g.context("gRPC server task")?;
                h.context("HTTP server task")?;
            }
            Err(_) => tracing::warn!("connections still open after the grace period; stopping"),
        }
        let e2 = engine.clone();
        tokio::task::spawn_blocking(move || e2.shutdown_schedulers())
            .await
            .context("stopping schedulers")?;
        tracing::info!(ms = started.elapsed().as_secs_f64() * 1e3, "stopped");
        Ok(())
    });

    Ok(RunningServer {
        grpc_addr,
        http_addr,
        health_addr,
        engine,
        stop_tx,
        ready_rx,
        task,
    })
}

/// Installs the global tracing subscriber (plain or JSON lines on stderr).
pub fn init_logging(format: LogFormat, filter: &str) -> anyhow::Result<()> {
    let filter = tracing_subscriber::EnvFilter::try_new(filter)
        .with_context(|| format!("invalid log filter {filter:?}"))?;
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_writer(std::io::stderr);
    let r = match format {
        LogFormat::Plain => builder.try_init(),
        LogFormat::Json => builder.json().flatten_event(true).try_init(),
    };
    r.map_err(|e| anyhow::anyhow!("cannot install the logger: {e}"))
}

async fn termination() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = term.recv() => tracing::info!("SIGTERM received"),
                    _ = tokio::signal::ctrl_c() => tracing::info!("Ctrl-C received"),
                }
            }
            Err(e) => {
                tracing::warn!(error = %e, "cannot listen for SIGTERM; Ctrl-C only");
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}

/// `dynaserve serve`: loads the models, serves until SIGTERM or Ctrl-C, drains, exits.
pub fn run(config: ServeConfig) -> anyhow::Result<()> {
    run_with_viewer(config, Viewer::builtin())
}

/// [`run`] with the scenes the browser viewer offers (`dynaserve view` adds a comparison).
pub fn run_with_viewer(config: ServeConfig, viewer: Viewer) -> anyhow::Result<()> {
    if config.print_metrics {
        print!("{}", crate::metrics::metrics_table());
        return Ok(());
    }
    config.validate().map_err(anyhow::Error::msg)?;
    init_logging(config.log_format, &config.log)?;
    let dirs = model_dirs(&config)?;
    let device = dynaserve_model::device_from_name(&config.device)?;
    let models = load_all_on(&dirs, &device)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .thread_name("dynaserve-io")
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async move {
        let names = models.names();
        let server = start_with_viewer(config, models, viewer).await?;
        println!(
            "{}",
            dynaserve_api::listening::listening_line(server.grpc_addr, server.http_addr, &names)
        );
        tracing::info!(grpc = %server.grpc_addr, http = %server.http_addr, health = ?server.health_addr, models = ?names, "listening");
        termination().await;
        server.shutdown();
        server.wait().await
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Run outside the repository, the default `models` directory is missing: the error says
    /// how to name the models.
    #[test]
    fn a_missing_models_directory_names_the_flags() {
        let config = ServeConfig {
            models_dir: PathBuf::from("no-such-models-directory"),
            ..ServeConfig::local(vec![])
        };
        let e = format!("{:#}", model_dirs(&config).unwrap_err());
        assert!(
            e.contains("--models-dir") && e.contains("no-such-models-directory"),
            "{e}"
        );
    }
}
