//! Simulating a mesh scene with rapier: rigid objects as rigid bodies with convex (or
//! compound-of-convex) colliders, elastic objects as FEM soft bodies over the template's
//! tetrahedra, all inside a closed box of six fixed walls.

use rapier3d::math::{Pose, Rotation, Vector};
use rapier3d::prelude::{
    CoefficientCombineRule, ColliderBuilder, PhysicsWorld, RigidBodyBuilder, RigidBodyHandle,
    SharedShape, SoftBodyBuilder, SoftBodyCellModel, SoftBodyHandle, SoftBodyMaterial,
};
use serde::Serialize;

use super::record::{MeshMaterial, MeshObject, MeshScene};
use super::templates::{MeshTemplate, templates, tet_volume6};
use crate::{Result, SimError};

/// Physics of the mesh scenes. Friction and restitution are combined by `Min` and the walls
/// have friction and restitution 1, so an object meets a wall with its own coefficients and two
/// objects with the smaller of theirs.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MeshPhysics {
    /// Gravity, metres per second squared.
    pub gravity: [f32; 3],
    /// The box is `[-box_half, box_half]^3`, metres.
    pub box_half: f32,
    /// Physics steps per second.
    pub physics_hz: u32,
    /// Physics steps per recorded frame.
    pub substeps: u32,
    /// Recorded frames, including the initial state.
    pub frames: usize,
    /// rapier solver iterations per step.
    pub solver_iterations: usize,
    /// Density of every object, kilograms per cubic metre.
    pub density: f32,
    /// Friction coefficient of rigid objects.
    pub rigid_friction: f32,
    /// Friction coefficient of elastic objects.
    pub elastic_friction: f32,
    /// Restitution coefficient of every object.
    pub restitution: f32,
    /// Young's modulus of elastic objects, pascals.
    pub young_modulus: f32,
    /// Poisson ratio of elastic objects.
    pub poisson_ratio: f32,
    /// Damping ratio of the elastic cells.
    pub elastic_damping_ratio: f32,
    /// Contact skin of an elastic surface, metres.
    pub particle_radius: f32,
    /// Whether an elastic body also keeps its enclosed volume (rapier's global volume
    /// constraint) on top of its cells' elasticity.
    pub volume_preservation: bool,
}

impl Default for MeshPhysics {
    /// Box `[-1, 1]^3`, gravity 9.81 m/s^2 down z, 240 Hz physics, 5 steps per frame (48 frames
    /// per second), 49 frames (1 s), density 1000, low friction, E = 200 kPa, nu = 0.45.
    fn default() -> Self {
        Self {
            gravity: [0.0, 0.0, -9.81],
            box_half: 1.0,
            physics_hz: 240,
            substeps: 5,
            frames: 49,
            solver_iterations: 4,
            density: 1000.0,
            rigid_friction: 0.01,
            elastic_friction: 0.15,
            restitution: 0.5,
            young_modulus: 2.0e5,
            poisson_ratio: 0.45,
            elastic_damping_ratio: 0.1,
            particle_radius: 0.004,
            volume_preservation: true,
        }
    }
}

impl MeshPhysics {
    /// Interval between recorded frames, seconds.
    pub fn dt_frame(&self) -> f32 {
        self.substeps as f32 / self.physics_hz as f32
    }

    /// Friction coefficient of a material.
    pub fn friction(&self, m: MeshMaterial) -> f32 {
        match m {
            MeshMaterial::Rigid => self.rigid_friction,
            MeshMaterial::Elastic => self.elastic_friction,
        }
    }

    fn validate(&self) -> Result<()> {
        if self.physics_hz == 0 || self.substeps == 0 || self.frames == 0 {
            return Err(SimError::Invalid(format!(
                "physics_hz, substeps and frames must be positive: {self:?}"
            )));
        }
        if !(self.box_half > 0.0 && self.density > 0.0 && self.young_modulus > 0.0) {
            return Err(SimError::Invalid(format!(
                "box, density and Young's modulus must be positive: {self:?}"
            )));
        }
        Ok(())
    }
}

/// One object to simulate.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MeshObjectSpec {
    /// Index into [`templates`].
    pub template: usize,
    /// Circumradius of the object (scale of the unit template), metres.
    pub scale: f32,
    /// Rigid or elastic.
    pub material: MeshMaterial,
    /// Initial centre of volume, metres.
    pub position: [f32; 3],
    /// Initial orientation, unit quaternion `[x, y, z, w]` (template frame to world).
    pub rotation: [f32; 4],
    /// Initial velocity of the centre of mass, metres per second.
    pub linvel: [f32; 3],
    /// Initial angular velocity (world frame), radians per second.
    pub angvel: [f32; 3],
}

