//! Launching a server as a child process for the duration of a run (`--spawn`).
//!
//! The command runs under `sh -c` (so it can be written as on a shell prompt). Unless it sets
//! them itself, `--grpc-addr 127.0.0.1:0 --http-addr 127.0.0.1:0` are appended so the server
//! picks free ports; the bound addresses are read from its `dynaserve listening: grpc=...
//! http=...` line, then `/ready` is polled until it answers 200. Stopping sends SIGTERM (the
//! server drains) and kills the process if it has not exited after a grace period.

use std::collections::VecDeque;
use std::process::Stdio;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use dynaserve_api::listening::parse_listening;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};

/// Lines of the child's stderr kept for error messages.
const TAIL: usize = 30;

/// A server launched by the load tester.
pub struct SpawnedServer {
    child: Child,
    /// The command as run (with the appended address flags).
    pub command: String,
    /// gRPC URL, `http://127.0.0.1:PORT`.
    pub grpc_url: String,
    /// HTTP base URL, `http://127.0.0.1:PORT`.
    pub http_url: String,
    tail: Arc<Mutex<VecDeque<String>>>,
}

fn tail_text(tail: &Mutex<VecDeque<String>>) -> String {
    let t = tail.lock().unwrap_or_else(|p| p.into_inner());
    if t.is_empty() {
        "(no output on stderr)".into()
    } else {
        t.iter().cloned().collect::<Vec<_>>().join("\n")
    }
}

impl SpawnedServer {
    /// Launches `command` and waits (up to `timeout`) until the server is ready.
    pub async fn start(command: &str, timeout: Duration) -> anyhow::Result<SpawnedServer> {
        let mut full = command.trim().to_string();
        anyhow::ensure!(!full.is_empty(), "--spawn needs a command");
        if !full.contains("--grpc-addr") {
            full.push_str(" --grpc-addr 127.0.0.1:0");
        }
        if !full.contains("--http-addr") {
            full.push_str(" --http-addr 127.0.0.1:0");
        }
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(format!("exec {full}"))
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .kill_on_drop(true)
            .spawn()
            .with_context(|| format!("cannot start `{full}`"))?;
        let tail = Arc::new(Mutex::new(VecDeque::with_capacity(TAIL)));
        if let Some(err) = child.stderr.take() {
            let tail = tail.clone();
            tokio::spawn(async move {
                let mut lines = BufReader::new(err).lines();
                while let Ok(Some(l)) = lines.next_line().await {
                    let mut t = tail.lock().unwrap_or_else(|p| p.into_inner());
                    if t.len() == TAIL {
                        t.pop_front();
                    }
                    t.push_back(l);
                }
            });
        }
        let stdout = child.stdout.take().context("no stdout of the server")?;
        let (tx, rx) = tokio::sync::oneshot::channel();
        tokio::spawn(async move {
            let mut tx = Some(tx);
            let mut lines = BufReader::new(stdout).lines();
            while let Ok(Some(l)) = lines.next_line().await {
                if let Some(addrs) = parse_listening(&l)
                    && let Some(tx) = tx.take()
                {
                    let _ = tx.send(addrs);
                }
            }
        });
        let started = Instant::now();
        let fail = |child_status: String, tail: &Mutex<VecDeque<String>>| {
            anyhow::anyhow!(
                "the spawned server `{full}` {child_status}; its last output:\n{}",
                tail_text(tail)
            )
        };
        let addrs = tokio::select! {
            r = tokio::time::timeout(timeout, rx) => match r {
                Ok(Ok(a)) => a,
                Ok(Err(_)) => {
                    let status = child.wait().await.map(|s| format!("exited ({s})")).unwrap_or_default();
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    return Err(fail(status, &tail));
                }
                Err(_) => return Err(fail(format!("printed no `dynaserve listening` line within {timeout:?}"), &tail)),
            },
            s = child.wait() => {
                tokio::time::sleep(Duration::from_millis(100)).await;
                return Err(fail(format!("exited ({})", s.map(|s| s.to_string()).unwrap_or_default()), &tail));
            }
        };
        let server = SpawnedServer {
            child,
            command: full.clone(),
            grpc_url: format!("http://{}", addrs.0),
            http_url: format!("http://{}", addrs.1),
            tail,
        };
        let mut server = server;
        let ready = format!("{}/ready", server.http_url);
        loop {
            if crate::transport::http_get(&ready).await.is_ok() {
                return Ok(server);
            }
            if let Ok(Some(status)) = server.child.try_wait() {
                return Err(fail(format!("exited ({status})"), &server.tail));
            }
            if started.elapsed() > timeout {
                let e = fail(format!("was not ready within {timeout:?}"), &server.tail);
                server.stop().await;
                return Err(e);
            }
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }

    /// Process id of the server (the shell `exec`s it, so it is the server's own).
    pub fn pid(&self) -> Option<u32> {
        self.child.id()
    }

    /// Stops the server: SIGTERM, then a kill after 20 s.
    pub async fn stop(mut self) {
        if let Some(pid) = self.child.id() {
            let _ = Command::new("kill")
                .arg("-TERM")
                .arg(pid.to_string())
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .await;
        }
        match tokio::time::timeout(Duration::from_secs(20), self.child.wait()).await {
            Ok(_) => {}
            Err(_) => {
                let _ = self.child.kill().await;
            }
        }
    }
}
