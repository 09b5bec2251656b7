//! Drawing and placing scenario objects: random draws within the parameters' ranges, objects
//! drawn but not placed, their extents, and poses settled in a separate rapier world (objects
//! at rest on the floor, towers).

use std::f32::consts::TAU;

use rand::Rng;
use rapier3d::math::Rotation;

use super::parameters::ScenarioParameters;
use crate::random::random_rotation;
use crate::scene::{ObjectSpec, SceneSpec, SimConfig, SimWorld, pose_from_arrays};
use crate::shapes::{Shape, ShapeKind};
use crate::{Result, SimError};

/// Draws uniformly in `[r[0], r[1]]` (the value itself for an empty interval).
pub(super) fn uniform<R: Rng + ?Sized>(rng: &mut R, r: [f32; 2]) -> f32 {
    if r[0] < r[1] {
        rng.random_range(r[0]..=r[1])
    } else {
        r[0]
    }
}

pub(super) fn count<R: Rng + ?Sized>(rng: &mut R, r: [usize; 2]) -> usize {
    rng.random_range(r[0]..=r[1])
}

/// A unit vector uniform on the sphere.
pub(super) fn random_direction<R: Rng + ?Sized>(rng: &mut R) -> [f32; 3] {
    let z: f32 = rng.random_range(-1.0..=1.0);
    let a: f32 = rng.random_range(0.0..TAU);
    let s = (1.0 - z * z).max(0.0).sqrt();
    [s * a.cos(), s * a.sin(), z]
}

pub(super) fn quat(r: Rotation) -> [f32; 4] {
    [r.x, r.y, r.z, r.w]
}

/// An object drawn from the parameters (shape among `kinds`, scale, material), not placed.
pub(super) fn draw_object<R: Rng + ?Sized>(
    p: &ScenarioParameters,
    kinds: &[ShapeKind],
    rng: &mut R,
) -> Result<ObjectSpec> {
    let kind = kinds[rng.random_range(0..kinds.len())];
    let shape_id = p
        .shapes
        .iter()
        .position(|k| *k == kind)
        .ok_or_else(|| SimError::Invalid(format!("shape {kind:?} is not in the shape list")))?;
    let shape = Shape::unit(kind, rng)?;
    let scale = uniform(rng, p.scale);
    let material = match &p.material_ranges {
        Some(m) => m.draw(rng),
        None => p.materials[rng.random_range(0..p.materials.len())].1,
    };
    Ok(ObjectSpec::rigid(shape, shape_id as i32, scale, material))
}

/// Bounds of an object's collider at `rotation` about its centre of mass: (min, max), metres.
pub(super) fn extents(o: &ObjectSpec, rotation: [f32; 4]) -> Result<([f32; 3], [f32; 3])> {
    let (offset, shape) = o.scaled_shape().collider()?;
    let aabb = shape.compute_aabb(&(pose_from_arrays([0.0; 3], rotation) * offset));
    Ok((
        [aabb.mins.x, aabb.mins.y, aabb.mins.z],
        [aabb.maxs.x, aabb.maxs.y, aabb.maxs.z],
    ))
}

/// Radius of a sphere about the centre of mass that holds the object, metres.
pub(super) fn bounding_radius(o: &ObjectSpec) -> Result<f32> {
    let (lo, hi) = extents(o, [0.0, 0.0, 0.0, 1.0])?;
    Ok((0..3)
        .map(|k| lo[k].abs().max(hi[k].abs()).powi(2))
        .sum::<f32>()
        .sqrt())
}

/// A pose as a centre of mass position (m) and a unit quaternion `[x, y, z, w]`.
pub(super) type PoseArrays = ([f32; 3], [f32; 4]);