impl MeshObjectSpec {
    fn pose(&self) -> Pose {
        let [x, y, z, w] = self.rotation;
        Pose::from_parts(
            Vector::from(self.position),
            Rotation::from_xyzw(x, y, z, w).normalize(),
        )
    }

    /// Initial world positions of the template's particles (mesh vertices then interior
    /// points), metres.
    pub fn initial_particles(&self, t: &MeshTemplate) -> Vec<Vector> {
        let pose = self.pose();
        t.particles()
            .iter()
            .map(|p| pose.transform_point(Vector::from(*p) * self.scale))
            .collect()
    }

    /// Initial velocity of a point at world position `x`: `v + w x (x - p)`, metres per second.
    pub fn velocity_at(&self, x: Vector) -> Vector {
        Vector::from(self.linvel) + Vector::from(self.angvel).cross(x - Vector::from(self.position))
    }
}

/// A scene to simulate: its objects.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MeshSceneSpec {
    /// The objects, in recording order.
    pub objects: Vec<MeshObjectSpec>,
}

enum Body {
    Rigid(RigidBodyHandle, Vec<Vector>),
    Elastic(SoftBodyHandle, usize),
}

fn with_rules(c: ColliderBuilder, friction: f32, restitution: f32) -> ColliderBuilder {
    c.friction(friction)
        .restitution(restitution)
        .friction_combine_rule(CoefficientCombineRule::Min)
        .restitution_combine_rule(CoefficientCombineRule::Min)
}

fn build_world(
    spec: &MeshSceneSpec,
    phys: &MeshPhysics,
    lib: &[MeshTemplate],
) -> Result<(PhysicsWorld, Vec<Body>, Vec<f32>)> {
    let mut world = PhysicsWorld {
        gravity: Vector::from(phys.gravity),
        ..PhysicsWorld::default()
    };
    world.integration_parameters.dt = 1.0 / phys.physics_hz as f32;
    world.integration_parameters.num_solver_iterations = phys.solver_iterations.max(1);
    world.integration_parameters.contact_recycling = false;
    let (h, t) = (phys.box_half, 0.25f32);
    for axis in 0..3 {
        for side in [-1.0f32, 1.0] {
            let mut centre = [0.0f32; 3];
            centre[axis] = side * (h + t);
            let mut half = [h + 2.0 * t; 3];
            half[axis] = t;
            world.insert(
                RigidBodyBuilder::fixed().translation(Vector::from(centre)),
                with_rules(ColliderBuilder::cuboid(half[0], half[1], half[2]), 1.0, 1.0),
            );
        }
    }
    let mut bodies = Vec::with_capacity(spec.objects.len());
    let mut masses = Vec::with_capacity(spec.objects.len());
    for (i, o) in spec.objects.iter().enumerate() {
        let t = lib.get(o.template).ok_or_else(|| {
            SimError::Invalid(format!(
                "object {i}: template {} does not exist ({} templates)",
                o.template,
                lib.len()
            ))
        })?;
        if !(o.scale.is_finite() && o.scale > 0.0) {
            return Err(SimError::Invalid(format!(
                "object {i}: scale {} is not positive",
                o.scale
            )));
        }
        let friction = phys.friction(o.material);
        match o.material {
            MeshMaterial::Rigid => {
                let parts = t
                    .parts
                    .iter()
                    .map(|part| {
                        let pts: Vec<Vector> =
                            part.iter().map(|p| Vector::from(*p) * o.scale).collect();
                        SharedShape::convex_hull(&pts)
                            .map(|s| (Pose::IDENTITY, s))
                            .ok_or_else(|| {
                                SimError::Shape(format!("template {}: flat part", t.name))
                            })
                    })
                    .collect::<Result<Vec<_>>>()?;
                let shape = if parts.len() == 1 {
                    parts.into_iter().next().map(|p| p.1)
                } else {
                    Some(SharedShape::compound(parts))
                }
                .ok_or_else(|| SimError::Shape(format!("template {}: no part", t.name)))?;
                let body = RigidBodyBuilder::dynamic()
                    .pose(o.pose())
                    .linvel(Vector::from(o.linvel))
                    .angvel(Vector::from(o.angvel))
                    .can_sleep(false);
                let collider = with_rules(
                    ColliderBuilder::new(shape).density(phys.density),
                    friction,
                    phys.restitution,
                );
                let (bh, ch) = world.insert(body, collider);
                masses.push(world.colliders[ch].mass());
                let local = t
                    .mesh
                    .vertices
                    .iter()
                    .map(|p| Vector::from(*p) * o.scale)
                    .collect();
                bodies.push(Body::Rigid(bh, local));
            }
            MeshMaterial::Elastic => {
                let particles = o.initial_particles(t);
                let mut lumped = vec![0.0f32; particles.len()];
                let p = |k: u32| {
                    let v = particles[k as usize];
                    [v.x, v.y, v.z]
                };
                for c in &t.tets {
                    let m = phys.density
                        * (tet_volume6(p(c[0]), p(c[1]), p(c[2]), p(c[3])) / 6.0) as f32;
                    for &k in c {
                        lumped[k as usize] += 0.25 * m;
                    }
                }
                masses.push(lumped.iter().sum());
                let material = SoftBodyMaterial {
                    young_modulus: phys.young_modulus,
                    poisson_ratio: phys.poisson_ratio,
                    elastic_damping_ratio: phys.elastic_damping_ratio,
                    ..SoftBodyMaterial::default()
                };
                let builder = SoftBodyBuilder::new(particles.clone())
                    .cells(t.tets.clone())
                    .surface(t.mesh.faces.clone())
                    .masses(lumped)
                    .cell_model(SoftBodyCellModel::Corotational)
                    .material(material)
                    .particle_radius(phys.particle_radius)
                    .volume_preservation(phys.volume_preservation)
                    .surface_collider(with_rules(
                        ColliderBuilder::ball(phys.particle_radius),
                        friction,
                        phys.restitution,
                    ))
                    .can_sleep(false);
                let sh = world.insert_soft_body(builder);
                let sb = world.soft_bodies.get_mut(sh).ok_or_else(|| {
                    SimError::Invalid(format!("object {i}: soft body was not inserted"))
                })?;
                for (k, x) in particles.iter().enumerate() {
                    sb.set_particle_velocity(k, o.velocity_at(*x));
                }
                bodies.push(Body::Elastic(sh, t.vertices()));
            }
        }
    }
    Ok((world, bodies, masses))
}

