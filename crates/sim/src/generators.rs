//! Scene generators (`movi-a`, `movi-b`, `wrecking-ball` and the physics scenarios of
//! [`crate::scenarios`]), per-scene seeding and dataset generation in parallel.
//!
//! Scene `i` of split `split` draws from a ChaCha8 generator keyed by `(seed, split, generator,
//! i)`, so scenes never repeat across splits or generators, and generating in parallel (rayon)
//! gives exactly the bytes of a serial run.

use std::f32::consts::TAU;
use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rapier3d::math::Pose;
use rapier3d::parry::query::intersection_test;
use rapier3d::prelude::SharedShape;
use serde::Serialize;

use crate::dataset::{self, Manifest, ObjectRecord, SceneLabel, SceneRecord, ShapeInfo, ShardInfo};
use crate::scenarios::{Scenario, ScenarioParameters, sample_scenario};
use crate::scene::{FloorSpec, Material, ObjectSpec, SceneSpec, SimConfig, simulate};
use crate::shapes::{Shape, ShapeKind};
use crate::{Result, SimError};

/// Kubric's metal: friction 0.4, restitution 0.3, density 2.7.
pub const METAL: Material = Material {
    friction: 0.4,
    restitution: 0.3,
    density: 2.7,
};
/// Kubric's rubber: friction 0.8, restitution 0.7, density 1.1.
pub const RUBBER: Material = Material {
    friction: 0.8,
    restitution: 0.7,
    density: 1.1,
};
/// Kubric's MOVi floor: friction 0.3, restitution 0.5, top at z = 0.
pub const MOVI_FLOOR: FloorSpec = FloorSpec {
    friction: 0.3,
    restitution: 0.5,
    half_extent: 40.0,
    thickness: 0.2,
};

/// How object scales are drawn.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ScaleDistribution {
    /// One of the listed values, uniformly.
    Choice(Vec<f32>),
    /// Uniform in `[low, high]`.
    Uniform {
        /// Lower bound.
        low: f32,
        /// Upper bound.
        high: f32,
    },
}

/// Parameters of the MOVi-like generators (Kubric's MOVi-A and MOVi-B worker), recorded in the
/// manifest.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MoviParameters {
    /// Fewest objects per scene.
    pub objects_min: usize,
    /// Most objects per scene.
    pub objects_max: usize,
    /// Shapes drawn uniformly.
    pub shapes: Vec<ShapeKind>,
    /// Scale distribution.
    pub scale: ScaleDistribution,
    /// Materials drawn uniformly: (name, material).
    pub materials: Vec<(String, Material)>,
    /// Spawn region lower corner, metres (shrunk by each object's bounding box).
    pub spawn_min: [f32; 3],
    /// Spawn region upper corner, metres.
    pub spawn_max: [f32; 3],
    /// Linear velocity is uniform in `[velocity_min, velocity_max]` minus `[x, y, 0]` of the
    /// spawn position (towards the centre), metres per second.
    pub velocity_min: [f32; 3],
    /// See `velocity_min`.
    pub velocity_max: [f32; 3],
    /// Placement attempts per object before the object is left out.
    pub spawn_attempts: usize,
    /// The floor.
    pub floor: FloorSpec,
    /// Gravity, metres per second squared.
    pub gravity: [f32; 3],
}

impl MoviParameters {
    /// Kubric's MOVi-A: cube, cylinder, sphere; scale 0.7 or 1.4.
    pub fn movi_a() -> Self {
        Self {
            shapes: ShapeKind::MOVI_A.to_vec(),
            scale: ScaleDistribution::Choice(vec![0.7, 1.4]),
            ..Self::movi_b()
        }
    }

