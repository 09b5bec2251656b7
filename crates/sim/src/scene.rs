//! Scene descriptions and their simulation with rapier3d.
//!
//! A [`SceneSpec`] lists objects (unit shape, scale, material, initial pose and velocity), the
//! floor and gravity. [`simulate`] builds a rapier world (one rigid body and one collider per
//! object, body origin at the centre of mass), steps it at `physics_hz` and records every
//! `substeps`-th state: frame 0 is the initial state (after the optional settling steps), frame
//! `t` the state `t * substeps` steps later.
//!
//! Kinematic objects ([`KinematicPath`], [`SceneSpec::kinematic`]) are rapier kinematic
//! position-based bodies: they follow the poses given for every frame (interpolated over the
//! physics steps between frames), push the dynamic objects they touch and are not pushed back.

use rapier3d::math::{Pose, Rotation, Vector};
use rapier3d::prelude::{
    CoefficientCombineRule, ColliderBuilder, ColliderHandle, PhysicsWorld, RigidBodyBuilder,
    RigidBodyHandle, RigidBodyType, SharedShape,
};
use serde::{Deserialize, Serialize};

use crate::shapes::Shape;
use crate::{Result, SimError};

/// Contact material of an object: friction and restitution coefficients (combined with the
/// other body's by multiplication) and density. Kubric's densities (2.7 for metal, 1.1 for
/// rubber) are used as given, in kilograms per cubic metre of the scene's units, so a unit cube
/// of metal weighs 2.7 kg.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Material {
    /// Friction coefficient.
    pub friction: f32,
    /// Restitution coefficient.
    pub restitution: f32,
    /// Mass per cubic metre, kilograms.
    pub density: f32,
}

/// One object of a scene.
#[derive(Clone, Debug)]
pub struct ObjectSpec {
    /// Unit shape, body frame with origin at the centre of mass.
    pub shape: Shape,
    /// Index of the shape in the dataset's shape list.
    pub shape_id: i32,
    /// Uniform scale applied to the unit shape.
    pub scale: f32,
    /// Contact material and density.
    pub material: Material,
    /// 0 rigid, 1 elastic (only rigid objects are simulated here).
    pub material_kind: i32,
    /// Initial centre of mass position, metres.
    pub position: [f32; 3],
    /// Initial orientation, unit quaternion `[x, y, z, w]`.
    pub rotation: [f32; 4],
    /// Initial linear velocity of the centre of mass, metres per second.
    pub linvel: [f32; 3],
    /// Initial angular velocity, radians per second (world frame).
    pub angvel: [f32; 3],
    /// Kept out of the world (disabled) while the scene settles, then released with its
    /// initial pose and velocity (e.g. a projectile fired at a settled stack).
    pub held_until_settled: bool,
}

impl ObjectSpec {
    /// A rigid object of `shape` (unit shape, body frame, scaled by `scale`) with `material`,
    /// at rest at the origin in the identity orientation: set `position`, `rotation`, `linvel`
    /// and `angvel` after. `shape_id` is its index in the dataset's shape list.
    pub fn rigid(shape: Shape, shape_id: i32, scale: f32, material: Material) -> ObjectSpec {
        ObjectSpec {
            shape,
            shape_id,
            scale,
            material,
            material_kind: 0,
            position: [0.0; 3],
            rotation: [0.0, 0.0, 0.0, 1.0],
            linvel: [0.0; 3],
            angvel: [0.0; 3],
            held_until_settled: false,
        }
    }

    /// [`ObjectSpec::rigid`] that weighs `mass` kilograms (its density is the mass over the
    /// scaled shape's volume), with contact `friction` and `restitution`. Refuses a mass that
    /// is not positive and finite, and a shape that spans no volume.
    pub fn rigid_of_mass(
        shape: Shape,
        shape_id: i32,
        scale: f32,
        mass: f32,
        friction: f32,
        restitution: f32,
    ) -> Result<ObjectSpec> {
        if !(mass.is_finite() && mass > 0.0) {
            return Err(SimError::Invalid(format!(
                "mass must be positive ({mass} kg)"
            )));
        }
        let (volume, _) = shape.scaled(scale).volume_and_centroid()?;
        if !(volume.is_finite() && volume > 0.0) {
            return Err(SimError::Invalid(format!(
                "its shape spans no volume ({volume} m^3)"
            )));
        }
        let material = Material {
            friction,
            restitution,
            density: mass / volume,
        };
        Ok(ObjectSpec::rigid(shape, shape_id, scale, material))
    }

