//! The README's shell commands, run against a real server: every ```sh block of README.md is
//! run as one bash script (`set -euo pipefail`, curl failing on an HTTP error status) in the
//! repository root, with `localhost:8080` / `localhost:50051` pointed at a server on loopback
//! serving the bundled models, and `cargo run --release --` replaced by this build's
//! `dynaserve` binary. Two blocks are not run here: the server command (this test starts the
//! same server in-process) and the test command (this is it). A README command that breaks
//! fails this test, naming the block.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use common::TempDir;
use dynaserve_server::ServeConfig;

/// Blocks run elsewhere: the server (started in-process below) and the test command itself.
const NOT_RUN: [&str; 2] = ["cargo run --release -- serve", "cargo test --workspace"];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The ```sh blocks of `text`, each with the line it starts on.
fn sh_blocks(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut cur: Option<(usize, String)> = None;
    for (i, line) in text.lines().enumerate() {
        match (&mut cur, line.trim_start()) {
            (None, "```sh") => cur = Some((i + 1, String::new())),
            (Some(_), "```") => out.extend(cur.take()),
            (Some((_, body)), _) => {
                body.push_str(line);
                body.push('\n');
            }
            _ => {}
        }
    }
    out
}

fn run_block(body: &str, http: &str, grpc: &str, cwd: &Path, tmp: &Path) -> (bool, String) {
    let exe = env!("CARGO_BIN_EXE_dynaserve");
    let script = body
        .replace("cargo run --release --", exe)
        .replace("localhost:8080", http)
        .replace("127.0.0.1:8080", http)
        .replace("localhost:50051", grpc)
        .replace("127.0.0.1:50051", grpc);
    let full = format!(
        "set -euo pipefail\ncurl() {{ command curl --fail-with-body --max-time 120 \"$@\"; }}\n{script}"
    );
    let out = Command::new("bash")
        .arg("-c")
        .arg(&full)
        .current_dir(cwd)
        .env("TMPDIR", tmp)
        .output()
        .expect("bash runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_readme_shell_command_works_against_a_real_server() {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let blocks = sh_blocks(&readme);
    assert!(
        blocks.len() >= 5,
        "the README has {} sh blocks",
        blocks.len()
    );
    for skip in NOT_RUN {
        assert!(
            blocks.iter().any(|(_, b)| b.trim() == skip),
            "the README lost its `{skip}` block"
        );
    }
    let config = ServeConfig::local(vec![
        root().join("models/rigidformer-small"),
        root().join("models/physiformer-small"),
    ]);
    let models = dynaserve_server::load_all(&config.models).unwrap();
    let server = dynaserve_server::start(config, models).await.unwrap();
    server.wait_ready(Duration::from_secs(60)).await.unwrap();
    let http = server.http_addr.to_string();
    let grpc = server.grpc_addr.to_string();
    // The commands run in the repository root, as a reader runs them; what they write there
    // (`--out tower.json`) is removed after.
    let tmp = TempDir::new("readme");
    let mut ran = 0;
    for (line, body) in &blocks {
        if NOT_RUN.contains(&body.trim()) {
            continue;
        }
        let (root_dir, http, grpc) = (root(), http.clone(), grpc.clone());
        let (body_c, tmp_dir) = (body.clone(), tmp.0.clone());
        let (ok, text) = tokio::task::spawn_blocking(move || {
            run_block(&body_c, &http, &grpc, &root_dir, &tmp_dir)
        })
        .await
        .unwrap();
        assert!(
            ok,
            "README.md line {line}: the block failed:\n{body}\n--- output ---\n{text}"
        );
        assert!(
            !text.trim().is_empty(),
            "README.md line {line}: no output:\n{body}"
        );
        ran += 1;
    }
    let _ = std::fs::remove_file(root().join("tower.json"));
    assert!(ran >= 4, "{ran} blocks ran");
    server.shutdown();
}

#[test]
fn blocks_are_found_with_their_lines() {
    let text = "a\n```sh\necho 1\necho 2\n```\n```text\nno\n```\n  ```sh\nx\n  ```\n";
    assert_eq!(
        sh_blocks(text),
        vec![(2, "echo 1\necho 2\n".to_string()), (9, "x\n".to_string())]
    );
}
