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
pub mod official;
pub mod rigid;
pub mod scene;

use std::collections::HashMap;
use std::path::Path;

use candle_core::{D, DType, Device, Tensor};
use candle_nn::VarMap;

use self::block::{AttentionKind, Block, modulate};
use self::config::{PHYSIFORMER, PhysiConfig};
use self::inputs::{
    Condition, DenoiseItem, PassInputs, Prepared, PreparedItem, PreparedScene, SceneLayout,
    assemble_prepared, build,
};
use self::official::{OfficialNet, OfficialScene};
use self::scene::MeshScene;
use crate::ModelError;
use crate::checkpoint::{dir_name, parse_config, write_checkpoint};
use crate::layers::{Init, Linear, Mlp, Mode, ParamStore, RmsNorm};

/// A PhysiFormer network (see the module docs): this crate's own, or the official
/// architecture of an imported checkpoint ([`official`]). Thread-safe.
pub struct PhysiFormer {
    name: String,
    config: PhysiConfig,
    device: Device,
    varmap: VarMap,
    net: Net,
}

/// Which network a [`PhysiFormer`] runs.
enum Net {
    Native(Box<Native>),
    Official(Box<OfficialNet>),
}

/// This crate's own network's weights.
struct Native {
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
        if let Some(o) = &config.official {
            let net = OfficialNet::new(o.clone(), &mut p)?;
            let varmap = p.finish()?;
            return Ok(PhysiFormer {
                name,
                config,
                device: device.clone(),
                varmap,
                net: Net::Official(Box::new(net)),
            });
        }
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
            net: Net::Native(Box::new(Native {
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
            })),
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

    /// This crate's own network, or an error for the official one (which serves inference
    /// only, through [`PhysiFormer::prepare`] and [`PhysiFormer::denoise_prepared`]).
    fn native(&self) -> candle_core::Result<&Native> {
        match &self.net {
            Net::Native(n) => Ok(n),
            Net::Official(_) => Err(candle_core::Error::Msg(
                "the official PhysiFormer network is served for inference only (no training, \
                 no padded passes)"
                    .into(),
            )),
        }
    }

    /// True for a network in the official architecture (an imported checkpoint).
    pub fn is_official(&self) -> bool {
        matches!(self.net, Net::Official(_))
    }

    /// The embedded frame-0 condition: embeddings of the positions and velocities plus the
    /// material MLP, `[B, 1, V, D]` (an embedded condition is returned as it is).
    fn embed_condition(&self, condition: &Condition) -> candle_core::Result<Tensor> {
        let n = self.native()?;
        match condition {
            Condition::Raw { x0, v0, material } => n
                .embed_x0
                .forward(x0)?
                .broadcast_add(&n.embed_v0.forward(v0)?)?
                .broadcast_add(&n.material.forward(material, false)?),
            Condition::Embedded(e) => Ok(e.clone()),
        }
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
        if let Net::Official(net) = &self.net {
            let s = net.prepare(scene, frames, &self.config, &self.device)?;
            return Ok(PreparedScene {
                kind: Prepared::Official(s),
            });
        }
        let layout = SceneLayout::new(&self.config, scene, frames)?;
        let embedded = self.embed_condition(&layout.raw_condition(&self.device)?)?;
        Ok(PreparedScene {
            kind: Prepared::Native { layout, embedded },
        })
    }

    /// One network evaluation of many prepared scenes, each at its own flow time: the
    /// predicted clean trajectory of every item, `[frames, V, 3]` flattened, metres. Equal to
    /// [`PhysiFormer::denoise`] on the same scenes, without laying out or validating again
    /// what does not change between steps. The official network evaluates the scenes one
    /// after the other.
    pub fn denoise_prepared(
        &self,
        items: &[PreparedItem<'_>],
    ) -> Result<Vec<Vec<f32>>, ModelError> {
        if let Net::Official(net) = &self.net {
            return items
                .iter()
                .map(|it| match &it.scene.kind {
                    Prepared::Official(s) => official_call(net, s, it.z, it.t),
                    Prepared::Native { .. } => Err(ModelError::InvalidInput(
                        "the scene was prepared for another network".into(),
                    )),
                })
                .collect();
        }
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
        let n = self.native()?;
        let (b, r) = (inp.b, self.config.registers.max(1));
        let cond = match &inp.condition {
            Condition::Embedded(e) => e.clone(),
            raw => self.embed_condition(raw)?,
        };
        let mut x = n.embed_z.forward(&inp.z)?.broadcast_add(&cond)?;
        let c = n
            .time
            .forward(&time_features(&inp.time, self.config.time_features)?, false)?
            .silu()?;
        let mut reg = n
            .registers
            .unsqueeze(0)?
            .broadcast_as((b, r, self.config.width))?
            .contiguous()?;
        for blk in &n.blocks {
            (x, reg) = blk.forward(&x, &reg, &c, inp, mode)?;
        }
        let m = n.final_ada.forward(&c)?.chunk(2, D::Minus1)?;
        let y = modulate(&n.final_norm.forward(&x, mode)?, &m[0], &m[1])?;
        let correction = n.head.forward(&y)?;
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
        if self.is_official() {
            return items
                .iter()
                .map(|it| {
                    let s = self.prepare(it.scene, it.frames)?;
                    let item = PreparedItem {
                        scene: &s,
                        z: it.z,
                        t: it.t,
                    };
                    Ok(self.denoise_prepared(&[item])?.remove(0))
                })
                .collect();
        }
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
        if !self.native()?.head.w.is_variable() {
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

/// One call of the official network on a prepared scene, in metres: `z` is mapped to the
/// network's coordinates and the prediction back.
fn official_call(
    net: &OfficialNet,
    s: &OfficialScene,
    z: &[f32],
    t: f32,
) -> Result<Vec<f32>, ModelError> {
    let n = s.frames * s.vertices * 3;
    if z.len() != n {
        return Err(ModelError::InvalidInput(format!(
            "the noisy trajectory holds {} values, expected {n}",
            z.len()
        )));
    }
    let zn: Vec<f32> = z
        .iter()
        .enumerate()
        .map(|(i, x)| (x - s.offset[i % 3]) / s.scale[i % 3])
        .collect();
    let out = net
        .forward(s, &zn, t)?
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
