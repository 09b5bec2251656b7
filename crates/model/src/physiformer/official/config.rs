//! The sizes and data conventions of a network in the official PhysiFormer architecture, as
//! the official code reads them from a checkpoint's state dict and saved training arguments.

use serde::{Deserialize, Serialize};

use crate::ModelError;

/// Which tokens attend to each other in a block of the official pattern.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// All vertices of one frame (and the prefix tokens).
    Spatial,
    /// One vertex across all frames (and the prefix tokens).
    Temporal,
    /// The vertices of one object in one frame (and the prefix tokens).
    Object,
}

/// The official block pattern, repeated over the depth.
pub const DEFAULT_PATTERN: [Axis; 4] =
    [Axis::Spatial, Axis::Temporal, Axis::Object, Axis::Temporal];

/// Sinusoidal features of the flow time before the timestep MLP (the official 256).
pub const TIME_FEATURES: usize = 256;

/// RMSNorm epsilon of every norm of the official network.
pub const NORM_EPS: f32 = 1e-6;

/// The official network and the conversions between metres and its coordinates.
///
/// A position `p` (metres) enters the network as
/// `(((p - c) / h - coord_shift) / coord_scale - norm_mean) / norm_std` per axis, where `c` and
/// `h` are the centre and half extent of the scene box when `normalize_to_scene_box` (else 0
/// and 1); a velocity (m/s) as `v / h / coord_scale / norm_std` (the official inference's
/// conditioning; its velocities are not divided by a frame interval).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OfficialConfig {
    /// Token width D (`hidden_size`).
    pub hidden: usize,
    /// Transformer blocks (`depth`).
    pub depth: usize,
    /// Attention heads (`num_heads`); `hidden / heads` is even.
    pub heads: usize,
    /// SwiGLU hidden width (`int(hidden * mlp_ratio * 2 / 3)`).
    pub ffn_hidden: usize,
    /// Learned register tokens (`num_register_tokens`).
    pub registers: usize,
    /// Scene tokens (`num_scene_tokens`), 0 without scene conditioning.
    pub scene_tokens: usize,
    /// Width of the scene condition vector (9 with `--env_and_mat`, 10 without).
    pub scene_cond_dim: usize,
    /// Tokens the scene condition MLP writes (1, broadcast, or `scene_tokens`).
    pub scene_cond_out_tokens: usize,
    /// Width of an object's material row (2 with `--env_and_mat`), 0 without materials.
    pub material_dim: usize,
    /// Object slots (`max_num_objects`): the largest object count of a scene.
    pub max_objects: usize,
    /// Class labels of the label embedder (`num_classes`); its table has one more row.
    pub classes: usize,
    /// The label every call is conditioned on (the official inference's `--labels`, 0).
    pub label: usize,
    /// Rotary codes on (`use_rope`).
    pub rope: bool,
    /// Largest frame count (`max_frames`).
    pub max_frames: usize,
    /// Axis of block `i` is `pattern[i % len]`.
    pub pattern: Vec<Axis>,
    /// Positions and velocities are divided by this after the shift (`coord_scale`).
    pub coord_scale: f32,
    /// Subtracted from positions before scaling (`coord_shift`), metres.
    pub coord_shift: f32,
    /// Per-axis mean subtracted after scaling (`norm_mean`).
    pub norm_mean: [f32; 3],
    /// Per-axis divisor after the mean (`norm_std`).
    pub norm_std: [f32; 3],
    /// Positions are first mapped from the scene box to `[-1, 1]^3` (`normalize_to_scene_box`).
    pub normalize_to_scene_box: bool,
    /// The frame-0 condition carries vertex velocities (`--cond_first_frame_velocity`).
    pub velocity_condition: bool,
    /// Material row `(softness, friction)` of a rigid object (`material_*_rigid`).
    pub rigid_material: [f32; 2],
    /// Material row `(softness, friction)` of an elastic object (`material_*_soft`).
    pub elastic_material: [f32; 2],
}

