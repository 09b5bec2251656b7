//! Checkpoints: a directory with `config.json`, `model.safetensors` and `card.md`.
//!
//! Loading checks every tensor's name, shape, dtype and values against the configuration and
//! fails with a message naming the problem; it never panics on a bad file. Weights stored as
//! f16, bf16 or f64 are converted to f32.

use std::collections::HashMap;
use std::path::Path;

use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;

use crate::config::RIGIDFORMER;
use crate::layers::ParamStore;
use crate::rigidformer::RigidFormer;
use crate::{ModelConfig, ModelError, WorldModel};

/// File names inside a checkpoint directory.
pub const CONFIG_FILE: &str = "config.json";
/// See [`CONFIG_FILE`].
pub const WEIGHTS_FILE: &str = "model.safetensors";
/// See [`CONFIG_FILE`].
pub const CARD_FILE: &str = "card.md";

/// Reads and validates `config.json` of a checkpoint directory.
pub fn read_config(dir: &Path) -> Result<ModelConfig, ModelError> {
    let config: ModelConfig = parse_config(dir, "configuration")?;
    config.validate()?;
    Ok(config)
}

/// Parses `config.json` of a checkpoint directory as `T`; errors name the file and call it a
/// valid `what` (e.g. "configuration").
pub(crate) fn parse_config<T: serde::de::DeserializeOwned>(
    dir: &Path,
    what: &str,
) -> Result<T, ModelError> {
    let path = dir.join(CONFIG_FILE);
    let text = std::fs::read_to_string(&path)
        .map_err(|e| ModelError::Checkpoint(format!("cannot read {}: {e}", path.display())))?;
    serde_json::from_str(&text).map_err(|e| {
        ModelError::Checkpoint(format!("{} is not a valid {what}: {e}", path.display()))
    })
}

pub(crate) fn read_weights(
    dir: &Path,
    device: &Device,
) -> Result<HashMap<String, Tensor>, ModelError> {
    let path = dir.join(WEIGHTS_FILE);
    let bytes = std::fs::read(&path)
        .map_err(|e| ModelError::Checkpoint(format!("cannot read {}: {e}", path.display())))?;
    // The safetensors parser validates header and sizes; the unwind guard turns any residual
    // panic on hostile input into an error as well.
    let parsed = std::panic::catch_unwind(|| candle_core::safetensors::load_buffer(&bytes, device));
    match parsed {
        Ok(Ok(map)) => Ok(map),
        Ok(Err(e)) => Err(ModelError::Checkpoint(format!(
            "{} is corrupted or not a safetensors file: {e}",
            path.display()
        ))),
        Err(_) => Err(ModelError::Checkpoint(format!(
            "{} is corrupted (the parser failed)",
            path.display()
        ))),
    }
}

/// The model name a checkpoint directory gives: its last component, or `fallback`.
pub(crate) fn dir_name(dir: &Path, fallback: &str) -> String {
    dir.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| fallback.into())
}

/// The `architecture` field of a checkpoint directory's `config.json` (`rigidformer`,
/// `rigidformer-ensemble`, `physiformer`), read without parsing the rest.
pub fn read_architecture(dir: &Path) -> Result<String, ModelError> {
    /// Just the family of a `config.json`.
    #[derive(serde::Deserialize)]
    struct Family {
        architecture: String,
    }
    let family: Family = parse_config(dir, "configuration")?;
    Ok(family.architecture)
}

/// Loads a RigidFormer checkpoint; `trainable` keeps gradient tracking on the weights.
pub fn load_rigidformer(
    dir: &Path,
    device: &Device,
    trainable: bool,
) -> Result<RigidFormer, ModelError> {
    let config = read_config(dir)?;
    let weights = read_weights(dir, device)?;
    let store = ParamStore::loaded(weights, device, trainable);
    RigidFormer::from_store(dir_name(dir, RIGIDFORMER), config, store, device)
}

/// Writes the checkpoint files every model family shares into `dir` (created if needed):
/// `config` as pretty JSON in `config.json` and the parameters of `varmap` in
/// `model.safetensors`, stored as `dtype` on the CPU.
pub(crate) fn write_checkpoint(
    dir: &Path,
    config: &impl serde::Serialize,
    varmap: &VarMap,
    dtype: DType,
) -> Result<(), ModelError> {
    std::fs::create_dir_all(dir)?;
    let json = serde_json::to_string_pretty(config)
        .map_err(|e| ModelError::Internal(format!("config serialisation: {e}")))?;
    std::fs::write(dir.join(CONFIG_FILE), json + "\n")?;
    let data = varmap
        .data()
        .lock()
        .map_err(|_| ModelError::Internal("parameter map lock poisoned".into()))?
        .iter()
        .map(|(k, v)| {
            Ok((
                k.clone(),
                v.as_tensor().to_dtype(dtype)?.to_device(&Device::Cpu)?,
            ))
        })
        .collect::<Result<HashMap<String, Tensor>, ModelError>>()?;
    save_tensors(&data, &dir.join(WEIGHTS_FILE))
}

