//! The `push` scenario: 1-3 objects resting on the floor (settled alone, then turned about z)
//! in a chain, each `push_gap` beyond the previous one's bounding circle in a direction turning
//! by up to `push_turn`, and a kinematic pusher (a cube `push_clearance` above the floor, the
//! scene's last object) following a random smooth path through them.
//!
//! The path is a Catmull-Rom spline through waypoints: a start behind the first object, each
//! object's centre shifted sideways by up to `push_lateral` of its bounding radius, and a point
//! `push_tail` beyond the last one. The pusher keeps its starting yaw and travels along the spline by
//! arc length at a speed that ramps up linearly from rest over `push_ramp` seconds to a cruise
//! speed drawn from `push_speed`. With `push_jitter` its velocity also changes at random from
//! frame to frame, as a planner's pusher does.

use std::f32::consts::TAU;

use rand::Rng;
use rapier3d::math::Rotation;

use super::parameters::ScenarioParameters;
use super::placement::{
    bounding_radius, count, draw_object, quat, rest_on_floor, uniform, upright_start,
};
use crate::Result;
use crate::scene::{KinematicPath, ObjectSpec, SimConfig};
use crate::shapes::ShapeKind;

/// Samples per spline segment of the arc-length table.
const SEGMENT_SAMPLES: usize = 64;

/// A planar polyline with its cumulative arc length, walked by distance.
struct ArcPath {
    points: Vec<[f32; 2]>,
    lengths: Vec<f32>,
}

impl ArcPath {
    /// The Catmull-Rom spline through `waypoints` (at least two), finely sampled.
    fn catmull_rom(waypoints: &[[f32; 2]]) -> ArcPath {
        let n = waypoints.len();
        let at = |i: isize| waypoints[i.clamp(0, n as isize - 1) as usize];
        let mut points = vec![waypoints[0]];
        for i in 0..n as isize - 1 {
            let (p0, p1, p2, p3) = (at(i - 1), at(i), at(i + 1), at(i + 2));
            for k in 1..=SEGMENT_SAMPLES {
                let t = k as f32 / SEGMENT_SAMPLES as f32;
                let (t2, t3) = (t * t, t * t * t);
                let c = |a: f32, b: f32, c: f32, d: f32| {
                    0.5 * (2.0 * b
                        + (c - a) * t
                        + (2.0 * a - 5.0 * b + 4.0 * c - d) * t2
                        + (3.0 * b - a - 3.0 * c + d) * t3)
                };
                points.push([c(p0[0], p1[0], p2[0], p3[0]), c(p0[1], p1[1], p2[1], p3[1])]);
            }
        }
        let mut lengths = vec![0.0];
        for w in points.windows(2) {
            let d = ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt();
            lengths.push(lengths[lengths.len() - 1] + d);
        }
        ArcPath { points, lengths }
    }

    /// The point `s` metres along the path (its end beyond the last point).
    fn at(&self, s: f32) -> [f32; 2] {
        let i = self.lengths.partition_point(|&l| l < s);
        if i == 0 {
            return self.points[0];
        }
        if i >= self.points.len() {
            return self.points[self.points.len() - 1];
        }
        let (l0, l1) = (self.lengths[i - 1], self.lengths[i]);
        let f = if l1 > l0 { (s - l0) / (l1 - l0) } else { 0.0 };
        let (a, b) = (self.points[i - 1], self.points[i]);
        [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])]
    }
}

/// Distance travelled after `t` seconds at a speed ramping linearly from 0 to `v` over `ramp`
/// seconds and constant after, metres.
fn travelled(t: f32, v: f32, ramp: f32) -> f32 {
    if t < ramp {
        0.5 * v * t * t / ramp
    } else {
        v * (t - 0.5 * ramp)
    }
}

/// Draws a push scene: the pushed objects, then the pusher (the last object) and its path for
/// the frames of `SimConfig::default()`.
pub(super) fn sample_push<R: Rng + ?Sized>(
    p: &ScenarioParameters,
    rng: &mut R,
) -> Result<(Vec<ObjectSpec>, KinematicPath, &'static str)> {
    let n = count(rng, p.push_objects);
    let heading = rng.random_range(0.0..TAU);
    let mut objects = Vec::with_capacity(n + 1);
    let mut waypoints = Vec::with_capacity(n + 2);
    let (mut centre, mut dir, mut last_r) = ([0.0f32; 2], [heading.cos(), heading.sin()], 0.0);
    for i in 0..n {
        let mut o = draw_object(p, &p.floor_shapes, rng)?;
        let (q, z) = rest_on_floor(p, &o, upright_start(o.shape.kind), rng)?;
        let r = bounding_radius(&o)?;
        if i > 0 {
            let turn = rng.random_range(-p.push_turn..=p.push_turn);
            let a = dir[1].atan2(dir[0]) + turn;
            dir = [a.cos(), a.sin()];
            let gap = uniform(rng, p.push_gap);
            let d = last_r + r + gap;
            centre = [centre[0] + d * dir[0], centre[1] + d * dir[1]];
        }
        let yaw = Rotation::from_rotation_z(rng.random_range(0.0..TAU));
        o.rotation = quat(yaw * Rotation::from_xyzw(q[0], q[1], q[2], q[3]));
        o.position = [centre[0], centre[1], z];
        let side = rng.random_range(-p.push_lateral..=p.push_lateral) * r;
        waypoints.push([centre[0] - side * dir[1], centre[1] + side * dir[0]]);
        last_r = r;
        objects.push(o);
    }
    let mut pusher = draw_object(p, &[ShapeKind::Cube], rng)?;
    pusher.scale = uniform(rng, p.pusher_scale);
    let half = 0.5 * pusher.scale;
    let first_r = bounding_radius(&objects[0])?;
    let back = first_r + std::f32::consts::SQRT_2 * half + uniform(rng, p.push_approach);
    let start = [
        objects[0].position[0] - back * heading.cos(),
        objects[0].position[1] - back * heading.sin(),
    ];
    waypoints.insert(0, start);
    let beyond = last_r + p.push_tail;
    waypoints.push([centre[0] + beyond * dir[0], centre[1] + beyond * dir[1]]);
    let z = half + p.push_clearance;
    let rotation = quat(Rotation::from_rotation_z(heading));
    pusher.position = [start[0], start[1], z];
    pusher.rotation = rotation;
    let path = ArcPath::catmull_rom(&waypoints);
    let speed = uniform(rng, p.push_speed);
    let cfg = SimConfig::default();
    let dt = cfg.dt_frame();
    // Drawn only with jitter, so scenes without it keep their random streams.
    let mut offset = [0.0f32; 2];
    let poses = (1..cfg.frames)
        .map(|f| {
            let xy = path.at(travelled(f as f32 * dt, speed, p.push_ramp));
            if p.push_jitter > 0.0 {
                for o in &mut offset {
                    *o += dt * rng.random_range(-p.push_jitter..=p.push_jitter);
                }
            }
            ([xy[0] + offset[0], xy[1] + offset[1], z], rotation)
        })
        .collect();
    objects.push(pusher);
    let variant = if n == 1 { "single" } else { "group" };
    Ok((objects, KinematicPath { object: n, poses }, variant))
}
