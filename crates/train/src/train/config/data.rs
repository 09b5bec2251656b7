//! The `[data]` section: where samples come from and how they are augmented, and the step
//! sizes any section may name.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::train::TrainError;

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
    /// impact, a pusher's first touch) instead of uniformly; see [`crate::train::events`]. The other
    /// samples, and validation windows, stay uniform. 0 disables.
    pub event_share: f32,
    /// Fraction of the samples whose window frame is drawn from the end of an object's
    /// motion (the last frames of a roll, slide or tumble and the first steps at rest; see
    /// [`crate::train::stops`]) instead of uniformly, among the samples `event_share` leaves
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

/// Whether `step_sizes` (frames) is a valid list of step sizes: non-empty, each in 1..=16.
pub(crate) fn valid_step_sizes(step_sizes: &[u32]) -> bool {
    !step_sizes.is_empty() && step_sizes.iter().all(|k| (1..=16).contains(k))
}
