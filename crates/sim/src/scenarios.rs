//! Physics scenario generators: scenes that each isolate one behaviour (`rest`, `drop`,
//! `slide`, `collide`, `stack-hit`) with MOVi-B's shapes, materials, floor and gravity, and
//! `physics-mix`, which draws one of them per scene.
//!
//! Objects that start on the floor or on each other are first settled in a separate rapier
//! world (dropped from 1 cm with zero velocity and stepped until every body is still), so
//! they start on a stable face at the equilibrium of rapier's soft contacts. Every scene's
//! scenario and variant is returned with it ([`SceneLabel`]) and recorded in the manifest.

use std::f32::consts::TAU;

use rand::Rng;
use rapier3d::math::Rotation;
use serde::{Deserialize, Serialize};

use crate::dataset::SceneLabel;
use crate::materials::{METAL, MOVI_FLOOR, RUBBER};
use crate::random::random_rotation;
use crate::scene::{
    FloorSpec, Material, ObjectSpec, SceneSpec, SimConfig, SimWorld, pose_from_arrays,
};
use crate::shapes::{Shape, ShapeKind};
use crate::{Result, SimError};

/// One behaviour a scenario scene isolates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Scenario {
    /// Objects at rest from frame 0: single objects, box towers, settled piles.
    Rest,
    /// One object dropped with random attitude and spin, bouncing and settling.
    Drop,
    /// Objects resting on the floor launched horizontally; friction stops them.
    Slide,
    /// Two objects thrown at each other, in the air or along the floor.
    Collide,
    /// A small box tower hit by a thrown object (the last object of the scene).
    StackHit,
}

impl Scenario {
    /// All scenarios, in the order `physics-mix` draws from.
    pub const ALL: [Scenario; 5] = [
        Scenario::Rest,
        Scenario::Drop,
        Scenario::Slide,
        Scenario::Collide,
        Scenario::StackHit,
    ];

    /// Name as used on the command line and in manifests.
    pub fn name(self) -> &'static str {
        match self {
            Scenario::Rest => "rest",
            Scenario::Drop => "drop",
            Scenario::Slide => "slide",
            Scenario::Collide => "collide",
            Scenario::StackHit => "stack-hit",
        }
    }

    /// The scenario of a name written by [`Scenario::name`].
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }
}

/// Arrangements of the `rest` scenario.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RestVariant {
    /// One to `rest_singles` objects of any shape, each alone on the floor.
    Single,
    /// A tower of cubes.
    Tower,
    /// A few objects dropped onto each other and settled.
    Pile,
}

impl RestVariant {
    /// Name recorded as the scene's variant.
    pub fn name(self) -> &'static str {
        match self {
            RestVariant::Single => "single",
            RestVariant::Tower => "tower",
            RestVariant::Pile => "pile",
        }
    }
}

