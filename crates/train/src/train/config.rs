//! Training configuration (`dynaserve train --config FILE`), read from TOML or JSON.
//!
//! Every knob has a default; a file only names what it changes. Unknown keys are rejected so a
//! misspelt knob is an error, not a silent default. `docs/training.md` lists the same knobs.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dynaserve_model::{
    DynamicsConfig, FeatureNormalization, InputGroup, LossConfig, ModelConfig, ModelUnit,
};
use serde::{Deserialize, Serialize};

use super::TrainError;

/// The whole training configuration: data, model, optimiser and run settings.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Where samples come from and how they are augmented.
    pub data: DataConfig,
    /// Which network to train.
    pub model: ModelSection,
    /// AdamW, schedule, clipping, batch size and length.
    pub optim: OptimConfig,
    /// Output directory, checkpoint cadence, logging, threads.
    pub run: RunConfig,
    /// The physics suite scored along the run (off by default).
    pub heldout: super::heldout::HeldoutConfig,
}

/// Data loading and augmentation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DataConfig {
    /// Training split directory (`manifest.json` + shards), relative to the working directory.
    pub train: PathBuf,
    /// Further split directories whose scenes join the training stream (e.g. the physics
    /// scenario mix beside MOVi-B); unless [`DataConfig::mix`] says otherwise, every scene
    /// of every directory is drawn equally often. They must share the first directory's frame
    /// interval and gravity.
    pub extra: Vec<PathBuf>,
    /// The share of the training samples drawn from each directory (`train`, then `extra` in
    /// order; relative weights, normalised to sum 1). Each sample draws its directory from
    /// these shares and takes that directory's next scene, so every batch mixes the
    /// directories. Empty (the default) keeps the pooled stream: all scenes in one epoch,
    /// shard after shard, each directory's share its share of the scenes.
    pub mix: Vec<f32>,
    /// Step sizes in frames, one drawn uniformly per sample (default {1, 2, 4}).
    pub step_sizes: Vec<u32>,
    /// Fewest surface points per object in a training sample (drawn uniformly per object).
    pub points_min: usize,
    /// Most surface points per object in a training sample (inclusive).
    pub points_max: usize,
    /// Draw each object's point subset (its size in `points_min..=points_max` and its points)
    /// once per scene instead of once per window: every window of a scene then shows the same
    /// cloud, as every step of a rollout does. Rotation, order, noise and the patch cut
    /// below still vary per window.
    pub points_per_scene: bool,
    /// Probability that an object additionally loses a contiguous patch of its points
    /// (a half-space cut, like an occluded view).
    pub point_drop_prob: f32,
    /// Largest fraction of an object's sampled points such a cut removes (uniform in
    /// `[0, point_drop_max]`).
    pub point_drop_max: f32,
    /// Rotate every sample by a uniform random angle about the gravity (z) axis.
    pub rotate_z: bool,
    /// Reflect half of the samples through a vertical plane (x -> -x, before the rotation
    /// about z): the mirror image of a rigid scene under gravity is an equally valid scene
    /// (its objects' clouds become their mirror images), so every recorded contact is seen
    /// in both handednesses.
    pub mirror: bool,
    /// Present the objects of every sample in a random order.
    pub shuffle_objects: bool,
    /// Standard deviation of Gaussian noise added to the input poses' translations (both
    /// observed frames, independently), metres. 0 disables. Targets are not perturbed, so the
    /// model learns to correct its inputs.
    pub noise_position: f32,
    /// Standard deviation of the random rotation (angle, radians, random axis) applied to the
    /// input poses, independently per frame. 0 disables.
    pub noise_rotation: f32,
    /// Probability that a sample's current pose is the model's own prediction instead of the
    /// recorded one ("pushforward"): the trainer steps the model (inference, no gradient) from
    /// the recorded poses at `t - 2k` and `t - k` and trains the step from there to the
    /// recorded pose at `t + k`, so the model learns to correct the errors it makes itself in
    /// a rollout. Only samples with `t >= 2k` qualify. 0 disables.
    pub pushforward: f32,
    /// Model steps `n` of a pushforward sample (1 to [`MAX_PUSHFORWARD_STEPS`]). With `n >= 2`
    /// the model steps from the recorded poses at `t - (n + 1)k` and `t - nk` to `t - (n - 1)k`,
    /// then on from its own predictions to `t`, and both observed poses of the sample are its
    /// own, as in a rollout past its `n`-th step; samples need `t >= (n + 1)k`. 1 (the default)
    /// replaces only the current pose.
    pub pushforward_steps: u32,
    /// Fraction of the samples whose window frame is drawn with probability proportional to
    /// its surprise (how far the objects' acceleration departs from the window before's: an
    /// impact, a pusher's first touch) instead of uniformly; see [`super::events`]. The other
    /// samples, and validation windows, stay uniform. 0 disables.
    pub event_share: f32,
    /// Fraction of the samples whose window frame is drawn from the end of an object's
    /// motion (the last frames of a roll, slide or tumble and the first steps at rest; see
    /// [`super::stops`]) instead of uniformly, among the samples `event_share` leaves
    /// uniform. Scenes where no object stops are drawn uniformly. Validation windows stay
    /// uniform. 0 disables.
    pub stop_share: f32,
    /// Windows carry the poses one step before the observed ones (`t - 2k`, noised like them)
    /// as `SceneState::earlier`, for models with history inputs; windows with `t < 2k` have
    /// none. Off keeps two observed frames (and every earlier configuration's sample stream).
    pub history: bool,
    /// Probability that a window's earlier poses are left out (the history then reads as
    /// unknown, as on the first step of a rollout from two poses), with `history`.
    pub history_drop: f32,
    /// Batches the loader thread prepares ahead of the trainer.
    pub prefetch: usize,
    /// Scenes read to fit the feature normalisation before training.
    pub norm_scenes: usize,
    /// Windows sampled per scene when fitting the normalisation.
    pub norm_windows: usize,
}

