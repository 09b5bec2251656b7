//! Scene generators (`movi-a`, `movi-b`, `wrecking-ball` and the physics scenarios of
//! [`crate::scenarios`]) and the generation of one scene: drawn with its seed (see
//! [`crate::random::scene_rng`]), sampled into reference clouds, simulated and recorded.
//! Writing a whole split is [`crate::writer`]'s.

mod movi;
mod wrecking_ball;

pub use movi::{MoviParameters, ScaleDistribution};
pub use wrecking_ball::WreckingBallParameters;

use rand::Rng;

use crate::dataset::{ObjectRecord, SceneLabel, SceneRecord};
use crate::random::scene_rng;
use crate::scenarios::{Scenario, ScenarioParameters, sample_scenario};
use crate::scene::{SceneSpec, SimConfig, simulate};
use crate::shapes::ShapeKind;
use crate::{Result, SimError};
use movi::sample_movi;
use wrecking_ball::sample_wrecking_ball;

/// A scene generator and its parameters.
#[derive(Clone, Debug, PartialEq)]
pub enum Generator {
    /// MOVi-A-like scenes.
    MoviA(MoviParameters),
    /// MOVi-B-like scenes.
    MoviB(MoviParameters),
    /// WreckingBall scenes.
    WreckingBall(WreckingBallParameters),
    /// Physics scenario scenes (`rest`, `drop`, `slide`, `collide`, `stack-hit`, or
    /// `physics-mix` drawing one of them per scene).
    Scenario(Box<ScenarioParameters>),
}

impl Generator {
    /// MOVi-A with Kubric's parameters.
    pub fn movi_a() -> Self {
        Generator::MoviA(MoviParameters::movi_a())
    }

    /// MOVi-B with Kubric's parameters and the procedural shape set.
    pub fn movi_b() -> Self {
        Generator::MoviB(MoviParameters::movi_b())
    }

    /// WreckingBall with `size^3` cubes (size 1 to 10).
    pub fn wrecking_ball(size: usize) -> Result<Self> {
        if !(1..=10).contains(&size) {
            return Err(SimError::Invalid(format!(
                "wrecking-ball size must be 1 to 10, got {size}"
            )));
        }
        Ok(Generator::WreckingBall(WreckingBallParameters::new(size)))
    }

    /// One physics scenario with its default parameters.
    pub fn scenario(scenario: Scenario) -> Self {
        Generator::Scenario(Box::new(ScenarioParameters::new(vec![scenario])))
    }

    /// Scenario scenes drawn from `p` (several scenarios: one drawn per scene).
    pub fn scenarios(p: ScenarioParameters) -> Self {
        Generator::Scenario(Box::new(p))
    }

    /// `physics-mix`: each scene draws one of the five scenarios uniformly.
    pub fn physics_mix() -> Self {
        Generator::Scenario(Box::new(ScenarioParameters::new(Scenario::ALL.to_vec())))
    }

    /// Name as used on the command line and in manifests.
    pub fn name(&self) -> &'static str {
        match self {
            Generator::MoviA(_) => "movi-a",
            Generator::MoviB(_) => "movi-b",
            Generator::WreckingBall(_) => "wrecking-ball",
            Generator::Scenario(p) => p.name(),
        }
    }

    /// Whether its scenes can hold kinematic objects (the `push` scenario's pusher), whose
    /// shards then carry the `kinematic` tensor.
    pub fn has_kinematic(&self) -> bool {
        matches!(self, Generator::Scenario(p) if p.scenarios.contains(&Scenario::Push))
    }

    /// The shapes objects can have; `shape_id` indexes this list.
    pub fn shapes(&self) -> Vec<ShapeKind> {
        match self {
            Generator::MoviA(p) | Generator::MoviB(p) => p.shapes.clone(),
            Generator::WreckingBall(_) => vec![ShapeKind::Cube, ShapeKind::Sphere],
            Generator::Scenario(p) => p.shapes.clone(),
        }
    }

    /// Gravity, metres per second squared.
    pub fn gravity(&self) -> [f32; 3] {
        match self {
            Generator::MoviA(p) | Generator::MoviB(p) => p.gravity,
            Generator::WreckingBall(p) => p.gravity,
            Generator::Scenario(p) => p.gravity,
        }
    }

    /// The parameters as JSON, for the manifest.
    pub fn parameters(&self) -> serde_json::Value {
        let v = match self {
            Generator::MoviA(p) | Generator::MoviB(p) => serde_json::to_value(p),
            Generator::WreckingBall(p) => serde_json::to_value(p),
            Generator::Scenario(p) => serde_json::to_value(p),
        };
        v.unwrap_or(serde_json::Value::Null)
    }

    /// Draws a scene description.
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> Result<SceneSpec> {
        self.sample_labelled(rng).map(|(spec, _)| spec)
    }

    /// Draws a scene description and, for scenario generators, its label.
    pub fn sample_labelled<R: Rng + ?Sized>(
        &self,
        rng: &mut R,
    ) -> Result<(SceneSpec, Option<SceneLabel>)> {
        match self {
            Generator::MoviA(p) | Generator::MoviB(p) => Ok((sample_movi(p, rng)?, None)),
            Generator::WreckingBall(p) => Ok((sample_wrecking_ball(p, rng)?, None)),
            Generator::Scenario(p) => {
                sample_scenario(p, rng).map(|(spec, label)| (spec, Some(label)))
            }
        }
    }
}

