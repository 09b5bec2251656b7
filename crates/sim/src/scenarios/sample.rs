//! The scene samplers of every scenario (`rest`, `drop`, `slide`, `collide`, `stack-hit`,
//! `push`, `roll`) and [`sample_scenario`], which draws one of the parameters' scenarios and
//! labels its scene.

use std::f32::consts::{FRAC_PI_2, TAU};

use rand::Rng;
use rapier3d::math::{Rotation, Vector};

use super::parameters::{RestVariant, Scenario, ScenarioParameters};
use super::placement::{
    SETTLE_ATTEMPTS, bounding_radius, count, draw_object, extents, presettle, quat,
    random_direction, rest_on_floor, tower, uniform, upright_start,
};
use super::push::sample_push;
use crate::dataset::SceneLabel;
use crate::random::random_rotation;
use crate::scene::{ObjectSpec, SceneSpec};
use crate::{Result, SimError};

fn sample_rest<R: Rng + ?Sized>(
    p: &ScenarioParameters,
    rng: &mut R,
) -> Result<(Vec<ObjectSpec>, RestVariant)> {
    let variant = p.rest_variants[rng.random_range(0..p.rest_variants.len())];
    let objects = match variant {
        RestVariant::Single => {
            let n = count(rng, p.rest_singles);
            let mut objects = Vec::with_capacity(n);
            // In a row 2.5 m apart along a random direction: never touching.
            let a = rng.random_range(0.0..TAU);
            for i in 0..n {
                let mut o = draw_object(p, &p.rest_shapes, rng)?;
                let start = if rng.random_bool(0.5) {
                    upright_start(o.shape.kind)
                } else {
                    None
                };
                let (q, z) = rest_on_floor(p, &o, start, rng)?;
                let d = 2.5 * (i as f32 - 0.5 * (n as f32 - 1.0));
                o.rotation = q;
                o.position = [d * a.cos(), d * a.sin(), z];
                objects.push(o);
            }
            objects
        }
        RestVariant::Tower => {
            let n = count(rng, p.tower_boxes);
            tower(p, n, p.tower_scale, rng)?
        }
        RestVariant::Pile => sample_pile(p, rng)?,
    };
    Ok((objects, variant))
}

/// A few objects dropped from just above each other onto a small area and settled.
fn sample_pile<R: Rng + ?Sized>(p: &ScenarioParameters, rng: &mut R) -> Result<Vec<ObjectSpec>> {
    for _ in 0..SETTLE_ATTEMPTS {
        let n = count(rng, p.pile_objects);
        let mut objects = Vec::with_capacity(n);
        let mut z = 0.01f32;
        for _ in 0..n {
            let mut o = draw_object(p, &p.floor_shapes, rng)?;
            o.rotation = random_rotation(rng);
            let (lo, hi) = extents(&o, o.rotation)?;
            o.position = [
                rng.random_range(-0.25..=0.25),
                rng.random_range(-0.25..=0.25),
                z - lo[2],
            ];
            z += hi[2] - lo[2] + 0.01;
            objects.push(o);
        }
        if let Some(poses) = presettle(p, &objects, p.presettle_max_steps)? {
            for (o, (t, q)) in objects.iter_mut().zip(poses) {
                o.position = t;
                o.rotation = q;
            }
            return Ok(objects);
        }
    }
    Err(SimError::Invalid(format!(
        "no pile came to rest in {SETTLE_ATTEMPTS} attempts"
    )))
}

fn sample_drop<R: Rng + ?Sized>(p: &ScenarioParameters, rng: &mut R) -> Result<ObjectSpec> {
    let mut o = draw_object(p, &p.shapes, rng)?;
    o.rotation = random_rotation(rng);
    let (lo, _) = extents(&o, o.rotation)?;
    let h = uniform(rng, p.drop_height);
    o.position = [
        rng.random_range(-1.0..=1.0),
        rng.random_range(-1.0..=1.0),
        h - lo[2],
    ];
    let spin = rng.random_range(0.0..=p.drop_spin);
    o.angvel = random_direction(rng).map(|c| c * spin);
    Ok(o)
}

