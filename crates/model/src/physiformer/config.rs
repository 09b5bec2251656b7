//! Architecture, flow and data conventions of a PhysiFormer checkpoint (`config.json`).

use serde::{Deserialize, Serialize};

use super::official::config::OfficialConfig;
use crate::ModelError;

/// Architecture name stored in a PhysiFormer `config.json`.
pub const PHYSIFORMER: &str = "physiformer";
/// Version of the PhysiFormer `config.json` format.
pub const PHYSI_FORMAT_VERSION: u32 = 1;

/// Per-object material input `(softness, friction)` of a rigid object.
pub const RIGID_MATERIAL: [f32; 2] = [0.0, 0.01];
/// Per-object material input `(softness, friction)` of an elastic object.
pub const ELASTIC_MATERIAL: [f32; 2] = [1.0, 0.15];

/// The trajectory the network's output is added to: the network predicts the clean trajectory
/// as this prior plus a learned correction, so an untrained network already forecasts the prior.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrajectoryPrior {
    /// Every frame at the initial positions `X_0` (checkpoints written before the prior was
    /// configurable have this one).
    #[default]
    Static,
    /// Each vertex's ballistic path from its initial position and velocity under gravity,
    /// `X_0 + V_0 s + g s^2 / 2` at `s = frame * dt_frame` seconds, clamped to the box.
    Ballistic,
    /// The same free flight, but an object that would leave the box is shifted back as a
    /// whole instead of vertex by vertex: an object resting on the floor stays on it, and a
    /// translating rigid object stays rigid (the vertex clamp squashes it against the floor).
    ObjectBallistic,
}

impl TrajectoryPrior {
    /// True when the prior differs from frame to frame (both ballistic kinds), so a pass lays
    /// it out `[B, T, V, 3]`; the static prior is the frame-0 positions `[B, 1, V, 3]`.
    pub fn per_frame(self) -> bool {
        self != TrajectoryPrior::Static
    }
}

/// Every size and constant of a PhysiFormer network; nothing about its shape is hard-coded.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhysiConfig {
    /// Architecture name; `"physiformer"`.
    pub architecture: String,
    /// `config.json` format version ([`PHYSI_FORMAT_VERSION`]).
    pub format_version: u32,

    // ---- data conventions ----
    /// Frames of a trajectory the model was trained on (frame 0 is the initial state).
    pub frames: usize,
    /// Interval between frames, seconds.
    pub dt_frame: f32,
    /// Half extent of the closed box the scenes live in, metres (the box is `[-e, e]^3`).
    pub box_half_extent: f32,
    /// Gravity of the training data, m/s^2.
    pub gravity: [f32; 3],
    /// Largest accepted vertex count of one scene.
    pub max_vertices: usize,
    /// Largest accepted object count of one scene.
    pub max_objects: usize,

    // ---- network ----
    /// Token width D.
    pub width: usize,
    /// Attention heads; `width` must be divisible by it, head width even.
    pub heads: usize,
    /// Transformer blocks; block `i` attends spatially (`i % 4 == 0`), per object
    /// (`i % 4 == 2`) or over time (odd `i`).
    pub blocks: usize,
    /// Learned global register tokens.
    pub registers: usize,
    /// SwiGLU hidden width.
    pub ffn_hidden: usize,
    /// Sinusoidal features of the flow time before its MLP.
    pub time_features: usize,
    /// Hidden width of the material MLP.
    pub material_hidden: usize,
    /// Base of the temporal rotary frequencies (1D RoPE over the frame index).
    pub temporal_rope_base: f32,
    /// RMSNorm epsilon.
    pub norm_eps: f32,

    // ---- flow matching ----
    /// Standard deviation of the noise the flow starts from, metres (0.1).
    pub noise_scale: f32,
    /// Mean of the logit-normal flow-time distribution of training.
    pub t_mu: f32,
    /// Standard deviation of the logit-normal flow-time distribution of training.
    pub t_sigma: f32,
    /// Floor of `1 - t` when turning the predicted trajectory into a velocity.
    pub t_eps: f32,
    /// Denoising steps a request gets when it does not ask for a number.
    pub default_steps: usize,
    /// The trajectory the network's output corrects ([`TrajectoryPrior`]); absent in older
    /// checkpoints, which are `static`.
    #[serde(default)]
    pub prior: TrajectoryPrior,
    /// Frames over which the network's correction of the prior grows from nothing to its full
    /// size: the output at frame `f` is `prior + min(1, f / n) * head`. Near frame 0 the prior
    /// (the initial state moving with its initial velocity) is nearly exact, and the ramp lets
    /// the network depart from it only as far as time allows. 0 = no ramp (checkpoints written
    /// before the option).
    #[serde(default)]
    pub correction_ramp_frames: usize,
    /// The official PhysiFormer network ([`OfficialConfig`]) in place of this crate's own:
    /// set for checkpoints imported from the official code, whose sizes and conventions it
    /// holds (the fields above then describe it: `width` its hidden size, `blocks` its depth).
    /// The prior and the correction ramp are this crate's additions and are off for it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub official: Option<OfficialConfig>,
}

