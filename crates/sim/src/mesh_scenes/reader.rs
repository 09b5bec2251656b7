//! Reading a mesh split directory: [`MeshDatasetReader`] validates `manifest.json` up front and
//! decodes shards on demand into [`MeshScene`]s.

use std::path::{Path, PathBuf};

use super::format::{MeshManifest, decode_mesh_shard};
use super::record::MeshScene;
use crate::dataset::{
    SceneIter, io_err, is_mesh_manifest, read_manifest_json, read_manifest_of_kind,
    scene_in_shards, shard_entry,
};
use crate::{Result, SimError};

/// Whether the split directory `dir` holds a mesh dataset (its manifest's `content` is
/// `mesh`). Errors when the manifest cannot be read or is not JSON.
pub fn is_mesh_dataset(dir: impl AsRef<Path>) -> Result<bool> {
    Ok(is_mesh_manifest(&read_manifest_json(dir.as_ref())?.1))
}

/// Reads a mesh split directory: the manifest up front, shards on demand.
///
/// ```no_run
/// use dynaserve_sim::mesh_scenes::MeshDatasetReader;
/// let reader = MeshDatasetReader::open("data/physi/d1/train")?;
/// let scene = reader.get(0)?;
/// // [V, T, 3] positions, faces over the scene's vertices, per-object ranges and materials
/// let (v, t) = (scene.num_vertices(), scene.frames);
/// assert_eq!(scene.positions.len(), v * t * 3);
/// for o in &scene.objects {
///     println!("{:?} {:?} {}", o.vertices, o.material, o.mass);
/// }
/// # Ok::<(), dynaserve_sim::SimError>(())
/// ```
#[derive(Clone, Debug)]
pub struct MeshDatasetReader {
    dir: PathBuf,
    manifest: MeshManifest,
}

impl MeshDatasetReader {
    /// Opens a split directory and validates its manifest (format, version, content, counts).
    /// A rigid-pose dataset is refused with an error that says so.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        let (path, manifest): (_, MeshManifest) = read_manifest_of_kind(
            &dir,
            true,
            "not a mesh dataset (no \"content\": \"mesh\"); read rigid-pose datasets with \
             DatasetReader",
        )?;
        manifest.validate(&path)?;
        Ok(Self { dir, manifest })
    }

    /// The manifest.
    pub fn manifest(&self) -> &MeshManifest {
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

    /// Reads and decodes shard `k`, checking its counts against the manifest.
    pub fn read_shard(&self, k: usize) -> Result<Vec<MeshScene>> {
        let info = shard_entry(&self.manifest.shards, k)?;
        let path = self.dir.join(&info.file);
        let bytes = std::fs::read(&path).map_err(io_err(&path))?;
        let m = &self.manifest;
        let scenes = decode_mesh_shard(&bytes, &path, m.frames, m.dt_frame)?;
        let objects: usize = scenes.iter().map(|s| s.objects.len()).sum();
        let vertices: usize = scenes.iter().map(|s| s.num_vertices()).sum();
        if scenes.len() != info.scenes || objects != info.objects || vertices != info.vertices {
            return Err(SimError::Shard {
                path,
                message: format!(
                    "holds {} scenes, {objects} objects, {vertices} vertices; the manifest says \
                     {}, {}, {}",
                    scenes.len(),
                    info.scenes,
                    info.objects,
                    info.vertices
                ),
            });
        }
        Ok(scenes)
    }

    /// Scene `i` (reads its whole shard).
    pub fn get(&self, i: usize) -> Result<MeshScene> {
        let ranges = self
            .manifest
            .shards
            .iter()
            .map(|s| (s.first_scene, s.scenes));
        scene_in_shards(ranges, i, self.len(), |k| self.read_shard(k))
    }

    /// Every scene in order (all shards in memory).
    pub fn read_all(&self) -> Result<Vec<MeshScene>> {
        let mut all = Vec::with_capacity(self.len());
        for k in 0..self.manifest.shards.len() {
            all.extend(self.read_shard(k)?);
        }
        Ok(all)
    }

    /// Streams the scenes in order, one shard in memory at a time; after an error the iterator
    /// ends.
    pub fn iter(&self) -> SceneIter<'_, MeshScene> {
        SceneIter::new(self.manifest.shards.len(), |k| self.read_shard(k))
    }
}
