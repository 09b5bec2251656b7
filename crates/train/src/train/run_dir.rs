//! A run directory's shared files, for RigidFormer and PhysiFormer runs alike: the checkpoint
//! directory replaced atomically (with the optimizer and state files inside it), finding the
//! checkpoint to resume from, and the CSV log cut back to a resumed step; a RigidFormer
//! checkpoint's training position ([`RunState`]).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::TrainError;
use super::config::TrainConfig;

/// File holding the optimizer state inside a checkpoint directory.
pub const OPTIMIZER_FILE: &str = "optimizer.safetensors";
/// File holding the training position inside a checkpoint directory.
pub const STATE_FILE: &str = "state.json";

/// Training position stored with every checkpoint.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunState {
    /// Iterations completed.
    pub step: u64,
    /// Training wall time over all sessions, seconds.
    pub elapsed_seconds: f64,
    /// Compute threads used.
    pub threads: usize,
    /// The configuration of the run.
    pub config: TrainConfig,
}

/// Reads `state.json` of a checkpoint directory.
pub fn read_state(ckpt: &Path) -> Result<RunState, TrainError> {
    let p = ckpt.join(STATE_FILE);
    let text = std::fs::read_to_string(&p).map_err(io(&p))?;
    serde_json::from_str(&text).map_err(|e| TrainError::Config(format!("{}: {e}", p.display())))
}

/// Maps an I/O error to [`TrainError::Io`] naming `path`.
pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> TrainError + '_ {
    move |e| TrainError::Io {
        path: path.to_path_buf(),
        source: e,
    }
}

/// `out/checkpoint`, the directory of a run's current checkpoint.
pub(crate) fn checkpoint_dir(out: &Path) -> PathBuf {
    out.join("checkpoint")
}

/// Writes `state` as `state.json` into the checkpoint directory `dir`.
pub(crate) fn write_state(dir: &Path, state: &impl Serialize) -> Result<(), TrainError> {
    let json = serde_json::to_string_pretty(state)
        .map_err(|e| TrainError::Config(format!("state serialisation: {e}")))?;
    let p = dir.join(STATE_FILE);
    std::fs::write(&p, json).map_err(io(&p))
}

/// Replaces `out/checkpoint` atomically by what `write` puts into the empty directory
/// `out/checkpoint.tmp` (swapped in by renames; [`resumable`] finds the old one if a swap is
/// cut short). Returns the checkpoint directory.
pub(crate) fn replace_checkpoint(
    out: &Path,
    write: impl FnOnce(&Path) -> Result<(), TrainError>,
) -> Result<PathBuf, TrainError> {
    let dir = checkpoint_dir(out);
    replace_dir(&dir, write)?;
    Ok(dir)
}

/// Replaces the directory `dir` atomically by what `write` puts into the empty directory
/// `dir.tmp`: the old `dir` is renamed to `dir.old`, `dir.tmp` to `dir`, then `dir.old` is
/// removed.
pub(crate) fn replace_dir(
    dir: &Path,
    write: impl FnOnce(&Path) -> Result<(), TrainError>,
) -> Result<(), TrainError> {
    let tmp = dir.with_extension("tmp");
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io(&tmp))?;
    }
    std::fs::create_dir_all(&tmp).map_err(io(&tmp))?;
    write(&tmp)?;
    let old = dir.with_extension("old");
    if old.exists() {
        std::fs::remove_dir_all(&old).map_err(io(&old))?;
    }
    if dir.exists() {
        std::fs::rename(dir, &old).map_err(io(dir))?;
    }
    std::fs::rename(&tmp, dir).map_err(io(&tmp))?;
    if old.exists() {
        std::fs::remove_dir_all(&old).map_err(io(&old))?;
    }
    Ok(())
}

/// The checkpoint to resume from: `checkpoint/`, or `checkpoint.old/` if a swap was cut short.
pub(crate) fn resumable(out: &Path) -> Option<PathBuf> {
    [checkpoint_dir(out), out.join("checkpoint.old")]
        .into_iter()
        .find(|d| d.join(STATE_FILE).exists())
}

/// Keeps `header` and the rows up to `step` (so a resumed run's log has no duplicates).
pub(crate) fn truncate_log(path: &Path, header: &str, step: u64) -> Result<(), TrainError> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return std::fs::write(path, format!("{header}\n")).map_err(io(path));
    };
    let mut out = String::from(header);
    out.push('\n');
    for l in text.lines().skip(1) {
        let s: Option<u64> = l.split(',').next().and_then(|x| x.parse().ok());
        if s.is_some_and(|s| s <= step) {
            out.push_str(l);
            out.push('\n');
        }
    }
    std::fs::write(path, out).map_err(io(path))
}
