//! The `[model]` section: the network to train (a preset, a `config.json` or an `init` model
//! directory) and the switches laid over it.

use std::path::PathBuf;

use dynaserve_model::{
    DynamicsConfig, FeatureNormalization, InputGroup, LossConfig, ModelConfig, ModelUnit,
};
use serde::{Deserialize, Serialize};

use crate::train::TrainError;

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
