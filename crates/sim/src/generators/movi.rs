//! The MOVi-like generators (`movi-a`, `movi-b`): Kubric's parameters and its scene sampler
//! (objects dropped at random poses without overlap, thrown towards the centre).

use rand::Rng;
use rapier3d::math::Pose;
use rapier3d::parry::query::intersection_test;
use rapier3d::prelude::SharedShape;
use serde::Serialize;

use crate::materials::{METAL, MOVI_FLOOR, RUBBER};
use crate::random::random_rotation;
use crate::scene::{FloorSpec, Material, ObjectSpec, SceneSpec};
use crate::shapes::{Shape, ShapeKind};
use crate::{Result, SimError};

/// How object scales are drawn.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ScaleDistribution {
    /// One of the listed values, uniformly.
    Choice(Vec<f32>),
    /// Uniform in `[low, high]`.
    Uniform {
        /// Lower bound.
        low: f32,
        /// Upper bound.
        high: f32,
    },
}

/// Parameters of the MOVi-like generators (Kubric's MOVi-A and MOVi-B worker), recorded in the
/// manifest.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MoviParameters {
    /// Fewest objects per scene.
    pub objects_min: usize,
    /// Most objects per scene.
    pub objects_max: usize,
    /// Shapes drawn uniformly.
    pub shapes: Vec<ShapeKind>,
    /// Scale distribution.
    pub scale: ScaleDistribution,
    /// Materials drawn uniformly: (name, material).
    pub materials: Vec<(String, Material)>,
    /// Spawn region lower corner, metres (shrunk by each object's bounding box).
    pub spawn_min: [f32; 3],
    /// Spawn region upper corner, metres.
    pub spawn_max: [f32; 3],
    /// Linear velocity is uniform in `[velocity_min, velocity_max]` minus `[x, y, 0]` of the
    /// spawn position (towards the centre), metres per second.
    pub velocity_min: [f32; 3],
    /// See `velocity_min`.
    pub velocity_max: [f32; 3],
    /// Placement attempts per object before the object is left out.
    pub spawn_attempts: usize,
    /// The floor.
    pub floor: FloorSpec,
    /// Gravity, metres per second squared.
    pub gravity: [f32; 3],
}

impl MoviParameters {
    /// Kubric's MOVi-A: cube, cylinder, sphere; scale 0.7 or 1.4.
    pub fn movi_a() -> Self {
        Self {
            shapes: ShapeKind::MOVI_A.to_vec(),
            scale: ScaleDistribution::Choice(vec![0.7, 1.4]),
            ..Self::movi_b()
        }
    }

    /// MOVi-B with the procedural shape set; scale uniform in [0.7, 1.4].
    pub fn movi_b() -> Self {
        Self {
            objects_min: 3,
            objects_max: 10,
            shapes: ShapeKind::MOVI_B.to_vec(),
            scale: ScaleDistribution::Uniform {
                low: 0.7,
                high: 1.4,
            },
            materials: vec![("metal".into(), METAL), ("rubber".into(), RUBBER)],
            spawn_min: [-5.0, -5.0, 1.0],
            spawn_max: [5.0, 5.0, 5.0],
            velocity_min: [-4.0, -4.0, 0.0],
            velocity_max: [4.0, 4.0, 0.0],
            spawn_attempts: 1000,
            floor: MOVI_FLOOR,
            gravity: [0.0, 0.0, -10.0],
        }
    }
}

fn world_shape(shape: &(Pose, SharedShape), pose: &Pose) -> Pose {
    *pose * shape.0
}

pub(super) fn sample_movi<R: Rng + ?Sized>(p: &MoviParameters, rng: &mut R) -> Result<SceneSpec> {
    if p.shapes.is_empty() || p.materials.is_empty() || p.objects_min > p.objects_max {
        return Err(SimError::Invalid("empty shape or material list".into()));
    }
    let count = rng.random_range(p.objects_min..=p.objects_max);
    let mut objects: Vec<ObjectSpec> = Vec::with_capacity(count);
    let mut placed: Vec<((Pose, SharedShape), Pose)> = Vec::with_capacity(count);
    for _ in 0..count {
        let shape_id = rng.random_range(0..p.shapes.len());
        let shape = Shape::unit(p.shapes[shape_id], rng)?;
        let scale = match &p.scale {
            ScaleDistribution::Choice(v) => v[rng.random_range(0..v.len())],
            ScaleDistribution::Uniform { low, high } => rng.random_range(*low..=*high),
        };
        let material = p.materials[rng.random_range(0..p.materials.len())].1;
        let collider = shape.scaled(scale).collider()?;
        let mut spot = None;
        for _ in 0..p.spawn_attempts {
            let rotation = random_rotation(rng);
            let rot = crate::scene::pose_from_arrays([0.0; 3], rotation);
            let aabb = collider.1.compute_aabb(&world_shape(&collider, &rot));
            // Drawn in axis order x, y, z.
            let position: [f32; 3] = std::array::from_fn(|k| {
                let lo = p.spawn_min[k] - aabb.mins[k];
                let hi = p.spawn_max[k] - aabb.maxs[k];
                if lo < hi {
                    rng.random_range(lo..hi)
                } else {
                    0.5 * (lo + hi)
                }
            });
            let pose = crate::scene::pose_from_arrays(position, rotation);
            let world = world_shape(&collider, &pose);
            let mut free = true;
            for (other, other_pose) in &placed {
                let hit = intersection_test(
                    &world,
                    collider.1.as_ref(),
                    &world_shape(other, other_pose),
                    other.1.as_ref(),
                )
                .map(|r| r.intersecting)
                .unwrap_or(true);
                if hit {
                    free = false;
                    break;
                }
            }
            if free {
                spot = Some((position, rotation, pose));
                break;
            }
        }
        let Some((position, rotation, pose)) = spot else {
            continue;
        };
        let mut linvel: [f32; 3] = std::array::from_fn(|k| {
            if p.velocity_min[k] < p.velocity_max[k] {
                rng.random_range(p.velocity_min[k]..p.velocity_max[k])
            } else {
                p.velocity_min[k]
            }
        });
        linvel[0] -= position[0];
        linvel[1] -= position[1];
        placed.push((collider, pose));
        objects.push(ObjectSpec {
            shape,
            shape_id: shape_id as i32,
            scale,
            material,
            material_kind: 0,
            position,
            rotation,
            linvel,
            angvel: [0.0; 3],
            held_until_settled: false,
        });
    }
    Ok(SceneSpec {
        objects,
        floor: p.floor,
        gravity: p.gravity,
        settle_steps: 0,
        kinematic: Vec::new(),
    })
}