/// Parameters of the scenario generators, recorded in the manifest. Ranges `[a, b]` are
/// drawn uniformly (integers inclusive).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScenarioParameters {
    /// Scenarios drawn uniformly per scene (one entry for a single-scenario generator).
    pub scenarios: Vec<Scenario>,
    /// Shapes drawn uniformly; `shape_id` indexes this list.
    pub shapes: Vec<ShapeKind>,
    /// Uniform scale range of the unit shapes.
    pub scale: [f32; 2],
    /// Materials drawn uniformly: (name, material).
    pub materials: Vec<(String, Material)>,
    /// The floor.
    pub floor: FloorSpec,
    /// Gravity, metres per second squared.
    pub gravity: [f32; 3],
    /// Physics steps run before frame 0 in `rest` and `stack-hit` scenes.
    pub settle_steps: u32,
    /// Longest pre-settling of objects placed on the floor or on a pile, physics steps.
    pub presettle_max_steps: u32,
    /// `rest` arrangements drawn uniformly.
    pub rest_variants: Vec<RestVariant>,
    /// Objects of a `rest` single scene.
    pub rest_singles: [usize; 2],
    /// Cubes of a `rest` tower.
    pub tower_boxes: [usize; 2],
    /// Largest horizontal offset of a tower box from the one below, per axis, metres.
    pub tower_offset: f32,
    /// Largest yaw of a tower box relative to the tower, radians.
    pub tower_yaw: f32,
    /// Objects of a `rest` pile.
    pub pile_objects: [usize; 2],
    /// Shapes of objects that start at rest (`rest` singles): every shape but the torus knot,
    /// which rapier never brings to rest on the floor (it creeps at about 3 cm/s).
    pub rest_shapes: Vec<ShapeKind>,
    /// Shapes of piles and of objects launched along the floor: `rest_shapes` without the
    /// sphere, which rolls instead of sliding or settling.
    pub floor_shapes: Vec<ShapeKind>,
    /// Height of a dropped object's lowest point at release, metres.
    pub drop_height: [f32; 2],
    /// Largest spin of a dropped object, radians per second (uniform in magnitude, uniform
    /// direction).
    pub drop_spin: f32,
    /// Objects of a `slide` scene (parallel lanes 2.5 m apart, one direction).
    pub slide_objects: [usize; 2],
    /// Launch speed of sliding objects, m/s, capped so that friction alone stops the object
    /// within `slide_stop_time`.
    pub slide_speed: [f32; 2],
    /// Longest stopping time under friction alone `v / (mu_object mu_floor |g|)`, seconds.
    pub slide_stop_time: f32,
    /// Probability that a `collide` scene is thrown in the air rather than along the floor.
    pub collide_air_fraction: f32,
    /// Speed of each object towards the other in `collide`, m/s (horizontal).
    pub collide_speed: [f32; 2],
    /// Time from release to the impact of the centres in the air variant, seconds.
    pub collide_air_time: [f32; 2],
    /// Clearance of both objects' lowest points above the floor at the air impact, metres.
    pub collide_air_clearance: [f32; 2],
    /// Sideways offset of the two aim points, as a fraction of the sum of the objects'
    /// bounding radii (air) or half-widths across the approach (floor).
    pub collide_offset: f32,
    /// Gap between the two objects along the approach direction at the start of the floor
    /// variant, metres. Each object is launched at least 1.2 times as fast as friction alone
    /// needs to stop it within half the gap, `sqrt(mu_object mu_floor |g| gap)`.
    pub collide_floor_gap: [f32; 2],
    /// Largest spin of objects thrown in the air, radians per second.
    pub collide_spin: f32,
    /// Cubes of a `stack-hit` tower.
    pub stack_boxes: [usize; 2],
    /// Scale of the `stack-hit` tower's cubes (smaller than MOVi-B's, so the thrown object
    /// is heavy enough to knock the tower over rather than bounce off).
    pub stack_scale: [f32; 2],
    /// Scale of the thrown object.
    pub projectile_scale: [f32; 2],
    /// Launch speed of the thrown object, m/s.
    pub projectile_speed: [f32; 2],
    /// Distance from the tower's circumscribed circle to the thrown object's bounding sphere at
    /// launch, metres.
    pub projectile_distance: f32,
    /// Aim height as a fraction of the tower height.
    pub projectile_aim: [f32; 2],
}

