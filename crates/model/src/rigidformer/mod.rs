//! RigidFormer: hierarchical point encoder -> object decoder with registers, gated attention,
//! FiLM on log2(dt_steps) and ARoPE -> anchor queries cross-attending to several decoder
//! depths -> per-anchor accelerations -> Verlet -> Kabsch -> rigid poses
//! (`docs/rigidformer.md`).
//!
//! One module per stage: `encoder`, `decoder`, `anchor_head` (with `attention` shared
//! by both), `projection` (inference) and [`train`] (loss). `inputs` lays a batch out for
//! one pass; [`features`] defines the per-point inputs.
//!
//! Shapes: `B` scenes, `O` objects in the batch, `M` the largest object count, `T = M + R`
//! decoder tokens, `N` the largest point count, `K` anchors, `S` set-abstraction centres, `G`
//! neighbours per centre, `C1 = point_dim`, `C2 = sa_dim`, `D = width`, `H` heads, `P =
//! rope_dim / 2` rotary pairs.

pub(crate) mod anchor_head;
pub(crate) mod attention;
mod base_prediction;
pub(crate) mod batch;
pub(crate) mod decoder;
pub(crate) mod encoder;
pub mod features;
pub(crate) mod free_flight;
mod gradient;
pub(crate) mod inertia;
pub(crate) mod inputs;
pub(crate) mod messages;
pub(crate) mod pose_inputs;
pub(crate) mod projection;
pub(crate) mod summary;
pub mod train;
mod widen;
pub(crate) mod wrench;

use std::time::{Duration, Instant};

use candle_core::{Device, Tensor};
use candle_nn::VarMap;

use self::anchor_head::AnchorHead;
use self::batch::{BatchInputs, SceneRequest};
use self::decoder::Decoder;
use self::encoder::Encoder;
use self::inputs::build_inputs;
use self::messages::ContactMessages;
use self::summary::SummaryMlp;
use crate::api::{Pose, StepItem, WorldModel};
use crate::batching::PassBudget;
use crate::config::RIGIDFORMER;
use crate::layers::{Exec, Mode, ParamStore};
use crate::prepare::{PreparedScene, prepare_scene, validate_state};
use crate::scene_threads::run_scene_groups;
use crate::{ModelConfig, ModelError, ObjectInput};

pub use self::train::{TrainItem, TrainOutput};

/// Default object budget of one forward pass inside [`WorldModel::step`] (per scene group,
/// [`crate::scene_threads`]): larger batches are split into consecutive passes of whole
/// scenes. Measured with scene groups on 2 cores: 64 streams of 10-object scenes in process
/// ran at 459 scene-steps/s with 32-scene passes per thread and 592 with 16, as a pass's
/// intermediates outgrow the core's L2 cache.
pub const DEFAULT_MAX_PASS_OBJECTS: usize = 160;

/// Wall-clock time of each phase of one batched step (CPU; on an accelerator the phases are
/// not synchronised, so only the total is meaningful there).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepProfile {
    /// Validation, world points, contact features, feature and geometry assembly.
    pub features: Duration,
    /// Point MLP and both set-abstraction levels (one token per object).
    pub encoder: Duration,
    /// Object decoder blocks.
    pub decoder: Duration,
    /// AVP, anchor queries, multi-scale cross-attention, acceleration head.
    pub anchors: Duration,
    /// Verlet, Kabsch and pose assembly.
    pub projection: Duration,
}

impl StepProfile {
    /// Sum of all phases.
    pub fn total(&self) -> Duration {
        self.features + self.encoder + self.decoder + self.anchors + self.projection
    }
}

/// The RigidFormer world model (see the module docs). Thread-safe; implements [`WorldModel`].
pub struct RigidFormer {
    name: String,
    config: ModelConfig,
    device: Device,
    varmap: VarMap,
    encoder: Encoder,
    decoder: Decoder,
    anchors: AnchorHead,
    summaries: Vec<SummaryMlp>,
    messages: Option<ContactMessages>,
    max_pass_objects: usize,
    fused_kernels: bool,
    scene_threads: bool,
}

