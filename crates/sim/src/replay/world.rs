//! A replay advanced one step at a time: the world [`super::replay`] builds, stepped with the
//! same kinematic interpolation and read out the same way, so that stepping it `n` times
//! gives exactly the first `n` steps of the replay. A served simulation keeps one of these per
//! scene and clones it where a scene forks.

use rapier3d::math::{Pose, Vector};
use rapier3d::prelude::{CollisionPipeline, PhysicsPipeline, PhysicsWorld, RigidBodyType};

use super::ReplayOptions;
use crate::scene::{SceneSpec, SimWorld, pose_from_arrays};
use crate::{Result, SimError};

/// A pose as the replay reports it: `[x, y, z, qx, qy, qz, qw]` (metres, unit quaternion,
/// scalar last).
pub type Pose7 = [f32; 7];

/// One scene's rapier world between steps.
pub struct ReplayWorld {
    sim: SimWorld,
    /// Physics steps per replay step.
    substeps: u32,
    /// Per object, whether it follows given poses.
    kinematic: Vec<bool>,
    /// Per object, the pose a kinematic object was last sent to (its start for the next
    /// step's interpolation).
    from: Vec<Pose>,
    /// Per object, the pose at the end of the last step (sign-continuous quaternions).
    poses: Vec<Pose7>,
    /// Mass of every object as simulated, kilograms.
    masses: Vec<f32>,
}

impl ReplayWorld {
    /// Builds the world of `spec` (objects, floor, gravity; no settling) at the rates of
    /// `opts`; the objects flagged in `kinematic` (`[objects]`, shorter means false) follow
    /// the poses given to [`ReplayWorld::step`].
    pub fn new(spec: &SceneSpec, kinematic: &[bool], opts: &ReplayOptions) -> Result<Self> {
        if spec.settle_steps > 0 {
            return Err(SimError::Invalid(
                "a stepped replay starts from the given state (no settling)".into(),
            ));
        }
        let cfg = opts.sim_config(0)?;
        let mut sim = SimWorld::new(spec, &cfg)?;
        let n = spec.objects.len();
        let kinematic: Vec<bool> = (0..n)
            .map(|i| kinematic.get(i).copied().unwrap_or(false))
            .collect();
        for (i, &k) in kinematic.iter().enumerate() {
            if k {
                sim.world.bodies[sim.bodies[i]]
                    .set_body_type(RigidBodyType::KinematicPositionBased, true);
            }
        }
        let masses = sim
            .colliders
            .iter()
            .map(|&c| sim.world.colliders[c].mass())
            .collect();
        let from: Vec<Pose> = spec.objects.iter().map(|o| o.initial_pose()).collect();
        let mut world = ReplayWorld {
            sim,
            substeps: cfg.substeps,
            kinematic,
            from,
            poses: Vec::with_capacity(n),
            masses,
        };
        world.poses = world.read_poses(None, 0)?;
        Ok(world)
    }

    /// Number of objects.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True for a world without objects.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Every object's pose now, `[objects]`.
    pub fn poses(&self) -> &[Pose7] {
        &self.poses
    }

    /// Mass of every object as simulated, kilograms.
    pub fn masses(&self) -> &[f32] {
        &self.masses
    }

    /// Which objects follow given poses, `[objects]`.
    pub fn kinematic(&self) -> &[bool] {
        &self.kinematic
    }

    /// Puts every object at `current` (`[objects]`) moving with the finite difference from
    /// `previous` over `dt` seconds (as a scene's `previous_pose` is read): a world rebuilt
    /// from poses alone, when the one that produced them is not at hand. Contacts start anew.
    pub fn restart(&mut self, previous: &[Pose7], current: &[Pose7], dt: f32) -> Result<()> {
        let n = self.poses.len();
        if previous.len() != n || current.len() != n {
            return Err(SimError::Invalid(format!(
                "a state of {} and {} poses for {n} objects",
                previous.len(),
                current.len()
            )));
        }
        for (j, (b, c)) in previous.iter().zip(current).enumerate() {
            let (v, w) = super::finite_difference(b, c, dt);
            if !(c.iter().all(|x| x.is_finite()) && v.iter().chain(&w).all(|x| x.is_finite())) {
                return Err(SimError::Invalid(format!("object {j}: pose is not finite")));
            }
            let pose = pose_from_arrays([c[0], c[1], c[2]], [c[3], c[4], c[5], c[6]]);
            let body = &mut self.sim.world.bodies[self.sim.bodies[j]];
            body.set_position(pose, true);
            if !self.kinematic[j] {
                body.set_linvel(Vector::new(v[0], v[1], v[2]), true);
                body.set_angvel(Vector::new(w[0], w[1], w[2]), true);
            }
            self.from[j] = pose;
        }
        self.poses = self.read_poses(Some(current), 0)?;
        Ok(())
    }

