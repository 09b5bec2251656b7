//! The training directories read as one sequence of shards.

use dynaserve_sim::{DatasetReader, SceneRecord};

use crate::train::TrainError;

/// The training directories as one sequence of shards: the first directory's shards, then
/// each further directory's.
pub struct Sources {
    readers: Vec<DatasetReader>,
    /// `(reader, local shard)` of every global shard.
    shards: Vec<(usize, usize)>,
}

impl Sources {
    /// Opens the directories; all must share the first one's frame interval and gravity.
    pub fn open(dirs: &[std::path::PathBuf]) -> Result<Sources, TrainError> {
        let mut readers: Vec<DatasetReader> = Vec::with_capacity(dirs.len());
        for d in dirs {
            let r = DatasetReader::open(d)?;
            if let Some(first) = readers.first() {
                let (a, b) = (first.manifest(), r.manifest());
                if a.dt_frame != b.dt_frame || a.gravity != b.gravity {
                    return Err(TrainError::Data(format!(
                        "{} has dt_frame {} and gravity {:?}, but {} has {} and {:?}",
                        d.display(),
                        b.dt_frame,
                        b.gravity,
                        first.dir().display(),
                        a.dt_frame,
                        a.gravity
                    )));
                }
            }
            readers.push(r);
        }
        let shards = readers
            .iter()
            .enumerate()
            .flat_map(|(i, r)| (0..r.manifest().shards.len()).map(move |s| (i, s)))
            .collect();
        Ok(Sources { readers, shards })
    }

    /// The first directory's reader (its manifest fixes the frame interval and gravity).
    pub fn primary(&self) -> &DatasetReader {
        &self.readers[0]
    }

    /// Every reader, in order.
    pub fn readers(&self) -> &[DatasetReader] {
        &self.readers
    }

    /// The directory (0 = `train`, then each extra) that global shard `shard` belongs to.
    pub fn directory_of(&self, shard: usize) -> usize {
        self.shards[shard].0
    }

    /// Scenes per global shard.
    pub(super) fn shard_sizes(&self) -> Vec<usize> {
        self.shards
            .iter()
            .map(|&(r, s)| self.readers[r].manifest().shards[s].scenes)
            .collect()
    }

    /// The scenes of global shard `global`.
    pub(super) fn read_shard(&self, global: usize) -> Result<Vec<SceneRecord>, TrainError> {
        let (r, s) = self.shards[global];
        Ok(self.readers[r].read_shard(s)?)
    }
}