/// Writes `tensors` (any device; each is written as stored) to the safetensors file `path`,
/// replacing an existing file atomically: the bytes go to a sibling `.tmp` file that is then
/// renamed over `path`, so a reader never sees a partial file. The file gets the permissions
/// of any new file of the process (its umask); candle's own writer leaves every weights file
/// readable by its owner alone, which a model directory served by another user cannot be.
pub fn save_tensors(tensors: &HashMap<String, Tensor>, path: &Path) -> Result<(), ModelError> {
    let bytes = safetensors::serialize(tensors, None)
        .map_err(|e| ModelError::Internal(format!("serialising {}: {e}", path.display())))?;
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = std::path::PathBuf::from(tmp);
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)?;
    Ok(())
}

impl RigidFormer {
    /// Writes the checkpoint (f32 weights) to `dir`, creating it if needed.
    pub fn save(&self, dir: &Path) -> Result<(), ModelError> {
        self.save_with_dtype(dir, DType::F32)
    }

    /// Writes the checkpoint with weights stored as `dtype` (F32, F16 or BF16); `card.md` is
    /// written only if the directory has none (a hand-written card is kept).
    pub fn save_with_dtype(&self, dir: &Path, dtype: DType) -> Result<(), ModelError> {
        if !matches!(dtype, DType::F32 | DType::F16 | DType::BF16) {
            return Err(ModelError::InvalidInput(format!(
                "cannot store weights as {dtype:?}"
            )));
        }
        write_checkpoint(dir, self.config(), self.varmap(), dtype)?;
        let card = dir.join(CARD_FILE);
        if !card.exists() {
            std::fs::write(card, self.default_card(dtype))?;
        }
        Ok(())
    }

    /// A model card describing the architecture, sizes and the choices this implementation
    /// made where the paper leaves them open. Training data and evaluation are added by the
    /// trainer.
    pub fn default_card(&self, dtype: DType) -> String {
        let c = self.config();
        format!(
            "# {name}\n\nRigidFormer world model (object-centric transformer with anchors, ARoPE and \
differentiable Kabsch projection).\n\n## Architecture\n\n- parameters: {params}, stored as {dtype:?}\n\
- width {w}, {h} heads of {hd}, {l} blocks, {r} registers, SwiGLU hidden {f}, K = {k} anchors\n\
- encoder: point MLP to {c1}, set abstraction over {s} FPS centres x {g} neighbours to {c2}, \
second level to one token per object\n- anchor queries attend to decoder depths {taps:?}\n\
- data conventions: dt_frame {dt} s, gravity {grav:?} m/s^2, contact radius {cr} m, ground {gz:?}\n\n\
## Choices not fixed by the paper\n\n\
- Mass enters the features as ln(mass); all 12 features are standardised with constants in config.json.\n\
- FPS starts at the point farthest from the cloud centroid, so anchors do not depend on point order; \
anchors are the first K FPS points of the reference cloud, encoder centres the first {s}.\n\
- Anchor queries also receive their own object's final decoder token (a linear map of it is added), \
and ARoPE also rotates the anchor cross-attention (queries by their own anchor, keys by their object); \
each tapped depth is RMS-normalised and gets a learned depth embedding before the shared K/V projection.\n\
- Each FiLM pair is one MLP on tau = log2(dt_steps) giving (gamma - 1, beta), initialised near (1, 0).\n\
- The training loss divides differences by loss.scale = {ls} m before Smooth L1 (beta = {lb}).\n\n\
## Training and evaluation\n\nNot yet recorded.\n",
            name = self.name(),
            params = self.parameter_count(),
            w = c.width,
            h = c.heads,
            hd = c.head_dim(),
            l = c.blocks,
            r = c.registers,
            f = c.ffn_hidden,
            k = c.anchors,
            c1 = c.point_dim,
            s = c.sa_centres,
            g = c.sa_neighbours,
            c2 = c.sa_dim,
            taps = c.anchor_taps,
            dt = c.dt_frame,
            grav = c.gravity,
            cr = c.contact_radius,
            gz = c.ground_z,
            ls = c.loss.scale,
            lb = c.loss.beta,
        )
    }
}
