//! What a network evaluation takes: scenes with their noisy trajectories and flow times
//! ([`DenoiseItem`]), or scenes prepared once per sample ([`PreparedScene`],
//! [`PreparedItem`]), and the trajectory prior the network's output may correct
//! ([`prior_trajectory`], defined in [`super::prior`]).

use super::official::OfficialScene;
pub use super::prior::prior_trajectory;
use super::scene::MeshScene;

/// One scene of a network evaluation: its condition, its current noisy trajectory and its own
/// flow time.
#[derive(Clone, Copy, Debug)]
pub struct DenoiseItem<'a> {
    /// The scene's condition.
    pub scene: &'a MeshScene,
    /// Noisy trajectory `[frames, V, 3]` flattened, metres.
    pub z: &'a [f32],
    /// Frames of this trajectory (frame 0 included).
    pub frames: usize,
    /// Flow time in `[0, 1]` (0 noise, 1 data).
    pub t: f32,
}

/// A scene prepared for sampling (see [`super::PhysiFormer::prepare`]): everything a
/// network evaluation needs from the scene that does not change between its denoising steps
/// (the embedded frame-0 condition, prefix tokens, object layout, frame code and prior), built
/// once per sample and kept with it. Only the noisy trajectory and the flow time change per
/// step ([`PreparedItem`]).
#[derive(Clone, Debug)]
pub struct PreparedScene {
    pub(crate) scene: OfficialScene,
}

impl PreparedScene {
    /// Frames the scene was prepared for (frame 0 included).
    pub fn frames(&self) -> usize {
        self.scene.frames()
    }

    /// Number of vertices V.
    pub fn vertices(&self) -> usize {
        self.scene.vertices()
    }
}

/// One prepared scene of a network evaluation: its current noisy trajectory and its own flow
/// time.
#[derive(Clone, Copy, Debug)]
pub struct PreparedItem<'a> {
    /// The prepared scene.
    pub scene: &'a PreparedScene,
    /// Noisy trajectory `[frames, V, 3]` flattened, metres (`frames` of the preparation).
    pub z: &'a [f32],
    /// Flow time in `[0, 1]` (0 noise, 1 data).
    pub t: f32,
}
