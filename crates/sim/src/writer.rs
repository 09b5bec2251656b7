//! Writing a pose dataset split: scenes generated in parallel shard by shard, then the
//! `manifest.json` that describes them (what `dynaserve sim generate` does).

use std::path::{Path, PathBuf};

use crate::Result;
use crate::dataset::{
    self, FORMAT, FORMAT_VERSION, Manifest, RESERVED_TENSORS, ShapeInfo, ShardInfo, Units, doc,
};
use crate::generators::{GenerateOptions, Generator, generate_scene};

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
    let mut written = dataset::PoseShards::default();
    let labels = dataset::write_shards(
        opts.scenes,
        opts.scenes_per_shard,
        |i| generate_scene(opts, i).map(|g| (g.record, g.label)),
        on_scene,
        |_, scenes| written.write(out, scenes, opts.sim.frames, opts.points),
    )?;
    let (shards, objects, mut bytes) = (written.shards, written.objects, written.bytes);
    let mut manifest = manifest(opts, shapes, shards, objects);
    if matches!(opts.generator, Generator::Scenario(_)) {
        manifest.scenarios = labels.into_iter().collect();
    }
    if opts.generator.has_kinematic() {
        manifest.tensors.push(doc(
            "kinematic",
            "I32",
            "[O]",
            "1 for an object whose poses were given (a pusher following a path), else 0",
        ));
    }
    bytes += dataset::write_manifest(out, &manifest)?;
    Ok(GenerateSummary {
        dir: out.to_path_buf(),
        manifest,
        bytes,
    })
}

/// The manifest of a split generated with `opts`: its shapes, shards and object count.
fn manifest(
    opts: &GenerateOptions,
    shapes: Vec<ShapeInfo>,
    shards: Vec<ShardInfo>,
    objects: usize,
) -> Manifest {
    Manifest {
        format: FORMAT.into(),
        format_version: FORMAT_VERSION,
        generator: opts.generator.name().into(),
        generator_parameters: opts.generator.parameters(),
        seed: opts.seed,
        split: opts.split.clone(),
        engine: "rapier3d 0.36 (enhanced-determinism, sleeping disabled, Multiply combine \
                 rules, contact recycling off, default soft contacts)"
            .into(),
        units: Units {
            length: "m".into(),
            mass: "kg".into(),
            time: "s".into(),
        },
        axis: "z".into(),
        quaternion_order: "xyzw".into(),
        gravity: opts.generator.gravity(),
        dt_frame: opts.sim.dt_frame(),
        physics_hz: opts.sim.physics_hz,
        substeps_per_frame: opts.sim.substeps,
        solver_iterations: opts.sim.solver_iterations,
        frames: opts.sim.frames,
        reference_points: opts.points,
        scenes: shards.iter().map(|s| s.scenes).sum(),
        objects,
        shards,
        shapes,
        materials: vec!["rigid".into(), "elastic".into()],
        tensors: vec![
            doc(
                "scene_object_offsets",
                "I64",
                "[S+1]",
                "objects of scene s are rows offsets[s]..offsets[s+1]",
            ),
            doc(
                "positions",
                "F32",
                "[O,T,3]",
                "centre of mass, world frame, m",
            ),
            doc(
                "rotations",
                "F32",
                "[O,T,4]",
                "unit quaternion [x,y,z,w], body to world, sign-continuous in time",
            ),
            doc(
                "reference_points",
                "F32",
                "[O,P,3]",
                "surface samples in the body frame (origin at the centre of mass), m",
            ),
            doc("mass", "F32", "[O]", "kg"),
            doc("friction", "F32", "[O]", "friction coefficient"),
            doc("restitution", "F32", "[O]", "restitution coefficient"),
            doc("scale", "F32", "[O,3]", "scale of the unit shape per axis"),
            doc("shape_id", "I32", "[O]", "index into shapes"),
            doc(
                "material",
                "I32",
                "[O]",
                "index into materials (0 rigid, 1 elastic)",
            ),
        ],
        reserved_tensors: RESERVED_TENSORS.iter().map(|s| s.to_string()).collect(),
        scenarios: None,
    }
}
