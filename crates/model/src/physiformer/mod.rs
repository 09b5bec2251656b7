//! PhysiFormer: a diffusion Transformer that samples whole mesh trajectories (rigid and
//! elastic objects) in world coordinates with flow matching (`docs/physiformer.md`).
//!
//! One network, in the official PhysiFormer architecture ([`official`]): one token per vertex
//! per frame (the noisy position embedded, plus the frame-0 condition and the material), a
//! prefix of register (and scene) tokens, blocks cycling spatial / temporal / per-object /
//! temporal attention with rotary codes, modulated by the flow time (adaLN-Zero), and a head
//! that predicts the clean trajectory (x-prediction). Published checkpoints load as they are
//! ([`PhysiFormer::import_official`]); this crate's own checkpoints are small configurations
//! of the same network that correct a trajectory prior ([`config::TrajectoryPrior`]).
//!
//! Modules: [`config`] (sizes, options and presets), [`scene`] (a scene's condition),
//! [`inputs`] (evaluation items, scenes prepared once per sample), [`prior`] (the trajectory
//! prior), [`flow`] (training loss and the Heun sampler), [`rigid`] (rigid fits of sampled
//! vertices).
//!
//! Shapes: `F` frames and `V` vertices of a scene.

pub mod config;
pub mod flow;
pub mod inputs;
pub mod official;
pub mod prior;
pub mod rigid;
pub mod scene;

use std::collections::HashMap;
use std::path::Path;

use candle_core::{DType, Device, Tensor};
use candle_nn::VarMap;

use self::config::{PHYSIFORMER, PhysiConfig};
use self::inputs::{DenoiseItem, PreparedItem, PreparedScene};
use self::official::{OfficialNet, OfficialScene};
use self::scene::MeshScene;
use crate::ModelError;
use crate::checkpoint::{dir_name, parse_config, write_checkpoint};
use crate::layers::{Mode, ParamStore};

/// A PhysiFormer network (see the module docs). Thread-safe.
pub struct PhysiFormer {
    name: String,
    config: PhysiConfig,
    device: Device,
    varmap: VarMap,
    net: Box<OfficialNet>,
    /// The weights are training variables (`new`, or `load` with `trainable`).
    trainable: bool,
}

impl PhysiFormer {
    /// A new network with seeded random weights (adaLN gates and the head start at zero, so
    /// the untrained model predicts that nothing moves).
    pub fn new(
        name: impl Into<String>,
        config: PhysiConfig,
        seed: u64,
        device: &Device,
    ) -> Result<PhysiFormer, ModelError> {
        config.validate()?;
        let store = ParamStore::random(seed, device, true);
        PhysiFormer::from_store(name.into(), config, store, device)
    }

    /// Loads `config.json` and `model.safetensors` from a checkpoint directory; `trainable`
    /// keeps gradient tracking on the weights.
    pub fn load(dir: &Path, device: &Device, trainable: bool) -> Result<PhysiFormer, ModelError> {
        let config = read_physi_config(dir)?;
        let weights = crate::checkpoint::read_weights(dir, device)?;
        let store = ParamStore::loaded(weights, device, trainable);
        PhysiFormer::from_store(dir_name(dir, PHYSIFORMER), config, store, device)
    }

    fn from_store(
        name: String,
        config: PhysiConfig,
        mut p: ParamStore,
        device: &Device,
    ) -> Result<PhysiFormer, ModelError> {
        let trainable = p.trainable();
        let net = OfficialNet::new(config.official.clone(), &mut p)?;
        let varmap = p.finish()?;
        Ok(PhysiFormer {
            name,
            config,
            device: device.clone(),
            varmap,
            net: Box::new(net),
            trainable,
        })
    }

    /// The model's name (its checkpoint directory's name).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Sizes and constants.
    pub fn config(&self) -> &PhysiConfig {
        &self.config
    }

    /// The device the weights live on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Every parameter by name (for optimisers and saving).
    pub fn varmap(&self) -> &VarMap {
        &self.varmap
    }

    /// Number of scalar parameters.
    pub fn parameter_count(&self) -> usize {
        self.varmap.all_vars().iter().map(|v| v.elem_count()).sum()
    }

    /// Prepares `scene` for sampling `frames` frames (frame 0 included): validates it once and
    /// lays out what every denoising step of it shares (see [`PreparedScene`]), for
    /// [`PhysiFormer::denoise_prepared`].
    pub fn prepare(&self, scene: &MeshScene, frames: usize) -> Result<PreparedScene, ModelError> {
        scene.validate(&self.config)?;
        if frames < 2 || frames > self.config.frames {
            return Err(ModelError::InvalidInput(format!(
                "frames: {frames} outside 2..={}",
                self.config.frames
            )));
        }
        let scene = self
            .net
            .prepare(scene, frames, &self.config, &self.device)?;
        Ok(PreparedScene { scene })
    }

