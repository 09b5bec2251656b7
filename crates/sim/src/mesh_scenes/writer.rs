//! Generating a mesh split: scenes sampled per index from their own seeded generator, simulated
//! in parallel, written in shards with a manifest.

use std::path::{Path, PathBuf};

use super::format::{
    MeshManifest, MeshShardInfo, SceneStart, TemplateInfo, encode_mesh_shard, tensor_docs,
};
use super::record::MeshScene;
use super::sets::MeshSet;
use super::simulate::{MeshPhysics, simulate_mesh_scene};
use super::templates::templates;
use crate::dataset::{
    FORMAT, FORMAT_VERSION, MESH_CONTENT, Units, prepare_dir, shard_file, write_file,
    write_manifest, write_shards,
};
use crate::random::scene_rng;
use crate::{Result, SimError};

/// What to generate.
#[derive(Clone, Debug)]
pub struct MeshGenerateOptions {
    /// The curriculum set.
    pub set: MeshSet,
    /// Dataset seed.
    pub seed: u64,
    /// Split name (`train`, `val`, `test`); part of every scene's seed.
    pub split: String,
    /// Number of scenes.
    pub scenes: usize,
    /// Scenes per shard file (the last shard may hold fewer).
    pub scenes_per_shard: usize,
    /// The physics.
    pub physics: MeshPhysics,
}

impl MeshGenerateOptions {
    /// Defaults: the paper-like physics of [`MeshPhysics::default`], 200 scenes per shard.
    pub fn new(set: MeshSet, seed: u64, split: &str, scenes: usize) -> Self {
        Self {
            set,
            seed,
            split: split.into(),
            scenes,
            scenes_per_shard: 200,
            physics: MeshPhysics::default(),
        }
    }
}

/// Scene `index` of a split, sampled and simulated (the same for any thread and scene count).
pub fn generate_mesh_scene(
    opts: &MeshGenerateOptions,
    index: u64,
) -> Result<(MeshScene, SceneStart)> {
    let mut rng = scene_rng(opts.seed, &opts.split, opts.set.name(), index);
    let (spec, start) = opts.set.sample(&mut rng, &opts.physics)?;
    let scene = simulate_mesh_scene(&spec, &opts.physics)
        .map_err(|e| SimError::Invalid(format!("scene {index}: {e}")))?;
    Ok((scene, start))
}

/// What [`generate_mesh_dataset`] wrote.
#[derive(Clone, Debug)]
pub struct MeshGenerateSummary {
    /// The split directory.
    pub dir: PathBuf,
    /// Its manifest.
    pub manifest: MeshManifest,
    /// Bytes written (shards and manifest).
    pub bytes: u64,
}

/// Generates a split into `out` (refusing an existing dataset unless `overwrite`), calling
/// `on_scene` after each simulated scene. Runs on the current rayon pool.
pub fn generate_mesh_dataset(
    opts: &MeshGenerateOptions,
    out: &Path,
    overwrite: bool,
    on_scene: &(dyn Fn() + Sync),
) -> Result<MeshGenerateSummary> {
    if opts.scenes == 0 || opts.scenes_per_shard == 0 {
        return Err(SimError::Invalid(
            "scenes and scenes per shard must be at least 1".into(),
        ));
    }
    let lib = templates()?;
    prepare_dir(out, overwrite)?;
    let mut shards = Vec::new();
    let (mut bytes, mut objects, mut vertices, mut faces) = (0u64, 0usize, 0usize, 0usize);
    let starts = write_shards(
        opts.scenes,
        opts.scenes_per_shard,
        |i| generate_mesh_scene(opts, i),
        on_scene,
        |first_scene, scenes: &[MeshScene]| {
            let file = shard_file(shards.len());
            let encoded = encode_mesh_shard(scenes, opts.physics.frames)?;
            write_file(&out.join(&file), &encoded)?;
            bytes += encoded.len() as u64;
            let info = MeshShardInfo {
                file,
                scenes: scenes.len(),
                objects: scenes.iter().map(|s| s.objects.len()).sum(),
                vertices: scenes.iter().map(|s| s.num_vertices()).sum(),
                faces: scenes.iter().map(|s| s.faces.len()).sum(),
                first_scene,
            };
            objects += info.objects;
            vertices += info.vertices;
            faces += info.faces;
            shards.push(info);
            Ok(())
        },
    )?;
    let p = &opts.physics;
    let manifest = MeshManifest {
        format: FORMAT.into(),
        format_version: FORMAT_VERSION,
        content: MESH_CONTENT.into(),
        generator: opts.set.name().into(),
        generator_parameters: opts.set.parameters(),
        seed: opts.seed,
        split: opts.split.clone(),
        engine: "rapier3d 0.36 (enhanced-determinism, sleeping disabled, Min combine rules, \
                 contact recycling off; elastic objects: soft bodies over tetrahedra, \
                 corotational cells, volume preservation)"
            .into(),
        physics: serde_json::to_value(p).map_err(|e| SimError::Invalid(e.to_string()))?,
        units: Units {
            length: "m".into(),
            mass: "kg".into(),
            time: "s".into(),
        },
        axis: "z".into(),
        gravity: p.gravity,
        bounds: [[-p.box_half; 3], [p.box_half; 3]],
        dt_frame: p.dt_frame(),
        physics_hz: p.physics_hz,
        substeps_per_frame: p.substeps,
        frames: p.frames,
        scenes: opts.scenes,
        objects,
        vertices,
        faces,
        shards,
        templates: lib
            .iter()
            .enumerate()
            .map(|(i, t)| TemplateInfo {
                id: i as i32,
                name: t.name.into(),
                convex: t.convex,
                vertices: t.vertices(),
                faces: t.mesh.faces.len(),
                tetrahedra: t.tets.len(),
            })
            .collect(),
        materials: vec!["rigid".into(), "elastic".into()],
        scene_starts: starts,
        tensors: tensor_docs(),
    };
    bytes += write_manifest(out, &manifest)?;
    Ok(MeshGenerateSummary {
        dir: out.to_path_buf(),
        manifest,
        bytes,
    })
}
