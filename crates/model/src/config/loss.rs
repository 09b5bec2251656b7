//! The one-step training loss of a RigidFormer: its weights ([`LossConfig`]) and the
//! thresholds of its resting, contact and rotation terms.

use serde::{Deserialize, Serialize};

/// Weights of the one-step training loss (equal weights by default; see `docs/rigidformer.md`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossConfig {
    /// Smooth L1 transition point, in units of `scale` (dimensionless).
    pub beta: f32,
    /// Differences (metres, or metres per step^2) are divided by this before the Smooth L1, so
    /// the loss sees O(1) numbers. Metres.
    pub scale: f32,
    /// Weights of `[pos_pre, acc_pre, pos_post, acc_post]`.
    pub weights: [f32; 4],
    /// Factor on the errors of objects at rest in the training window (ground truth: the
    /// previous, current and target poses within [`REST_TRANSLATION_PER_FRAME_M`] and
    /// [`REST_ROTATION_PER_FRAME_RAD`] per frame of each other); 1 weighs them as any
    /// object. Dimensionless, > 0; absent in older `config.json` files, which means 1.
    #[serde(default = "unit_weight")]
    pub rest_weight: f32,
    /// Factor on the errors of moving objects that touch another object at the window's
    /// current frame t: some point of theirs within [`OBJECT_CONTACT_WEIGHT_DISTANCE_M`] of
    /// another object's point (the contact search the inputs run anyway). Resting objects keep
    /// `rest_weight`. 1 weighs them as any object. Dimensionless, > 0; absent in older
    /// `config.json` files, which means 1.
    #[serde(default = "unit_weight")]
    pub object_contact_weight: f32,
    /// Weight of a fifth loss term on each object's rotation error: the post-projection
    /// anchor errors less their mean over the object's anchors (what is left is the rotation
    /// error times each anchor's lever arm), rescaled to a lever arm of
    /// [`ROTATION_LEVER_ARM_M`] by the object's anchor radius, so an error of so many degrees
    /// weighs the same on a small object as on a large one (the anchor terms weigh it by the
    /// object's size; the evaluation scores degrees). Same units, step-size balance and object
    /// weights as the anchor terms. Dimensionless, >= 0; 0, or absent in older `config.json`
    /// files, leaves the method's four terms alone.
    #[serde(default)]
    pub rotation_weight: f32,
}

/// Lever arm at which [`LossConfig::rotation_weight`]'s term measures rotation errors, metres,
/// about the anchor radius of a MOVi-sized object (unit shapes at scale 0.7-1.4): one loss unit
/// (1 mm) there is 2 milliradians (0.11 degrees).
pub const ROTATION_LEVER_ARM_M: f32 = 0.5;

/// Smallest anchor radius [`LossConfig::rotation_weight`]'s term divides by, metres.
pub const ROTATION_MIN_RADIUS_M: f32 = 0.01;

/// Contact test of [`LossConfig::object_contact_weight`]: largest distance from one of an
/// object's points to another object's point, metres.
pub const OBJECT_CONTACT_WEIGHT_DISTANCE_M: f32 = 0.1;

/// Resting test of [`LossConfig::rest_weight`]: largest centre displacement per frame, metres
/// (0.5 mm a frame: 1.2 cm/s at 24 frames a second).
pub const REST_TRANSLATION_PER_FRAME_M: f32 = 5.0e-4;
/// Resting test of [`LossConfig::rest_weight`]: largest rotation per frame, radians (0.05
/// degrees a frame: 1.2 degrees a second at 24 frames a second).
pub const REST_ROTATION_PER_FRAME_RAD: f32 = 8.7e-4;

fn unit_weight() -> f32 {
    1.0
}

impl Default for LossConfig {
    fn default() -> Self {
        // Quadratic only below 1 mm: every larger error pulls with the same force, so the
        // millimetre precision that keeps resting objects still is not drowned by the large,
        // barely predictable errors of impacts (with 1 cm, a resting object's 1.5 mm one-step
        // error weighed a hundredth of an impact's).
        LossConfig {
            beta: 1.0,
            scale: 0.001,
            weights: [1.0; 4],
            rest_weight: 1.0,
            object_contact_weight: 1.0,
            rotation_weight: 0.0,
        }
    }
}
