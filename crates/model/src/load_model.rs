//! Loading a checkpoint directory as whichever model family its `config.json` names.
//!
//! Sits above [`crate::checkpoint`] (single-model files) and [`crate::ensemble`] (which
//! loads its members through the checkpoint readers), so neither imports the other back.

use std::path::Path;
use std::sync::Arc;

use candle_core::Device;

use crate::checkpoint::{load_rigidformer, read_architecture};
use crate::config::RIGIDFORMER;
use crate::ensemble::{ENSEMBLE, Ensemble};
use crate::{ModelError, WorldModel};

/// Loads the checkpoint in `dir` for inference on `device`: a RigidFormer, or an ensemble of
/// them (`crate::ensemble`), by `config.json`'s `architecture`.
///
/// Errors ([`ModelError::Checkpoint`]) name the missing file, the unparsable config, the
/// corrupted weights file, or the first tensor whose name, shape, dtype or values do not match.
pub fn load_model(dir: &Path, device: &Device) -> Result<Arc<dyn WorldModel>, ModelError> {
    match read_architecture(dir)?.as_str() {
        RIGIDFORMER => Ok(Arc::new(load_rigidformer(dir, device, false)?)),
        ENSEMBLE => Ok(Arc::new(Ensemble::load(dir, device)?)),
        other => Err(ModelError::Checkpoint(format!(
            "unknown architecture {other:?}"
        ))),
    }
}
