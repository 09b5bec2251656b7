//! The rapier family: the rigid-body simulator the training data came from, served as a model.
//! Each object is rebuilt from the request (the convex hull of its cloud, or of its mesh's
//! vertices; its mass at uniform density over the hull, friction and restitution) on the
//! data's floor under its gravity, started from the request's poses and velocities, stepped
//! at the physics rate and sampled once per step of `dt_steps` frames: exactly what
//! `dynaserve sim replay` computes for the same scene ([`ReplayWorld`]).
//!
//! A scene's world travels with its state ([`SceneState::carry`]): each step continues a copy
//! of the world that produced the state, so forks and Predict variants go on exactly as a
//! replay would. A state whose poses were set from outside (no world of those poses) is
//! rebuilt from them, its velocities the finite difference of its last two poses. Kinematic
//! objects follow the poses a session gives them, interpolated over the physics steps as in a
//! replay with paths. A scheduler pass steps its scenes in parallel on rayon's threads.

use std::any::Any;
use std::path::Path;
use std::sync::Arc;

use dynaserve_api::limits::{Caps, Limits, MAX_DT_STEPS};
use dynaserve_api::spec::{About, ModelInfo, ModelKind, Motion, Scene, Shape};
use dynaserve_model::{Carry, Pose, SceneState};
use dynaserve_sim::materials::MOVI_FLOOR;
use dynaserve_sim::replay::{
    Pose7, ReplayObject, ReplayOptions, ReplayWorld, Start, object_spec, scene_spec,
};
use dynaserve_sim::scene::FloorSpec;
use serde::{Deserialize, Serialize};

use super::built_scene::build_scene;
use super::contract::{Prepared, Resident, SceneStep, Stepped, SteppedScene, SteppingModel};
use super::{LoadOptions, ModelFamily};
use crate::error::ApiError;

/// config.json's `architecture` for the simulator.
pub const RAPIER: &str = "rapier";

/// Loads simulator directories: a config.json of [`RapierConfig`].
pub struct RapierFamily;

impl ModelFamily for RapierFamily {
    fn recognises(&self, architecture: &str) -> bool {
        architecture == RAPIER
    }

    fn load(&self, dir: &Path, _opts: &LoadOptions) -> anyhow::Result<Resident> {
        let path = dir.join(dynaserve_model::checkpoint::CONFIG_FILE);
        let text = std::fs::read_to_string(&path)?;
        let config: RapierConfig =
            serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let name = dir
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or(RAPIER)
            .to_string();
        Ok(Resident::Stepping(Arc::new(RapierModel::new(
            name, config,
        )?)))
    }
}

/// A simulator's config.json: the conditions its scenes are simulated under.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RapierConfig {
    /// Always `rapier`.
    pub architecture: String,
    /// Interval of one frame, seconds (the learned models' `dt_frame`).
    #[serde(default = "default_dt_frame")]
    pub dt_frame: f32,
    /// Physics steps per second.
    #[serde(default = "default_physics_hz")]
    pub physics_hz: u32,
    /// Solver iterations per physics step.
    #[serde(default = "default_solver_iterations")]
    pub solver_iterations: usize,
    /// The floor (top at z = 0).
    #[serde(default = "default_floor")]
    pub floor: FloorSpec,
    /// Gravity, m/s^2.
    #[serde(default = "default_gravity")]
    pub gravity: [f32; 3],
}

fn default_dt_frame() -> f32 {
    ReplayOptions::default().dt_frame
}
fn default_physics_hz() -> u32 {
    ReplayOptions::default().physics_hz
}
fn default_solver_iterations() -> usize {
    ReplayOptions::default().solver_iterations
}
fn default_floor() -> FloorSpec {
    MOVI_FLOOR
}
fn default_gravity() -> [f32; 3] {
    ReplayOptions::default().gravity
}

impl RapierConfig {
    /// The replay options of steps of `dt_steps` frames.
    pub fn replay_options(&self, dt_steps: u32) -> ReplayOptions {
        ReplayOptions {
            dt_frame: self.dt_frame,
            dt_steps,
            physics_hz: self.physics_hz,
            solver_iterations: self.solver_iterations,
            floor: self.floor,
            gravity: self.gravity,
        }
    }
}

/// The simulator, resident.
pub struct RapierModel {
    name: String,
    config: RapierConfig,
}

/// Points a mesh is sampled to while its scene is validated (the simulator itself uses the
/// mesh's vertices).
const VALIDATION_POINTS: usize = 64;

impl RapierModel {
    /// The simulator named `name` under `config` (its rates must be whole physics steps per
    /// frame).
    pub fn new(name: String, config: RapierConfig) -> anyhow::Result<RapierModel> {
        if config.architecture != RAPIER {
            anyhow::bail!("architecture {:?} is not {RAPIER:?}", config.architecture);
        }
        let per_frame = config.dt_frame * config.physics_hz as f32;
        if !(per_frame >= 1.0 && (per_frame - per_frame.round()).abs() < 1e-3) {
            anyhow::bail!(
                "a frame of {} s is not a whole number of physics steps at {} Hz",
                config.dt_frame,
                config.physics_hz
            );
        }
        Ok(RapierModel { name, config })
    }

    /// The world of a state: a copy of the one that produced it, or one rebuilt from its poses.
    fn world_for(&self, item: &SceneStep) -> Result<ReplayWorld, String> {
        let scene = item
            .scene
            .as_any()
            .downcast_ref::<RapierScene>()
            .ok_or("scene was prepared by another family")?;
        let current: Vec<Pose7> = item.state.current.iter().map(pose7).collect();
        if let Some(w) = item.state.carry.get::<ReplayWorld>()
            && w.poses() == current.as_slice()
        {
            return Ok(w.clone());
        }
        let mut w = scene.start.clone();
        let dt = (f64::from(item.dt_steps) * f64::from(self.config.dt_frame)) as f32;
        let previous: Vec<Pose7> = item.state.previous.iter().map(pose7).collect();
        w.restart(&previous, &current, dt)
            .map_err(|e| e.to_string())?;
        Ok(w)
    }

