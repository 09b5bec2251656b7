//! Kubric's materials and MOVi floor, shared by the MOVi generators, the physics scenarios and
//! the tests that rebuild their scenes.

use crate::scene::{FloorSpec, Material};

/// Kubric's metal: friction 0.4, restitution 0.3, density 2.7.
pub const METAL: Material = Material {
    friction: 0.4,
    restitution: 0.3,
    density: 2.7,
};
/// Kubric's rubber: friction 0.8, restitution 0.7, density 1.1.
pub const RUBBER: Material = Material {
    friction: 0.8,
    restitution: 0.7,
    density: 1.1,
};
/// Kubric's MOVi floor: friction 0.3, restitution 0.5, top at z = 0.
pub const MOVI_FLOOR: FloorSpec = FloorSpec {
    friction: 0.3,
    restitution: 0.5,
    half_extent: 40.0,
    thickness: 0.2,
};