/// Round objects laid on their side (axis horizontal, settled there), spun about their axis
/// at the launch speed over the centre's height, as a cylinder rolling without slipping (a
/// cone or mug starts close to that and friction does the rest); lanes 3 m apart along the
/// axes.
fn sample_roll<R: Rng + ?Sized>(p: &ScenarioParameters, rng: &mut R) -> Result<Vec<ObjectSpec>> {
    let n = count(rng, p.roll_objects);
    let yaw = rng.random_range(0.0..TAU);
    let on_side = quat(Rotation::from_rotation_z(yaw) * Rotation::from_rotation_x(FRAC_PI_2));
    let mut objects = Vec::with_capacity(n);
    for i in 0..n {
        let mut o = draw_object(p, &p.roll_shapes, rng)?;
        let (q, z) = rest_on_floor(p, &o, Some(on_side), rng)?;
        // The body axis in the world, flattened: the object rolls about it. (Computed with
        // rapier's quaternion, as the committed roll data were generated.)
        let axis = Rotation::from_xyzw(q[0], q[1], q[2], q[3]) * Vector::Z;
        let flat = Vector::new(axis.x, axis.y, 0.0);
        let a = if flat.length() > 1e-3 {
            let f = flat.normalize();
            [f.x, f.y]
        } else {
            [yaw.cos(), yaw.sin()]
        };
        let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let speed = sign * uniform(rng, p.roll_speed);
        let spin = speed / z.max(0.05);
        // Rolling about `a` at `spin`: the centre moves along `a x z` at spin * height.
        let lane = 3.0 * (i as f32 - 0.5 * (n as f32 - 1.0));
        o.rotation = q;
        o.position = [lane * a[0], lane * a[1], z];
        o.angvel = [spin * a[0], spin * a[1], 0.0];
        o.linvel = [speed * a[1], -speed * a[0], 0.0];
        objects.push(o);
    }
    Ok(objects)
}

/// Effective friction coefficient of an object on the floor (Multiply rule).
fn floor_mu(p: &ScenarioParameters, o: &ObjectSpec) -> f32 {
    o.material.friction * p.floor.friction
}

fn sample_slide<R: Rng + ?Sized>(p: &ScenarioParameters, rng: &mut R) -> Result<Vec<ObjectSpec>> {
    let n = count(rng, p.slide_objects);
    let a = rng.random_range(0.0..TAU);
    let (dir, side) = ([a.cos(), a.sin()], [-a.sin(), a.cos()]);
    let g = -p.gravity[2];
    let mut objects = Vec::with_capacity(n);
    for i in 0..n {
        let mut o = draw_object(p, &p.floor_shapes, rng)?;
        let (q, z) = rest_on_floor(p, &o, upright_start(o.shape.kind), rng)?;
        let lane = 2.5 * (i as f32 - 0.5 * (n as f32 - 1.0));
        let cap = p.slide_stop_time * floor_mu(p, &o) * g;
        let speed = uniform(rng, [p.slide_speed[0], p.slide_speed[1].min(cap)]);
        let back = rng.random_range(0.0..=1.0);
        o.rotation = q;
        o.position = [
            lane * side[0] - back * dir[0],
            lane * side[1] - back * dir[1],
            z,
        ];
        o.linvel = [speed * dir[0], speed * dir[1], 0.0];
        objects.push(o);
    }
    Ok(objects)
}

fn sample_collide<R: Rng + ?Sized>(
    p: &ScenarioParameters,
    rng: &mut R,
) -> Result<(Vec<ObjectSpec>, &'static str)> {
    let a = rng.random_range(0.0..TAU);
    let (dir, side) = ([a.cos(), a.sin(), 0.0], [-a.sin(), a.cos(), 0.0]);
    if rng.random_bool(f64::from(p.collide_air_fraction)) {
        // In the air: both centres would meet at the aim point at time `t` without the impact.
        let mut objects = [
            draw_object(p, &p.shapes, rng)?,
            draw_object(p, &p.shapes, rng)?,
        ];
        let r = [bounding_radius(&objects[0])?, bounding_radius(&objects[1])?];
        let speed = [uniform(rng, p.collide_speed), uniform(rng, p.collide_speed)];
        let mut t = uniform(rng, p.collide_air_time);
        // Start clear of each other by at least 20 cm.
        t = t.max((r[0] + r[1] + 0.2) / (speed[0] + speed[1]));
        let z = r[0].max(r[1]) + uniform(rng, p.collide_air_clearance);
        let offset = rng.random_range(-p.collide_offset..=p.collide_offset) * (r[0] + r[1]);
        let g = p.gravity;
        for (k, o) in objects.iter_mut().enumerate() {
            let sign = if k == 0 { 1.0 } else { -1.0 };
            let aim: [f32; 3] = std::array::from_fn(|c| 0.5 * sign * offset * side[c]);
            let aim = [aim[0], aim[1], z];
            let start: [f32; 3] = std::array::from_fn(|c| aim[c] - sign * speed[k] * t * dir[c]);
            o.position = start;
            o.linvel = std::array::from_fn(|c| (aim[c] - start[c]) / t - 0.5 * g[c] * t);
            o.rotation = random_rotation(rng);
            let spin = rng.random_range(0.0..=p.collide_spin);
            o.angvel = random_direction(rng).map(|c| c * spin);
        }
        Ok((objects.to_vec(), "air"))
    } else {
        // Along the floor: both resting on a face, launched towards each other, the gap
        // measured along the approach direction and each fast enough to cross half of it
        // against friction.
        let mut objects = Vec::with_capacity(2);
        let gap = uniform(rng, p.collide_floor_gap);
        // Per object: extent towards the other and half-width across the approach.
        let mut front = [0.0f32; 2];
        let mut width = [0.0f32; 2];
        let to_dir_frame = Rotation::from_rotation_z(-a);
        for k in 0..2 {
            let mut o = draw_object(p, &p.floor_shapes, rng)?;
            let (q, z) = rest_on_floor(p, &o, upright_start(o.shape.kind), rng)?;
            o.rotation = q;
            o.position[2] = z;
            let local = quat(to_dir_frame * Rotation::from_xyzw(q[0], q[1], q[2], q[3]));
            let (lo, hi) = extents(&o, local)?;
            front[k] = if k == 0 { hi[0] } else { -lo[0] };
            width[k] = lo[1].abs().max(hi[1].abs());
            objects.push(o);
        }
        let offset = rng.random_range(-p.collide_offset..=p.collide_offset) * (width[0] + width[1]);
        let g = -p.gravity[2];
        for (k, o) in objects.iter_mut().enumerate() {
            let sign = if k == 0 { -1.0 } else { 1.0 };
            let d = 0.5 * gap + front[k];
            let least = 1.2 * (floor_mu(p, o) * g * gap).sqrt();
            let low = p.collide_speed[0].max(least);
            let speed = uniform(rng, [low, p.collide_speed[1].max(low)]);
            let s = 0.5 * sign * offset;
            o.position[0] = sign * d * dir[0] + s * side[0];
            o.position[1] = sign * d * dir[1] + s * side[1];
            o.linvel = [-sign * speed * dir[0], -sign * speed * dir[1], 0.0];
        }
        Ok((objects, "floor"))
    }
}