/// A host buffer as an f32 tensor of `shape` on `device`.
pub(crate) fn host_tensor(
    device: &Device,
    data: &[f32],
    shape: &[usize],
) -> candle_core::Result<Tensor> {
    Tensor::from_slice(data, shape, &Device::Cpu)?.to_device(device)
}

/// Host row indices as a u32 tensor `[len]` on `device`.
pub(crate) fn host_index(device: &Device, data: &[u32]) -> candle_core::Result<Tensor> {
    Tensor::from_slice(data, data.len(), &Device::Cpu)?.to_device(device)
}

impl RigidFormer {
    /// A randomly initialised model (deterministic for a given `seed`), trainable.
    pub fn new(config: ModelConfig, seed: u64, device: &Device) -> Result<RigidFormer, ModelError> {
        config.validate()?;
        let store = ParamStore::random(seed, device, true);
        Self::from_store(RIGIDFORMER.into(), config, store, device)
    }

    /// A randomly initialised model for inference only, as a loaded checkpoint is (weights are
    /// constants, not training variables, so layers may keep inference copies of them);
    /// otherwise the same network and weights as [`RigidFormer::new`] with the same `seed`.
    pub fn new_frozen(
        config: ModelConfig,
        seed: u64,
        device: &Device,
    ) -> Result<RigidFormer, ModelError> {
        config.validate()?;
        let store = ParamStore::random(seed, device, false);
        Self::from_store(RIGIDFORMER.into(), config, store, device)
    }

    /// Builds the network from a parameter store (random or loaded). Parameters are created in
    /// a fixed order (encoder, decoder, anchor head with the optional contact wrench, then the
    /// optional summaries and contact messages) so a seed always gives the same weights, with or without them.
    pub(crate) fn from_store(
        name: String,
        config: ModelConfig,
        mut p: ParamStore,
        device: &Device,
    ) -> Result<RigidFormer, ModelError> {
        config.validate()?;
        let encoder = Encoder::new(&mut p, &config)?;
        let decoder = Decoder::new(&mut p, &config)?;
        let anchors = AnchorHead::new(&mut p, &config, device)?;
        let summaries = SummaryMlp::all(&mut p, &config)?;
        let messages = match config.dynamics.contact_messages {
            true => Some(ContactMessages::new(&mut p, &config, device)?),
            false => None,
        };
        Ok(RigidFormer {
            name,
            config,
            device: device.clone(),
            varmap: p.finish()?,
            encoder,
            decoder,
            anchors,
            summaries,
            messages,
            max_pass_objects: DEFAULT_MAX_PASS_OBJECTS,
            fused_kernels: true,
            scene_threads: true,
        })
    }

    /// Sets the object budget of one forward pass (at least one scene always runs per pass).
    /// Results do not depend on it.
    pub fn with_max_pass_objects(mut self, objects: usize) -> RigidFormer {
        self.max_pass_objects = objects.max(1);
        self
    }

    /// Allows (the default) or forbids the fused CPU kernels of [`crate::kernels`]; without
    /// them every layer runs as a composition of candle ops, as on other devices. Results agree
    /// within float rounding; this exists to compare the two.
    pub fn with_fused_kernels(mut self, fused: bool) -> RigidFormer {
        self.fused_kernels = fused;
        self
    }

    /// Allows (the default) or forbids running a batch's scenes as concurrent groups, one per
    /// compute thread ([`crate::scene_threads`]; CPU only). Without it every operation of the
    /// batch is split across the threads instead. Results agree within float rounding (each
    /// group pads to its own largest scene); this exists to compare the two.
    pub fn with_scene_threads(mut self, on: bool) -> RigidFormer {
        self.scene_threads = on;
        self
    }

