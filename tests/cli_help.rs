//! What the binary's help tells a newcomer: every subcommand's line names what it offers.

use std::process::Command;

fn help(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_dynaserve"))
        .args(args)
        .output()
        .unwrap();
    assert!(out.status.success(), "{args:?}");
    String::from_utf8(out.stdout).unwrap()
}

/// `eval` scores three baselines, rapier among them, and the command list says so.
#[test]
fn eval_help_names_every_baseline() {
    let top = help(&["--help"]);
    let line = top
        .lines()
        .find(|l| l.trim_start().starts_with("eval"))
        .unwrap();
    for b in ["static", "ballistic", "rapier"] {
        assert!(line.contains(b), "{line}");
    }
    let eval = help(&["eval", "--help"]);
    assert!(eval.contains("rapier"), "{eval}");
    let import = help(&["import", "physiformer", "--help"]);
    assert!(
        import.contains("--checkpoint") && import.contains("--no-ema"),
        "{import}"
    );
}