fn sample_stack_hit<R: Rng + ?Sized>(
    p: &ScenarioParameters,
    rng: &mut R,
) -> Result<Vec<ObjectSpec>> {
    let n = count(rng, p.stack_boxes);
    let mut objects = tower(p, n, p.stack_scale, rng)?;
    let height: f32 = objects.iter().map(|o| o.scale).sum();
    let half_width = objects.iter().map(|o| 0.5 * o.scale).fold(0.0, f32::max);
    let mut ball = draw_object(p, &p.shapes, rng)?;
    ball.scale = uniform(rng, p.projectile_scale);
    let r = bounding_radius(&ball)?;
    let a = rng.random_range(0.0..TAU);
    let dir = [a.cos(), a.sin()];
    let aim_z = uniform(rng, p.projectile_aim) * height;
    let dist = half_width * std::f32::consts::SQRT_2 + p.projectile_distance + r;
    let start = [dist * dir[0], dist * dir[1], aim_z.max(r + 0.05)];
    let speed = uniform(rng, p.projectile_speed);
    let flight = dist / speed;
    let vz = (aim_z - start[2]) / flight - 0.5 * p.gravity[2] * flight;
    ball.position = start;
    ball.rotation = random_rotation(rng);
    ball.linvel = [-speed * dir[0], -speed * dir[1], vz];
    ball.held_until_settled = true;
    objects.push(ball);
    Ok(objects)
}

/// Draws one scenario scene and its label. `rest` and `stack-hit` scenes settle for
/// `settle_steps` before frame 0 (the thrown object held out); the others start at once from
/// pre-settled poses. A `push` scene's pusher is kinematic ([`SceneSpec::kinematic`]).
pub fn sample_scenario<R: Rng + ?Sized>(
    p: &ScenarioParameters,
    rng: &mut R,
) -> Result<(SceneSpec, SceneLabel)> {
    p.validate()?;
    let scenario = p.scenarios[rng.random_range(0..p.scenarios.len())];
    let mut kinematic = Vec::new();
    let (objects, variant, settle) = match scenario {
        Scenario::Rest => {
            let (o, v) = sample_rest(p, rng)?;
            (o, v.name(), p.settle_steps)
        }
        Scenario::Drop => (vec![sample_drop(p, rng)?], "drop", 0),
        Scenario::Slide => (sample_slide(p, rng)?, "floor", 0),
        Scenario::Collide => {
            let (o, v) = sample_collide(p, rng)?;
            (o, v, 0)
        }
        Scenario::StackHit => (sample_stack_hit(p, rng)?, "tower", p.settle_steps),
        Scenario::Roll => (sample_roll(p, rng)?, "floor", 0),
        Scenario::Push => {
            let (o, path, v) = sample_push(p, rng)?;
            kinematic.push(path);
            (o, v, 0)
        }
    };
    Ok((
        SceneSpec {
            objects,
            floor: p.floor,
            gravity: p.gravity,
            settle_steps: settle,
            kinematic,
        },
        SceneLabel {
            scenario: scenario.name().to_string(),
            variant: variant.to_string(),
        },
    ))
}