    /// MOVi-B with the procedural shape set; scale uniform in [0.7, 1.4].
    pub fn movi_b() -> Self {
        Self {
            objects_min: 3,
            objects_max: 10,
            shapes: ShapeKind::MOVI_B.to_vec(),
            scale: ScaleDistribution::Uniform {
                low: 0.7,
                high: 1.4,
            },
            materials: vec![("metal".into(), METAL), ("rubber".into(), RUBBER)],
            spawn_min: [-5.0, -5.0, 1.0],
            spawn_max: [5.0, 5.0, 5.0],
            velocity_min: [-4.0, -4.0, 0.0],
            velocity_max: [4.0, 4.0, 0.0],
            spawn_attempts: 1000,
            floor: MOVI_FLOOR,
            gravity: [0.0, 0.0, -10.0],
        }
    }
}

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

/// Uniformly distributed unit quaternion `[x, y, z, w]` (Shoemake's method).
pub fn random_rotation<R: Rng + ?Sized>(rng: &mut R) -> [f32; 4] {
    let (u1, u2, u3) = (
        rng.random::<f64>(),
        rng.random::<f64>(),
        rng.random::<f64>(),
    );
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let t2 = std::f64::consts::TAU * u2;
    let t3 = std::f64::consts::TAU * u3;
    [
        (a * t2.sin()) as f32,
        (a * t2.cos()) as f32,
        (b * t3.sin()) as f32,
        (b * t3.cos()) as f32,
    ]
}

fn world_shape(shape: &(Pose, SharedShape), pose: &Pose) -> Pose {
    *pose * shape.0
}

fn sample_movi<R: Rng + ?Sized>(p: &MoviParameters, rng: &mut R) -> Result<SceneSpec> {
    if p.shapes.is_empty() || p.materials.is_empty() || p.objects_min > p.objects_max {
        return Err(SimError::Invalid("empty shape or material list".into()));
    }
    let count = rng.random_range(p.objects_min..=p.objects_max);
    let mut objects: Vec<ObjectSpec> = Vec::with_capacity(count);
    let mut placed: Vec<((Pose, SharedShape), Pose)> = Vec::with_capacity(count);
    for _ in 0..count {
        let shape_id = rng.random_range(0..p.shapes.len());
        let shape = Shape::unit(p.shapes[shape_id], rng)?;
        let scale = match &p.scale {
            ScaleDistribution::Choice(v) => v[rng.random_range(0..v.len())],
            ScaleDistribution::Uniform { low, high } => rng.random_range(*low..=*high),
        };
        let material = p.materials[rng.random_range(0..p.materials.len())].1;
        let collider = shape.scaled(scale).collider()?;
        let mut spot = None;
        for _ in 0..p.spawn_attempts {
            let rotation = random_rotation(rng);
            let rot = crate::scene::pose_from_arrays([0.0; 3], rotation);
            let aabb = collider.1.compute_aabb(&world_shape(&collider, &rot));
            // Drawn in axis order x, y, z.
            let position: [f32; 3] = std::array::from_fn(|k| {
                let lo = p.spawn_min[k] - aabb.mins[k];
                let hi = p.spawn_max[k] - aabb.maxs[k];
                if lo < hi {
                    rng.random_range(lo..hi)
                } else {
                    0.5 * (lo + hi)
                }
            });
            let pose = crate::scene::pose_from_arrays(position, rotation);
            let world = world_shape(&collider, &pose);
            let mut free = true;
            for (other, other_pose) in &placed {
                let hit = intersection_test(
                    &world,
                    collider.1.as_ref(),
                    &world_shape(other, other_pose),
                    other.1.as_ref(),
                )
                .map(|r| r.intersecting)
                .unwrap_or(true);
                if hit {
                    free = false;
                    break;
                }
            }
            if free {
                spot = Some((position, rotation, pose));
                break;
            }
        }
        let Some((position, rotation, pose)) = spot else {
            continue;
        };
        let mut linvel: [f32; 3] = std::array::from_fn(|k| {
            if p.velocity_min[k] < p.velocity_max[k] {
                rng.random_range(p.velocity_min[k]..p.velocity_max[k])
            } else {
                p.velocity_min[k]
            }
        });
        linvel[0] -= position[0];
        linvel[1] -= position[1];
        placed.push((collider, pose));
        objects.push(ObjectSpec {
            shape,
            shape_id: shape_id as i32,
            scale,
            material,
            material_kind: 0,
            position,
            rotation,
            linvel,
            angvel: [0.0; 3],
            held_until_settled: false,
        });
    }
    Ok(SceneSpec {
        objects,
        floor: p.floor,
        gravity: p.gravity,
        settle_steps: 0,
    })
}