    /// One scene's step.
    fn step_one(&self, item: &SceneStep) -> Result<Stepped, String> {
        let mut world = self.world_for(item)?;
        let targets: Vec<(usize, Pose7)> = match &item.drive {
            Some(d) => d
                .kinematic
                .iter()
                .zip(&d.next)
                .enumerate()
                .filter(|(_, (k, _))| **k)
                .map(|(j, (_, p))| (j, pose7(p)))
                .collect(),
            None => Vec::new(),
        };
        let poses = world
            .step(&targets)
            .map_err(|e| e.to_string())?
            .iter()
            .map(pose_of)
            .collect();
        Ok(Stepped {
            poses,
            carry: Carry::new(world),
            // One deterministic simulation: nothing to disagree with.
            spread: None,
        })
    }
}

/// A served pose as the replay writes it.
fn pose7(p: &Pose) -> Pose7 {
    let (t, q) = (p.translation, p.rotation);
    [t[0], t[1], t[2], q[0], q[1], q[2], q[3]]
}

/// A replay pose as served ([`pose7`] undone).
fn pose_of(p: &Pose7) -> Pose {
    Pose {
        translation: [p[0], p[1], p[2]],
        rotation: [p[3], p[4], p[5], p[6]],
    }
}

/// A scene prepared for the simulator: its world at the start.
pub struct RapierScene {
    start: ReplayWorld,
    bytes: usize,
}

impl SteppedScene for RapierScene {
    fn len(&self) -> usize {
        self.start.len()
    }

    fn bytes(&self) -> usize {
        self.bytes
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// The simulator's object of a request object (its cloud or its mesh's vertices).
fn replay_object(o: &dynaserve_api::spec::ObjectSpec) -> ReplayObject<'_> {
    ReplayObject {
        hull: match &o.shape {
            Shape::Points(p) => p,
            Shape::Mesh(m) => &m.vertices,
        },
        translation: o.pose.translation,
        rotation: o.pose.rotation,
        start: match o.motion {
            Motion::Rest => Start::Rest,
            Motion::Velocity { linear, angular } => Start::Velocity(linear, angular),
            Motion::PreviousPose(p) => Start::Previous(p.translation, p.rotation),
        },
        mass: o.mass,
        friction: o.friction,
        restitution: o.restitution,
    }
}

impl SteppingModel for RapierModel {
    fn name(&self) -> &str {
        &self.name
    }

    fn dt_frame(&self) -> f64 {
        f64::from(self.config.dt_frame)
    }

    fn limits(&self, caps: &Caps) -> Limits {
        Limits {
            caps: Caps {
                max_dt_steps: caps.max_dt_steps.min(MAX_DT_STEPS),
                ..*caps
            },
            default_points: VALIDATION_POINTS.min(caps.max_points_per_object),
        }
    }

    fn info(&self, limits: Limits) -> ModelInfo {
        ModelInfo {
            name: self.name.clone(),
            kind: ModelKind::Stepping {
                about: About {
                    architecture: RAPIER.to_string(),
                    dt_frame: self.dt_frame(),
                    gravity: self.config.gravity,
                    config: serde_json::to_value(&self.config).unwrap_or_default(),
                },
                limits,
            },
            members: Vec::new(),
            gradients: false,
        }
    }

    fn gradients_unsupported(&self) -> Option<String> {
        Some(format!(
            "model {} is the rapier simulator, which computes no gradients; use a RigidFormer \
             model for them",
            self.name
        ))
    }

    fn prepare(
        &self,
        scene: &Scene,
        path: &str,
        limits: &Limits,
        dt_steps: u32,
        kinematic: &[bool],
    ) -> Result<Prepared, ApiError> {
        let opts = self.config.replay_options(dt_steps);
        let dt_step = opts.dt_frame * dt_steps as f32;
        // The same checks as for a learned model, with errors naming the field.
        let state = build_scene(scene, path, limits, dt_step)?.state;
        let objects = scene
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| {
                object_spec(&replay_object(o), i, dt_step)
                    .map_err(|e| ApiError::invalid(format!("{path}.objects[{i}]"), e.to_string()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let start = ReplayWorld::new(&scene_spec(objects, &opts), kinematic, &opts)
            .map_err(|e| ApiError::invalid(path, e.to_string()))?;
        let bytes = scene
            .objects
            .iter()
            .map(|o| match &o.shape {
                Shape::Points(p) => p.len() * 12 + 512,
                Shape::Mesh(m) => m.vertices.len() * 12 + 512,
            })
            .sum();
        // The simulator's own start poses (normalised quaternions), which the carry matches.
        let state = SceneState {
            current: start.poses().iter().map(pose_of).collect(),
            carry: Carry::new(start.clone()),
            ..state
        };
        Ok(Prepared {
            scene: Arc::new(RapierScene { start, bytes }),
            state,
            outside: Vec::new(),
        })
    }

    fn forward_objects(&self) -> Option<usize> {
        None
    }

    /// Every scene on its own, spread over rayon's worker threads (a panic fails the pass,
    /// which the scheduler turns into its jobs' errors).
    fn step(&self, items: &[&SceneStep]) -> Result<Vec<Result<Stepped, String>>, String> {
        use rayon::prelude::*;
        Ok(items.par_iter().map(|s| self.step_one(s)).collect())
    }
}