/// Steps `objects` (with their poses and velocities) in a world of their own until every body
/// is still (centre speed below 5 mm/s and spin below 0.02 rad/s for 0.25 s), at most
/// `max_steps` physics steps. Returns the settled poses, or `None` if they never came to rest.
pub(super) fn presettle(
    p: &ScenarioParameters,
    objects: &[ObjectSpec],
    max_steps: u32,
) -> Result<Option<Vec<PoseArrays>>> {
    let spec = SceneSpec {
        objects: objects.to_vec(),
        floor: p.floor,
        gravity: p.gravity,
        settle_steps: 0,
        kinematic: Vec::new(),
    };
    let cfg = SimConfig::default();
    let mut sim = SimWorld::new(&spec, &cfg)?;
    let hold = (cfg.physics_hz / 4).max(1);
    let mut still = 0u32;
    for _ in 0..max_steps {
        sim.world.step();
        let moving = sim.bodies.iter().any(|&h| {
            let b = &sim.world.bodies[h];
            b.linvel().length() > 5e-3 || b.angvel().length() > 0.02
        });
        still = if moving { 0 } else { still + 1 };
        if still >= hold {
            let poses = (0..objects.len())
                .map(|i| {
                    let pose = sim.pose(i);
                    let (t, q) = (pose.translation, pose.rotation);
                    ([t.x, t.y, t.z], [q.x, q.y, q.z, q.w])
                })
                .collect::<Vec<_>>();
            if poses
                .iter()
                .any(|(t, q)| !(t.iter().chain(q).all(|c| c.is_finite())))
            {
                return Ok(None);
            }
            return Ok(Some(poses));
        }
    }
    Ok(None)
}

/// Attempts at finding a configuration that comes to rest before giving up.
pub(super) const SETTLE_ATTEMPTS: usize = 16;

/// Settles `o` alone on the floor from `start` rotation (or random ones after a failure):
/// returns its resting rotation and centre height, with the object centred at x = y = 0.
pub(super) fn rest_on_floor<R: Rng + ?Sized>(
    p: &ScenarioParameters,
    o: &ObjectSpec,
    start: Option<[f32; 4]>,
    rng: &mut R,
) -> Result<([f32; 4], f32)> {
    for attempt in 0..SETTLE_ATTEMPTS {
        let rotation = match (attempt, start) {
            (0, Some(q)) => q,
            _ => random_rotation(rng),
        };
        let (lo, _) = extents(o, rotation)?;
        let mut probe = o.clone();
        probe.rotation = rotation;
        probe.position = [0.0, 0.0, 0.01 - lo[2]];
        probe.linvel = [0.0; 3];
        probe.angvel = [0.0; 3];
        if let Some(poses) = presettle(p, &[probe], p.presettle_max_steps)? {
            let (t, q) = poses[0];
            return Ok((q, t[2]));
        }
    }
    Err(SimError::Invalid(format!(
        "a {:?} of scale {} did not come to rest in {SETTLE_ATTEMPTS} attempts",
        o.shape.kind, o.scale
    )))
}

/// Upright (flat) start for shapes whose random landings can end on a round side or rim, where
/// a launched object would roll instead of slide.
pub(super) fn upright_start(kind: ShapeKind) -> Option<[f32; 4]> {
    match kind {
        ShapeKind::Cylinder
        | ShapeKind::Cone
        | ShapeKind::Mug
        | ShapeKind::Gear
        | ShapeKind::Torus => Some([0.0, 0.0, 0.0, 1.0]),
        _ => None,
    }
}

/// A tower of `n` cubes of scales drawn from `scale`, centred on the origin, with a common random yaw, each box offset by up to
/// `tower_offset` and turned by up to `tower_yaw` relative to the tower.
pub(super) fn tower<R: Rng + ?Sized>(
    p: &ScenarioParameters,
    n: usize,
    scale: [f32; 2],
    rng: &mut R,
) -> Result<Vec<ObjectSpec>> {
    let yaw = rng.random_range(0.0..TAU);
    let mut z = 0.0f32;
    let mut boxes = Vec::with_capacity(n);
    for _ in 0..n {
        let mut o = draw_object(p, &[ShapeKind::Cube], rng)?;
        o.scale = uniform(rng, scale);
        let turn = yaw + rng.random_range(-p.tower_yaw..=p.tower_yaw);
        let dx = rng.random_range(-p.tower_offset..=p.tower_offset);
        let dy = rng.random_range(-p.tower_offset..=p.tower_offset);
        o.rotation = quat(Rotation::from_rotation_z(turn));
        o.position = [dx, dy, z + 0.5 * o.scale];
        z += o.scale;
        boxes.push(o);
    }
    Ok(boxes)
}
