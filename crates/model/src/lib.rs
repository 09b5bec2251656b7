//! Learned physics world models in candle for Dynaserve: RigidFormer (anchors, ARoPE,
//! differentiable Kabsch) with a batched multi-scene step API and checkpoint loading.
//!
//! Callers use the [`WorldModel`] trait: [`WorldModel::prepare`] a scene once (validation,
//! anchors, encoder grouping), then [`WorldModel::step`] many scenes at once, or [`rollout`].
//! Trainers use [`RigidFormer::train_forward`] and [`RigidFormer::varmap`]. Scenes whose
//! kinematic objects follow given poses step by [`Drive`] (serving, evaluation and training
//! alike).
//! Units: metres, seconds, kilograms; z up; ground plane at z = 0; quaternions `[x, y, z, w]`.

pub mod api;
pub mod batching;
pub mod checkpoint;
pub mod config;
pub mod device;
pub mod drive;
pub mod ensemble;
pub mod error;
pub mod gradient;
pub mod kernels;
pub mod layers;
mod load_model;
pub mod physiformer;
mod prepare;
pub mod rigidformer;
pub mod runtime;
pub mod scene_threads;
pub mod team;
pub mod trained_ranges;

pub use api::{
    Carry, ObjectInput, Pose, PoseSpread, SceneState, SpreadStep, StepItem, WorldModel, rollout,
};
pub use batching::PassBudget;
pub use checkpoint::{load_rigidformer, read_architecture, read_config, save_tensors};
pub use config::{
    APPROACH_FEATURES, BASE_POINT_FEATURES, CONTACT_PARTNER_FEATURES, CONTACT_PARTNER_MAX_LN_RATIO,
    CONTACT_SUMMARY_FEATURES, CONTACT_VELOCITY_FEATURES, DynamicsConfig, FeatureNormalization,
    HISTORY_FEATURES, InputGroup, LN_MASS_FEATURE, LossConfig, ModelConfig, ModelUnit,
    OBJECT_SUMMARY_FEATURES, PreparedKey, SURFACE_NORMAL_FEATURES,
};
pub use device::{check_device_name, cuda_compiled, device_from_name, device_name};
pub use drive::{Drive, frame_targets};
pub use ensemble::Ensemble;
pub use error::ModelError;
pub use gradient::{CostTarget, GradientItem, PathCost, PathGradient, path_cost};
pub use kernels::kabsch::{self as kabsch_op, KabschOp};
pub use layers::Mode;
pub use load_model::load_model;
pub use physiformer::PhysiFormer;
pub use prepare::{
    MAX_BODY_EXTENT, MAX_DT_STEPS, MAX_WORLD_EXTENT, PreparedScene, model_masses, normalise_pose,
};
pub use rigidformer::features::{
    Body, CONTACT_PATCH_SCALE, FeatureFrame, ScenePoints, approach_features, body_normals,
    contact_partner_features, contact_summary, contact_velocity, history_features,
    nearest_object_gap, object_params, object_summary, raw_point_features, surface_normal_features,
};
pub use rigidformer::{RigidFormer, StepProfile, TrainItem, TrainOutput};
pub use runtime::{
    configure_compute, configure_compute_split, keep_freed_memory, training_elementwise_threads,
};
pub use trained_ranges::{OutOfRange, TrainedRanges};

/// Re-exported so callers can name devices and dtypes without depending on candle directly.
pub use candle_core::{DType, Device};