    /// Advances one step. `targets` gives the pose at the end of the step of some kinematic
    /// objects (`(object, pose)`); a kinematic object without one stays where it was last sent.
    /// Between steps a kinematic object moves along the straight line and the slerp from its
    /// last pose to the new one. Returns every object's pose after the step.
    pub fn step(&mut self, targets: &[(usize, Pose7)]) -> Result<&[Pose7]> {
        let mut to = self.from.clone();
        for &(j, p) in targets {
            if !self.kinematic.get(j).copied().unwrap_or(false) {
                return Err(SimError::Invalid(format!(
                    "object {j} is not kinematic; only kinematic objects take poses"
                )));
            }
            let q = [p[3], p[4], p[5], p[6]];
            let norm = q.iter().map(|c| c * c).sum::<f32>().sqrt();
            if !(p.iter().all(|c| c.is_finite()) && norm > 1e-6) {
                return Err(SimError::Invalid(format!(
                    "kinematic object {j}: pose is not finite or its quaternion is zero"
                )));
            }
            to[j] = pose_from_arrays([p[0], p[1], p[2]], q);
        }
        for s in 0..self.substeps {
            let f = (s + 1) as f32 / self.substeps as f32;
            for (j, &k) in self.kinematic.iter().enumerate() {
                if !k {
                    continue;
                }
                let (a, b) = (self.from[j], to[j]);
                let at = if s + 1 == self.substeps {
                    b
                } else {
                    Pose::from_parts(
                        a.translation.lerp(b.translation, f),
                        a.rotation.slerp(b.rotation, f),
                    )
                };
                self.sim.world.bodies[self.sim.bodies[j]].set_next_kinematic_position(at);
            }
            self.sim.world.step();
        }
        self.from = to;
        let previous = std::mem::take(&mut self.poses);
        self.poses = self.read_poses(Some(&previous), 1)?;
        Ok(&self.poses)
    }

    /// Every object's pose, its quaternion's sign continuous with `previous`; an error naming
    /// the first object whose pose is not finite at `frame`.
    fn read_poses(&self, previous: Option<&[Pose7]>, frame: usize) -> Result<Vec<Pose7>> {
        (0..self.sim.bodies.len())
            .map(|i| {
                let pose = self.sim.pose(i);
                let (t, q) = (pose.translation, pose.rotation);
                let mut q = [q.x, q.y, q.z, q.w];
                if let Some(prev) = previous.and_then(|p| p.get(i)) {
                    let d: f32 = (0..4).map(|k| prev[3 + k] * q[k]).sum();
                    if d < 0.0 {
                        q = q.map(|c| -c);
                    }
                }
                if !(t.is_finite() && q.iter().all(|c| c.is_finite())) {
                    return Err(SimError::Diverged(format!(
                        "object {i} at frame {frame} has a non-finite pose"
                    )));
                }
                Ok([t.x, t.y, t.z, q[0], q[1], q[2], q[3]])
            })
            .collect()
    }
}

