//! What a dataset stores per scene and object, in memory: [`SceneRecord`], [`ObjectRecord`] and
//! a scenario scene's [`SceneLabel`].

use serde::{Deserialize, Serialize};

/// One object of a scene as stored in a dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectRecord {
    /// Centre of mass per frame, world frame, metres: `[T]`.
    pub positions: Vec<[f32; 3]>,
    /// Orientation per frame, unit quaternion `[x, y, z, w]` body to world: `[T]`.
    pub rotations: Vec<[f32; 4]>,
    /// Surface samples in the body frame (origin at the centre of mass), metres: `[P]`.
    pub reference_points: Vec<[f32; 3]>,
    /// Mass, kilograms.
    pub mass: f32,
    /// Friction coefficient.
    pub friction: f32,
    /// Restitution coefficient.
    pub restitution: f32,
    /// Scale of the unit shape per axis.
    pub scale: [f32; 3],
    /// Index into the manifest's shape list.
    pub shape_id: i32,
    /// 0 rigid, 1 elastic.
    pub material: i32,
    /// Kinematic: its poses were given (a pusher following a path), not simulated; the other
    /// objects react to it and it is not pushed back. Stored as the `kinematic` tensor, absent
    /// (all false) when no object of a shard is kinematic.
    pub kinematic: bool,
}

/// One scene: its objects and the interval between frames.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneRecord {
    /// The objects.
    pub objects: Vec<ObjectRecord>,
    /// Interval between recorded frames, seconds.
    pub dt_frame: f32,
}

/// What a scenario scene isolates, recorded per scene in the manifest's `scenarios`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SceneLabel {
    /// Scenario name: `rest`, `drop`, `slide`, `collide`, `stack-hit` or `push`.
    pub scenario: String,
    /// Arrangement within the scenario: `single`, `tower` or `pile` (rest), `drop`, `floor`
    /// (slide), `air` or `floor` (collide), `tower` (stack-hit), `single` or `group` (push).
    pub variant: String,
}
