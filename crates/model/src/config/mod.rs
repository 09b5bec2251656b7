//! Model configuration: architecture sizes and the data conventions a checkpoint was trained
//! with. Stored as `config.json` in every checkpoint directory.
//!
//! Files: [`model`] ([`ModelConfig`], presets, validation), [`dynamics`] (the physics switches,
//! input groups and units), [`feature_layout`] (feature counts and positions),
//! [`normalization`] (the input features' constants), [`loss`] (training loss weights).
//! Every item is re-exported here, so `crate::config::X` names it.

pub mod dynamics;
pub mod feature_layout;
pub mod loss;
pub mod model;
pub mod normalization;

pub use self::dynamics::{DynamicsConfig, InputGroup, ModelUnit};
pub use self::feature_layout::{
    APPROACH_FEATURES, BASE_POINT_FEATURES, CONTACT_PARTNER_FEATURES, CONTACT_PARTNER_MAX_LN_RATIO,
    CONTACT_SUMMARY_FEATURES, CONTACT_VELOCITY_FEATURES, HISTORY_FEATURES, LN_MASS_FEATURE,
    OBJECT_SUMMARY_FEATURES, SURFACE_NORMAL_FEATURES,
};
pub use self::loss::{
    LossConfig, OBJECT_CONTACT_WEIGHT_DISTANCE_M, REST_ROTATION_PER_FRAME_RAD,
    REST_TRANSLATION_PER_FRAME_M, ROTATION_LEVER_ARM_M, ROTATION_MIN_RADIUS_M,
};
pub use self::model::{FORMAT_VERSION, ModelConfig, PreparedKey, RIGIDFORMER};
pub use self::normalization::FeatureNormalization;