    /// One network evaluation of many prepared scenes, each at its own flow time: the
    /// predicted clean trajectory of every item, `[frames, V, 3]` flattened, metres. Equal to
    /// [`PhysiFormer::denoise`] on the same scenes, without laying out or validating again
    /// what does not change between steps. The scenes are evaluated one after the other (a
    /// scene's tokens fill the matrix products; padding scenes to one size would not).
    pub fn denoise_prepared(
        &self,
        items: &[PreparedItem<'_>],
    ) -> Result<Vec<Vec<f32>>, ModelError> {
        items
            .iter()
            .map(|it| call(&self.net, &it.scene.scene, it.z, it.t))
            .collect()
    }

    /// One network evaluation of many scenes, each at its own flow time: the predicted clean
    /// trajectory of every item, `[frames, V, 3]` flattened, metres; the error of an invalid
    /// scene names its index.
    pub fn denoise(&self, items: &[DenoiseItem<'_>]) -> Result<Vec<Vec<f32>>, ModelError> {
        items
            .iter()
            .enumerate()
            .map(|(i, it)| {
                let s = self.prepare(it.scene, it.frames).map_err(|e| match e {
                    ModelError::InvalidInput(m) => {
                        ModelError::InvalidInput(format!("scene {i}: {m}"))
                    }
                    other => other,
                })?;
                call(&self.net, &s.scene, it.z, it.t)
            })
            .collect()
    }

    /// Imports a checkpoint of the official PhysiFormer code ([`official::import`]): a
    /// PyTorch `.pt` as its training writes it (EMA weights when `use_ema` and present), or a
    /// `.safetensors` export of its state dict with its training arguments as JSON in `args`.
    /// Writes a model directory (`config.json`, `model.safetensors`, `card.md`) at `out` and
    /// returns the loaded model. `max_objects` raises the scene object limit (default: the
    /// checkpoint's slots, at least 10, as the official demo runs).
    pub fn import_official(
        checkpoint: &Path,
        args: Option<&Path>,
        out: &Path,
        use_ema: bool,
        max_objects: Option<usize>,
        device: &Device,
    ) -> Result<PhysiFormer, ModelError> {
        let is_pt = checkpoint.extension().is_some_and(|e| e != "safetensors");
        let ckpt = if is_pt {
            if args.is_some() {
                return Err(ModelError::InvalidInput(
                    "--args is for a .safetensors export; a .pt carries its arguments".into(),
                ));
            }
            official::import::read_pt(checkpoint, use_ema)?
        } else {
            official::import::read_safetensors(checkpoint, args)?
        };
        let config = official::import::config_from(&ckpt, max_objects)?;
        let tensors = official::import::to_f32(ckpt.tensors.clone())?;
        let store = ParamStore::loaded(tensors, device, false);
        let model = PhysiFormer::from_store(dir_name(out, PHYSIFORMER), config, store, device)?;
        model.save(out)?;
        let origin = checkpoint.file_name().map_or_else(
            || checkpoint.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        let card = official::import::card(
            model.name(),
            &origin,
            &ckpt,
            &model.config,
            model.parameter_count(),
        );
        std::fs::write(out.join("card.md"), card)?;
        Ok(model)
    }

    /// Writes `config.json` and `model.safetensors` (f32) into `dir`, creating it.
    pub fn save(&self, dir: &Path) -> Result<(), ModelError> {
        write_checkpoint(dir, &self.config, &self.varmap, DType::F32)
    }

    /// Replaces every weight by the tensor of the same name in `weights` (e.g. EMA weights).
    /// Only for trainable models (`new`, or `load` with `trainable`): a frozen model keeps
    /// transposed copies of its weights for inference, which this would leave stale.
    pub fn set_weights(&self, weights: &HashMap<String, Tensor>) -> Result<(), ModelError> {
        if !self.trainable {
            return Err(ModelError::InvalidInput(
                "set_weights needs a trainable model (load it with trainable = true)".into(),
            ));
        }
        let data = self
            .varmap
            .data()
            .lock()
            .map_err(|_| ModelError::Internal("parameter map lock poisoned".into()))?;
        for (name, var) in data.iter() {
            let w = weights
                .get(name)
                .ok_or_else(|| ModelError::Internal(format!("no weight {name}")))?;
            var.set(w)?;
        }
        Ok(())
    }
}

/// One inference call of the network on a prepared scene, in metres: `z` is mapped to the
/// network's coordinates and the prediction back.
fn call(net: &OfficialNet, s: &OfficialScene, z: &[f32], t: f32) -> Result<Vec<f32>, ModelError> {
    let n = s.frames * s.vertices * 3;
    if z.len() != n {
        return Err(ModelError::InvalidInput(format!(
            "the noisy trajectory holds {} values, expected {n}",
            z.len()
        )));
    }
    if !(0.0..=1.0).contains(&t) {
        return Err(ModelError::InvalidInput(format!(
            "flow time {t} outside [0, 1]"
        )));
    }
    let zn = s.to_network(z);
    let out = net
        .forward(s, &zn, t, Mode::Inference)?
        .to_device(&Device::Cpu)?
        .to_dtype(DType::F32)?
        .flatten_all()?
        .to_vec1::<f32>()?;
    Ok(out
        .iter()
        .enumerate()
        .map(|(i, x)| x * s.scale[i % 3] + s.offset[i % 3])
        .collect())
}

/// Reads and validates a PhysiFormer `config.json` from a checkpoint directory.
pub fn read_physi_config(dir: &Path) -> Result<PhysiConfig, ModelError> {
    let config: PhysiConfig = parse_config(dir, "PhysiFormer configuration").map_err(|e| {
        let legacy = std::fs::read_to_string(dir.join(crate::checkpoint::CONFIG_FILE))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .is_some_and(|v| v.get("width").is_some() && v.get("official").is_none());
        if legacy {
            ModelError::Checkpoint(format!(
                "{}: a checkpoint of the network this crate ran before it adopted the official \
                 PhysiFormer architecture, which it no longer runs; retrain it \
                 (docs/physiformer.md) or import a published checkpoint",
                dir.display()
            ))
        } else {
            e
        }
    })?;
    config.validate()?;
    Ok(config)
}
