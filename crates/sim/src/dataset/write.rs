//! Writing a split directory: preparing it, the shard loop (scenes made in parallel, handed
//! over shard by shard), the shard files and the manifest; shared by the pose and mesh writers
//! and by the training crate's restart splits.

use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;

use super::{SceneRecord, ShardInfo, encode_shard, io_err};
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

/// The file name of a split's shard number `index`: `shard-00000.safetensors`, ...
pub fn shard_file(index: usize) -> String {
    format!("shard-{index:05}.safetensors")
}

/// The pose shards of a split as they are written: each [`PoseShards::write`] encodes a
/// batch of scenes as the next shard file and records it for the manifest.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoseShards {
    /// The manifest's shard list, in file order.
    pub shards: Vec<ShardInfo>,
    /// Scenes written.
    pub scenes: usize,
    /// Objects written.
    pub objects: usize,
    /// Bytes of shard files written.
    pub bytes: u64,
}

impl PoseShards {
    /// Encodes `scenes` ([`encode_shard`]: `frames` frames, `points` reference points per
    /// object) and writes them to `dir` as the next shard file ([`shard_file`]). An empty batch
    /// writes nothing.
    pub fn write(
        &mut self,
        dir: &Path,
        scenes: &[SceneRecord],
        frames: usize,
        points: usize,
    ) -> Result<()> {
        if scenes.is_empty() {
            return Ok(());
        }
        let file = shard_file(self.shards.len());
        let encoded = encode_shard(scenes, frames, points)?;
        write_file(&dir.join(&file), &encoded)?;
        let objects = scenes.iter().map(|s| s.objects.len()).sum();
        self.shards.push(ShardInfo {
            file,
            scenes: scenes.len(),
            objects,
            first_scene: self.scenes,
        });
        self.scenes += scenes.len();
        self.objects += objects;
        self.bytes += encoded.len() as u64;
        Ok(())
    }
}

/// Makes scenes `0..scenes` shard by shard (`per_shard` scenes each, the last fewer): a
/// shard's scenes in parallel on rayon's pool with `make(i)` (then `on_scene()`), then hands
/// them to `write(first_scene, scenes)`, which stores them as one shard. Returns each scene's
/// label `L`, in scene order.
pub(crate) fn write_shards<S: Send, L: Send>(
    scenes: usize,
    per_shard: usize,
    make: impl Fn(u64) -> Result<(S, L)> + Sync,
    on_scene: &(dyn Fn() + Sync),
    mut write: impl FnMut(usize, &[S]) -> Result<()>,
) -> Result<Vec<L>> {
    if per_shard == 0 {
        return Err(SimError::Invalid(
            "scenes per shard must be at least 1".into(),
        ));
    }
    let mut labels = Vec::with_capacity(scenes);
    for first in (0..scenes).step_by(per_shard) {
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
        write(first, &made)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::decode_shard;

    /// A one-object scene whose object starts at `x` along x, metres.
    fn scene(x: f32) -> SceneRecord {
        let mut object = crate::dataset::shard::tests::object(false);
        object.positions[0][0] = x;
        SceneRecord {
            objects: vec![object],
            dt_frame: 1.0 / 24.0,
        }
    }

    #[test]
    fn pose_shards_number_files_in_order_and_skip_empty_batches() {
        let dir =
            std::env::temp_dir().join(format!("dynaserve-pose-shards-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut shards = PoseShards::default();
        shards.write(&dir, &[scene(0.0), scene(1.0)], 2, 1).unwrap();
        shards.write(&dir, &[], 2, 1).unwrap();
        shards.write(&dir, &[scene(2.0)], 2, 1).unwrap();
        let files: Vec<&str> = shards.shards.iter().map(|s| s.file.as_str()).collect();
        assert_eq!(files, [shard_file(0), shard_file(1)]);
        assert_eq!(shards.shards[1].first_scene, 2);
        assert_eq!((shards.scenes, shards.objects), (3, 3));
        let sizes: u64 = files
            .iter()
            .map(|f| std::fs::metadata(dir.join(f)).unwrap().len())
            .sum();
        assert_eq!(shards.bytes, sizes);
        let path = dir.join(files[1]);
        let back = decode_shard(&std::fs::read(&path).unwrap(), &path, 2, 1, 1.0 / 24.0).unwrap();
        assert_eq!(back.len(), 1);
        assert_eq!(back[0].objects[0].positions[0], [2.0, 0.0, 0.5]);
        assert!(!dir.join(shard_file(2)).exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