/// A copy that continues exactly as the original would: every set of the world is copied and
/// the pipelines, which hold only scratch space, start fresh.
impl Clone for ReplayWorld {
    fn clone(&self) -> Self {
        let w = &self.sim.world;
        let world = PhysicsWorld {
            gravity: w.gravity,
            integration_parameters: w.integration_parameters,
            physics_pipeline: PhysicsPipeline::new(),
            collision_pipeline: CollisionPipeline::new(),
            islands: w.islands.clone(),
            broad_phase: w.broad_phase.clone(),
            narrow_phase: w.narrow_phase.clone(),
            bodies: w.bodies.clone(),
            colliders: w.colliders.clone(),
            impulse_joints: w.impulse_joints.clone(),
            multibody_joints: w.multibody_joints.clone(),
            soft_bodies: w.soft_bodies.clone(),
            ccd_solver: w.ccd_solver.clone(),
        };
        ReplayWorld {
            sim: SimWorld {
                world,
                bodies: self.sim.bodies.clone(),
                colliders: self.sim.colliders.clone(),
                shapes: self.sim.shapes.clone(),
            },
            substeps: self.substeps,
            kinematic: self.kinematic.clone(),
            from: self.from.clone(),
            poses: self.poses.clone(),
            masses: self.masses.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{PathDoc, ReplayOptions, replay};
    use super::*;
    use crate::scene::simulate;
    use dynaserve_api::json;

    /// The corners of a cube of half-size `half` metres.
    fn cube(half: f32) -> Vec<[f32; 3]> {
        dynaserve_geometry::mesh::cube()
            .vertices
            .iter()
            .map(|v| v.map(|c| 2.0 * half * c))
            .collect()
    }

    fn object(x: f32, vx: f32) -> json::ObjectSpec {
        json::ObjectSpec {
            points: Some(cube(0.1)),
            mesh: None,
            pose: json::Pose {
                translation: [x, 0.0, 0.1],
                rotation: [0.0, 0.0, 0.0, 1.0],
            },
            previous_pose: None,
            velocity: Some(json::Velocity {
                linear: [vx, 0.0, 0.0],
                angular: [0.0, 0.0, 1.0],
            }),
            mass: 1.0,
            friction: 0.5,
            restitution: 0.2,
        }
    }

    /// The stepped world reproduces the whole-trajectory simulation exactly (a pusher driven
    /// into a sliding box), and a clone taken midway continues as the original does.
    #[test]
    fn stepping_equals_the_whole_simulation_and_clones_continue_alike() {
        let scene = json::Scene {
            objects: vec![object(0.0, 1.0), object(-0.5, 0.0)],
        };
        let steps = 12;
        let path = PathDoc {
            object: 1,
            poses: (1..=steps)
                .map(|k| [-0.5 + 0.05 * k as f32, 0.0, 0.1, 0.0, 0.0, 0.0, 1.0])
                .collect(),
        };
        let opts = ReplayOptions::default();
        let stepped = replay(&scene, std::slice::from_ref(&path), steps, &opts).unwrap();

        let dt = opts.dt_frame;
        let objects = scene
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| {
                super::super::object_spec(
                    &super::super::ReplayObject::from_json(o, i).unwrap(),
                    i,
                    dt,
                )
            })
            .collect::<Result<Vec<_>>>()
            .unwrap();
        let mut spec = super::super::scene_spec(objects, &opts);
        spec.kinematic = vec![super::super::kinematic_path(&path)];
        let whole = simulate(&spec, &opts.sim_config(steps).unwrap()).unwrap();
        for (t, frame) in stepped.poses.iter().enumerate() {
            for (j, p) in frame.iter().enumerate() {
                let (x, q) = (whole.positions[j][t], whole.rotations[j][t]);
                assert_eq!(p[..3], x[..], "object {j} frame {t}");
                assert_eq!(p[3..], q[..], "object {j} frame {t}");
            }
        }

        spec.kinematic.clear();
        let mut a = ReplayWorld::new(&spec, &[false, true], &opts).unwrap();
        for k in 0..5 {
            a.step(&[(1, path.poses[k])]).unwrap();
        }
        let mut b = a.clone();
        for k in 5..steps {
            let pa = a.step(&[(1, path.poses[k])]).unwrap().to_vec();
            let pb = b.step(&[(1, path.poses[k])]).unwrap().to_vec();
            assert_eq!(pa, pb, "step {k}");
            assert_eq!(pa, stepped.poses[k + 1], "step {k}");
        }
        assert!(
            a.step(&[(0, path.poses[0])]).is_err(),
            "object 0 is not kinematic"
        );
    }
}
