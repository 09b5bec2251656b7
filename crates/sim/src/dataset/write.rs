//! Writing a split directory: preparing it, the shard loop (scenes made in parallel, encoded,
//! written shard by shard) and the manifest; shared by the pose and mesh writers.

use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;

use super::io_err;
use crate::{Result, SimError};

/// Creates `dir` if needed. A directory that already holds a manifest is refused unless
/// `overwrite`, in which case its manifest and shard files are removed first.
pub fn prepare_dir(dir: &Path, overwrite: bool) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let manifest = dir.join("manifest.json");
    if manifest.exists() {
        if !overwrite {
            return Err(SimError::Invalid(format!(
                "{} already holds a dataset (pass --overwrite to replace it)",
                dir.display()
            )));
        }
        std::fs::remove_file(&manifest).map_err(io_err(&manifest))?;
    }
    for entry in std::fs::read_dir(dir).map_err(io_err(dir))? {
        let entry = entry.map_err(io_err(dir))?;
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with("shard-") && name.ends_with(".safetensors") {
            if !overwrite {
                return Err(SimError::Invalid(format!(
                    "{} already holds shard files (pass --overwrite to replace them)",
                    dir.display()
                )));
            }
            std::fs::remove_file(entry.path()).map_err(io_err(&entry.path()))?;
        }
    }
    Ok(())
}

/// Writes `bytes` to `path` through a temporary file and a rename.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).map_err(io_err(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io_err(path))
}

/// Generates scenes `0..scenes` shard by shard (`per_shard` scenes each, the last fewer): a
/// shard's scenes in parallel on rayon's pool with `make(i)` (then `on_scene()`), then the shard,
/// encoded by `encode`, written to `out/shard-00000.safetensors`, ... and reported to
/// `on_shard(file, first_scene, scenes, bytes)`. Returns each scene's label `L`, in scene order.
pub(crate) fn write_shards<S: Send, L: Send>(
    out: &Path,
    scenes: usize,
    per_shard: usize,
    make: impl Fn(u64) -> Result<(S, L)> + Sync,
    on_scene: &(dyn Fn() + Sync),
    encode: impl Fn(&[S]) -> Result<Vec<u8>>,
    mut on_shard: impl FnMut(String, usize, &[S], u64),
) -> Result<Vec<L>> {
    if per_shard == 0 {
        return Err(SimError::Invalid(
            "scenes per shard must be at least 1".into(),
        ));
    }
    let mut labels = Vec::with_capacity(scenes);
    let (mut first, mut shard) = (0usize, 0usize);
    while first < scenes {
        let end = (first + per_shard).min(scenes);
        let made = (first..end)
            .into_par_iter()
            .map(|i| {
                let s = make(i as u64);
                on_scene();
                s
            })
            .collect::<Result<Vec<_>>>()?;
        let (made, shard_labels): (Vec<S>, Vec<L>) = made.into_iter().unzip();
        labels.extend(shard_labels);
        let file = format!("shard-{shard:05}.safetensors");
        let encoded = encode(&made)?;
        write_file(&out.join(&file), &encoded)?;
        on_shard(file, first, &made, encoded.len() as u64);
        shard += 1;
        first = end;
    }
    Ok(labels)
}

/// Writes a split's `manifest.json` (pretty JSON, pose or mesh manifest); returns its size in
/// bytes.
pub fn write_manifest(dir: &Path, manifest: &impl Serialize) -> Result<u64> {
    let path = dir.join("manifest.json");
    let mut text = serde_json::to_string_pretty(manifest).map_err(|e| SimError::Manifest {
        path: path.clone(),
        message: e.to_string(),
    })?;
    text.push('\n');
    write_file(&path, text.as_bytes())?;
    Ok(text.len() as u64)
}