impl PhysiConfig {
    fn base() -> PhysiConfig {
        PhysiConfig {
            architecture: PHYSIFORMER.into(),
            format_version: PHYSI_FORMAT_VERSION,
            frames: 49,
            dt_frame: 5.0 / 240.0,
            box_half_extent: 1.0,
            gravity: [0.0, 0.0, -9.81],
            max_vertices: 512,
            max_objects: 16,
            width: 64,
            heads: 4,
            blocks: 4,
            registers: 4,
            ffn_hidden: 172,
            time_features: 64,
            material_hidden: 64,
            temporal_rope_base: 10_000.0,
            norm_eps: 1e-6,
            noise_scale: 0.1,
            t_mu: -0.8,
            t_sigma: 0.8,
            t_eps: 0.05,
            default_steps: 50,
            prior: TrajectoryPrior::Ballistic,
            correction_ramp_frames: 0,
            official: None,
        }
    }

    /// The CPU-trainable configuration: width 64, 4 heads of 16, 4 blocks (one cycle of
    /// spatial / temporal / per-object / temporal), 4 registers, about 0.2 M parameters.
    pub fn small() -> PhysiConfig {
        PhysiConfig::base()
    }

    /// The publication's "B" size: width 768, 12 heads, 12 blocks, 16 registers, SwiGLU hidden
    /// `4 * 768 * 2 / 3`, 256 time features.
    pub fn b() -> PhysiConfig {
        PhysiConfig {
            width: 768,
            heads: 12,
            blocks: 12,
            registers: 16,
            ffn_hidden: 2048,
            time_features: 256,
            material_hidden: 768,
            ..PhysiConfig::base()
        }
    }

    /// A very small network for tests (width 32, 2 heads, 4 blocks, 2 registers).
    pub fn tiny() -> PhysiConfig {
        PhysiConfig {
            width: 32,
            heads: 2,
            blocks: 4,
            registers: 2,
            ffn_hidden: 64,
            time_features: 16,
            material_hidden: 16,
            frames: 9,
            ..PhysiConfig::base()
        }
    }

    /// A preset by name: `small` or `b`.
    pub fn preset(name: &str) -> Result<PhysiConfig, ModelError> {
        match name {
            "small" => Ok(PhysiConfig::small()),
            "b" | "B" => Ok(PhysiConfig::b()),
            "tiny" => Ok(PhysiConfig::tiny()),
            other => Err(ModelError::InvalidInput(format!(
                "unknown PhysiFormer preset {other:?} (expected small, b or tiny)"
            ))),
        }
    }