impl OfficialConfig {
    /// Channels of one head.
    pub fn head_dim(&self) -> usize {
        self.hidden / self.heads.max(1)
    }

    /// Tokens before the vertex tokens: registers, then scene tokens.
    pub fn prefix_tokens(&self) -> usize {
        self.registers + self.scene_tokens
    }

    /// Coordinate frequencies per axis of the vertex rotary code: `max(1, (head_dim / 2) / 3)`.
    pub fn coord_freqs(&self) -> usize {
        (self.head_dim() / 2 / 3).max(1)
    }

    /// Axis of block `i`.
    pub fn axis(&self, i: usize) -> Axis {
        self.pattern[i % self.pattern.len()]
    }

    /// Per-axis affine map from metres to network coordinates: `x_n = (x - offset) / scale`
    /// for positions, `v_n = v / scale` for velocities, given the scene box half extent `h`
    /// (metres, centred at the origin).
    pub fn to_network(&self, half_extent: f32) -> ([f32; 3], [f32; 3]) {
        let h = if self.normalize_to_scene_box {
            half_extent
        } else {
            1.0
        };
        let mut scale = [0f32; 3];
        let mut offset = [0f32; 3];
        for a in 0..3 {
            scale[a] = h * self.coord_scale * self.norm_std[a];
            offset[a] = h * (self.coord_shift + self.coord_scale * self.norm_mean[a]);
        }
        (scale, offset)
    }

    /// Checks every size; the error names the field.
    pub fn validate(&self) -> Result<(), ModelError> {
        let bad = |m: String| Err(ModelError::Checkpoint(format!("official network: {m}")));
        for (name, v) in [
            ("hidden", self.hidden),
            ("depth", self.depth),
            ("heads", self.heads),
            ("ffn_hidden", self.ffn_hidden),
            ("max_objects", self.max_objects),
            ("classes", self.classes),
            ("max_frames", self.max_frames),
            ("pattern", self.pattern.len()),
        ] {
            if v == 0 {
                return bad(format!("{name} must be positive"));
            }
        }
        if !self.hidden.is_multiple_of(self.heads) || !self.head_dim().is_multiple_of(2) {
            return bad(format!(
                "hidden {} must split into {} heads of an even width",
                self.hidden, self.heads
            ));
        }
        if self.label > self.classes {
            return bad(format!(
                "label {} exceeds classes {}",
                self.label, self.classes
            ));
        }
        if self.scene_tokens > 0
            && self.scene_cond_out_tokens != 1
            && self.scene_cond_out_tokens != self.scene_tokens
        {
            return bad(format!(
                "the scene condition writes {} tokens; expected 1 or {}",
                self.scene_cond_out_tokens, self.scene_tokens
            ));
        }
        if self.scene_tokens > 0 && !matches!(self.scene_cond_dim, 9 | 10) {
            return bad(format!(
                "scene_cond_dim {} is neither 9 (--env_and_mat) nor 10",
                self.scene_cond_dim
            ));
        }
        if !matches!(self.material_dim, 0 | 2) {
            return bad(format!(
                "object_material_dim {} is not supported (2, the (softness, friction) rows of \
                 --env_and_mat, or 0)",
                self.material_dim
            ));
        }
        let positive = self.coord_scale.is_finite()
            && self.coord_scale > 0.0
            && self.norm_std.iter().all(|s| s.is_finite() && *s > 0.0);
        let finite = self.coord_shift.is_finite()
            && self.norm_mean.iter().all(|m| m.is_finite())
            && self
                .rigid_material
                .iter()
                .chain(&self.elastic_material)
                .all(|m| m.is_finite());
        if !positive || !finite {
            return bad(
                "coord_scale and norm_std must be finite and positive, coord_shift, norm_mean \
                 and the material rows finite"
                    .into(),
            );
        }
        Ok(())
    }
}