impl ScenarioParameters {
    /// The defaults for scenes of `scenarios` (drawn uniformly per scene): MOVi-B shapes,
    /// scale, materials, floor and gravity.
    pub fn new(scenarios: Vec<Scenario>) -> Self {
        let rest_shapes: Vec<ShapeKind> = ShapeKind::MOVI_B
            .iter()
            .copied()
            .filter(|k| *k != ShapeKind::TorusKnot)
            .collect();
        let floor_shapes = rest_shapes
            .iter()
            .copied()
            .filter(|k| *k != ShapeKind::Sphere)
            .collect();
        Self {
            scenarios,
            shapes: ShapeKind::MOVI_B.to_vec(),
            scale: [0.7, 1.4],
            materials: vec![("metal".into(), METAL), ("rubber".into(), RUBBER)],
            floor: MOVI_FLOOR,
            gravity: [0.0, 0.0, -10.0],
            settle_steps: 720,
            presettle_max_steps: 2400,
            rest_shapes,
            rest_variants: vec![RestVariant::Single, RestVariant::Tower, RestVariant::Pile],
            rest_singles: [1, 3],
            tower_boxes: [2, 6],
            tower_offset: 0.003,
            tower_yaw: 0.05,
            pile_objects: [2, 4],
            floor_shapes,
            drop_height: [0.5, 3.0],
            drop_spin: 4.0,
            slide_objects: [1, 3],
            slide_speed: [1.0, 5.0],
            slide_stop_time: 3.0,
            collide_air_fraction: 0.5,
            collide_speed: [2.5, 5.0],
            collide_air_time: [0.5, 0.8],
            collide_air_clearance: [0.5, 1.5],
            collide_offset: 0.3,
            collide_floor_gap: [2.0, 3.5],
            collide_spin: 2.0,
            stack_boxes: [2, 4],
            stack_scale: [0.5, 0.8],
            projectile_scale: [1.0, 1.4],
            projectile_speed: [5.0, 9.0],
            projectile_distance: 3.0,
            projectile_aim: [0.2, 0.8],
        }
    }

    /// Generator name: the scenario's own name, or `physics-mix` for several.
    pub fn name(&self) -> &'static str {
        match self.scenarios.as_slice() {
            [one] => one.name(),
            _ => "physics-mix",
        }
    }

    fn validate(&self) -> Result<()> {
        let bad = |what: &str| Err(SimError::Invalid(format!("scenario parameters: {what}")));
        if self.scenarios.is_empty() {
            return bad("no scenario");
        }
        if self.shapes.is_empty()
            || self.materials.is_empty()
            || self.rest_shapes.is_empty()
            || self.floor_shapes.is_empty()
        {
            return bad("empty shape or material list");
        }
        if self
            .floor_shapes
            .iter()
            .chain(&self.rest_shapes)
            .any(|k| !self.shapes.contains(k))
            || !self.shapes.contains(&ShapeKind::Cube)
        {
            return bad("floor shapes and the cube must be in the shape list");
        }
        if self.rest_variants.is_empty() {
            return bad("no rest variant");
        }
        let ranges = [
            self.rest_singles,
            self.tower_boxes,
            self.pile_objects,
            self.slide_objects,
            self.stack_boxes,
        ];
        if ranges.iter().any(|r| r[0] == 0 || r[0] > r[1]) {
            return bad("an object-count range is empty or starts at 0");
        }
        let spans = [
            self.scale,
            self.drop_height,
            self.slide_speed,
            self.collide_speed,
            self.collide_air_time,
            self.collide_air_clearance,
            self.collide_floor_gap,
            self.stack_scale,
            self.projectile_scale,
            self.projectile_speed,
            self.projectile_aim,
        ];
        if spans
            .iter()
            .any(|r| !(r[0].is_finite() && r[1].is_finite() && r[0] > 0.0 && r[0] <= r[1]))
        {
            return bad("a range is empty, not positive or not finite");
        }
        if !(0.0..=1.0).contains(&self.collide_air_fraction) {
            return bad("collide_air_fraction must be in [0, 1]");
        }
        if self.gravity[2].is_nan() || self.gravity[2] >= 0.0 {
            return bad("gravity must point down (negative z)");
        }
        Ok(())
    }
}

/// Draws uniformly in `[r[0], r[1]]` (the value itself for an empty interval).
fn uniform<R: Rng + ?Sized>(rng: &mut R, r: [f32; 2]) -> f32 {
    if r[0] < r[1] {
        rng.random_range(r[0]..=r[1])
    } else {
        r[0]
    }
}