impl DataConfig {
    /// Checks shares for [`DataConfig::mix`] over `directories` directories: empty (the pooled
    /// stream), or one finite share >= 0 per directory, not all zero.
    pub fn check_mix(shares: &[f32], directories: usize) -> Result<(), TrainError> {
        if !shares.is_empty()
            && (shares.len() != directories
                || shares.iter().any(|w| !(w.is_finite() && *w >= 0.0))
                || shares.iter().all(|&w| w == 0.0))
        {
            return Err(TrainError::Config(format!(
                "data.mix {shares:?} must hold one share per directory ({directories}: train, then each extra), each finite and >= 0, not all 0"
            )));
        }
        Ok(())
    }
}

/// Most model steps a pushforward sample may take (`DataConfig::pushforward_steps`); each is
/// one more inference pass over the chosen samples.
pub const MAX_PUSHFORWARD_STEPS: u32 = 8;

impl Default for DataConfig {
    fn default() -> Self {
        DataConfig {
            train: PathBuf::from("data/movi-b/train"),
            extra: Vec::new(),
            mix: Vec::new(),
            step_sizes: vec![1, 2, 4],
            points_min: 128,
            points_max: 384,
            points_per_scene: false,
            point_drop_prob: 0.1,
            point_drop_max: 0.3,
            rotate_z: true,
            mirror: false,
            shuffle_objects: true,
            noise_position: 0.0,
            noise_rotation: 0.0,
            pushforward: 0.0,
            pushforward_steps: 1,
            event_share: 0.0,
            stop_share: 0.0,
            history: false,
            history_drop: 0.0,
            prefetch: 8,
            norm_scenes: 200,
            norm_windows: 4,
        }
    }
}

/// The network to train.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelSection {
    /// A preset of the model crate (`small`, `paper` or `tiny`); ignored when `config` is set.
    pub preset: String,
    /// Path of a `config.json` (a [`ModelConfig`]) to use instead of a preset, relative to
    /// the working directory unless absolute.
    pub config: Option<PathBuf>,
    /// Seed of the random initialisation.
    pub seed: u64,
    /// Fit the feature normalisation constants (12, or 15 with the contact velocity) from the
    /// training data before training (recorded in the checkpoint's `config.json`); otherwise
    /// keep the config's values.
    pub fit_normalization: bool,
    /// Start from the weights, configuration and normalisation of this model directory
    /// (a released model or a run's `checkpoint/`) instead of a random initialisation:
    /// fine-tuning. `preset`, `config`, `seed` and `fit_normalization` are then unused. The
    /// optimiser state starts fresh (warm-up and schedule as configured).
    pub init: Option<PathBuf>,
    /// The contact velocity inputs (`DynamicsConfig::contact_velocity`): unset keeps what the
    /// preset, config or `init` model has. `true` on an `init` model without them widens it
    /// (zero weights on the 3 new inputs, so it starts as the same function; its 12
    /// normalisation constants are kept and the 3 new ones fitted from the training data).
    /// `false` on an `init` model that has them is an error.
    pub contact_velocity: Option<bool>,
    /// The surface normal inputs (`DynamicsConfig::surface_normals`): unset keeps what the
    /// preset, config or `init` model has. `true` on an `init` model without them widens it
    /// (zero weights on the 7 new inputs, so it starts as the same function; its existing
    /// normalisation constants are kept and the 7 new ones fitted from the training data).
    /// `false` on an `init` model that has them is an error.
    pub surface_normals: Option<bool>,
    /// The history inputs (`DynamicsConfig::history`): unset keeps what the preset, config or
    /// `init` model has. `true` on an `init` model without them widens it (zero weights on the
    /// 3 new inputs; the 3 new normalisation constants fitted from the training data). Needs
    /// `data.history`. `false` on an `init` model that has them is an error.
    pub history: Option<bool>,
    /// The approach inputs (`DynamicsConfig::approach`): unset keeps what the preset, config
    /// or `init` model has. `true` on an `init` model without them widens it (zero weights on
    /// the 3 new inputs; the 3 new normalisation constants fitted from the training data).
    /// `false` on an `init` model that has them is an error.
    pub approach: Option<bool>,
    /// The contact partner inputs (`DynamicsConfig::contact_partner`): as `approach`, with 4
    /// new inputs.
    pub contact_partner: Option<bool>,
    /// The object state summary (`DynamicsConfig::object_summary`): unset keeps what the
    /// preset, config or `init` model has. `true` on an `init` model without it widens it
    /// (the summary MLP's last layer zero, so it starts as the same function; its first layer
    /// drawn from `seed`). `false` on an `init` model that has it is an error.
    pub object_summary: Option<bool>,
    /// The contact summary (`DynamicsConfig::contact_summary`), as `object_summary` for the
    /// object state summary: unset keeps what the model has, `true` widens an `init` model
    /// without it, `false` on one that has it is an error.
    pub contact_summary: Option<bool>,
    /// The contact wrench (`DynamicsConfig::contact_wrench`): unset keeps what the preset,
    /// config or `init` model has. `true` on an `init` model without one adds it (its output
    /// layer zero, so training starts from the same function; its other layers drawn from
    /// `seed`). `false` on an `init` model that has one is an error.
    pub contact_wrench: Option<bool>,
    /// The contact messages (`DynamicsConfig::contact_messages`), as `contact_wrench`: unset
    /// keeps what the model has, `true` adds them to an `init` model without them (output
    /// layer zero), `false` on one that has them is an error. Give them their own rate with
    /// `[optim.lr_scale]` `"messages."`.
    pub contact_messages: Option<bool>,
    /// The rigid Verlet base (`DynamicsConfig::rigid_extrapolation`): unset keeps what the
    /// preset, config or `init` model has; set, it switches the base of any of them (an `init`
    /// model keeps its weights and learns the new base's residual).
    pub rigid_extrapolation: Option<bool>,
    /// The floor-aware Verlet base (`DynamicsConfig::floor_base`): unset keeps what the preset,
    /// config or `init` model has; set, it switches the base of any of them (an `init` model
    /// keeps its weights and learns the new base's residual).
    pub floor_base: Option<bool>,
    /// Scene-relative mass (`DynamicsConfig::relative_mass`): unset keeps what the preset,
    /// config or `init` model has; set, it switches it on any of them (an `init` model keeps
    /// its weights and learns from the scaled masses).
    pub relative_mass: Option<bool>,
    /// Kinematic lead (`DynamicsConfig::kinematic_lead`): unset keeps what the preset, config
    /// or `init` model has; set, it switches it on any of them. On, a training window's
    /// kinematic objects are seen moving at the increment into their recorded next pose
    /// (`SceneState::lead_kinematic`), as a server session with actions shows them.
    pub kinematic_lead: Option<bool>,
    /// The Smooth L1 transition point of the loss (`LossConfig::beta`, in units of its
    /// 1 mm scale): unset keeps what the preset, config or `init` model has. Errors below it
    /// pull quadratically (weakly), errors above it linearly; a smaller value gives the
    /// sub-millimetre errors of resting objects a full L1 gradient.
    pub loss_beta: Option<f32>,
    /// Factor on the loss of objects at rest in their window (`LossConfig::rest_weight`;
    /// ground truth within 0.5 mm and 0.05 degrees a frame): unset keeps what the preset,
    /// config or `init` model has (1 unless set before). Above 1 it weighs the millimetre
    /// errors that make resting objects drift against those of impacts.
    pub rest_weight: Option<f32>,
    /// Factor on the loss of moving objects that touch another object at the window's current
    /// frame (`LossConfig::object_contact_weight`; a point within 0.1 m of another object's):
    /// unset keeps what the preset, config or `init` model has (1 unless set before).
    pub object_contact_weight: Option<f32>,
    /// Weight of the loss term on each object's rotation error (`LossConfig::rotation_weight`,
    /// `docs/rigidformer.md`): unset keeps what the preset, config or `init` model has (0, off,
    /// unless set before).
    pub rotation_weight: Option<f32>,
    /// Deepens the `init` model before training: one new decoder block after each of these
    /// block indices (0-based, distinct), each starting as the identity
    /// (`RigidFormer::deepened`), so training starts from the same function with more depth.
    /// Needs `init`; unset or empty keeps the depth.
    pub insert_blocks_after: Option<Vec<usize>>,
    /// Widens the `init` model's point encoder before training to `[point_dim, sa_dim]`
    /// channels (per-point MLP, which the anchors read too, and first set-abstraction level;
    /// `RigidFormer::widened_encoder`), new channels starting at zero so training starts from
    /// the same function. Needs `init`; unset keeps the widths.
    pub widen_encoder: Option<[usize; 2]>,
}

