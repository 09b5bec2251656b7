//! Rapier replay of a scene file: the ground truth for a scene in the server's JSON scene
//! format (a `POST /v1/rollout` body, a session's create body or a bare scene) with some objects
//! driven along given paths, e.g. to check a planner's pusher path in rapier.
//!
//! Every object is simulated as the convex hull of its reference points (or of its mesh's
//! vertices), with the scene's mass (uniform density over the hull), friction and restitution
//! combined by multiplication, on the MOVi floor (friction 0.3, restitution 0.5, top at z = 0)
//! under gravity (0, 0, -10) at 240 Hz: the conditions the bundled model was trained on. An
//! object's initial motion is its `velocity`, or the finite difference from its
//! `previous_pose` over one step. Kinematic objects follow their paths
//! ([`SceneSpec::kinematic`]); poses are reported in the scene's body frames.

pub mod cli;
pub mod world;

use dynaserve_api::json;
use rapier3d::math::{Rotation, Vector};
use serde::{Deserialize, Serialize};

use crate::materials::MOVI_FLOOR;
use crate::scene::{FloorSpec, KinematicPath, ObjectSpec, SceneSpec, SimConfig};
use crate::shapes::{Part, Polytope, Shape, ShapeKind};
use crate::{Result, SimError};
pub use world::{Pose7, ReplayWorld};

/// How a scene is replayed: frame interval, physics rate, floor and gravity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReplayOptions {
    /// Interval of one frame, seconds (the model's `dt_frame`; 1/24 s for the bundled model).
    pub dt_frame: f32,
    /// Frames per step.
    pub dt_steps: u32,
    /// Physics steps per second.
    pub physics_hz: u32,
    /// rapier solver iterations per physics step.
    pub solver_iterations: usize,
    /// The floor.
    pub floor: FloorSpec,
    /// Gravity, metres per second squared.
    pub gravity: [f32; 3],
}

impl Default for ReplayOptions {
    /// The MOVi conditions: 1/24 s frames of 10 physics steps at 240 Hz, 4 solver iterations,
    /// one frame per step, the MOVi floor, gravity (0, 0, -10).
    fn default() -> Self {
        Self {
            dt_frame: 1.0 / 24.0,
            dt_steps: 1,
            physics_hz: 240,
            solver_iterations: 4,
            floor: MOVI_FLOOR,
            gravity: [0.0, 0.0, -10.0],
        }
    }
}

impl ReplayOptions {
    fn sim_config(&self, steps: usize) -> Result<SimConfig> {
        let per_frame = self.dt_frame * self.physics_hz as f32;
        let substeps = per_frame.round();
        if !(self.dt_frame > 0.0 && substeps >= 1.0 && (per_frame - substeps).abs() < 1e-3) {
            return Err(SimError::Invalid(format!(
                "a frame of {} s is not a whole number of physics steps at {} Hz",
                self.dt_frame, self.physics_hz
            )));
        }
        if self.dt_steps == 0 {
            return Err(SimError::Invalid("dt_steps must be at least 1".into()));
        }
        Ok(SimConfig {
            physics_hz: self.physics_hz,
            substeps: substeps as u32 * self.dt_steps,
            frames: steps + 1,
            solver_iterations: self.solver_iterations,
        })
    }
}

/// The path of one kinematic object: its pose `[x, y, z, qx, qy, qz, qw]` (metres, unit
/// quaternion scalar last) at the end of every step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathDoc {
    /// Index of the object in the scene.
    pub object: usize,
    /// Poses `[steps, 7]`.
    pub poses: Vec<[f32; 7]>,
}

/// The paths file of `dynaserve sim replay --paths`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathsDoc {
    /// One path per kinematic object, all of the same length.
    pub paths: Vec<PathDoc>,
}

/// A replayed trajectory.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Replay {
    /// Interval of one step, seconds (`dt_steps * dt_frame`).
    pub dt_step: f32,
    /// Steps replayed.
    pub steps: usize,
    /// Pose `[x, y, z, qx, qy, qz, qw]` of every object at every step: `[steps + 1, objects,
    /// 7]`, entry 0 the initial state.
    pub poses: Vec<Vec<[f32; 7]>>,
    /// Mass of every object as simulated, kilograms.
    pub masses: Vec<f32>,
}

/// A scene file as read by [`parse_scene`].
#[derive(Clone, Debug, PartialEq)]
pub struct SceneFile {
    /// The scene.
    pub scene: json::Scene,
    /// The document's `steps`, if it has them (a rollout request).
    pub steps: Option<usize>,
    /// The document's `dt_steps`, if it has them and they are positive.
    pub dt_steps: Option<u32>,
}