fn sample_wrecking_ball<R: Rng + ?Sized>(
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
    })
}

fn mix(mut z: u64) -> u64 {
    // SplitMix64 finaliser: a bijection on u64 with good avalanche.
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

fn fnv1a(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01B3)
    })
}

/// The random generator of scene `index` of `split` for `generator` and `seed`: a ChaCha8 key
/// made of the four mixed inputs, so distinct inputs give independent streams.
pub fn scene_rng(seed: u64, split: &str, generator: &str, index: u64) -> ChaCha8Rng {
    let words = [
        mix(seed),
        mix(fnv1a(split) ^ 0x5350_4c49_5400_0000),
        mix(index ^ 0x5343_454e_4500_0000),
        mix(fnv1a(generator)),
    ];
    let mut key = [0u8; 32];
    for (chunk, w) in key.chunks_exact_mut(8).zip(words) {
        chunk.copy_from_slice(&w.to_le_bytes());
    }
    ChaCha8Rng::from_seed(key)
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

    fn validate(&self) -> Result<()> {
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

/// What a dataset generation produced.
#[derive(Clone, Debug)]
pub struct GenerateSummary {
    /// The split directory.
    pub dir: PathBuf,
    /// The manifest written.
    pub manifest: Manifest,
    /// Total bytes of shards and manifest.
    pub bytes: u64,
}

/// Generates a dataset split into `out`: shards of `scenes_per_shard` scenes generated in
/// parallel on rayon's pool, then `manifest.json`. Refuses a directory that already holds a
/// manifest unless `overwrite`. `on_scene` is called once per finished scene (progress).
pub fn generate_dataset(
    opts: &GenerateOptions,
    out: &Path,
    overwrite: bool,
    on_scene: &(dyn Fn() + Sync),
) -> Result<GenerateSummary> {
    opts.validate()?;
    dataset::prepare_dir(out, overwrite)?;
    let shapes: Vec<ShapeInfo> = opts
        .generator
        .shapes()
        .iter()
        .enumerate()
        .map(|(i, k)| ShapeInfo {
            id: i as i32,
            name: k.name().to_string(),
            description: k.description().to_string(),
        })
        .collect();
    let (mut shards, mut bytes, mut objects) = (Vec::new(), 0u64, 0usize);
    let labels = dataset::write_shards(
        out,
        opts.scenes,
        opts.scenes_per_shard,
        |i| generate_scene(opts, i).map(|g| (g.record, g.label)),
        on_scene,
        |scenes| dataset::encode_shard(scenes, opts.sim.frames, opts.points),
        |file, first_scene, scenes, size| {
            bytes += size;
            let n_obj: usize = scenes.iter().map(|s| s.objects.len()).sum();
            objects += n_obj;
            shards.push(ShardInfo {
                file,
                scenes: scenes.len(),
                objects: n_obj,
                first_scene,
            });
        },
    )?;
    let mut manifest = Manifest::new(opts, shapes, shards, objects);
    if matches!(opts.generator, Generator::Scenario(_)) {
        manifest.scenarios = labels.into_iter().collect();
    }
    bytes += dataset::write_manifest(out, &manifest)?;
    Ok(GenerateSummary {
        dir: out.to_path_buf(),
        manifest,
        bytes,
    })
}