/// Simulates a scene: frame 0 is the initial state, frame `t` the state after `t * substeps`
/// physics steps. Errors on an unknown template, a bad scale or a non-finite state.
pub fn simulate_mesh_scene(spec: &MeshSceneSpec, phys: &MeshPhysics) -> Result<MeshScene> {
    phys.validate()?;
    let lib = templates()?;
    let (mut world, bodies, masses) = build_world(spec, phys, lib)?;
    let frames = phys.frames;
    let mut objects = Vec::with_capacity(spec.objects.len());
    let mut faces = Vec::new();
    let mut initial_velocities = Vec::new();
    let mut v0 = 0usize;
    for (i, o) in spec.objects.iter().enumerate() {
        let t = &lib[o.template];
        let n = t.vertices();
        let f0 = faces.len();
        faces.extend(t.mesh.faces.iter().map(|f| f.map(|k| k + v0 as u32)));
        for x in o.initial_particles(t).iter().take(n) {
            let v = o.velocity_at(*x);
            initial_velocities.extend([v.x, v.y, v.z]);
        }
        objects.push(MeshObject {
            vertices: v0..v0 + n,
            faces: f0..faces.len(),
            material: o.material,
            template_id: o.template as i32,
            scale: o.scale,
            mass: masses[i],
            friction: phys.friction(o.material),
            restitution: phys.restitution,
        });
        v0 += n;
    }
    // Recorded frame-major, transposed to [V, T, 3] at the end.
    let mut by_frame: Vec<Vec<[f32; 3]>> = Vec::with_capacity(frames);
    for frame in 0..frames {
        if frame > 0 {
            for _ in 0..phys.substeps {
                world.step();
            }
        }
        let mut xs = Vec::with_capacity(v0);
        for b in &bodies {
            match b {
                Body::Rigid(h, local) => {
                    let pose = *world.bodies[*h].position();
                    xs.extend(local.iter().map(|p| pose.transform_point(*p).to_array()));
                }
                Body::Elastic(h, n) => {
                    let sb = world.soft_bodies.get(*h).ok_or_else(|| {
                        SimError::Diverged(format!("soft body vanished at frame {frame}"))
                    })?;
                    xs.extend((0..*n).map(|k| sb.particle_position(k).to_array()));
                }
            }
        }
        if let Some(v) = xs.iter().position(|x| !x.iter().all(|c| c.is_finite())) {
            return Err(SimError::Diverged(format!(
                "vertex {v} at frame {frame} is not finite"
            )));
        }
        by_frame.push(xs);
    }
    let mut positions = Vec::with_capacity(v0 * frames * 3);
    for v in 0..v0 {
        for xs in &by_frame {
            positions.extend_from_slice(&xs[v]);
        }
    }
    Ok(MeshScene {
        frames,
        dt_frame: phys.dt_frame(),
        positions,
        initial_velocities,
        faces,
        objects,
    })
}