fn count<R: Rng + ?Sized>(rng: &mut R, r: [usize; 2]) -> usize {
    rng.random_range(r[0]..=r[1])
}

/// A unit vector uniform on the sphere.
fn random_direction<R: Rng + ?Sized>(rng: &mut R) -> [f32; 3] {
    let z: f32 = rng.random_range(-1.0..=1.0);
    let a: f32 = rng.random_range(0.0..TAU);
    let s = (1.0 - z * z).max(0.0).sqrt();
    [s * a.cos(), s * a.sin(), z]
}

fn quat(r: Rotation) -> [f32; 4] {
    [r.x, r.y, r.z, r.w]
}

/// An object drawn from the parameters (shape among `kinds`, scale, material), not placed.
fn draw_object<R: Rng + ?Sized>(
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
    let material = p.materials[rng.random_range(0..p.materials.len())].1;
    Ok(ObjectSpec {
        shape,
        shape_id: shape_id as i32,
        scale,
        material,
        material_kind: 0,
        position: [0.0; 3],
        rotation: [0.0, 0.0, 0.0, 1.0],
        linvel: [0.0; 3],
        angvel: [0.0; 3],
        held_until_settled: false,
    })
}

/// Bounds of an object's collider at `rotation` about its centre of mass: (min, max), metres.
fn extents(o: &ObjectSpec, rotation: [f32; 4]) -> Result<([f32; 3], [f32; 3])> {
    let (offset, shape) = o.scaled_shape().collider()?;
    let aabb = shape.compute_aabb(&(pose_from_arrays([0.0; 3], rotation) * offset));
    Ok((
        [aabb.mins.x, aabb.mins.y, aabb.mins.z],
        [aabb.maxs.x, aabb.maxs.y, aabb.maxs.z],
    ))
}

/// Radius of a sphere about the centre of mass that holds the object, metres.
fn bounding_radius(o: &ObjectSpec) -> Result<f32> {
    let (lo, hi) = extents(o, [0.0, 0.0, 0.0, 1.0])?;
    Ok((0..3)
        .map(|k| lo[k].abs().max(hi[k].abs()).powi(2))
        .sum::<f32>()
        .sqrt())
}

/// A pose as a centre of mass position (m) and a unit quaternion `[x, y, z, w]`.
type PoseArrays = ([f32; 3], [f32; 4]);

/// Steps `objects` (with their poses and velocities) in a world of their own until every body
/// is still (centre speed below 5 mm/s and spin below 0.02 rad/s for 0.25 s), at most
/// `max_steps` physics steps. Returns the settled poses, or `None` if they never came to rest.
fn presettle(
    p: &ScenarioParameters,
    objects: &[ObjectSpec],
    max_steps: u32,
) -> Result<Option<Vec<PoseArrays>>> {
    let spec = SceneSpec {
        objects: objects.to_vec(),
        floor: p.floor,
        gravity: p.gravity,
        settle_steps: 0,
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
const SETTLE_ATTEMPTS: usize = 16;

/// Settles `o` alone on the floor from `start` rotation (or random ones after a failure):
/// returns its resting rotation and centre height, with the object centred at x = y = 0.
fn rest_on_floor<R: Rng + ?Sized>(
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
fn upright_start(kind: ShapeKind) -> Option<[f32; 4]> {
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
fn tower<R: Rng + ?Sized>(
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
            tower(p, n, p.scale, rng)?
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
/// pre-settled poses.
pub fn sample_scenario<R: Rng + ?Sized>(
    p: &ScenarioParameters,
    rng: &mut R,
) -> Result<(SceneSpec, SceneLabel)> {
    p.validate()?;
    let scenario = p.scenarios[rng.random_range(0..p.scenarios.len())];
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
    };
    Ok((
        SceneSpec {
            objects,
            floor: p.floor,
            gravity: p.gravity,
            settle_steps: settle,
        },
        SceneLabel {
            scenario: scenario.name().to_string(),
            variant: variant.to_string(),
        },
    ))
}
