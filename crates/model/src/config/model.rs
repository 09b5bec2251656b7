//! The architecture sizes and data conventions of a RigidFormer checkpoint ([`ModelConfig`]),
//! its presets and validation.

use serde::{Deserialize, Serialize};

use super::dynamics::DynamicsConfig;
use super::loss::LossConfig;
use super::normalization::FeatureNormalization;
use crate::ModelError;
use crate::trained_ranges::TrainedRanges;

/// Architecture name stored in a RigidFormer `config.json`; also the name a newly built or
/// trained model carries (a loaded checkpoint is named by its directory).
pub const RIGIDFORMER: &str = "rigidformer";

/// Current `config.json` format version.
pub const FORMAT_VERSION: u32 = 1;

/// Architecture and data conventions of a RigidFormer checkpoint (`config.json`).
///
/// Every size is a value here; nothing about the network shape is hard-coded.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    /// Architecture name; `"rigidformer"`.
    pub architecture: String,
    /// `config.json` format version ([`FORMAT_VERSION`]).
    pub format_version: u32,

    // ---- data conventions ----
    /// Interval of one recorded frame in seconds (MOVi-like: 1/24).
    pub dt_frame: f32,
    /// Gravity of the training data, m/s^2 (z up).
    pub gravity: [f32; 3],
    /// Nominal number of surface points per object the model was trained with (a hint for
    /// clients; any count from 1 to `max_points_per_object` is accepted).
    pub points_per_object: usize,
    /// Largest accepted point count per object.
    pub max_points_per_object: usize,
    /// Largest accepted number of objects in one scene.
    pub max_objects: usize,
    /// Contact feature radius, metres (default 0.25).
    pub contact_radius: f32,
    /// Height of the ground plane's top in metres, or `None` for no ground.
    pub ground_z: Option<f32>,
    /// Normalisation of the per-point features ([`DynamicsConfig::point_features`]).
    pub normalization: FeatureNormalization,
    /// Scale dividing relative point positions inside the encoder, metres.
    pub position_scale: f32,

    // ---- encoder ----
    /// Width of the per-point features (shared point MLP output; pooled by AVP).
    pub point_dim: usize,
    /// Number of set-abstraction centres per object (farthest point sampling).
    pub sa_centres: usize,
    /// Neighbours grouped around each centre (nearest points on the reference cloud).
    pub sa_neighbours: usize,
    /// Width of the first set-abstraction level.
    pub sa_dim: usize,

    // ---- decoder ----
    /// Token width D.
    pub width: usize,
    /// Attention heads; `width` must be divisible by it.
    pub heads: usize,
    /// Decoder blocks L.
    pub blocks: usize,
    /// Learned register tokens R.
    pub registers: usize,
    /// SwiGLU hidden width.
    pub ffn_hidden: usize,
    /// Hidden width of the FiLM MLPs (one pair per block).
    pub film_hidden: usize,
    /// Width of each head's rotary part (ARoPE); a multiple of 6 (x, y, z pairs), at most the
    /// head width. The rest of the head passes through.
    pub rope_dim: usize,
    /// Lowest ARoPE frequency, radians per metre.
    pub rope_freq_min: f32,
    /// Highest ARoPE frequency, radians per metre.
    pub rope_freq_max: f32,
    /// RMSNorm epsilon.
    pub norm_eps: f32,

    // ---- anchors ----
    /// Anchors per object K.
    pub anchors: usize,
    /// Initial AVP bandwidth sigma, metres (learned as log sigma).
    pub avp_sigma: f32,
    /// Decoder depths (block indices, 0-based) whose outputs the anchor queries attend to.
    pub anchor_taps: Vec<usize>,
    /// Acceleration output scale, metres per step^2: the head predicts `a / accel_scale`.
    pub accel_scale: f32,
    /// A second, coarse output unit, metres per step^2 like `accel_scale`: the head predicts
    /// three more numbers per anchor in this unit and adds them to the fine ones, so a
    /// bounce's correction (tenths of a metre) and a resting body's (tenths of a millimetre)
    /// are each O(1) in one of the two. `None` (absent in older `config.json` files): one unit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub accel_coarse_scale: Option<f32>,

    /// Training loss settings.
    pub loss: LossConfig,
    /// Input and output parametrisation; absent in older checkpoints (all off).
    #[serde(default)]
    pub dynamics: DynamicsConfig,
    /// Floor projection, metres: after the Kabsch fit, an object with a point more than this
    /// depth below `ground_z` is raised along z until its lowest point is at that depth (its
    /// rotation and horizontal position kept): the floor's non-penetration constraint applied
    /// to the network's answer, as the Kabsch fit applies rigidity, with the small
    /// penetration a contact solver keeps at rest (its slop) left alone. Kinematic objects
    /// are never raised. Applied by the inference step, which pushforward training also
    /// runs; the loss reads the network's anchors before it. `None` (absent in older
    /// `config.json` files): off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub floor_projection: Option<f32>,
    /// Mass, friction and restitution of the objects the model was trained on; the server
    /// warns about requests outside them. Absent in older `config.json` files and in models
    /// not yet trained (no warning then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trained_ranges: Option<TrainedRanges>,
}

