//! The Python client (`clients/python`) against a real server on 127.0.0.1 with the real
//! checkpoints (the RigidFormer and the shipped PhysiFormer): the test makes a virtual
//! environment under `target/`, installs the package with pip together with its `grpc` extra
//! (grpcio, protobuf) and its `stubs` extra (the pinned grpcio-tools that checks the committed
//! stubs), runs the package's own tests over HTTP and gRPC and the push planner example over each
//! with a small budget, whose plans are replayed in rapier by this build's `dynaserve sim replay`.

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use common::*;
use dynaserve_server::ServeConfig;
use tokio::process::Command;

async fn run(cmd: &mut Command, what: &str) -> String {
    let out = cmd.output().await.unwrap_or_else(|e| panic!("{what}: {e}"));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{what} failed:\n{text}");
    text
}

/// A virtual environment with the client installed; its python.
async fn venv(root: &Path) -> PathBuf {
    let dir = root.join("target").join("python-client-venv");
    let python = dir.join("bin").join("python");
    if !python.is_file() {
        run(
            Command::new("python3")
                .args(["-m", "venv", "--system-site-packages"])
                .arg(&dir),
            "python3 -m venv",
        )
        .await;
    }
    run(
        Command::new(&python)
            .args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--disable-pip-version-check",
            ])
            .arg(format!(
                "{}[grpc,stubs]",
                root.join("clients").join("python").display()
            )),
        "pip install ./clients/python[grpc,stubs]",
    )
    .await;
    python
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_client_tests_and_push_planner_run_against_a_real_server() {
    let m = test_model();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let physiformer = root.join("models").join("physiformer-small");
    let config = ServeConfig::local(vec![m.dir.clone(), physiformer]);
    let models = dynaserve_server::load_all(&config.models).unwrap();
    let server = dynaserve_server::start(config, models).await.unwrap();
    server.wait_ready(Duration::from_secs(60)).await.unwrap();
    let python = venv(root).await;
    let url = format!("http://{}", server.http_addr);
    let tests = run(
        Command::new(&python)
            .args(["-m", "unittest", "discover", "-v", "-s"])
            .arg(root.join("clients/python/tests"))
            .env("DYNASERVE_HTTP", &url)
            .env("DYNASERVE_GRPC", server.grpc_addr.to_string()),
        "python client tests",
    )
    .await;
    println!("{tests}");
    assert!(tests.contains("OK"), "{tests}");
    // The push planner over each transport, with a small budget, on two seeds.
    let grpc = server.grpc_addr.to_string();
    let record_dir = std::env::temp_dir().join(format!("dynaserve-planner-{}", std::process::id()));
    for (flag, address) in [("--server", url.as_str()), ("--grpc", grpc.as_str())] {
        let dir = record_dir.join(&flag[2..]);
        std::fs::create_dir_all(&dir).unwrap();
        let record = dir.join("planner.json");
        let planner = run(
            Command::new(&python)
                .arg(root.join("clients/python/examples/push_planner.py"))
                .arg("--json")
                .arg(&record)
                .args([
                    flag,
                    address,
                    "--rounds",
                    "2",
                    "--samples",
                    "16",
                    "--iterations",
                    "1",
                    "--seeds",
                    "0-1",
                    "--dynaserve",
                    env!("CARGO_BIN_EXE_dynaserve"),
                ]),
            "push planner",
        )
        .await;
        println!("{planner}");
        assert!(planner.contains("final distance to the goal"), "{planner}");
        // Both executed pusher paths were replayed in rapier: two finite distances in metres.
        let line = planner
            .lines()
            .find(|l| l.contains("(rapier replay)"))
            .unwrap_or_else(|| panic!("no rapier replay in:\n{planner}"));
        let metres: Vec<f64> = line
            .split_whitespace()
            .filter_map(|w| w.trim_end_matches(',').parse().ok())
            .collect();
        assert_eq!(metres.len(), 2, "{line}");
        assert!(metres.iter().all(|d| d.is_finite() && *d >= 0.0), "{line}");
        // One plan per seed, then the summary over both.
        assert_eq!(
            planner
                .matches("final distance to the goal (rapier replay)")
                .count(),
            2,
            "{planner}"
        );
        assert!(
            planner.contains("over 2 seeds (rapier replay)"),
            "{planner}"
        );
        // The record holds both seeds' replayed distances, as `train compare` reads them.
        let read = dynaserve_train::train::planner_record::read_planner(&dir)
            .unwrap()
            .expect("planner.json written");
        assert_eq!(
            read.seeds.iter().map(|s| s.seed).collect::<Vec<_>>(),
            [0, 1]
        );
        assert_eq!(read.settings["rounds"], 2);
        assert!(
            planner.contains(&format!(
                "planned {:.3} m, random plan {:.3} m",
                read.seeds[1].planned, read.seeds[1].random
            )),
            "{planner}\n{read:?}"
        );
    }
    let _ = std::fs::remove_dir_all(&record_dir);
    server.shutdown();
    server.wait().await.unwrap();
}