/// Reads a scene from a JSON document: a rollout request or session create body (its `scene`)
/// or a bare scene (`{"objects": [...]}`).
pub fn parse_scene(text: &str) -> Result<SceneFile> {
    let doc: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| SimError::Invalid(format!("scene file is not JSON: {e}")))?;
    let number = |key: &str| doc.get(key).and_then(|v| v.as_u64()).filter(|&v| v > 0);
    let steps = number("steps").and_then(|v| usize::try_from(v).ok());
    let dt_steps = number("dt_steps").and_then(|v| u32::try_from(v).ok());
    let scene = doc.get("scene").cloned().unwrap_or(doc);
    let scene =
        serde_json::from_value(scene).map_err(|e| SimError::Invalid(format!("scene: {e}")))?;
    Ok(SceneFile {
        scene,
        steps,
        dt_steps,
    })
}

/// How an object of a replayed scene starts moving.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Start {
    /// At rest.
    Rest,
    /// Linear `[3]` m/s and angular `[3]` rad/s velocity, world frame.
    Velocity([f32; 3], [f32; 3]),
    /// The pose one step earlier (translation metres, quaternion `[x, y, z, w]`): the motion is
    /// its finite difference over the step.
    Previous([f32; 3], [f32; 4]),
}

/// One object as the replay builds it, whatever form the scene came in.
#[derive(Clone, Copy, Debug)]
pub struct ReplayObject<'a> {
    /// Body-frame points whose convex hull is the object (its cloud, or its mesh's vertices),
    /// metres.
    pub hull: &'a [[f32; 3]],
    /// Position, metres.
    pub translation: [f32; 3],
    /// Orientation, quaternion `[x, y, z, w]` (normalised here).
    pub rotation: [f32; 4],
    /// Initial motion.
    pub start: Start,
    /// Kilograms.
    pub mass: f32,
    /// Coulomb friction coefficient.
    pub friction: f32,
    /// Coefficient of restitution.
    pub restitution: f32,
}

impl<'a> ReplayObject<'a> {
    /// The object of a JSON scene (its points, or its mesh's vertices).
    pub fn from_json(o: &'a json::ObjectSpec, i: usize) -> Result<ReplayObject<'a>> {
        let field = |m: &str| SimError::Invalid(format!("scene.objects[{i}]: {m}"));
        let hull: &[[f32; 3]] = match (&o.points, &o.mesh) {
            (Some(p), None) => p,
            (None, Some(m)) => &m.vertices,
            _ => return Err(field("needs exactly one of points and mesh")),
        };
        let start = match (&o.velocity, &o.previous_pose) {
            (Some(v), None) => Start::Velocity(v.linear, v.angular),
            (None, Some(p)) => Start::Previous(p.translation, p.rotation),
            (None, None) => Start::Rest,
            (Some(_), Some(_)) => return Err(field("has both velocity and previous_pose")),
        };
        Ok(ReplayObject {
            hull,
            translation: o.pose.translation,
            rotation: o.pose.rotation,
            start,
            mass: o.mass,
            friction: o.friction,
            restitution: o.restitution,
        })
    }
}

/// The simulated object of `o` (object `i` of its scene; `dt_step`: seconds per step, over
/// which a previous pose is differenced).
pub fn object_spec(o: &ReplayObject<'_>, i: usize, dt_step: f32) -> Result<ObjectSpec> {
    let field = |m: &str| SimError::Invalid(format!("scene.objects[{i}]: {m}"));
    if o.hull.iter().flatten().any(|c| !c.is_finite()) {
        return Err(field("points must be finite"));
    }
    let hull =
        Polytope::hull(o.hull).map_err(|e| field(&format!("no convex hull of its points: {e}")))?;
    let shape = Shape {
        kind: ShapeKind::Hull,
        parts: vec![Part::Polytope(hull)],
    };
    for (name, v) in [("friction", o.friction), ("restitution", o.restitution)] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(field(&format!("{name} must be finite and non-negative")));
        }
    }
    let rotation = unit(o.rotation).ok_or_else(|| field("pose.rotation is not a rotation"))?;
    if o.translation.iter().any(|c| !c.is_finite()) {
        return Err(field("pose.translation must be finite"));
    }
    let (linvel, angvel) = match o.start {
        Start::Velocity(v, w) => (v, w),
        Start::Previous(t, q) => {
            unit(q).ok_or_else(|| field("previous_pose.rotation is not a rotation"))?;
            let [x, y, z] = o.translation;
            let [a, b, c] = t;
            let before = [a, b, c, q[0], q[1], q[2], q[3]];
            let now = [
                x,
                y,
                z,
                o.rotation[0],
                o.rotation[1],
                o.rotation[2],
                o.rotation[3],
            ];
            finite_difference(&before, &now, dt_step)
        }
        Start::Rest => ([0.0; 3], [0.0; 3]),
    };
    if linvel.iter().chain(&angvel).any(|c| !c.is_finite()) {
        return Err(field("velocity must be finite"));
    }
    let rigid = ObjectSpec::rigid_of_mass(shape, 0, 1.0, o.mass, o.friction, o.restitution)
        .map_err(|e| match e {
            SimError::Invalid(m) => field(&m),
            e => e,
        })?;
    Ok(ObjectSpec {
        position: o.translation,
        rotation,
        linvel,
        angvel,
        ..rigid
    })
}