    /// Changes, through `edit`, any switch of the dynamics and the loss that leaves the weights'
    /// shapes alone (the Verlet bases, scene-relative mass, the kinematic lead, the free-flight
    /// gate, the loss's constants): the one way a trainer applies a configuration's switches to
    /// a loaded model. Refuses an edit that turns an input group or a unit ([`crate::ModelUnit`])
    /// on or off, which changes the network's parameters (widen the model for those:
    /// [`RigidFormer::widened_with_inputs`], [`RigidFormer::widened_with_unit`]).
    pub fn with_settings(
        mut self,
        edit: impl FnOnce(&mut crate::DynamicsConfig, &mut crate::LossConfig),
    ) -> Result<RigidFormer, ModelError> {
        let before = self.config.dynamics.clone();
        edit(&mut self.config.dynamics, &mut self.config.loss);
        let d = &self.config.dynamics;
        let inputs_changed = crate::InputGroup::ALL
            .iter()
            .any(|g| g.enabled(d) != g.enabled(&before));
        let units_changed = crate::ModelUnit::ALL
            .iter()
            .any(|u| u.enabled(d) != u.enabled(&before));
        if inputs_changed || units_changed {
            return Err(ModelError::InvalidInput(
                "a settings edit may not switch an input group or a unit (they need widening)"
                    .into(),
            ));
        }
        Ok(self)
    }

    /// Sets the model's name (normally its checkpoint directory name).
    pub fn with_name(mut self, name: impl Into<String>) -> RigidFormer {
        self.name = name.into();
        self
    }

    /// The trainable parameters, by name (for AdamW and for saving).
    pub fn varmap(&self) -> &VarMap {
        &self.varmap
    }

    /// The device the weights live on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Number of scalar parameters.
    pub fn parameter_count(&self) -> usize {
        self.varmap.all_vars().iter().map(|v| v.elem_count()).sum()
    }

    /// True for parameters that conventionally get no weight decay (norm scales, biases,
    /// registers, embeddings, the AVP bandwidth).
    pub fn is_no_decay(name: &str) -> bool {
        name.ends_with(".bias")
            || name.contains("norm")
            || name.contains("registers")
            || name.contains("embedding")
            || name.contains("log_sigma")
    }

    /// The network from assembled inputs to accelerations `[O, K, 3]` (m/step^2).
    fn network(
        &self,
        inp: &BatchInputs,
        mode: Mode,
        profile: Option<&mut StepProfile>,
    ) -> Result<Tensor, ModelError> {
        let exec = Exec {
            mode,
            fused: self.fused_kernels && self.device.is_cpu(),
        };
        self.network_exec(inp, exec, profile)
    }

    /// [`RigidFormer::network`] with the kernels chosen by `exec`.
    fn network_exec(
        &self,
        inp: &BatchInputs,
        exec: Exec,
        profile: Option<&mut StepProfile>,
    ) -> Result<Tensor, ModelError> {
        let t0 = Instant::now();
        let (h, tokens) = self
            .encoder
            .forward(inp, &self.device, exec, self.messages.as_ref())?;
        let mut tokens = tokens;
        for s in &self.summaries {
            tokens = s.add_to(inp, &tokens, &self.device, exec)?;
        }
        let t1 = Instant::now();
        let decoded = self.decoder.forward(inp, &tokens, exec, &self.device)?;
        let t2 = Instant::now();
        let acc = self
            .anchors
            .forward(&self.config, inp, &h, &decoded, exec)?;
        if let Some(p) = profile {
            p.encoder += t1 - t0;
            p.decoder += t2 - t1;
            p.anchors += t2.elapsed();
        }
        Ok(acc)
    }

