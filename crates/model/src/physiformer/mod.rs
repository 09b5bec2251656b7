//! PhysiFormer: a diffusion Transformer that samples whole mesh trajectories (rigid and
//! elastic objects) in world coordinates with flow matching (`docs/physiformer.md`).
//!
//! Tokens are one per vertex per frame: the noisy position embedded linearly, plus the
//! embeddings of the vertex's frame-0 position and velocity and of its object's material.
//! Learned registers join every attention group. Blocks cycle spatial / temporal /
//! per-object / temporal attention ([`block`]), modulated by the flow time (adaLN-Zero).
//! The head predicts the clean trajectory (x-prediction) as a displacement from frame 0.
//!
//! Modules: [`config`] (sizes and presets), [`scene`] (a scene's condition), [`inputs`]
//! (padded pass layout, scenes prepared once per sample), [`block`], [`flow`] (training loss
//! and the Heun sampler), [`rigid`] (rigid fits of sampled vertices).
//!
//! Shapes: `B` scenes in a pass, `T` frames and `V` vertices (the largest of the pass), `R`
//! registers, `D = width`.

pub mod block;
pub mod config;
pub mod flow;
pub mod inputs;
pub mod rigid;
pub mod scene;

use std::collections::HashMap;
use std::path::Path;

use candle_core::{D, DType, Device, Tensor};
use candle_nn::VarMap;

use self::block::{AttentionKind, Block, modulate};
use self::config::{PHYSIFORMER, PhysiConfig};
use self::inputs::{
    Condition, DenoiseItem, PassInputs, PreparedItem, PreparedScene, SceneLayout,
    assemble_prepared, build,
};
use self::scene::MeshScene;
use crate::ModelError;
use crate::checkpoint::{dir_name, parse_config, write_checkpoint};
use crate::layers::{Init, Linear, Mlp, Mode, ParamStore, RmsNorm};

/// The PhysiFormer network (see the module docs). Thread-safe.
pub struct PhysiFormer {
    name: String,
    config: PhysiConfig,
    device: Device,
    varmap: VarMap,
    embed_z: Linear,
    embed_x0: Linear,
    embed_v0: Linear,
    material: Mlp,
    time: Mlp,
    registers: Tensor,
    blocks: Vec<Block>,
    final_norm: RmsNorm,
    final_ada: Linear,
    head: Linear,
}

