//! Compiles every `proto/dynaserve/v1/*.proto` with the protoc binary shipped by the
//! `protoc-bin-vendored` crate (no system protoc needed) and writes a file descriptor set for
//! gRPC server reflection.

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let protoc = protoc_bin_vendored::protoc_bin_path()?;
    // SAFETY: build scripts run single-threaded; nothing else reads the environment concurrently.
    unsafe { std::env::set_var("PROTOC", protoc) };

    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../proto");
    let dir = root.join("dynaserve/v1");
    // Every .proto of the package, sorted so the generated code does not depend on the
    // directory's order.
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "proto"))
        .collect();
    files.sort();
    let out_dir = PathBuf::from(std::env::var("OUT_DIR")?);
    println!("cargo:rerun-if-changed={}", dir.display());
    for file in &files {
        println!("cargo:rerun-if-changed={}", file.display());
    }

    tonic_prost_build::configure()
        .file_descriptor_set_path(out_dir.join("dynaserve_v1_descriptor.bin"))
        .compile_protos(&files, &[root])?;
    Ok(())
}