impl Default for ModelSection {
    fn default() -> Self {
        ModelSection {
            preset: "small".into(),
            config: None,
            seed: 0,
            fit_normalization: true,
            init: None,
            contact_velocity: None,
            surface_normals: None,
            history: None,
            approach: None,
            contact_partner: None,
            object_summary: None,
            contact_summary: None,
            contact_wrench: None,
            contact_messages: None,
            rigid_extrapolation: None,
            floor_base: None,
            relative_mass: None,
            kinematic_lead: None,
            loss_beta: None,
            rest_weight: None,
            object_contact_weight: None,
            rotation_weight: None,
            insert_blocks_after: None,
            widen_encoder: None,
        }
    }
}

impl ModelSection {
    /// Sets the switches that leave the weights' shapes alone, where this section sets them:
    /// `rigid_extrapolation`, `floor_base`, `relative_mass`, `kinematic_lead`, `loss_beta`,
    /// `rest_weight`, `object_contact_weight` and `rotation_weight`. The one list of them, for a named
    /// configuration ([`ModelSection::model_config`]) and for an `init` model
    /// (`RigidFormer::with_settings`) alike.
    pub fn apply_settings(&self, dynamics: &mut DynamicsConfig, loss: &mut LossConfig) {
        if let Some(on) = self.rigid_extrapolation {
            dynamics.rigid_extrapolation = on;
        }
        if let Some(on) = self.floor_base {
            dynamics.floor_base = on;
        }
        if let Some(on) = self.relative_mass {
            dynamics.relative_mass = on;
        }
        if let Some(on) = self.kinematic_lead {
            dynamics.kinematic_lead = on;
        }
        if let Some(beta) = self.loss_beta {
            loss.beta = beta;
        }
        if let Some(w) = self.rest_weight {
            loss.rest_weight = w;
        }
        if let Some(w) = self.object_contact_weight {
            loss.object_contact_weight = w;
        }
        if let Some(w) = self.rotation_weight {
            loss.rotation_weight = w;
        }
    }

    /// The model configuration this section names (before normalisation fitting), with
    /// the optional input groups (`contact_velocity` to `contact_partner`; the normalisation then
    /// resized to its defaults), the units (`object_summary`, `contact_summary`,
    /// `contact_wrench`, `contact_messages`) and
    /// [`ModelSection::apply_settings`] applied.
    pub fn model_config(&self) -> Result<ModelConfig, TrainError> {
        let mut c = self.named_config()?;
        self.apply_settings(&mut c.dynamics, &mut c.loss);
        for unit in ModelUnit::ALL {
            if let Some(on) = self.unit_switch(unit) {
                unit.set(&mut c.dynamics, on);
            }
        }
        let inputs = c.dynamics.point_features();
        for group in InputGroup::ALL {
            if let Some(on) = self.input_switch(group) {
                group.set(&mut c.dynamics, on);
            }
        }
        if c.dynamics.point_features() != inputs {
            c.normalization = FeatureNormalization::defaults_for(&c.dynamics);
        }
        Ok(c)
    }

    /// This section's switch for an optional input group (`contact_velocity`,
    /// `surface_normals`, `history`, `approach`, `contact_partner`): unset keeps what the model
    /// has.
    pub fn input_switch(&self, group: InputGroup) -> Option<bool> {
        match group {
            InputGroup::ContactVelocity => self.contact_velocity,
            InputGroup::SurfaceNormals => self.surface_normals,
            InputGroup::History => self.history,
            InputGroup::Approach => self.approach,
            InputGroup::ContactPartner => self.contact_partner,
        }
    }