/// Sinusoidal features of the flow time: `t [B]` -> `[B, n]` (frequencies geometric from 1 to
/// 1000, the time scaled by 1000 first).
fn time_features(t: &Tensor, n: usize) -> candle_core::Result<Tensor> {
    let half = n / 2;
    let freqs: Vec<f32> = (0..half)
        .map(|i| (-(1000f32).ln() * i as f32 / half as f32).exp())
        .collect();
    let f = Tensor::from_vec(freqs, (1, half), t.device())?;
    let arg = (t.unsqueeze(1)? * 1000.0)?.broadcast_mul(&f)?;
    Tensor::cat(&[arg.cos()?, arg.sin()?], D::Minus1)
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
        let w = config.width;
        let blocks = (0..config.blocks)
            .map(|i| {
                Block::new(
                    &mut p,
                    &format!("blocks.{i}"),
                    AttentionKind::of_block(i),
                    w,
                    config.heads,
                    config.ffn_hidden,
                    config.norm_eps,
                )
            })
            .collect::<Result<Vec<_>, _>>()?;
        let embed_z = p.linear("embed.z", 3, w, true)?;
        let embed_x0 = p.linear("embed.x0", 3, w, false)?;
        let embed_v0 = p.linear("embed.v0", 3, w, false)?;
        let material = Mlp::new(&mut p, "embed.material", 2, config.material_hidden, w)?;
        let time = Mlp::new(&mut p, "embed.time", config.time_features, w, w)?;
        let registers = p.get(
            "registers",
            &[config.registers.max(1), w],
            Init::Uniform(0.02),
        )?;
        let final_norm = p.rms_norm("final.norm", w, config.norm_eps)?;
        let final_ada = Linear::new(
            p.get("final.ada.weight", &[2 * w, w], Init::Const(0.0))?,
            Some(p.get("final.ada.bias", &[2 * w], Init::Const(0.0))?),
        );
        let head = Linear::new(
            p.get("final.head.weight", &[3, w], Init::Const(0.0))?,
            Some(p.get("final.head.bias", &[3], Init::Const(0.0))?),
        );
        let varmap = p.finish()?;
        Ok(PhysiFormer {
            name,
            config,
            device: device.clone(),
            varmap,
            embed_z,
            embed_x0,
            embed_v0,
            material,
            time,
            registers,
            blocks,
            final_norm,
            final_ada,
            head,
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

    /// The embedded frame-0 condition: embeddings of the positions and velocities plus the
    /// material MLP, `[B, 1, V, D]` (an embedded condition is returned as it is).
    fn embed_condition(&self, condition: &Condition) -> candle_core::Result<Tensor> {
        match condition {
            Condition::Raw { x0, v0, material } => self
                .embed_x0
                .forward(x0)?
                .broadcast_add(&self.embed_v0.forward(v0)?)?
                .broadcast_add(&self.material.forward(material, false)?),
            Condition::Embedded(e) => Ok(e.clone()),
        }
    }

    /// Prepares `scene` for sampling `frames` frames (frame 0 included): validates it once and
    /// lays out what every denoising step of it shares (see [`PreparedScene`]), for
    /// [`PhysiFormer::denoise_prepared`].
    pub fn prepare(&self, scene: &MeshScene, frames: usize) -> Result<PreparedScene, ModelError> {
        scene.validate(&self.config)?;
        let layout = SceneLayout::new(&self.config, scene, frames)?;
        let embedded = self.embed_condition(&layout.raw_condition(&self.device)?)?;
        Ok(PreparedScene { layout, embedded })
    }

    /// One network evaluation of many prepared scenes, each at its own flow time: the
    /// predicted clean trajectory of every item, `[frames, V, 3]` flattened, metres. Equal to
    /// [`PhysiFormer::denoise`] on the same scenes, without laying out or validating again
    /// what does not change between steps.
    pub fn denoise_prepared(
        &self,
        items: &[PreparedItem<'_>],
    ) -> Result<Vec<Vec<f32>>, ModelError> {
        let inp = assemble_prepared(&self.config, items, &self.device)?;
        let sizes: Vec<(usize, usize)> = items
            .iter()
            .map(|it| (it.scene.frames(), it.scene.vertices()))
            .collect();
        self.run_pass(&inp, &sizes)
    }

    /// Runs a laid-out pass and cuts each scene's `(frames, vertices)` out of the padded
    /// output.
    fn run_pass(
        &self,
        inp: &PassInputs,
        sizes: &[(usize, usize)],
    ) -> Result<Vec<Vec<f32>>, ModelError> {
        let out = self
            .forward(inp, Mode::Inference)?
            .to_device(&Device::Cpu)?
            .to_dtype(DType::F32)?;
        let (t, v) = (inp.t, inp.v);
        let data = out.flatten_all()?.to_vec1::<f32>()?;
        Ok(sizes
            .iter()
            .enumerate()
            .map(|(s, &(frames, nv))| {
                let mut o = Vec::with_capacity(frames * nv * 3);
                for fr in 0..frames {
                    let at = ((s * t + fr) * v) * 3;
                    o.extend_from_slice(&data[at..at + nv * 3]);
                }
                o
            })
            .collect())
    }

    /// The network on a laid-out pass: predicted clean trajectories `[B, T, V, 3]`, metres.
    pub(crate) fn forward(&self, inp: &PassInputs, mode: Mode) -> candle_core::Result<Tensor> {
        let (b, r) = (inp.b, self.config.registers.max(1));
        let cond = match &inp.condition {
            Condition::Embedded(e) => e.clone(),
            raw => self.embed_condition(raw)?,
        };
        let mut x = self.embed_z.forward(&inp.z)?.broadcast_add(&cond)?;
        let c = self
            .time
            .forward(&time_features(&inp.time, self.config.time_features)?, false)?
            .silu()?;
        let mut reg = self
            .registers
            .unsqueeze(0)?
            .broadcast_as((b, r, self.config.width))?
            .contiguous()?;
        for blk in &self.blocks {
            (x, reg) = blk.forward(&x, &reg, &c, inp, mode)?;
        }
        let m = self.final_ada.forward(&c)?.chunk(2, D::Minus1)?;
        let y = modulate(&self.final_norm.forward(&x, mode)?, &m[0], &m[1])?;
        let correction = self.head.forward(&y)?;
        let correction = match self.config.correction_ramp_frames {
            0 => correction,
            n => correction.broadcast_mul(&correction_ramp(inp.t, n, x.device())?)?,
        };
        correction.broadcast_add(&inp.prior)
    }

    /// One network evaluation of many scenes, each at its own flow time: the predicted clean
    /// trajectory of every item, `[frames, V, 3]` flattened, metres. Scenes must be valid
    /// ([`scene::MeshScene::validate`]).
    pub fn denoise(&self, items: &[DenoiseItem<'_>]) -> Result<Vec<Vec<f32>>, ModelError> {
        for (i, it) in items.iter().enumerate() {
            it.scene.validate(&self.config).map_err(|e| match e {
                ModelError::InvalidInput(m) => ModelError::InvalidInput(format!("scene {i}: {m}")),
                other => other,
            })?;
        }
        let inp = build(&self.config, items, &self.device)?;
        let sizes: Vec<(usize, usize)> = items
            .iter()
            .map(|it| (it.frames, it.scene.vertices()))
            .collect();
        self.run_pass(&inp, &sizes)
    }

    /// Writes `config.json` and `model.safetensors` (f32) into `dir`, creating it.
    pub fn save(&self, dir: &Path) -> Result<(), ModelError> {
        write_checkpoint(dir, &self.config, &self.varmap, DType::F32)
    }

    /// Replaces every weight by the tensor of the same name in `weights` (e.g. EMA weights).
    /// Only for trainable models (`new`, or `load` with `trainable`): a frozen model keeps
    /// transposed copies of its weights for inference, which this would leave stale.
    pub fn set_weights(&self, weights: &HashMap<String, Tensor>) -> Result<(), ModelError> {
        if !self.head.w.is_variable() {
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

/// The weight `min(1, f / n)` of the network's correction at frame `f` of `frames`
/// (`PhysiConfig::correction_ramp_frames`): `[1, frames, 1, 1]`.
fn correction_ramp(frames: usize, n: usize, device: &Device) -> candle_core::Result<Tensor> {
    let w: Vec<f32> = (0..frames)
        .map(|f| (f as f32 / n as f32).min(1.0))
        .collect();
    Tensor::from_vec(w, (1, frames, 1, 1), device)
}

/// Reads and validates a PhysiFormer `config.json` from a checkpoint directory.
pub fn read_physi_config(dir: &Path) -> Result<PhysiConfig, ModelError> {
    let config: PhysiConfig = parse_config(dir, "PhysiFormer configuration")?;
    config.validate()?;
    Ok(config)
}