    /// The scaled shape in the body frame.
    pub fn scaled_shape(&self) -> Shape {
        self.shape.scaled(self.scale)
    }

    /// The initial pose as a rapier pose.
    pub fn initial_pose(&self) -> Pose {
        pose_from_arrays(self.position, self.rotation)
    }
}

/// Static floor: a large box whose top face is the plane `z = 0`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FloorSpec {
    /// Friction coefficient.
    pub friction: f32,
    /// Restitution coefficient.
    pub restitution: f32,
    /// Half side of the floor square, metres.
    pub half_extent: f32,
    /// Thickness, metres.
    pub thickness: f32,
}

/// A scene: objects, floor and gravity.
#[derive(Clone, Debug)]
pub struct SceneSpec {
    /// The dynamic objects.
    pub objects: Vec<ObjectSpec>,
    /// The static floor.
    pub floor: FloorSpec,
    /// Gravity, metres per second squared.
    pub gravity: [f32; 3],
    /// Physics steps run before frame 0 so that stacked objects reach the equilibrium of
    /// rapier's soft contacts (objects `held_until_settled` wait outside); 0 for none.
    pub settle_steps: u32,
    /// Objects that are kinematic and follow these paths (each object at most once; they hold
    /// their initial pose while the scene settles); empty for none.
    pub kinematic: Vec<KinematicPath>,
}

/// Stepping and recording parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SimConfig {
    /// Physics steps per second.
    pub physics_hz: u32,
    /// Physics steps per recorded frame.
    pub substeps: u32,
    /// Recorded frames, including the initial state.
    pub frames: usize,
    /// rapier solver iterations per step.
    pub solver_iterations: usize,
}

impl Default for SimConfig {
    /// MOVi-like recording: 240 Hz physics, 24 frames per second, 101 frames (4.17 s).
    fn default() -> Self {
        Self {
            physics_hz: 240,
            substeps: 10,
            frames: 101,
            solver_iterations: 4,
        }
    }
}

impl SimConfig {
    /// Interval between recorded frames, seconds.
    pub fn dt_frame(&self) -> f32 {
        self.substeps as f32 / self.physics_hz as f32
    }

    /// Physics step, seconds.
    pub fn dt_step(&self) -> f32 {
        1.0 / self.physics_hz as f32
    }

    /// One integration substep, seconds: rapier 0.36 integrates each physics step in as many
    /// substeps as it has solver iterations, so free flight over a frame is
    /// [`SimConfig::integration_substeps`] symplectic Euler steps of this length.
    pub fn dt_substep(&self) -> f32 {
        self.dt_step() / self.solver_iterations.max(1) as f32
    }

    /// Integration substeps per recorded frame (see [`SimConfig::dt_substep`]).
    pub fn integration_substeps(&self) -> u32 {
        self.substeps * self.solver_iterations.max(1) as u32
    }

    fn validate(&self) -> Result<()> {
        if self.physics_hz == 0 || self.substeps == 0 || self.frames == 0 {
            return Err(SimError::Invalid(format!(
                "physics_hz, substeps and frames must be positive: {self:?}"
            )));
        }
        Ok(())
    }
}

/// Recorded trajectories of one scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectories {
    /// Centre of mass per object per frame, metres: `[objects][frames]`.
    pub positions: Vec<Vec<[f32; 3]>>,
    /// Orientation per object per frame, `[x, y, z, w]`, sign-continuous in time.
    pub rotations: Vec<Vec<[f32; 4]>>,
    /// Mass per object as rapier computed it from the collider, kilograms.
    pub masses: Vec<f32>,
}

/// The path of a kinematic object: the pose it has at every recorded frame after frame 0 (it
/// starts from its object's initial pose). Between two frames it moves at constant speed:
/// translation interpolated linearly and rotation spherically over the physics steps.
#[derive(Clone, Debug, PartialEq)]
pub struct KinematicPath {
    /// Index of the object in the scene.
    pub object: usize,
    /// Centre of mass (metres) and unit quaternion `[x, y, z, w]` at frames `1, 2, ...`:
    /// `[frames - 1]` entries (more are ignored).
    pub poses: Vec<([f32; 3], [f32; 4])>,
}

