//! Reading a split directory: [`DatasetReader`] and the streaming [`SceneIter`], with the shard
//! and scene lookups the mesh reader shares.

use std::path::{Path, PathBuf};

use super::io_err;
use super::manifest::{Manifest, read_manifest_of_kind};
use super::records::SceneRecord;
use super::shard::{ObjectParameters, decode_shard, shard_object_parameters};
use crate::{Result, SimError};

/// Entry `k` of a manifest's shard list, or an error naming how many there are.
pub(crate) fn shard_entry<S>(shards: &[S], k: usize) -> Result<&S> {
    shards.get(k).ok_or_else(|| {
        SimError::Invalid(format!(
            "shard {k} out of range (the split has {})",
            shards.len()
        ))
    })
}

/// Scene `i` of a split whose shards hold the scenes `first..first + count` given by `ranges`
/// (in shard order): finds its shard, reads it with `read_shard` and takes the scene out.
pub(crate) fn scene_in_shards<T>(
    ranges: impl IntoIterator<Item = (usize, usize)>,
    i: usize,
    scenes: usize,
    read_shard: impl FnOnce(usize) -> Result<Vec<T>>,
) -> Result<T> {
    let (k, first) = ranges
        .into_iter()
        .enumerate()
        .find(|(_, (first, count))| i >= *first && i < first + count)
        .map(|(k, (first, _))| (k, first))
        .ok_or_else(|| {
            SimError::Invalid(format!("scene {i} out of range (the split has {scenes})"))
        })?;
    read_shard(k)?
        .into_iter()
        .nth(i - first)
        .ok_or_else(|| SimError::Invalid(format!("scene {i} missing from its shard")))
}

/// Reads a split directory: the manifest up front, shards on demand.
#[derive(Clone, Debug)]
pub struct DatasetReader {
    dir: PathBuf,
    manifest: Manifest,
}

impl DatasetReader {
    /// Opens a split directory and validates its manifest (format, version, counts).
    pub fn open(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        let (path, manifest): (_, Manifest) = read_manifest_of_kind(
            &dir,
            false,
            "a mesh dataset (\"content\": \"mesh\"); read it with \
             mesh_scenes::MeshDatasetReader",
        )?;
        manifest.validate(&path)?;
        Ok(Self { dir, manifest })
    }

    /// The manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The split directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Number of scenes.
    pub fn len(&self) -> usize {
        self.manifest.scenes
    }

    /// Whether the split holds no scene.
    pub fn is_empty(&self) -> bool {
        self.manifest.scenes == 0
    }

    /// Reads and decodes shard `k`, checking it against the manifest.
    pub fn read_shard(&self, k: usize) -> Result<Vec<SceneRecord>> {
        let info = shard_entry(&self.manifest.shards, k)?;
        let path = self.dir.join(&info.file);
        let bytes = std::fs::read(&path).map_err(io_err(&path))?;
        let m = &self.manifest;
        let scenes = decode_shard(&bytes, &path, m.frames, m.reference_points, m.dt_frame)?;
        let objects: usize = scenes.iter().map(|s| s.objects.len()).sum();
        if scenes.len() != info.scenes || objects != info.objects {
            return Err(SimError::Shard {
                path,
                message: format!(
                    "holds {} scenes and {objects} objects, the manifest says {} and {}",
                    scenes.len(),
                    info.scenes,
                    info.objects
                ),
            });
        }
        Ok(scenes)
    }

    /// The [`ObjectParameters`] (`([mass kg, friction, restitution], kinematic)`) of every
    /// object of the split, one list per scene, in order; reads only those tensors' values
    /// from each shard.
    pub fn object_parameters(&self) -> Result<Vec<Vec<ObjectParameters>>> {
        let mut all = Vec::new();
        for info in &self.manifest.shards {
            let path = self.dir.join(&info.file);
            let bytes = std::fs::read(&path).map_err(io_err(&path))?;
            all.extend(shard_object_parameters(&bytes, &path)?);
        }
        Ok(all)
    }

    /// Streams all scenes in order, one shard in memory at a time. After an error the iterator
    /// ends.
    pub fn iter(&self) -> SceneIter<'_> {
        SceneIter::new(self.manifest.shards.len(), |k| self.read_shard(k))
    }

    /// Scene `i` (reads its whole shard).
    pub fn get(&self, i: usize) -> Result<SceneRecord> {
        let ranges = self
            .manifest
            .shards
            .iter()
            .map(|s| (s.first_scene, s.scenes));
        scene_in_shards(ranges, i, self.len(), |k| self.read_shard(k))
    }
}

/// Iterator over the scenes (of type `T`) of a split, one shard in memory at a time (see
/// [`DatasetReader::iter`]); after an error it ends.
pub struct SceneIter<'a, T = SceneRecord> {
    read_shard: Box<dyn Fn(usize) -> Result<Vec<T>> + 'a>,
    shards: usize,
    next_shard: usize,
    current: std::vec::IntoIter<T>,
    failed: bool,
}

impl<'a, T> SceneIter<'a, T> {
    /// Streams the scenes of `shards` shards, reading shard `k` with `read_shard(k)`.
    pub(crate) fn new(shards: usize, read_shard: impl Fn(usize) -> Result<Vec<T>> + 'a) -> Self {
        Self {
            read_shard: Box::new(read_shard),
            shards,
            next_shard: 0,
            current: Vec::new().into_iter(),
            failed: false,
        }
    }
}

impl<T> Iterator for SceneIter<'_, T> {
    type Item = Result<T>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        loop {
            if let Some(s) = self.current.next() {
                return Some(Ok(s));
            }
            if self.next_shard >= self.shards {
                return None;
            }
            match (self.read_shard)(self.next_shard) {
                Ok(scenes) => {
                    self.next_shard += 1;
                    self.current = scenes.into_iter();
                }
                Err(e) => {
                    self.failed = true;
                    return Some(Err(e));
                }
            }
        }
    }
}
