//! Graceful shutdown of the real binary: SIGTERM drains running rollouts to completion within
//! the drain deadline, and closes what is left after it with UNAVAILABLE.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::*;
use futures::StreamExt;

struct Server {
    child: Child,
    grpc: String,
    http: std::net::SocketAddr,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn spawn(model: &std::path::Path, drain_s: f64) -> Server {
    let mut child = Command::new(env!("CARGO_BIN_EXE_dynaserve"))
        .args(["serve", "--model"])
        .arg(model)
        .args([
            "--grpc-addr",
            "127.0.0.1:0",
            "--http-addr",
            "127.0.0.1:0",
            "--drain-timeout-s",
            &drain_s.to_string(),
            "--log",
            "warn",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start dynaserve");
    let stdout = child.stdout.take().unwrap();
    let mut line = String::new();
    BufReader::new(stdout).read_line(&mut line).unwrap();
    let (grpc, http) = dynaserve_api::listening::parse_listening(&line)
        .unwrap_or_else(|| panic!("not a listening line: {line:?}"));
    Server {
        grpc: format!("http://{grpc}"),
        http,
        child,
    }
}

async fn wait_ready(s: &Server) {
    let t = Instant::now();
    loop {
        if http(s.http, "GET", "/ready", &[], None).await.status == 200 {
            return;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "never ready");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

fn sigterm(child: &Child) {
    let ok = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok);
}

fn wait_exit(child: &mut Child, within: Duration) -> std::process::ExitStatus {
    let t = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s;
        }
        assert!(
            t.elapsed() < within,
            "process did not exit within {within:?}"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_drains_a_running_rollout_to_completion() {
    let m = test_model();
    let mut server = spawn(&m.dir, 30.0);
    wait_ready(&server).await;
    let mut c = dynaserve_client::Client::connect(&server.grpc)
        .await
        .unwrap();
    // Size the rollout to last about two seconds on this machine and model, so that most of it
    // runs after SIGTERM.
    let probe = rollout_request(&m.name, scene(21, 3, 48), 20);
    let t = Instant::now();
    c.rollout_collect(&probe).await.unwrap();
    let per_step = t.elapsed().as_secs_f64() / 20.0;
    let steps = ((2.0 / per_step) as u32).clamp(50, 10_000);
    let req = rollout_request(&m.name, scene(21, 3, 48), steps);
    let mut rollout = c.rollout(&req).await.unwrap();
    let first = rollout.frames.next().await.unwrap().unwrap();
    assert_eq!(first.step, 1);
    let t = Instant::now();
    sigterm(&server.child);
    // Readiness turns off while the rollout goes on: /ready answers 503 "draining", new work
    // is refused, and metrics can still be scraped.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let ready = http(server.http, "GET", "/ready", &[], None).await;
    assert_eq!(ready.status, 503, "{}", ready.text());
    assert!(ready.text().contains("draining"), "{}", ready.text());
    assert_eq!(
        http(server.http, "GET", "/metrics", &[], None).await.status,
        200
    );
    let refused = post_json(server.http, "/v1/rollout", &probe).await;
    assert_eq!(refused.status, 503, "{}", refused.text());
    let mut last = first.step;
    while let Some(f) = rollout.frames.next().await {
        let f = f.expect("drained rollout must end cleanly");
        assert_eq!(f.step, last + 1);
        last = f.step;
    }
    assert_eq!(last, steps, "rollout cut short");
    let drained_for = t.elapsed();
    assert!(
        drained_for > Duration::from_millis(500),
        "the rollout was not running during the drain ({drained_for:?})"
    );
    let status = wait_exit(&mut server.child, Duration::from_secs(15));
    assert!(status.success(), "exit status {status:?}");
    assert!(t.elapsed() < Duration::from_secs(30));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rollouts_still_running_at_the_drain_deadline_are_closed_with_unavailable() {
    let m = test_model();
    let mut server = spawn(&m.dir, 0.5);
    wait_ready(&server).await;
    let mut c = dynaserve_client::Client::connect(&server.grpc)
        .await
        .unwrap();
    let req = rollout_request(&m.name, scene(22, 2, 32), 10_000);
    let mut rollout = c.rollout(&req).await.unwrap();
    rollout.frames.next().await.unwrap().unwrap();
    let t = Instant::now();
    sigterm(&server.child);
    let mut end = None;
    while let Some(f) = rollout.frames.next().await {
        if let Err(e) = f {
            end = Some(e);
            break;
        }
    }
    let waited = t.elapsed();
    match end {
        Some(dynaserve_client::ClientError::Status(s)) => {
            assert_eq!(s.code(), tonic::Code::Unavailable, "{s:?}");
            assert!(s.message().contains("drain deadline"), "{}", s.message());
        }
        other => panic!("expected UNAVAILABLE, got {other:?}"),
    }
    assert!(waited >= Duration::from_millis(450), "{waited:?}");
    assert!(waited < Duration::from_secs(5), "{waited:?}");
    let status = wait_exit(&mut server.child, Duration::from_secs(10));
    assert!(status.success(), "exit status {status:?}");
}
