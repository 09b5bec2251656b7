//! The procedural shape set: unit shapes as unions of convex parts, their rapier colliders and
//! exact surface samples.
//!
//! Every unit shape fits `[-0.5, 0.5]^3` with its longest bounding-box side equal to 1 (Kubric's
//! convention) and is then moved so that its centre of mass (uniform density) is the origin of
//! its body frame. Curved primitives (sphere, cylinder, cone) are rapier's exact shapes; every
//! other shape is a union of convex polyhedra that touch but do not overlap, so its volume (and
//! hence its mass) is the sum of its parts'. Reference clouds are sampled from the surface of
//! exactly the solid the physics engine simulates.
//!
//! - `kind`: the [`ShapeKind`]s and their names;
//! - `part`: the convex [`Part`]s a shape is made of;
//! - `builders`: how each unit shape's parts are built;
//! - `shape`: [`Shape`], the union of parts, with its collider and surface samples.

mod builders;
mod kind;
mod part;
mod shape;

pub use builders::ROUND_SEGMENTS;
pub use kind::ShapeKind;
pub use part::{Part, Polytope};
pub use shape::Shape;

#[cfg(test)]
mod tests;