impl KinematicPath {
    pub(crate) fn check(&self, objects: usize, frames: usize, seen: &mut [bool]) -> Result<()> {
        let o = self.object;
        if o >= objects {
            return Err(SimError::Invalid(format!(
                "kinematic object {o} does not exist (the scene has {objects} objects)"
            )));
        }
        if std::mem::replace(&mut seen[o], true) {
            return Err(SimError::Invalid(format!(
                "object {o} has two kinematic paths"
            )));
        }
        if self.poses.len() + 1 < frames {
            return Err(SimError::Invalid(format!(
                "kinematic object {o} has {} poses; {} frames need {}",
                self.poses.len(),
                frames,
                frames - 1
            )));
        }
        for (i, (t, q)) in self.poses.iter().take(frames - 1).enumerate() {
            let norm = q.iter().map(|c| c * c).sum::<f32>().sqrt();
            if !(t.iter().all(|c| c.is_finite()) && norm.is_finite() && norm > 1e-6) {
                return Err(SimError::Invalid(format!(
                    "kinematic object {o}: pose {i} is not finite or its quaternion is zero"
                )));
            }
        }
        Ok(())
    }
}

/// Rapier pose from a translation and an `[x, y, z, w]` quaternion (normalised).
pub fn pose_from_arrays(t: [f32; 3], q: [f32; 4]) -> Pose {
    Pose::from_parts(
        Vector::new(t[0], t[1], t[2]),
        Rotation::from_xyzw(q[0], q[1], q[2], q[3]).normalize(),
    )
}

/// A built rapier world for a scene: the world, one body per object (in object order) and
/// each object's collider shape with its pose in the body frame.
pub struct SimWorld {
    /// The rapier world.
    pub world: PhysicsWorld,
    /// Body handles, in object order.
    pub bodies: Vec<RigidBodyHandle>,
    /// Collider handles, in object order.
    pub colliders: Vec<ColliderHandle>,
    /// Collider shape of each object and its pose relative to the body.
    pub shapes: Vec<(Pose, SharedShape)>,
}

impl SimWorld {
    /// Builds the rapier world: gravity, 1 / `physics_hz` step, sleeping disabled, Multiply
    /// combine rules for friction and restitution on every collider.
    pub fn new(spec: &SceneSpec, cfg: &SimConfig) -> Result<Self> {
        cfg.validate()?;
        let mut world = PhysicsWorld {
            gravity: Vector::new(spec.gravity[0], spec.gravity[1], spec.gravity[2]),
            ..PhysicsWorld::default()
        };
        world.integration_parameters.dt = cfg.dt_step();
        world.integration_parameters.num_solver_iterations = cfg.solver_iterations.max(1);
        // Fresh contacts every step: reusing the previous step's contact points lets objects
        // standing on a many-sided face creep by centimetres.
        world.integration_parameters.contact_recycling = false;
        let f = &spec.floor;
        world.insert(
            RigidBodyBuilder::fixed().translation(Vector::new(0.0, 0.0, -0.5 * f.thickness)),
            ColliderBuilder::cuboid(f.half_extent, f.half_extent, 0.5 * f.thickness)
                .friction(f.friction)
                .restitution(f.restitution)
                .friction_combine_rule(CoefficientCombineRule::Multiply)
                .restitution_combine_rule(CoefficientCombineRule::Multiply),
        );
        let mut bodies = Vec::with_capacity(spec.objects.len());
        let mut shapes = Vec::with_capacity(spec.objects.len());
        let mut colliders = Vec::with_capacity(spec.objects.len());
        for o in &spec.objects {
            let (offset, shape) = o.scaled_shape().collider()?;
            let body = RigidBodyBuilder::dynamic()
                .pose(o.initial_pose())
                .linvel(Vector::new(o.linvel[0], o.linvel[1], o.linvel[2]))
                .angvel(Vector::new(o.angvel[0], o.angvel[1], o.angvel[2]))
                .can_sleep(false)
                .enabled(!(o.held_until_settled && spec.settle_steps > 0));
            let collider = ColliderBuilder::new(shape.clone())
                .position(offset)
                .density(o.material.density)
                .friction(o.material.friction)
                .restitution(o.material.restitution)
                .friction_combine_rule(CoefficientCombineRule::Multiply)
                .restitution_combine_rule(CoefficientCombineRule::Multiply);
            let (h, c) = world.insert(body, collider);
            bodies.push(h);
            colliders.push(c);
            shapes.push((offset, shape));
        }
        Ok(Self {
            world,
            bodies,
            colliders,
            shapes,
        })
    }