    fn requests<'a>(&self, batch: &[StepItem<'a>]) -> Result<Vec<SceneRequest<'a>>, ModelError> {
        batch
            .iter()
            .enumerate()
            .map(|(i, it)| {
                let what = format!("batch[{i}]");
                let scene = prepared_for(&self.config, it.scene, &what)?;
                let state = validate_state(scene, it.state, it.dt_steps, &what)?;
                Ok(SceneRequest {
                    scene,
                    previous: state.previous,
                    current: state.current,
                    earlier: state.earlier,
                    dt_steps: it.dt_steps,
                })
            })
            .collect()
    }

    /// [`WorldModel::step`] with per-phase wall-clock times added to `profile`.
    pub fn step_profiled(
        &self,
        batch: &[StepItem<'_>],
        profile: &mut StepProfile,
    ) -> Result<Vec<Vec<Pose>>, ModelError> {
        self.step_mode(batch, Mode::Inference, Some(profile))
    }

    /// One batched step with an explicit kernel [`Mode`] (the training kernels give the same
    /// result up to rounding; used to test that).
    pub fn step_mode(
        &self,
        batch: &[StepItem<'_>],
        mode: Mode,
        mut profile: Option<&mut StepProfile>,
    ) -> Result<Vec<Vec<Pose>>, ModelError> {
        if batch.is_empty() {
            return Ok(Vec::new());
        }
        let t0 = Instant::now();
        let requests = self.requests(batch)?;
        if let Some(p) = profile.as_deref_mut() {
            p.features += t0.elapsed();
        }
        // Split into passes of whole scenes under the object budget (the one batching rule).
        let objects: Vec<usize> = batch.iter().map(|it| it.scene.len()).collect();
        let passes = |range: std::ops::Range<usize>, mut profile: Option<&mut StepProfile>| {
            let mut out = Vec::with_capacity(range.len());
            for pass in PassBudget::objects(self.max_pass_objects).plan(&objects[range.clone()]) {
                let pass = range.start + pass.start..range.start + pass.end;
                out.extend(self.step_pass(&requests[pass], mode, profile.as_deref_mut())?);
            }
            Ok(out)
        };
        // Groups of scenes on their own threads (not with a profile: phases would overlap).
        if self.scene_threads && profile.is_none() && self.device.is_cpu() {
            return run_scene_groups(&objects, |range| passes(range, None));
        }
        passes(0..batch.len(), profile)
    }

    fn step_pass(
        &self,
        requests: &[SceneRequest<'_>],
        mode: Mode,
        mut profile: Option<&mut StepProfile>,
    ) -> Result<Vec<Vec<Pose>>, ModelError> {
        let t0 = Instant::now();
        let inp = build_inputs(&self.config, requests)?;
        let t1 = Instant::now();
        let acc = self.network(&inp, mode, profile.as_deref_mut())?;
        let acc: Vec<f32> = acc.flatten_all()?.to_device(&Device::Cpu)?.to_vec1()?;
        let t2 = Instant::now();
        let out = projection::project_poses(&self.config, &inp, &acc)?;
        if let Some(p) = profile {
            p.features += t1 - t0;
            p.projection += t2.elapsed();
        }
        Ok(out)
    }
}

/// The preparation of `scene` for a model with `cfg`'s anchor and grouping sizes (the scene
/// itself or one an ensemble attached); fails if it has none.
fn prepared_for<'a>(
    cfg: &ModelConfig,
    scene: &'a PreparedScene,
    what: &str,
) -> Result<&'a PreparedScene, ModelError> {
    let key = cfg.prepared_key();
    scene.for_key(key).ok_or_else(|| {
        ModelError::InvalidInput(format!(
            "{what}: the scene was prepared for a model with {:?}, this model uses {key:?}",
            scene.key
        ))
    })
}

impl WorldModel for RigidFormer {
    fn name(&self) -> &str {
        &self.name
    }

    fn config(&self) -> &ModelConfig {
        &self.config
    }

    fn prepare(&self, objects: Vec<ObjectInput>) -> Result<PreparedScene, ModelError> {
        prepare_scene(&self.config, objects)
    }

    fn step(&self, batch: &[StepItem<'_>]) -> Result<Vec<Vec<Pose>>, ModelError> {
        self.step_mode(batch, Mode::Inference, None)
    }

    fn path_gradients(
        &self,
        items: &[crate::GradientItem<'_>],
    ) -> Result<Vec<Vec<crate::PathGradient>>, ModelError> {
        self.gradients(items)
    }
}
