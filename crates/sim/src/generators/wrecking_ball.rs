//! The `wrecking-ball` generator: a tower of `size^3` cubes and a ball swung into it.

use std::f32::consts::TAU;

use rand::Rng;
use serde::Serialize;

use crate::Result;
use crate::scene::{FloorSpec, Material, ObjectSpec, SceneSpec};
use crate::shapes::{Shape, ShapeKind};

/// Parameters of the WreckingBall generator: an `n x n x n` stack of cubes and a heavy ball
/// fired at it from a random direction.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WreckingBallParameters {
    /// Cubes per side of the stack.
    pub size: usize,
    /// Cube edge, metres.
    pub cube_edge: f32,
    /// Horizontal gap between neighbouring cubes, metres.
    pub gap: f32,
    /// Cube material.
    pub cube_material: Material,
    /// Ball radius, metres.
    pub ball_radius: f32,
    /// Ball material.
    pub ball_material: Material,
    /// Distance from the stack's face to the ball's surface at launch, metres.
    pub launch_distance: f32,
    /// Launch speed range, metres per second.
    pub speed: [f32; 2],
    /// Aim height range as a fraction of the stack height.
    pub aim_height: [f32; 2],
    /// Largest sideways aim offset as a fraction of the stack width.
    pub aim_offset: f32,
    /// The floor.
    pub floor: FloorSpec,
    /// Gravity, metres per second squared.
    pub gravity: [f32; 3],
    /// Physics steps the stack settles (without the ball) before frame 0.
    pub settle_steps: u32,
}

impl WreckingBallParameters {
    /// Default parameters for a stack of `size^3` cubes.
    pub fn new(size: usize) -> Self {
        Self {
            size,
            cube_edge: 0.4,
            gap: 0.002,
            cube_material: Material {
                friction: 0.5,
                restitution: 0.2,
                density: 1.0,
            },
            ball_radius: 0.5,
            ball_material: Material {
                friction: 0.4,
                restitution: 0.3,
                density: 7.8,
            },
            launch_distance: 4.0,
            speed: [6.0, 10.0],
            aim_height: [0.2, 0.8],
            aim_offset: 0.3,
            floor: FloorSpec {
                friction: 0.5,
                restitution: 0.2,
                half_extent: 40.0,
                thickness: 0.2,
            },
            gravity: [0.0, 0.0, -9.81],
            settle_steps: 240,
        }
    }
}

pub(super) fn sample_wrecking_ball<R: Rng + ?Sized>(
    p: &WreckingBallParameters,
    rng: &mut R,
) -> Result<SceneSpec> {
    let n = p.size;
    let cube = Shape::unit(ShapeKind::Cube, rng)?;
    let ball = Shape::unit(ShapeKind::Sphere, rng)?;
    let pitch = p.cube_edge + p.gap;
    let mut objects = Vec::with_capacity(n * n * n + 1);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let c = |a: usize| (a as f32 - 0.5 * (n as f32 - 1.0)) * pitch;
                objects.push(ObjectSpec {
                    shape: cube.clone(),
                    shape_id: 0,
                    scale: p.cube_edge,
                    material: p.cube_material,
                    material_kind: 0,
                    position: [c(i), c(j), 0.5 * p.cube_edge + k as f32 * p.cube_edge],
                    rotation: [0.0, 0.0, 0.0, 1.0],
                    linvel: [0.0; 3],
                    angvel: [0.0; 3],
                    held_until_settled: false,
                });
            }
        }
    }
    let half_width = 0.5 * (n as f32 * pitch - p.gap);
    let height = n as f32 * p.cube_edge;
    let azimuth = rng.random_range(0.0..TAU);
    let dir = [azimuth.cos(), azimuth.sin()];
    let side = [-dir[1], dir[0]];
    let offset = rng.random_range(-p.aim_offset..=p.aim_offset) * 2.0 * half_width;
    let aim_z = rng.random_range(p.aim_height[0]..=p.aim_height[1]) * height;
    let aim = [offset * side[0], offset * side[1], aim_z];
    // Start outside the stack's circumscribed circle so the ball clears every corner.
    let start_dist = half_width * std::f32::consts::SQRT_2 + p.launch_distance + p.ball_radius;
    let start = [
        aim[0] + start_dist * dir[0],
        aim[1] + start_dist * dir[1],
        aim_z.max(p.ball_radius),
    ];
    let speed = rng.random_range(p.speed[0]..=p.speed[1]);
    let flight = start_dist / speed;
    // Aim high by the drop over the flight time so the ball arrives at the aimed height.
    let vz = (aim_z - start[2]) / flight - 0.5 * p.gravity[2] * flight;
    objects.push(ObjectSpec {
        shape: ball,
        shape_id: 1,
        scale: 2.0 * p.ball_radius,
        material: p.ball_material,
        material_kind: 0,
        position: start,
        rotation: [0.0, 0.0, 0.0, 1.0],
        linvel: [-speed * dir[0], -speed * dir[1], vz],
        angvel: [0.0; 3],
        held_until_settled: true,
    });
    Ok(SceneSpec {
        objects,
        floor: p.floor,
        gravity: p.gravity,
        settle_steps: p.settle_steps,
        kinematic: Vec::new(),
    })
}
