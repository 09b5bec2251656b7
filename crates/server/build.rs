//! Embeds the example scenes (`examples/scenes/*.json` at the workspace root) in the server, so
//! the viewer's `GET /v1/examples` lists them whatever the working directory. Writes
//! `$OUT_DIR/examples.rs`: a `&[(&str, &str)]` of (file stem, file contents), sorted by name.
//! A missing directory (a dependency-only build) gives an empty list.

use std::fmt::Write as _;
use std::path::PathBuf;

fn main() {
    let manifest = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets it"));
    let dir = manifest.join("../../examples/scenes");
    println!("cargo:rerun-if-changed={}", dir.display());
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map(|entries| {
            entries
                .filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| p.extension().is_some_and(|e| e == "json"))
                .collect()
        })
        .unwrap_or_default();
    files.sort();
    let mut out = String::from("&[\n");
    for f in &files {
        println!("cargo:rerun-if-changed={}", f.display());
        let stem = f.file_stem().unwrap_or_default().to_string_lossy();
        let path = f.canonicalize().unwrap_or_else(|_| f.clone());
        writeln!(out, "    ({stem:?}, include_str!({:?})),", path.display()).unwrap();
    }
    out.push(']');
    let dest =
        PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets it")).join("examples.rs");
    std::fs::write(dest, out).expect("writing examples.rs");
}