/// What to generate.
#[derive(Clone, Debug)]
pub struct GenerateOptions {
    /// The generator.
    pub generator: Generator,
    /// Dataset seed.
    pub seed: u64,
    /// Split name (`train`, `val`, `test`); part of every scene's seed.
    pub split: String,
    /// Number of scenes.
    pub scenes: usize,
    /// Reference points per object.
    pub points: usize,
    /// Scenes per shard file (the last shard may hold fewer).
    pub scenes_per_shard: usize,
    /// Stepping and recording.
    pub sim: SimConfig,
}

impl GenerateOptions {
    /// Defaults for a generator: 1024 points, MOVi recording (240 Hz, 24 fps, 101 frames),
    /// shards of about 20 MB.
    pub fn new(generator: Generator, seed: u64, split: &str, scenes: usize) -> Self {
        let scenes_per_shard = match &generator {
            Generator::WreckingBall(p) => (64 / p.size.pow(3).max(1)).clamp(1, 64).max(4),
            _ => 100,
        };
        Self {
            generator,
            seed,
            split: split.to_string(),
            scenes,
            points: 1024,
            scenes_per_shard,
            sim: SimConfig::default(),
        }
    }

    /// Checks points, scenes per shard and the split name.
    pub(crate) fn validate(&self) -> Result<()> {
        if self.points == 0 {
            return Err(SimError::Invalid("points must be at least 1".into()));
        }
        if self.scenes_per_shard == 0 {
            return Err(SimError::Invalid(
                "scenes per shard must be at least 1".into(),
            ));
        }
        if self.split.is_empty() {
            return Err(SimError::Invalid("split name is empty".into()));
        }
        Ok(())
    }
}

/// A generated scene: its description (with the exact shapes) and its record.
#[derive(Clone, Debug)]
pub struct GeneratedScene {
    /// What was simulated.
    pub spec: SceneSpec,
    /// Trajectories, reference clouds and parameters as stored in the dataset.
    pub record: SceneRecord,
    /// Scenario generators only: what the scene isolates.
    pub label: Option<SceneLabel>,
}

/// Generates scene `index`: draws the scene, samples each object's reference cloud (body frame,
/// on the scaled shape), simulates it.
pub fn generate_scene(opts: &GenerateOptions, index: u64) -> Result<GeneratedScene> {
    opts.validate()?;
    let mut rng = scene_rng(opts.seed, &opts.split, opts.generator.name(), index);
    let (spec, label) = opts.generator.sample_labelled(&mut rng)?;
    let clouds = spec
        .objects
        .iter()
        .map(|o| o.scaled_shape().sample_surface(opts.points, &mut rng))
        .collect::<Result<Vec<_>>>()?;
    let traj = simulate(&spec, &opts.sim)?;
    let objects = spec
        .objects
        .iter()
        .zip(clouds)
        .enumerate()
        .map(|(i, (o, reference_points))| ObjectRecord {
            positions: traj.positions[i].clone(),
            rotations: traj.rotations[i].clone(),
            reference_points,
            mass: traj.masses[i],
            friction: o.material.friction,
            restitution: o.material.restitution,
            scale: [o.scale; 3],
            shape_id: o.shape_id,
            material: o.material_kind,
            kinematic: spec.kinematic.iter().any(|k| k.object == i),
        })
        .collect();
    Ok(GeneratedScene {
        spec,
        record: SceneRecord {
            objects,
            dt_frame: opts.sim.dt_frame(),
        },
        label,
    })
}
