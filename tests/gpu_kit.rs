//! The GPU kit (deploy/gpu-kit) end to end on the CPU, as it runs on a GPU machine: packed
//! around this build's binary, then every stage (parity, data, throughput, training for a
//! wall-clock budget, export, evaluation) with the `kit-tiny` configuration, and a second run that
//! resumes from the first one's output alone.

use std::path::{Path, PathBuf};
use std::process::Command;

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("dynaserve-kit-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{cmd:?} failed:\n{text}");
    text
}

/// `kit.sh` on the CPU with the tiny configuration and small evaluation splits.
fn kit(kit: &Path, out: &Path, work: &Path, extra: &[&str]) -> String {
    run(Command::new(kit.join("kit.sh"))
        .args([
            "--device",
            "cpu",
            "--config",
            "kit-tiny",
            "--minutes",
            "0.05",
        ])
        .args([
            "--eval-scenes",
            "2",
            "--fresh-scenes",
            "2",
            "--suite-scenes",
            "1",
        ])
        .args(["--serve-batches", "1,2", "--train-batches", "2"])
        .args(["--train-presets", "tiny"])
        .arg("--out")
        .arg(out)
        .arg("--work")
        .arg(work)
        .args(extra));
    std::fs::read_to_string(out.join("summary.txt")).unwrap()
}

fn listing(archive: &Path) -> String {
    run(Command::new("tar").arg("-tzf").arg(archive))
}

/// Every file of the kit's output is at most 16 MiB.
fn assert_small_files(out: &Path) {
    for e in std::fs::read_dir(out).unwrap() {
        let e = e.unwrap();
        let len = e.metadata().unwrap().len();
        assert!(len <= 16 << 20, "{} is {len} bytes", e.path().display());
    }
}

#[test]
fn the_kit_runs_every_stage_on_the_cpu_and_resumes_from_its_own_output() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = scratch("run");
    let packed = dir.join("kit");
    let pack = run(Command::new(root.join("deploy/gpu-kit/pack.sh"))
        .args([
            "--binary",
            env!("CARGO_BIN_EXE_dynaserve"),
            "--link",
            "--out",
        ])
        .arg(&packed));
    assert!(pack.contains("gpu kit:"), "{pack}");

    let work = dir.join("work");
    let first = dir.join("out1");
    let summary = kit(&packed, &first, &work, &[]);
    assert!(summary.contains("parity: PASSED"), "{summary}");
    assert!(summary.contains("data: 1 training splits"), "{summary}");
    assert!(summary.contains("train: stopped at iteration"), "{summary}");
    // Throughput: the step at both batch sizes and a training rate for the tiny preset.
    for row in ["| 1 | ", "| 2 | ", "| tiny | 2 | "] {
        assert!(summary.contains(row), "no row {row:?} in:\n{summary}");
    }
    assert!(!summary.contains("failed (kit.log)"), "{summary}");
    assert!(summary.contains("Translation RMSE"), "{summary}");
    // Fewer test scenes than the release's scorecard: the comparison says why it was skipped.
    assert!(summary.contains("not compared"), "{summary}");
    let files = listing(&first.join("results.tar.gz"));
    for f in [
        "results/model/model.safetensors",
        "results/model/config.json",
        "results/parity.json",
        "results/scorecard/eval.json",
        "results/scorecard/fresh.json",
        "results/scorecard/physics-suite.json",
        "results/log.csv",
        "results/loss.png",
        "results/summary.txt",
    ] {
        assert!(files.lines().any(|l| l == f), "{f} missing from:\n{files}");
    }
    assert!(first.join("resume.tar.part-00").exists());
    assert_small_files(&first);

    // A fresh work folder: the second run has only the first one's output to resume from.
    let second = dir.join("out2");
    let summary = kit(
        &packed,
        &second,
        &dir.join("work2"),
        &[
            "--resume",
            first.to_str().unwrap(),
            "--stages",
            "data,train",
        ],
    );
    let resumed = summary
        .split("resumed from iteration ")
        .nth(1)
        .and_then(|s| s.split(',').next())
        .and_then(|s| s.parse::<u64>().ok())
        .unwrap_or_else(|| panic!("no resumed iteration in:\n{summary}"));
    let stopped = summary
        .split("stopped at iteration ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse::<u64>().ok())
        .unwrap();
    assert!(resumed > 0 && stopped > resumed, "{summary}");
    assert_small_files(&second);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A configuration the kit does not carry is refused, naming those it does.
#[test]
fn an_unknown_configuration_is_refused_with_the_list() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = scratch("unknown");
    run(Command::new(root.join("deploy/gpu-kit/pack.sh"))
        .args([
            "--binary",
            env!("CARGO_BIN_EXE_dynaserve"),
            "--link",
            "--out",
        ])
        .arg(dir.join("kit")));
    let out = Command::new(dir.join("kit/kit.sh"))
        .args(["--device", "cpu", "--config", "no-such", "--out"])
        .arg(dir.join("out"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("no configuration no-such") && err.contains("kit-tiny"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