/// The scene of `objects` under the floor and gravity of `opts`, without settling or paths.
pub fn scene_spec(objects: Vec<ObjectSpec>, opts: &ReplayOptions) -> SceneSpec {
    SceneSpec {
        objects,
        floor: opts.floor,
        gravity: opts.gravity,
        settle_steps: 0,
        kinematic: Vec::new(),
    }
}

/// The velocity that moves a body from `before` to `now` in `dt` seconds: linear `[3]` m/s and
/// angular `[3]` rad/s, world frame (quaternions normalised first).
pub fn finite_difference(before: &Pose7, now: &Pose7, dt: f32) -> ([f32; 3], [f32; 3]) {
    let rot = |p: &Pose7| {
        let q = unit([p[3], p[4], p[5], p[6]]).unwrap_or([0.0, 0.0, 0.0, 1.0]);
        Rotation::from_xyzw(q[0], q[1], q[2], q[3])
    };
    let d = rot(now) * rot(before).inverse();
    let w = d.to_scaled_axis() / dt;
    let v =
        (Vector::new(now[0], now[1], now[2]) - Vector::new(before[0], before[1], before[2])) / dt;
    (v.to_array(), w.to_array())
}

fn unit(q: [f32; 4]) -> Option<[f32; 4]> {
    let n = q.iter().map(|c| c * c).sum::<f32>().sqrt();
    (n.is_finite() && n > 1e-6).then(|| q.map(|c| c / n))
}

/// Replays `scene` for `steps` steps with the objects of `paths` driven along them (every path
/// must hold at least `steps` poses; with no path, `steps` is all that sets the length).
pub fn replay(
    scene: &json::Scene,
    paths: &[PathDoc],
    steps: usize,
    opts: &ReplayOptions,
) -> Result<Replay> {
    if steps == 0 {
        return Err(SimError::Invalid("replay needs at least one step".into()));
    }
    if scene.objects.is_empty() {
        return Err(SimError::Invalid("scene.objects is empty".into()));
    }
    let dt_step = opts.dt_frame * opts.dt_steps as f32;
    let objects = scene
        .objects
        .iter()
        .enumerate()
        .map(|(i, o)| object_spec(&ReplayObject::from_json(o, i)?, i, dt_step))
        .collect::<Result<Vec<_>>>()?;
    let n = objects.len();
    let mut kinematic = vec![false; n];
    let mut seen = vec![false; n];
    for p in paths {
        kinematic_path(p).check(n, steps + 1, &mut seen)?;
        kinematic[p.object] = true;
    }
    let mut world = ReplayWorld::new(&scene_spec(objects, opts), &kinematic, opts)?;
    let mut poses = Vec::with_capacity(steps + 1);
    poses.push(world.poses().to_vec());
    for k in 0..steps {
        let targets: Vec<(usize, Pose7)> = paths.iter().map(|p| (p.object, p.poses[k])).collect();
        poses.push(world.step(&targets)?.to_vec());
    }
    Ok(Replay {
        dt_step,
        steps,
        poses,
        masses: world.masses().to_vec(),
    })
}

/// `p` as the simulator's kinematic path.
fn kinematic_path(p: &PathDoc) -> KinematicPath {
    KinematicPath {
        object: p.object,
        poses: p
            .poses
            .iter()
            .map(|x| ([x[0], x[1], x[2]], [x[3], x[4], x[5], x[6]]))
            .collect(),
    }
}