    /// The per-axis affine map `(scale, offset)` from the network's coordinates to metres,
    /// `x = x_n * scale + offset`, in which the sampler's starting noise is drawn: the
    /// identity for this crate's network (it works in metres), the official network's
    /// normalisation for an imported checkpoint.
    pub fn noise_frame(&self) -> ([f32; 3], [f32; 3]) {
        match &self.official {
            Some(o) => o.to_network(self.box_half_extent),
            None => ([1.0; 3], [0.0; 3]),
        }
    }

    /// Channels of one attention head.
    pub fn head_dim(&self) -> usize {
        self.width / self.heads.max(1)
    }

    /// Coordinate frequencies per axis of the spatial rotary code: `(head_dim / 2) / 3`.
    pub fn coord_freqs(&self) -> usize {
        self.head_dim() / 2 / 3
    }

    /// Checks every size and constant; the error names the field.
    pub fn validate(&self) -> Result<(), ModelError> {
        let bad = |m: String| Err(ModelError::Checkpoint(m));
        if self.architecture != PHYSIFORMER {
            return bad(format!(
                "architecture is {:?}, expected {PHYSIFORMER:?}",
                self.architecture
            ));
        }
        if self.format_version != PHYSI_FORMAT_VERSION {
            return bad(format!(
                "format_version {} is not supported (expected {PHYSI_FORMAT_VERSION})",
                self.format_version
            ));
        }
        let positive = [
            ("frames", self.frames),
            ("width", self.width),
            ("heads", self.heads),
            ("blocks", self.blocks),
            ("ffn_hidden", self.ffn_hidden),
            ("time_features", self.time_features),
            ("material_hidden", self.material_hidden),
            ("max_vertices", self.max_vertices),
            ("max_objects", self.max_objects),
            ("default_steps", self.default_steps),
        ];
        for (name, v) in positive {
            if v == 0 {
                return bad(format!("{name} must be positive"));
            }
        }
        if self.frames < 2 {
            return bad("frames must be at least 2".into());
        }
        if !self.width.is_multiple_of(self.heads) || !self.head_dim().is_multiple_of(2) {
            return bad(format!(
                "width {} must split into {} heads of an even width",
                self.width, self.heads
            ));
        }
        if self.coord_freqs() == 0 {
            return bad("head width must be at least 6 for the coordinate rotary code".into());
        }
        if !self.time_features.is_multiple_of(2) {
            return bad("time_features must be even".into());
        }
        let floats = [
            ("dt_frame", self.dt_frame),
            ("box_half_extent", self.box_half_extent),
            ("noise_scale", self.noise_scale),
            ("t_sigma", self.t_sigma),
            ("t_eps", self.t_eps),
            ("temporal_rope_base", self.temporal_rope_base),
            ("norm_eps", self.norm_eps),
        ];
        for (name, v) in floats {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("{name} must be finite and positive, got {v}"));
            }
        }
        if !self.t_mu.is_finite() || self.gravity.iter().any(|g| !g.is_finite()) {
            return bad("t_mu and gravity must be finite".into());
        }
        if self.t_eps >= 1.0 {
            return bad("t_eps must be below 1".into());
        }
        if let Some(o) = &self.official {
            o.validate()?;
            if self.prior != TrajectoryPrior::Static || self.correction_ramp_frames != 0 {
                return bad(
                    "the official network takes no prior and no correction ramp (prior static, \
                     correction_ramp_frames 0)"
                        .into(),
                );
            }
            if self.frames > o.max_frames {
                return bad(format!(
                    "frames {} exceed the official network's max_frames {}",
                    self.frames, o.max_frames
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_config_written_before_the_prior_option_reads_as_static() {
        let mut json = serde_json::to_value(PhysiConfig::small()).unwrap();
        json.as_object_mut().unwrap().remove("prior");
        let old: PhysiConfig = serde_json::from_value(json).unwrap();
        assert_eq!(old.prior, TrajectoryPrior::Static);
        assert_eq!(PhysiConfig::small().prior, TrajectoryPrior::Ballistic);
    }
}