/// The sizes a prepared scene's caches were built for (see [`ModelConfig::prepared_key`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PreparedKey {
    /// Anchors per object (K).
    pub anchors: usize,
    /// Set-abstraction centres per object.
    pub sa_centres: usize,
    /// Neighbours per set-abstraction centre.
    pub sa_neighbours: usize,
}

impl ModelConfig {
    /// The CPU-trainable configuration (width 128, 4 heads of 32, 6 blocks, 8 registers, K = 8,
    /// 32 centres x 8 neighbours in the encoder).
    pub fn small() -> ModelConfig {
        ModelConfig {
            architecture: RIGIDFORMER.into(),
            format_version: FORMAT_VERSION,
            dt_frame: 1.0 / 24.0,
            gravity: [0.0, 0.0, -10.0],
            points_per_object: 512,
            max_points_per_object: 8192,
            max_objects: 1024,
            contact_radius: 0.25,
            ground_z: Some(0.0),
            normalization: FeatureNormalization::defaults_for(&DynamicsConfig::residual()),
            position_scale: 0.5,
            point_dim: 32,
            sa_centres: 32,
            sa_neighbours: 8,
            sa_dim: 64,
            width: 128,
            heads: 4,
            blocks: 6,
            registers: 8,
            ffn_hidden: 512,
            film_hidden: 32,
            rope_dim: 24,
            rope_freq_min: 0.5,
            rope_freq_max: 16.0,
            norm_eps: 1e-6,
            anchors: 8,
            avp_sigma: 0.2,
            anchor_taps: vec![1, 3, 5],
            accel_scale: 0.02,
            accel_coarse_scale: None,
            loss: LossConfig::default(),
            dynamics: DynamicsConfig::residual(),
            floor_projection: None,
            trained_ranges: None,
        }
    }

    /// The paper's main configuration (width 256, 8 heads of 32, SwiGLU 4x, 8 blocks,
    /// 16 registers, K = 8; encoder 32 centres x 16 neighbours).
    pub fn paper() -> ModelConfig {
        ModelConfig {
            sa_neighbours: 16,
            width: 256,
            heads: 8,
            blocks: 8,
            registers: 16,
            ffn_hidden: 1024,
            anchor_taps: vec![1, 3, 5, 7],
            ..ModelConfig::small()
        }
    }

    /// A very small configuration for tests (width 32, 2 heads, 2 blocks).
    pub fn tiny() -> ModelConfig {
        ModelConfig {
            point_dim: 16,
            sa_centres: 8,
            sa_neighbours: 8,
            sa_dim: 16,
            width: 32,
            heads: 2,
            blocks: 2,
            registers: 2,
            ffn_hidden: 64,
            film_hidden: 8,
            rope_dim: 12,
            anchors: 4,
            anchor_taps: vec![0, 1],
            ..ModelConfig::small()
        }
    }

    /// What a prepared scene depends on: `(anchors, sa_centres, sa_neighbours)`. A scene
    /// prepared by one model steps on any model with the same key.
    pub fn prepared_key(&self) -> PreparedKey {
        PreparedKey {
            anchors: self.anchors,
            sa_centres: self.sa_centres,
            sa_neighbours: self.sa_neighbours,
        }
    }

