//! Recorded objects for the window samplers' unit tests.

use dynaserve_sim::ObjectRecord;

/// An unrotated object of one reference point at `positions` (metres, one per frame), 1 kg,
/// friction 0.5, restitution 0.2, kinematic or not.
pub(crate) fn object(positions: Vec<[f32; 3]>, kinematic: bool) -> ObjectRecord {
    ObjectRecord {
        rotations: vec![[0.0, 0.0, 0.0, 1.0]; positions.len()],
        positions,
        reference_points: vec![[0.0; 3]],
        mass: 1.0,
        friction: 0.5,
        restitution: 0.2,
        scale: [1.0; 3],
        shape_id: 0,
        material: 0,
        kinematic,
    }
}