    /// This section's switch for an optional unit (`object_summary`, `contact_summary`,
    /// `contact_wrench`, `contact_messages`): unset keeps what the model has.
    pub fn unit_switch(&self, unit: ModelUnit) -> Option<bool> {
        match unit {
            ModelUnit::ObjectSummary => self.object_summary,
            ModelUnit::ContactSummary => self.contact_summary,
            ModelUnit::ContactWrench => self.contact_wrench,
            ModelUnit::ContactMessages => self.contact_messages,
        }
    }

    fn named_config(&self) -> Result<ModelConfig, TrainError> {
        if let Some(path) = &self.config {
            let text = std::fs::read_to_string(path).map_err(|e| TrainError::Io {
                path: path.clone(),
                source: e,
            })?;
            let c: ModelConfig = serde_json::from_str(&text).map_err(|e| {
                TrainError::Config(format!("{}: not a model config: {e}", path.display()))
            })?;
            c.validate()?;
            return Ok(c);
        }
        match self.preset.as_str() {
            "small" => Ok(ModelConfig::small()),
            "paper" => Ok(ModelConfig::paper()),
            "tiny" => Ok(ModelConfig::tiny()),
            other => Err(TrainError::Config(format!(
                "model.preset {other:?} is not one of small, paper, tiny"
            ))),
        }
    }
}

/// Optimiser, learning-rate schedule and length of training.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OptimConfig {
    /// Scenes per iteration (one window each).
    pub batch_size: usize,
    /// Total iterations; the cosine schedule reaches `min_lr_ratio * lr` here.
    pub iterations: u64,
    /// Peak learning rate.
    pub lr: f64,
    /// Linear warm-up length in iterations.
    pub warmup: u64,
    /// Learning rate at iteration 0 as a fraction of `lr` (default 0.1).
    pub warmup_start: f64,
    /// Final learning rate of the cosine decay as a fraction of `lr`.
    pub min_lr_ratio: f64,
    /// AdamW first-moment decay.
    pub beta1: f64,
    /// AdamW second-moment decay.
    pub beta2: f64,
    /// AdamW epsilon.
    pub eps: f64,
    /// Decoupled weight decay for matrices (norm scales, biases, registers, embeddings and the
    /// AVP bandwidth get none).
    pub weight_decay: f64,
    /// Global gradient-norm clip (over all parameters); 0 disables.
    pub grad_clip: f64,
    /// Decay of the exponential moving average of the weights kept beside the raw weights
    /// (exported when better); 0 disables.
    pub ema_decay: f64,
    /// Learning-rate factors by parameter-name prefix (`[optim.lr_scale]`, e.g.
    /// `"contact_summary." = 10.0`): every parameter whose name starts with a prefix trains at
    /// that multiple of the schedule's rate (the longest matching prefix wins; weight decay
    /// scales with it), the rest at the schedule's. For layers added to a trained model, which
    /// start at zero and would otherwise learn at the rate chosen to keep the trained weights
    /// near their optimum. Every factor must be finite and positive and every prefix must name
    /// at least one parameter. Empty by default.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub lr_scale: BTreeMap<String, f64>,
    /// Sharpness-aware minimisation's radius (0 disables, the default): each iteration takes
    /// the gradient again at the weights moved by this distance (global L2 norm over all
    /// parameters) along the batch's normalised gradient, and the update uses that second
    /// gradient at the unmoved weights. It seeks weights whose loss stays low in a
    /// neighbourhood, which tends to generalise better; each iteration costs two passes.
    #[serde(skip_serializing_if = "is_zero")]
    pub sam_rho: f64,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

impl Default for OptimConfig {
    fn default() -> Self {
        OptimConfig {
            batch_size: 16,
            iterations: 20_000,
            lr: 5e-4,
            warmup: 500,
            warmup_start: 0.1,
            min_lr_ratio: 0.02,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 0.05,
            grad_clip: 1.0,
            ema_decay: 0.999,
            lr_scale: BTreeMap::new(),
            sam_rho: 0.0,
        }
    }
}

/// Where results go and how often.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Run directory: `checkpoint/`, `log.csv`, `loss.png`, `train-config.toml`.
    pub out_dir: PathBuf,
    /// Minutes between checkpoints (also written at the end and on Ctrl-C / SIGTERM).
    pub checkpoint_minutes: f64,
    /// Iterations between CSV log rows (losses are averaged over them).
    pub log_every: u64,
    /// Threads of the dedicated compute pool (model forward/backward).
    pub threads: usize,
    /// Threads that draw and prepare the samples of a batch (window, augmentation, anchors
    /// and encoder groups). 1 prepares them one after another on the loader thread; more
    /// keep a fast device fed. The batches are the same for any value.
    pub loader_threads: usize,
    /// Device the model trains on: `cpu`, `cuda` or `cuda:N` (a build with `--features
    /// cuda`). Not part of the run's identity: a run may be resumed on another device.
    pub device: String,
    /// Seed of the data order and augmentation.
    pub seed: u64,
    /// Show a progress bar (otherwise a plain line per log row).
    pub progress: bool,
    /// Iterations after which a copy of the checkpoint is kept as `checkpoint-NNNNN/` beside
    /// `checkpoint/` (weights, optimiser moments with the weight average, state), for
    /// averaging weights along a run (`dynaserve train export --run DIR/checkpoint-NNNNN
    /// --ema`, then `dynaserve train average`). Empty keeps none.
    pub keep_checkpoints: Vec<u64>,
}

impl Default for RunConfig {
    fn default() -> Self {
        RunConfig {
            out_dir: PathBuf::from("runs/rigidformer-small"),
            checkpoint_minutes: 5.0,
            log_every: 20,
            threads: 2,
            loader_threads: 1,
            device: "cpu".to_string(),
            seed: 0,
            progress: true,
            keep_checkpoints: Vec::new(),
        }
    }
}