    /// The first setting (its `config.json` name) in which `other` serves scenes differently
    /// from `self`, or `None`: the frame interval, gravity and ground, the request limits and
    /// nominal point count, the scene-relative mass, whether normals are estimated and whether
    /// the caller leads kinematic objects. Two such models can step one scene from one state,
    /// each from its own preparation when their [`PreparedKey`]s (anchor and grouping sizes)
    /// differ; their sizes, input features, normalisation and loss may differ too.
    pub fn serving_mismatch(&self, other: &ModelConfig) -> Option<&'static str> {
        let (a, b) = (&self.dynamics, &other.dynamics);
        [
            ("dt_frame", self.dt_frame == other.dt_frame),
            ("gravity", self.gravity == other.gravity),
            ("ground_z", self.ground_z == other.ground_z),
            (
                "points_per_object",
                self.points_per_object == other.points_per_object,
            ),
            (
                "max_points_per_object",
                self.max_points_per_object == other.max_points_per_object,
            ),
            ("max_objects", self.max_objects == other.max_objects),
            ("dynamics.relative_mass", a.relative_mass == b.relative_mass),
            (
                "dynamics.surface_normals or dynamics.approach (normals estimated)",
                a.reads_normals() == b.reads_normals(),
            ),
            (
                "dynamics.kinematic_lead",
                a.kinematic_lead == b.kinematic_lead,
            ),
        ]
        .into_iter()
        .find_map(|(name, same)| (!same).then_some(name))
    }

    /// Number of per-point input features (see [`DynamicsConfig::point_features`]).
    pub fn point_features(&self) -> usize {
        self.dynamics.point_features()
    }

    /// Width of one attention head.
    pub fn head_dim(&self) -> usize {
        self.width / self.heads.max(1)
    }

    /// Checks internal consistency; every violation is named.
    pub fn validate(&self) -> Result<(), ModelError> {
        let bad = |m: String| Err(ModelError::Checkpoint(format!("config.json: {m}")));
        if self.architecture != RIGIDFORMER {
            return bad(format!(
                "architecture {:?} is not supported (expected {RIGIDFORMER:?})",
                self.architecture
            ));
        }
        if self.format_version != FORMAT_VERSION {
            return bad(format!(
                "format_version {} is not supported (expected {FORMAT_VERSION})",
                self.format_version
            ));
        }
        let positive = [
            ("points_per_object", self.points_per_object),
            ("max_points_per_object", self.max_points_per_object),
            ("max_objects", self.max_objects),
            ("point_dim", self.point_dim),
            ("sa_centres", self.sa_centres),
            ("sa_neighbours", self.sa_neighbours),
            ("sa_dim", self.sa_dim),
            ("width", self.width),
            ("heads", self.heads),
            ("blocks", self.blocks),
            ("ffn_hidden", self.ffn_hidden),
            ("film_hidden", self.film_hidden),
            ("anchors", self.anchors),
        ];
        for (name, v) in positive {
            if v == 0 {
                return bad(format!("{name} must be > 0"));
            }
        }
        if !self.width.is_multiple_of(self.heads) {
            return bad(format!(
                "width {} is not divisible by heads {}",
                self.width, self.heads
            ));
        }
        if !self.rope_dim.is_multiple_of(6) || self.rope_dim > self.head_dim() {
            return bad(format!(
                "rope_dim {} must be a multiple of 6 and at most the head width {}",
                self.rope_dim,
                self.head_dim()
            ));
        }
        let finite_pos = [
            ("dt_frame", self.dt_frame),
            ("contact_radius", self.contact_radius),
            ("position_scale", self.position_scale),
            ("rope_freq_min", self.rope_freq_min),
            ("rope_freq_max", self.rope_freq_max),
            ("norm_eps", self.norm_eps),
            ("avp_sigma", self.avp_sigma),
            ("accel_scale", self.accel_scale),
            (
                "accel_coarse_scale",
                self.accel_coarse_scale.unwrap_or(self.accel_scale),
            ),
            ("loss.beta", self.loss.beta),
            ("loss.scale", self.loss.scale),
            ("loss.rest_weight", self.loss.rest_weight),
            (
                "loss.object_contact_weight",
                self.loss.object_contact_weight,
            ),
        ];
        for (name, v) in finite_pos {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("{name} must be finite and > 0, got {v}"));
            }
        }
        let w = self.loss.rotation_weight;
        if !(w.is_finite() && w >= 0.0) {
            return bad(format!(
                "loss.rotation_weight must be finite and >= 0, got {w}"
            ));
        }
        if self.rope_freq_max < self.rope_freq_min {
            return bad("rope_freq_max must be >= rope_freq_min".into());
        }
        if self.anchor_taps.is_empty() {
            return bad("anchor_taps must name at least one block".into());
        }
        if let Some(&t) = self.anchor_taps.iter().find(|&&t| t >= self.blocks) {
            return bad(format!(
                "anchor_taps entry {t} is not a block index (blocks = {})",
                self.blocks
            ));
        }
        let features = self.point_features();
        if self.normalization.mean.len() != features || self.normalization.std.len() != features {
            return bad(format!(
                "normalization: {} means and {} stds, the features need {features} of each",
                self.normalization.mean.len(),
                self.normalization.std.len()
            ));
        }
        if self
            .normalization
            .std
            .iter()
            .any(|s| !(s.is_finite() && *s > 0.0))
            || self.normalization.mean.iter().any(|m| !m.is_finite())
        {
            return bad("normalization: means must be finite and stds finite and > 0".into());
        }
        if self.gravity.iter().any(|g| !g.is_finite())
            || self.ground_z.is_some_and(|z| !z.is_finite())
            || self
                .loss
                .weights
                .iter()
                .any(|w| !(w.is_finite() && *w >= 0.0))
        {
            return bad("gravity, ground_z and loss.weights must be finite".into());
        }
        if self
            .floor_projection
            .is_some_and(|d| !(d.is_finite() && d >= 0.0))
        {
            return bad("floor_projection must be a finite depth >= 0 metres".into());
        }
        if let Some(r) = &self.trained_ranges {
            r.validate()
                .map_err(|m| ModelError::Checkpoint(format!("config.json: {m}")))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{BASE_POINT_FEATURES, InputGroup};

    #[test]
    fn presets_are_valid_and_round_trip() {
        for c in [
            ModelConfig::small(),
            ModelConfig::paper(),
            ModelConfig::tiny(),
        ] {
            c.validate().unwrap();
            let s = serde_json::to_string_pretty(&c).unwrap();
            let back: ModelConfig = serde_json::from_str(&s).unwrap();
            assert_eq!(back, c);
        }
        assert_eq!(ModelConfig::paper().head_dim(), 32);
    }

    /// `configs/small.json` and `configs/paper.json` are the presets; set
    /// `DYNASERVE_BLESS_CONFIGS=1` to rewrite them after changing a preset.
    #[test]
    fn shipped_config_files_match_presets() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
        for (name, preset) in [
            ("small", ModelConfig::small()),
            ("paper", ModelConfig::paper()),
        ] {
            let path = dir.join(format!("{name}.json"));
            if std::env::var_os("DYNASERVE_BLESS_CONFIGS").is_some() {
                let text = serde_json::to_string_pretty(&preset).unwrap() + "\n";
                std::fs::write(&path, text).unwrap();
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let parsed: ModelConfig = serde_json::from_str(&text).unwrap();
            assert_eq!(
                parsed,
                preset,
                "{} differs from ModelConfig::{name}()",
                path.display()
            );
        }
    }

    #[test]
    fn invalid_configs_are_named() {
        let mut c = ModelConfig::small();
        c.heads = 3;
        assert!(c.validate().unwrap_err().to_string().contains("heads"));
        let mut c = ModelConfig::small();
        c.anchor_taps = vec![9];
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("anchor_taps")
        );
        let mut c = ModelConfig::small();
        c.dynamics.contact_velocity = false;
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("the features need 12")
        );
    }

    /// A `config.json` written before the contact velocity (no such key, 12 constants) reads
    /// as a 12-feature model.
    #[test]
    fn input_groups_sit_after_the_base_features_in_layout_order() {
        let mut d = DynamicsConfig::default();
        assert_eq!(InputGroup::SurfaceNormals.offset(&d), BASE_POINT_FEATURES);
        InputGroup::ContactVelocity.set(&mut d, true);
        assert!(d.contact_velocity);
        assert_eq!(InputGroup::ContactVelocity.offset(&d), BASE_POINT_FEATURES);
        assert_eq!(InputGroup::SurfaceNormals.offset(&d), 15);
        InputGroup::SurfaceNormals.set(&mut d, true);
        assert_eq!(d.point_features(), 22);
        assert_eq!(FeatureNormalization::defaults_for(&d).len(), 22);
    }

    #[test]
    fn configs_without_contact_velocity_read_as_twelve_features() {
        let mut old = serde_json::to_value(ModelConfig::small()).unwrap();
        let dynamics = old["dynamics"].as_object_mut().unwrap();
        dynamics.remove("contact_velocity");
        old["normalization"] = serde_json::to_value(FeatureNormalization::default()).unwrap();
        let c: ModelConfig = serde_json::from_value(old).unwrap();
        c.validate().unwrap();
        assert!(!c.dynamics.contact_velocity);
        assert_eq!(c.point_features(), 12);
        assert_eq!(ModelConfig::small().point_features(), 15);
    }
}