    /// Current pose of object `i` (body frame = centre of mass frame).
    pub fn pose(&self, i: usize) -> Pose {
        *self.world.bodies[self.bodies[i]].position()
    }

    /// Total mechanical energy in joules: kinetic (translation and rotation) plus gravitational
    /// potential `-m g . x_com` (zero on the plane through the origin normal to gravity).
    pub fn energy(&self) -> f64 {
        let g = self.world.gravity;
        self.bodies
            .iter()
            .map(|&h| {
                let b = &self.world.bodies[h];
                b.kinetic_energy() as f64 - (b.mass() * g.dot(b.center_of_mass())) as f64
            })
            .sum()
    }
}

/// Simulates a scene and records its trajectories; a kinematic object's recorded poses are its
/// path's poses.
pub fn simulate(spec: &SceneSpec, cfg: &SimConfig) -> Result<Trajectories> {
    simulate_observed(spec, cfg, |_, _| {})
}

/// [`simulate`], calling `observe(frame, world)` at every recorded frame (after the state of
/// that frame is reached), e.g. to check energy or contacts in tests.
pub fn simulate_observed(
    spec: &SceneSpec,
    cfg: &SimConfig,
    mut observe: impl FnMut(usize, &SimWorld),
) -> Result<Trajectories> {
    let paths = &spec.kinematic;
    let mut sim = SimWorld::new(spec, cfg)?;
    let n = spec.objects.len();
    let mut seen = vec![false; n];
    for p in paths {
        p.check(n, cfg.frames, &mut seen)?;
        sim.world.bodies[sim.bodies[p.object]]
            .set_body_type(RigidBodyType::KinematicPositionBased, true);
    }
    if spec.settle_steps > 0 {
        for _ in 0..spec.settle_steps {
            sim.world.step();
        }
        for (o, &h) in spec.objects.iter().zip(&sim.bodies) {
            if o.held_until_settled {
                let b = &mut sim.world.bodies[h];
                b.set_enabled(true);
                b.set_position(o.initial_pose(), true);
                b.set_linvel(Vector::new(o.linvel[0], o.linvel[1], o.linvel[2]), true);
                b.set_angvel(Vector::new(o.angvel[0], o.angvel[1], o.angvel[2]), true);
            }
        }
    }
    // The collider's mass: a body held out of the world gets its mass properties back only at
    // the next step.
    let masses: Vec<f32> = sim
        .colliders
        .iter()
        .map(|&c| sim.world.colliders[c].mass())
        .collect();
    let mut positions = vec![Vec::with_capacity(cfg.frames); n];
    let mut rotations: Vec<Vec<[f32; 4]>> = vec![Vec::with_capacity(cfg.frames); n];
    for frame in 0..cfg.frames {
        if frame > 0 {
            for s in 0..cfg.substeps {
                let f = (s + 1) as f32 / cfg.substeps as f32;
                for p in paths {
                    let from = match frame {
                        1 => spec.objects[p.object].initial_pose(),
                        _ => pose_from_arrays(p.poses[frame - 2].0, p.poses[frame - 2].1),
                    };
                    let to = pose_from_arrays(p.poses[frame - 1].0, p.poses[frame - 1].1);
                    let at = if s + 1 == cfg.substeps {
                        to
                    } else {
                        Pose::from_parts(
                            from.translation.lerp(to.translation, f),
                            from.rotation.slerp(to.rotation, f),
                        )
                    };
                    sim.world.bodies[sim.bodies[p.object]].set_next_kinematic_position(at);
                }
                sim.world.step();
            }
        }
        for i in 0..n {
            let pose = sim.pose(i);
            let t = pose.translation;
            let q = pose.rotation;
            let mut q = [q.x, q.y, q.z, q.w];
            if let Some(prev) = rotations[i].last() {
                let d: f32 = (0..4).map(|k| prev[k] * q[k]).sum();
                if d < 0.0 {
                    q = q.map(|c| -c);
                }
            }
            if !(t.is_finite() && q.iter().all(|c| c.is_finite())) {
                return Err(SimError::Diverged(format!(
                    "object {i} at frame {frame} has a non-finite pose"
                )));
            }
            positions[i].push([t.x, t.y, t.z]);
            rotations[i].push(q);
        }
        observe(frame, &sim);
    }
    Ok(Trajectories {
        positions,
        rotations,
        masses,
    })
}