/// The TOML table of `path` laid over the table of the file its `base` key names, recursively;
/// `chain` holds the files being read, so that a cycle is an error instead of a hang.
fn toml_with_bases(path: &Path, chain: &mut Vec<PathBuf>) -> Result<toml::Table, TrainError> {
    let err = |m: String| TrainError::Config(format!("{}: {m}", path.display()));
    let text = std::fs::read_to_string(path).map_err(|e| TrainError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    let mut table: toml::Table = toml::from_str(&text).map_err(|e| err(e.to_string()))?;
    let Some(base) = table.remove("base") else {
        return Ok(table);
    };
    let base = base
        .as_str()
        .ok_or_else(|| err("`base` must be a file name".into()))?;
    let base_path = path.parent().unwrap_or(Path::new(".")).join(base);
    let key = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
    if chain.contains(&key) {
        return Err(err(format!("`base` chain returns to {}", path.display())));
    }
    chain.push(key);
    let mut merged = toml_with_bases(&base_path, chain)?;
    chain.pop();
    overlay(&mut merged, table);
    Ok(merged)
}

/// Lays `top` over `under`: tables merge key by key, every other value replaces.
fn overlay(under: &mut toml::Table, top: toml::Table) {
    for (k, v) in top {
        match (under.get_mut(&k), v) {
            (Some(toml::Value::Table(u)), toml::Value::Table(t)) => overlay(u, t),
            (_, v) => {
                under.insert(k, v);
            }
        }
    }
}

/// Whether `step_sizes` (frames) is a valid list of step sizes: non-empty, each in 1..=16.
pub(crate) fn valid_step_sizes(step_sizes: &[u32]) -> bool {
    !step_sizes.is_empty() && step_sizes.iter().all(|k| (1..=16).contains(k))
}

impl TrainConfig {
    /// Reads a TOML (`.toml`) or JSON (any other extension) configuration and validates it.
    /// A TOML file may name another in a top-level `base = "file.toml"` (relative to its own
    /// directory): it is that file with this one's keys laid over it (tables merged key by
    /// key, any other value, arrays included, replaced).
    pub fn from_file(path: &Path) -> Result<TrainConfig, TrainError> {
        let cfg: TrainConfig = if path.extension().is_some_and(|e| e == "toml") {
            toml_with_bases(path, &mut Vec::new())?
                .try_into()
                .map_err(|e| TrainError::Config(format!("{}: {e}", path.display())))?
        } else {
            let text = std::fs::read_to_string(path).map_err(|e| TrainError::Io {
                path: path.to_path_buf(),
                source: e,
            })?;
            serde_json::from_str(&text)
                .map_err(|e| TrainError::Config(format!("{}: {e}", path.display())))?
        };
        cfg.validate()?;
        Ok(cfg)
    }

    /// Checks ranges; every violation is named.
    pub fn validate(&self) -> Result<(), TrainError> {
        let bad = |m: &str| Err(TrainError::Config(m.to_string()));
        self.heldout.validate()?;
        if self.run.loader_threads == 0 {
            return bad("run.loader_threads must be at least 1");
        }
        let d = &self.data;
        if !valid_step_sizes(&d.step_sizes) {
            return bad("data.step_sizes must be non-empty, each in 1..=16");
        }
        if d.points_min == 0 || d.points_max < d.points_min {
            return bad("data.points_min must be >= 1 and <= data.points_max");
        }
        if !(0.0..=1.0).contains(&d.point_drop_prob) || !(0.0..0.95).contains(&d.point_drop_max) {
            return bad("data.point_drop_prob must be in [0, 1] and point_drop_max in [0, 0.95)");
        }
        if !(d.noise_position >= 0.0 && d.noise_rotation >= 0.0) {
            return bad("data.noise_position and noise_rotation must be >= 0");
        }
        if !(0.0..=1.0).contains(&d.pushforward) {
            return bad("data.pushforward must be a probability in [0, 1]");
        }
        if !(1..=MAX_PUSHFORWARD_STEPS).contains(&d.pushforward_steps) {
            return bad(&format!(
                "data.pushforward_steps must be 1 to {MAX_PUSHFORWARD_STEPS}"
            ));
        }
        if !(0.0..=1.0).contains(&d.event_share) {
            return bad("data.event_share must be a fraction in [0, 1]");
        }
        if !(0.0..=1.0).contains(&d.stop_share) {
            return bad("data.stop_share must be a fraction in [0, 1]");
        }
        if !(0.0..=1.0).contains(&d.history_drop) {
            return bad("data.history_drop must be a probability in [0, 1]");
        }
        if self.model.history == Some(true) && !d.history {
            return bad(
                "model.history = true needs data.history = true (else its inputs are always zero)",
            );
        }
        DataConfig::check_mix(&d.mix, 1 + d.extra.len())?;
        if d.prefetch == 0 {
            return bad("data.prefetch must be >= 1");
        }
        if let Some(beta) = self.model.loss_beta
            && !(beta > 0.0 && beta.is_finite())
        {
            return bad("model.loss_beta must be finite and > 0");
        }
        if let Some(w) = self.model.rest_weight
            && !(w > 0.0 && w.is_finite())
        {
            return bad("model.rest_weight must be finite and > 0");
        }
        if let Some(w) = self.model.object_contact_weight
            && !(w > 0.0 && w.is_finite())
        {
            return bad("model.object_contact_weight must be finite and > 0");
        }
        if let Some(w) = self.model.rotation_weight
            && !(w >= 0.0 && w.is_finite())
        {
            return bad("model.rotation_weight must be finite and >= 0");
        }
        if self
            .model
            .insert_blocks_after
            .as_ref()
            .is_some_and(|v| !v.is_empty())
            && self.model.init.is_none()
        {
            return bad("model.insert_blocks_after deepens the model.init model: set model.init");
        }
        if self.model.widen_encoder.is_some() && self.model.init.is_none() {
            return bad("model.widen_encoder widens the model.init model: set model.init");
        }
        let o = &self.optim;
        if o.batch_size == 0 || o.iterations == 0 {
            return bad("optim.batch_size and optim.iterations must be >= 1");
        }
        if !(o.lr > 0.0 && o.lr.is_finite()) {
            return bad("optim.lr must be finite and > 0");
        }
        if !(0.0..=1.0).contains(&o.warmup_start) || !(0.0..=1.0).contains(&o.min_lr_ratio) {
            return bad("optim.warmup_start and optim.min_lr_ratio must be in [0, 1]");
        }
        if !(0.0..1.0).contains(&o.beta1) || !(0.0..1.0).contains(&o.beta2) || o.eps <= 0.0 {
            return bad("optim.beta1/beta2 must be in [0, 1) and eps > 0");
        }
        if o.weight_decay < 0.0 || o.grad_clip < 0.0 || !(0.0..1.0).contains(&o.ema_decay) {
            return bad("optim.weight_decay, grad_clip >= 0 and ema_decay in [0, 1)");
        }
        if o.lr_scale.values().any(|f| !(f.is_finite() && *f > 0.0)) {
            return bad("optim.lr_scale factors must be finite and > 0");
        }
        if !(o.sam_rho.is_finite() && o.sam_rho >= 0.0) {
            return bad("optim.sam_rho must be finite and >= 0");
        }
        let r = &self.run;
        if r.checkpoint_minutes.is_nan()
            || r.checkpoint_minutes <= 0.0
            || r.log_every == 0
            || r.threads == 0
        {
            return bad("run.checkpoint_minutes > 0, run.log_every >= 1 and run.threads >= 1");
        }
        if let Some(k) = r
            .keep_checkpoints
            .iter()
            .find(|&&k| k == 0 || k > o.iterations)
        {
            return bad(&format!(
                "run.keep_checkpoints names iteration {k}: each must be in 1..={} (optim.iterations)",
                o.iterations
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `base` file's keys stay where the derived file is silent; a derived table key or
    /// array replaces the base's; a chain that returns to a file is an error.
    #[test]
    fn base_files_are_overlaid_and_cycles_refused() {
        let dir =
            std::env::temp_dir().join(format!("dynaserve-config-base-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let write = |name: &str, text: &str| std::fs::write(dir.join(name), text).unwrap();
        write(
            "base.toml",
            "[data]\nstep_sizes = [1, 2, 4]\nmirror = true\n[optim]\nbatch_size = 24\niterations = 8000\n",
        );
        write(
            "child.toml",
            "base = \"base.toml\"\n[data]\nstep_sizes = [2]\n[optim]\nbatch_size = 48\n",
        );
        let c = TrainConfig::from_file(&dir.join("child.toml")).unwrap();
        assert_eq!(c.data.step_sizes, vec![2]);
        assert!(c.data.mirror);
        assert_eq!((c.optim.batch_size, c.optim.iterations), (48, 8000));
        write("a.toml", "base = \"b.toml\"\n");
        write("b.toml", "base = \"a.toml\"\n");
        let e = TrainConfig::from_file(&dir.join("a.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("chain returns"), "{e}");
        write("bad.toml", "base = 3\n");
        let e = TrainConfig::from_file(&dir.join("bad.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("`base` must be a file name"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// r68 and r69 are r66, and r70 is r68, with the changes their headers name and nothing else.
    #[test]
    fn derived_run_configs_differ_from_their_base_as_stated() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
        let load = |n: &str| TrainConfig::from_file(&dir.join(n)).unwrap();
        let r66 = load("rigidformer-small-r66.toml");
        let mut want = r66.clone();
        want.data.mirror = true;
        want.run.out_dir = PathBuf::from("runs/rigidformer-small-r68");
        want.run.threads = 2;
        want.run.seed = 68;
        assert_eq!(load("rigidformer-small-r68.toml"), want);
        let mut want = load("rigidformer-small-r68.toml");
        want.optim.iterations = 20000;
        want.optim.ema_decay = 0.9995;
        want.run.out_dir = PathBuf::from("runs/rigidformer-small-r70");
        want.run.seed = 70;
        assert_eq!(load("rigidformer-small-r70.toml"), want);
        let mut want = r66;
        want.optim.batch_size = 48;
        want.optim.iterations = 4000;
        want.optim.warmup = 150;
        want.run.out_dir = PathBuf::from("runs/rigidformer-small-r69");
        want.run.threads = 2;
        want.run.seed = 69;
        assert_eq!(load("rigidformer-small-r69.toml"), want);
    }

    /// The committed RigidFormer configurations (the experiments' included), by file name
    /// relative to `configs/`, sorted.
    fn committed_config_files() -> Vec<(String, PathBuf)> {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
        let mut files = Vec::new();
        for (sub, prefix) in [("", "rigidformer"), ("experiments/", "")] {
            for entry in std::fs::read_dir(dir.join(sub)).unwrap() {
                let p = entry.unwrap().path();
                let name = p.file_name().unwrap().to_string_lossy().into_owned();
                if name.starts_with(prefix) && name.ends_with(".toml") {
                    files.push((format!("{sub}{name}"), p));
                }
            }
        }
        files.sort();
        files
    }

    /// The leaves of `value` (a serialised configuration) that differ from `default`'s at the
    /// same path, by dotted path.
    fn changed_leaves(
        path: &str,
        value: &serde_json::Value,
        default: Option<&serde_json::Value>,
        out: &mut std::collections::BTreeMap<String, serde_json::Value>,
    ) {
        if let (serde_json::Value::Object(map), Some(serde_json::Value::Object(base))) =
            (value, default)
        {
            for (k, v) in map {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                changed_leaves(&p, v, base.get(k), out);
            }
        } else if default != Some(value) {
            out.insert(path.to_string(), value.clone());
        }
    }

    /// `value` as JSON, with every number that is exactly an `f32` (the configuration's
    /// single-precision fields, widened by serde) written as that `f32`'s shortest form, so
    /// that the record reads `0.001`, not `0.0010000000474974513`, and stays exact.
    fn record_value(value: &serde_json::Value) -> String {
        use serde_json::Value;
        match value {
            Value::Number(n) if !n.is_i64() && !n.is_u64() => match n.as_f64() {
                Some(x) if f64::from(x as f32) == x => format!("{:?}", x as f32),
                _ => value.to_string(),
            },
            Value::Array(items) => {
                let items: Vec<String> = items.iter().map(record_value).collect();
                format!("[{}]", items.join(","))
            }
            Value::Object(map) => {
                let items: Vec<String> = map
                    .iter()
                    .map(|(k, v)| format!("{}:{}", Value::String(k.clone()), record_value(v)))
                    .collect();
                format!("{{{}}}", items.join(","))
            }
            _ => value.to_string(),
        }
    }

    /// Every committed configuration resolves (bases laid under it) to the settings recorded
    /// in `configs/resolved.txt`, one line per key that differs from the defaults
    /// (`file: key = value`, the value as JSON). A file edited in place changes every run
    /// built on it through `base`; this test names each such run, so that a record is not
    /// rewritten unnoticed. After a deliberate change (a new run, a new default), rewrite the
    /// record with `DYNASERVE_WRITE_RESOLVED=1` and review its diff.
    #[test]
    fn committed_configs_resolve_as_recorded() {
        use std::collections::BTreeSet;
        let default = serde_json::to_value(TrainConfig::default()).unwrap();
        let mut lines = Vec::new();
        for (name, path) in committed_config_files() {
            let c = TrainConfig::from_file(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
            let mut leaves = std::collections::BTreeMap::new();
            changed_leaves(
                "",
                &serde_json::to_value(c).unwrap(),
                Some(&default),
                &mut leaves,
            );
            for (key, value) in leaves {
                lines.push(format!("{name}: {key} = {}", record_value(&value)));
            }
        }
        let record = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/resolved.txt");
        if std::env::var_os("DYNASERVE_WRITE_RESOLVED").is_some() {
            std::fs::write(&record, lines.join("\n") + "\n").unwrap();
            return;
        }
        let text = std::fs::read_to_string(&record).unwrap();
        let recorded: BTreeSet<&str> = text.lines().collect();
        let now: BTreeSet<&str> = lines.iter().map(String::as_str).collect();
        let mut changes: Vec<String> = recorded
            .difference(&now)
            .map(|l| format!("- {l}"))
            .chain(now.difference(&recorded).map(|l| format!("+ {l}")))
            .collect();
        changes.sort_by(|a, b| a[2..].cmp(&b[2..]));
        assert!(
            changes.is_empty(),
            "committed configurations no longer resolve as configs/resolved.txt records \
             (recorded -, now +; DYNASERVE_WRITE_RESOLVED=1 rewrites it):\n{}",
            changes.join("\n")
        );
    }

    /// Every committed RigidFormer training configuration, the experiments' included, parses
    /// and validates (a typo in one surfaces here, not an hour into a run); the relative-mass
    /// run switches it on.
    #[test]
    fn committed_configs_parse_and_validate() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
        let files = committed_config_files();
        for (name, p) in &files {
            TrainConfig::from_file(p).unwrap_or_else(|e| panic!("{name}: {e}"));
        }
        let experiments = files
            .iter()
            .filter(|(n, _)| n.starts_with("experiments/"))
            .count();
        let runs = files.len() - experiments;
        assert!(
            runs >= 30,
            "only {runs} configurations in {}",
            dir.display()
        );
        // The diagnoses' and experiments' configurations too, so that the card's commands run.
        assert!(
            experiments >= 20,
            "only {experiments} configurations in {}/experiments",
            dir.display()
        );
        let r24 = TrainConfig::from_file(&dir.join("rigidformer-small-r24.toml")).unwrap();
        assert_eq!(r24.model.relative_mass, Some(true));
        let r43 = TrainConfig::from_file(&dir.join("rigidformer-small-r43.toml")).unwrap();
        assert_eq!(r43.model.kinematic_lead, Some(true));
        let r48 = TrainConfig::from_file(&dir.join("rigidformer-small-r48.toml")).unwrap();
        assert_eq!(r48.data.stop_share, 0.3);
        let refused = |text: &str, field: &str| {
            let c: TrainConfig = toml::from_str(text).unwrap();
            let e = c.validate().unwrap_err().to_string();
            assert!(
                e.contains(field),
                "{text:?} refused for another reason: {e}"
            );
        };
        refused("[data]\nstop_share = 1.5\n", "stop_share");
        let r50 = TrainConfig::from_file(&dir.join("rigidformer-small-r50.toml")).unwrap();
        assert_eq!(r50.data.pushforward_steps, 6);
        refused(
            &format!(
                "[data]\npushforward_steps = {}\n",
                MAX_PUSHFORWARD_STEPS + 1
            ),
            "pushforward_steps",
        );
        let r54 = TrainConfig::from_file(&dir.join("rigidformer-small-r54.toml")).unwrap();
        assert_eq!(r54.model.contact_summary, Some(true));
        assert_eq!(r54.optim.lr_scale.get("contact_summary."), Some(&10.0));
        assert!(r54.model.model_config().unwrap().dynamics.contact_summary);
        refused("[optim.lr_scale]\n\"a.\" = 0.0\n", "lr_scale");
        refused("[optim.lr_scale]\n\"a.\" = nan\n", "lr_scale");
        let lead = r43.model.model_config().unwrap();
        assert!(lead.dynamics.kinematic_lead);
        assert!(
            !ModelSection::default()
                .model_config()
                .unwrap()
                .dynamics
                .kinematic_lead
        );
    }

    #[test]
    fn loss_beta_switches_the_named_config_and_is_checked() {
        let c: TrainConfig = toml::from_str("[model]\nloss_beta = 0.1\n").unwrap();
        assert_eq!(c.model.model_config().unwrap().loss.beta, 0.1);
        c.validate().unwrap();
        let zero: TrainConfig = toml::from_str("[model]\nloss_beta = 0.0\n").unwrap();
        assert!(zero.validate().is_err());
    }

    #[test]
    fn rest_weight_switches_the_named_config_and_is_checked() {
        assert_eq!(
            ModelSection::default()
                .model_config()
                .unwrap()
                .loss
                .rest_weight,
            1.0
        );
        let c: TrainConfig = toml::from_str("[model]\nrest_weight = 4.0\n").unwrap();
        assert_eq!(c.model.model_config().unwrap().loss.rest_weight, 4.0);
        c.validate().unwrap();
        let neg: TrainConfig = toml::from_str("[model]\nrest_weight = -1.0\n").unwrap();
        assert!(neg.validate().is_err());
    }

    #[test]
    fn contact_and_rotation_weights_switch_the_named_config_and_are_checked() {
        let loss = |c: &ModelSection| c.model_config().unwrap().loss;
        assert_eq!(loss(&ModelSection::default()).object_contact_weight, 1.0);
        assert_eq!(loss(&ModelSection::default()).rotation_weight, 0.0);
        let c: TrainConfig =
            toml::from_str("[model]\nobject_contact_weight = 3.0\nrotation_weight = 0.5\n")
                .unwrap();
        assert_eq!(loss(&c.model).object_contact_weight, 3.0);
        assert_eq!(loss(&c.model).rotation_weight, 0.5);
        c.validate().unwrap();
        for bad in ["object_contact_weight = nan", "rotation_weight = -0.5"] {
            let c: TrainConfig = toml::from_str(&format!("[model]\n{bad}\n")).unwrap();
            assert!(c.validate().is_err(), "{bad}");
        }
    }

    /// Each unit's `[model]` switch turns it on in the named configuration; unset, it is off.
    #[test]
    fn unit_switches_change_the_named_config() {
        for unit in ModelUnit::ALL {
            let has = |c: &ModelSection| unit.enabled(&c.model_config().unwrap().dynamics);
            assert!(!has(&ModelSection::default()), "{}", unit.key());
            let text = format!("[model]\n{} = true\n", unit.key());
            let c: TrainConfig = toml::from_str(&text).unwrap();
            assert!(has(&c.model), "{}", unit.key());
            assert_eq!(c.model.unit_switch(unit), Some(true));
        }
    }

    /// The error of `[model] line` without `init`, and the validated config with one.
    fn without_and_with_init(line: &str) -> (String, TrainConfig) {
        let c: TrainConfig = toml::from_str(&format!("[model]\n{line}\n")).unwrap();
        let err = c.validate().unwrap_err().to_string();
        let c: TrainConfig =
            toml::from_str(&format!("[model]\ninit = \"runs/x\"\n{line}\n")).unwrap();
        c.validate().unwrap();
        (err, c)
    }

    #[test]
    fn a_widened_encoder_and_inserted_blocks_need_an_init_model() {
        let (err, c) = without_and_with_init("widen_encoder = [64, 96]");
        assert!(err.contains("model.widen_encoder"), "{err}");
        assert_eq!(c.model.widen_encoder, Some([64, 96]));
        let (err, c) = without_and_with_init("insert_blocks_after = [1, 3]");
        assert!(err.contains("set model.init"), "{err}");
        assert_eq!(c.model.insert_blocks_after, Some(vec![1, 3]));
    }

    #[test]
    fn rigid_extrapolation_switches_the_named_config() {
        let preset = ModelSection::default().model_config().unwrap();
        assert!(preset.dynamics.rigid_extrapolation);
        let c: TrainConfig = toml::from_str("[model]\nrigid_extrapolation = false\n").unwrap();
        let off = c.model.model_config().unwrap();
        assert!(!off.dynamics.rigid_extrapolation);
        assert_eq!(
            off.dynamics.contact_velocity,
            preset.dynamics.contact_velocity
        );
    }

    #[test]
    fn surface_normals_resize_the_named_configs_normalisation() {
        let c: TrainConfig = toml::from_str("[model]\nsurface_normals = true\n").unwrap();
        let on = c.model.model_config().unwrap();
        assert!(on.dynamics.surface_normals && on.dynamics.contact_velocity);
        assert_eq!(on.normalization.len(), 22);
        on.validate().unwrap();
        let c: TrainConfig =
            toml::from_str("[model]\nsurface_normals = true\ncontact_velocity = false\n").unwrap();
        let without_cv = c.model.model_config().unwrap();
        assert_eq!(without_cv.normalization.len(), 19);
        without_cv.validate().unwrap();
        // The approach inputs come last: 3 more, with their own default constants.
        let c: TrainConfig =
            toml::from_str("[model]\nsurface_normals = true\napproach = true\n").unwrap();
        let approach = c.model.model_config().unwrap();
        assert!(approach.dynamics.approach);
        assert_eq!(approach.normalization.len(), 25);
        assert_eq!(approach.normalization.mean[22..], [0.0, 1.0, 0.0]);
        approach.validate().unwrap();
    }

    #[test]
    fn toml_overrides_defaults_and_rejects_unknown_keys() {
        let c: TrainConfig =
            toml::from_str("[optim]\nbatch_size = 4\n[data]\npoints_min = 64\n").unwrap();
        assert_eq!(c.optim.batch_size, 4);
        assert_eq!(c.data.points_min, 64);
        assert_eq!(c.optim.lr, OptimConfig::default().lr);
        c.validate().unwrap();
        assert!(toml::from_str::<TrainConfig>("[optim]\nbatchsize = 4\n").is_err());
        let mut c = TrainConfig::default();
        c.data.points_max = 1;
        assert!(c.validate().unwrap_err().to_string().contains("points_min"));
    }

    #[test]
    fn mix_needs_one_share_per_directory() {
        let ok: TrainConfig =
            toml::from_str("[data]\nextra = [\"a\", \"b\"]\nmix = [0.5, 0.25, 0.0]\n").unwrap();
        ok.validate().unwrap();
        for bad in [
            "mix = [0.5, 0.5]",
            "mix = [0.5, -0.25, 1.0]",
            "mix = [0.0, 0.0, 0.0]",
            "mix = [0.5, nan, 1.0]",
        ] {
            let c: TrainConfig =
                toml::from_str(&format!("[data]\nextra = [\"a\", \"b\"]\n{bad}\n")).unwrap();
            let err = c.validate().unwrap_err().to_string();
            assert!(err.contains("data.mix"), "{bad}: {err}");
        }
    }
}
