//! Embeds the example scenes (`examples/scenes/` at the workspace root) in the server, so the
//! viewer's `GET /v1/examples` lists them whatever the working directory. Writes
//! `$OUT_DIR/examples.rs` (every `examples/scenes/*.json`, rollout bodies) and
//! `$OUT_DIR/generate_examples.rs` (every `examples/scenes/generate/*.json`, generate bodies):
//! each a `&[(&str, &str)]` of (file stem, file contents), sorted by name. A missing directory
//! (a dependency-only build) gives an empty list.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn main() {
    let manifest = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets it"));
    let out = PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets it"));
    let scenes = manifest.join("../../examples/scenes");
    embed(&scenes, &out.join("examples.rs"));
    embed(&scenes.join("generate"), &out.join("generate_examples.rs"));
}

/// Writes `dest`: the list of `dir`'s JSON files as `include_str!`s.
fn embed(dir: &Path, dest: &Path) {
    println!("cargo:rerun-if-changed={}", dir.display());
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| p.is_file() && p.extension().is_some_and(|e| e == "json"))
                .collect()
        })
        .unwrap_or_default();
    files.sort();
    let mut text = String::from("&[\n");
    for f in &files {
        println!("cargo:rerun-if-changed={}", f.display());
        let stem = f.file_stem().unwrap_or_default().to_string_lossy();
        let path = f.canonicalize().unwrap_or_else(|_| f.clone());
        writeln!(text, "    ({stem:?}, include_str!({:?})),", path.display()).unwrap();
    }
    text.push(']');
    std::fs::write(dest, text).expect("writing the embedded example list");
}
