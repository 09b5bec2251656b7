//! Architecture, flow and data conventions of a PhysiFormer checkpoint (`config.json`).

use serde::{Deserialize, Serialize};

use super::official::config::{DEFAULT_PATTERN, OfficialConfig};
use crate::ModelError;

/// Architecture name stored in a PhysiFormer `config.json`.
pub const PHYSIFORMER: &str = "physiformer";
/// Version of the PhysiFormer `config.json` format.
pub const PHYSI_FORMAT_VERSION: u32 = 1;

/// Per-object material input `(softness, friction)` of a rigid object.
pub const RIGID_MATERIAL: [f32; 2] = [0.0, 0.01];
/// Per-object material input `(softness, friction)` of an elastic object.
pub const ELASTIC_MATERIAL: [f32; 2] = [1.0, 0.15];

/// The trajectory the network's output is added to. Without one (the official network's
/// training) the network predicts the clean trajectory itself; with one it predicts a
/// correction of it, so an untrained network already forecasts the prior.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrajectoryPrior {
    /// No prior: the network's output is the trajectory (published checkpoints).
    #[default]
    None,
    /// Every frame at the initial positions `X_0`.
    Static,
    /// Each vertex's ballistic path from its initial position and velocity under gravity,
    /// `X_0 + V_0 s + g s^2 / 2` at `s = frame * dt_frame` seconds, clamped to the box.
    Ballistic,
    /// The same free flight, but an object that would leave the box is shifted back as a
    /// whole instead of vertex by vertex: an object resting on the floor stays on it, and a
    /// translating rigid object stays rigid (the vertex clamp squashes it against the floor).
    ObjectBallistic,
}

/// A PhysiFormer checkpoint's `config.json`: the data conventions, the flow, this crate's
/// options on the network's output, and the network (in the official architecture,
/// [`OfficialConfig`]); nothing about its shape is hard-coded.
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

    // ---- flow matching ----
    /// Standard deviation of the noise the flow starts from, in the network's coordinates
    /// (metres when they are metres; 0.1).
    pub noise_scale: f32,
    /// Mean of the logit-normal flow-time distribution of training.
    pub t_mu: f32,
    /// Standard deviation of the logit-normal flow-time distribution of training.
    pub t_sigma: f32,
    /// Floor of `1 - t` when turning the predicted trajectory into a velocity.
    pub t_eps: f32,
    /// Denoising steps a request gets when it does not ask for a number.
    pub default_steps: usize,

    // ---- this crate's options on the network's output (off for published checkpoints) ----
    /// The trajectory the network's output corrects ([`TrajectoryPrior`]).
    #[serde(default)]
    pub prior: TrajectoryPrior,
    /// Frames over which the network's correction of the prior grows from nothing to its full
    /// size: the output at frame `f` is `prior + min(1, f / n) * correction`. Near frame 0 the
    /// prior (the initial state moving with its initial velocity) is nearly exact, and the
    /// ramp lets the network depart from it only as far as time allows. 0 = no ramp; needs a
    /// prior.
    #[serde(default)]
    pub correction_ramp_frames: usize,

    // ---- the network ----
    /// The network's sizes and coordinate conventions, in the official PhysiFormer
    /// architecture (the only one this crate runs).
    pub official: OfficialConfig,
}

/// The official network of `hidden` width and the conventions of this crate's training data
/// (metres, this crate's material rows, no scene tokens).
fn network(hidden: usize, depth: usize, heads: usize, registers: usize) -> OfficialConfig {
    OfficialConfig {
        hidden,
        depth,
        heads,
        ffn_hidden: hidden * 8 / 3,
        registers,
        scene_tokens: 0,
        scene_cond_dim: 0,
        scene_cond_out_tokens: 0,
        material_dim: 2,
        max_objects: 16,
        classes: 1,
        label: 0,
        rope: true,
        max_frames: 49,
        pattern: DEFAULT_PATTERN.to_vec(),
        coord_scale: 1.0,
        coord_shift: 0.0,
        norm_mean: [0.0; 3],
        norm_std: [1.0; 3],
        normalize_to_scene_box: false,
        velocity_condition: true,
        rigid_material: RIGID_MATERIAL,
        elastic_material: ELASTIC_MATERIAL,
    }
}

impl PhysiConfig {
    fn base(official: OfficialConfig) -> PhysiConfig {
        PhysiConfig {
            architecture: PHYSIFORMER.into(),
            format_version: PHYSI_FORMAT_VERSION,
            frames: 49,
            dt_frame: 5.0 / 240.0,
            box_half_extent: 1.0,
            gravity: [0.0, 0.0, -9.81],
            max_vertices: 512,
            max_objects: 16,
            noise_scale: 0.1,
            t_mu: -0.8,
            t_sigma: 0.8,
            t_eps: 0.05,
            default_steps: 50,
            prior: TrajectoryPrior::ObjectBallistic,
            correction_ramp_frames: 8,
            official,
        }
    }

    /// The CPU-trainable configuration: width 64, 2 heads of 32 (the vertex rotary code gets
    /// 5 frequencies per axis), 4 blocks (one cycle of spatial / temporal / object /
    /// temporal), 4 registers, about 0.2 M parameters, correcting the object-wise ballistic
    /// prior with a ramp of 8 frames.
    pub fn small() -> PhysiConfig {
        PhysiConfig::base(network(64, 4, 2, 4))
    }

    /// The official default size ("B"): width 768, 12 heads, 12 blocks, 16 registers, SwiGLU
    /// hidden `4 * 768 * 2 / 3`, about 130 M parameters; same output options as `small`.
    pub fn b() -> PhysiConfig {
        PhysiConfig::base(network(768, 12, 12, 16))
    }

    /// A very small network for tests (width 32, 2 heads, 4 blocks, 2 registers, 9 frames).
    pub fn tiny() -> PhysiConfig {
        PhysiConfig {
            frames: 9,
            ..PhysiConfig::base(OfficialConfig {
                max_frames: 9,
                ..network(32, 4, 2, 2)
            })
        }
    }

    /// A preset by name: `small`, `b` or `tiny`.
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
    /// `x = x_n * scale + offset`, in which the sampler's starting noise is drawn (the
    /// identity for a network in metres, the official normalisation of an imported
    /// checkpoint).
    pub fn noise_frame(&self) -> ([f32; 3], [f32; 3]) {
        self.official.to_network(self.box_half_extent)
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
        let floats = [
            ("dt_frame", self.dt_frame),
            ("box_half_extent", self.box_half_extent),
            ("noise_scale", self.noise_scale),
            ("t_sigma", self.t_sigma),
            ("t_eps", self.t_eps),
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
        if self.prior == TrajectoryPrior::None && self.correction_ramp_frames != 0 {
            return bad("correction_ramp_frames needs a prior (prior is none)".into());
        }
        self.official.validate()?;
        if self.frames > self.official.max_frames {
            return bad(format!(
                "frames {} exceed the network's max_frames {}",
                self.frames, self.official.max_frames
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_config_without_a_prior_reads_as_none_and_a_ramp_needs_one() {
        let mut json = serde_json::to_value(PhysiConfig::small()).unwrap();
        let o = json.as_object_mut().unwrap();
        o.remove("prior");
        let c: PhysiConfig = serde_json::from_value(json).unwrap();
        assert_eq!(c.prior, TrajectoryPrior::None);
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("needs a prior")
        );
        assert_eq!(PhysiConfig::small().prior, TrajectoryPrior::ObjectBallistic);
        for p in ["small", "b", "tiny"] {
            PhysiConfig::preset(p).unwrap().validate().unwrap();
        }
    }
}
