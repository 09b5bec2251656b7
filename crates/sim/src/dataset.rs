//! The dataset format: safetensors shards and a JSON manifest, with a streaming reader.
//!
//! A split directory holds `manifest.json` and `shard-00000.safetensors`, ... Each shard holds
//! consecutive scenes (`O` objects over its `S` scenes, `T` frames, `P` reference points):
//!
//! | tensor | dtype | shape | meaning |
//! |---|---|---|---|
//! | `scene_object_offsets` | i64 | `[S + 1]` | objects of scene `s` are rows `offsets[s]..offsets[s+1]` |
//! | `positions` | f32 | `[O, T, 3]` | centre of mass, world frame, metres |
//! | `rotations` | f32 | `[O, T, 4]` | unit quaternion `[x, y, z, w]`, body to world |
//! | `reference_points` | f32 | `[O, P, 3]` | surface samples, body frame (origin at the centre of mass), metres |
//! | `mass` | f32 | `[O]` | kilograms |
//! | `friction`, `restitution` | f32 | `[O]` | coefficients (combined by multiplication) |
//! | `scale` | f32 | `[O, 3]` | scale of the unit shape per axis |
//! | `shape_id` | i32 | `[O]` | index into the manifest's `shapes` |
//! | `material` | i32 | `[O]` | 0 rigid, 1 elastic |
//!
//! Reserved for mesh trajectories (not written by the rigid generators): `vertex_offsets` i64
//! `[O + 1]`, `vertex_positions` f32 `[V, T, 3]`, `faces` i32 `[F, 3]`, `face_offsets` i64
//! `[O + 1]`. Readers ignore tensors they do not know.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::generators::GenerateOptions;
use crate::{Result, SimError};

/// Name written in every manifest's `format` field.
pub const FORMAT: &str = "dynaserve-sim";
/// Current format version.
pub const FORMAT_VERSION: u32 = 1;
/// Tensor names reserved for mesh trajectories.
pub const RESERVED_TENSORS: [&str; 4] = [
    "vertex_offsets",
    "vertex_positions",
    "faces",
    "face_offsets",
];

/// One object of a scene as stored in a dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectRecord {
    /// Centre of mass per frame, world frame, metres: `[T]`.
    pub positions: Vec<[f32; 3]>,
    /// Orientation per frame, unit quaternion `[x, y, z, w]` body to world: `[T]`.
    pub rotations: Vec<[f32; 4]>,
    /// Surface samples in the body frame (origin at the centre of mass), metres: `[P]`.
    pub reference_points: Vec<[f32; 3]>,
    /// Mass, kilograms.
    pub mass: f32,
    /// Friction coefficient.
    pub friction: f32,
    /// Restitution coefficient.
    pub restitution: f32,
    /// Scale of the unit shape per axis.
    pub scale: [f32; 3],
    /// Index into the manifest's shape list.
    pub shape_id: i32,
    /// 0 rigid, 1 elastic.
    pub material: i32,
}

/// One scene: its objects and the interval between frames.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneRecord {
    /// The objects.
    pub objects: Vec<ObjectRecord>,
    /// Interval between recorded frames, seconds.
    pub dt_frame: f32,
}

/// Units of the stored quantities.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Units {
    /// Length unit.
    pub length: String,
    /// Mass unit.
    pub mass: String,
    /// Time unit.
    pub time: String,
}

/// One shard file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShardInfo {
    /// File name inside the split directory.
    pub file: String,
    /// Scenes in the shard.
    pub scenes: usize,
    /// Objects in the shard.
    pub objects: usize,
    /// Index (in the split) of the shard's first scene.
    pub first_scene: usize,
}

/// One entry of the shape list.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShapeInfo {
    /// The `shape_id` of objects with this shape.
    pub id: i32,
    /// Short name.
    pub name: String,
    /// What the unit shape is and how it is built.
    pub description: String,
}

/// What a scenario scene isolates, recorded per scene in the manifest's `scenarios`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SceneLabel {
    /// Scenario name: `rest`, `drop`, `slide`, `collide` or `stack-hit`.
    pub scenario: String,
    /// Arrangement within the scenario: `single`, `tower` or `pile` (rest), `drop`, `floor`
    /// (slide), `air` or `floor` (collide), `tower` (stack-hit).
    pub variant: String,
}

/// Description of one stored tensor.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TensorDoc {
    /// Tensor name.
    pub name: String,
    /// Data type (`F32`, `I32`, `I64`).
    pub dtype: String,
    /// Shape in symbols (`O` objects, `S` scenes, `T` frames, `P` points).
    pub shape: String,
    /// Meaning and unit.
    pub description: String,
}

/// The `manifest.json` of a split directory.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Always `dynaserve-sim`.
    pub format: String,
    /// Format version.
    pub format_version: u32,
    /// Generator name (`movi-a`, `movi-b`, `wrecking-ball`).
    pub generator: String,
    /// Generator parameters.
    pub generator_parameters: serde_json::Value,
    /// Dataset seed.
    pub seed: u64,
    /// Split name.
    pub split: String,
    /// Physics engine that produced the trajectories.
    pub engine: String,
    /// Units.
    pub units: Units,
    /// Up axis (`z`).
    pub axis: String,
    /// Quaternion component order (`xyzw`).
    pub quaternion_order: String,
    /// Gravity, metres per second squared.
    pub gravity: [f32; 3],
    /// Interval between frames, seconds.
    pub dt_frame: f32,
    /// Physics steps per second.
    pub physics_hz: u32,
    /// Physics steps per frame.
    pub substeps_per_frame: u32,
    /// rapier solver iterations per step.
    pub solver_iterations: usize,
    /// Frames per scene (`T`), including the initial state.
    pub frames: usize,
    /// Reference points per object (`P`).
    pub reference_points: usize,
    /// Scenes in the split.
    pub scenes: usize,
    /// Objects in the split.
    pub objects: usize,
    /// Shard files in order.
    pub shards: Vec<ShardInfo>,
    /// Shape list; `shape_id` indexes it.
    pub shapes: Vec<ShapeInfo>,
    /// Material list; `material` indexes it.
    pub materials: Vec<String>,
    /// The tensors of every shard.
    pub tensors: Vec<TensorDoc>,
    /// Tensor names reserved for mesh trajectories.
    pub reserved_tensors: Vec<String>,
    /// Scenario generators only: the label of every scene, in scene order (absent in other
    /// datasets and in datasets written before scenarios existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scenarios: Option<Vec<SceneLabel>>,
}

/// A [`TensorDoc`] from its four fields.
pub(crate) fn doc(name: &str, dtype: &str, shape: &str, description: &str) -> TensorDoc {
    TensorDoc {
        name: name.into(),
        dtype: dtype.into(),
        shape: shape.into(),
        description: description.into(),
    }
}

impl Manifest {
    /// The manifest of a generated split.
    pub fn new(
        opts: &GenerateOptions,
        shapes: Vec<ShapeInfo>,
        shards: Vec<ShardInfo>,
        objects: usize,
    ) -> Self {
        Self {
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

    fn validate(&self, path: &Path) -> Result<()> {
        let bad = |message: String| SimError::Manifest {
            path: path.to_path_buf(),
            message,
        };
        if self.format != FORMAT {
            return Err(bad(format!(
                "format is {:?}, expected {FORMAT:?}",
                self.format
            )));
        }
        if self.format_version == 0 || self.format_version > FORMAT_VERSION {
            return Err(bad(format!(
                "format version {} is not supported (this reader knows 1..={FORMAT_VERSION})",
                self.format_version
            )));
        }
        if self.frames == 0 || self.reference_points == 0 {
            return Err(bad("frames and reference_points must be positive".into()));
        }
        if !(self.dt_frame.is_finite() && self.dt_frame > 0.0) {
            return Err(bad(format!("dt_frame {} is not positive", self.dt_frame)));
        }
        let total: usize = self.shards.iter().map(|s| s.scenes).sum();
        if total != self.scenes {
            return Err(bad(format!(
                "shards hold {total} scenes but the manifest says {}",
                self.scenes
            )));
        }
        let mut next = 0;
        for s in &self.shards {
            if s.first_scene != next {
                return Err(bad(format!(
                    "shard {} starts at scene {} instead of {next}",
                    s.file, s.first_scene
                )));
            }
            if s.file.contains('/') || s.file.contains('\\') || s.file.starts_with('.') {
                return Err(bad(format!("shard file name {:?} is not plain", s.file)));
            }
            next += s.scenes;
        }
        if let Some(labels) = &self.scenarios
            && labels.len() != self.scenes
        {
            return Err(bad(format!(
                "{} scenario labels for {} scenes",
                labels.len(),
                self.scenes
            )));
        }
        Ok(())
    }
}

pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SimError + '_ {
    move |source| SimError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Reads `dir/manifest.json` as JSON; returns its path and value.
pub(crate) fn read_manifest_json(dir: &Path) -> Result<(PathBuf, serde_json::Value)> {
    let path = dir.join("manifest.json");
    let text = std::fs::read_to_string(&path).map_err(io_err(&path))?;
    let value = serde_json::from_str(&text).map_err(|e| SimError::Manifest {
        path: path.clone(),
        message: e.to_string(),
    })?;
    Ok((path, value))
}

/// Parses a manifest read by [`read_manifest_json`] into its type; errors name `path`.
pub(crate) fn parse_manifest<M: DeserializeOwned>(
    path: &Path,
    value: serde_json::Value,
) -> Result<M> {
    serde_json::from_value(value).map_err(|e| SimError::Manifest {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// Entry `k` of a manifest's shard list, or an error naming how many there are.
pub(crate) fn shard_entry<S>(shards: &[S], k: usize) -> Result<&S> {
    shards.get(k).ok_or_else(|| {
        SimError::Invalid(format!(
            "shard {k} out of range (the split has {})",
            shards.len()
        ))
    })
}

/// Scene `i` of a split whose shards hold the scenes `first..first + count` given by `ranges`
/// (in shard order): finds its shard, reads it with `read_shard` and takes the scene out.
pub(crate) fn scene_in_shards<T>(
    ranges: impl IntoIterator<Item = (usize, usize)>,
    i: usize,
    scenes: usize,
    read_shard: impl FnOnce(usize) -> Result<Vec<T>>,
) -> Result<T> {
    let (k, first) = ranges
        .into_iter()
        .enumerate()
        .find(|(_, (first, count))| i >= *first && i < first + count)
        .map(|(k, (first, _))| (k, first))
        .ok_or_else(|| {
            SimError::Invalid(format!("scene {i} out of range (the split has {scenes})"))
        })?;
    read_shard(k)?
        .into_iter()
        .nth(i - first)
        .ok_or_else(|| SimError::Invalid(format!("scene {i} missing from its shard")))
}

/// Creates `dir` if needed. A directory that already holds a manifest is refused unless
/// `overwrite`, in which case its manifest and shard files are removed first.
pub fn prepare_dir(dir: &Path, overwrite: bool) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let manifest = dir.join("manifest.json");
    if manifest.exists() {
        if !overwrite {
            return Err(SimError::Invalid(format!(
                "{} already holds a dataset (pass --overwrite to replace it)",
                dir.display()
            )));
        }
        std::fs::remove_file(&manifest).map_err(io_err(&manifest))?;
    }
    for entry in std::fs::read_dir(dir).map_err(io_err(dir))? {
        let entry = entry.map_err(io_err(dir))?;
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with("shard-") && name.ends_with(".safetensors") {
            if !overwrite {
                return Err(SimError::Invalid(format!(
                    "{} already holds shard files (pass --overwrite to replace them)",
                    dir.display()
                )));
            }
            std::fs::remove_file(entry.path()).map_err(io_err(&entry.path()))?;
        }
    }
    Ok(())
}

/// Writes `bytes` to `path` through a temporary file and a rename.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).map_err(io_err(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io_err(path))
}

/// Generates scenes `0..scenes` shard by shard (`per_shard` scenes each, the last fewer): a
/// shard's scenes in parallel on rayon's pool with `make(i)` (then `on_scene()`), then the shard,
/// encoded by `encode`, written to `out/shard-00000.safetensors`, ... and reported to
/// `on_shard(file, first_scene, scenes, bytes)`. Returns each scene's label `L`, in scene order.
pub(crate) fn write_shards<S: Send, L: Send>(
    out: &Path,
    scenes: usize,
    per_shard: usize,
    make: impl Fn(u64) -> Result<(S, L)> + Sync,
    on_scene: &(dyn Fn() + Sync),
    encode: impl Fn(&[S]) -> Result<Vec<u8>>,
    mut on_shard: impl FnMut(String, usize, &[S], u64),
) -> Result<Vec<L>> {
    if per_shard == 0 {
        return Err(SimError::Invalid(
            "scenes per shard must be at least 1".into(),
        ));
    }
    let mut labels = Vec::with_capacity(scenes);
    let (mut first, mut shard) = (0usize, 0usize);
    while first < scenes {
        let end = (first + per_shard).min(scenes);
        let made = (first..end)
            .into_par_iter()
            .map(|i| {
                let s = make(i as u64);
                on_scene();
                s
            })
            .collect::<Result<Vec<_>>>()?;
        let (made, shard_labels): (Vec<S>, Vec<L>) = made.into_iter().unzip();
        labels.extend(shard_labels);
        let file = format!("shard-{shard:05}.safetensors");
        let encoded = encode(&made)?;
        write_file(&out.join(&file), &encoded)?;
        on_shard(file, first, &made, encoded.len() as u64);
        shard += 1;
        first = end;
    }
    Ok(labels)
}

/// Writes a split's `manifest.json` (pretty JSON, pose or mesh manifest); returns its size in
/// bytes.
pub fn write_manifest(dir: &Path, manifest: &impl Serialize) -> Result<u64> {
    let path = dir.join("manifest.json");
    let mut text = serde_json::to_string_pretty(manifest).map_err(|e| SimError::Manifest {
        path: path.clone(),
        message: e.to_string(),
    })?;
    text.push('\n');
    write_file(&path, text.as_bytes())?;
    Ok(text.len() as u64)
}

fn f32_bytes<'a>(values: impl Iterator<Item = &'a f32>) -> Vec<u8> {
    values.flat_map(|v| v.to_le_bytes()).collect()
}

/// Serialises scenes into one shard (safetensors bytes). Every object must have `frames` poses
/// and `points` reference points.
pub fn encode_shard(scenes: &[SceneRecord], frames: usize, points: usize) -> Result<Vec<u8>> {
    let objects: Vec<&ObjectRecord> = scenes.iter().flat_map(|s| &s.objects).collect();
    for (i, o) in objects.iter().enumerate() {
        if o.positions.len() != frames
            || o.rotations.len() != frames
            || o.reference_points.len() != points
        {
            return Err(SimError::Invalid(format!(
                "object {i}: {} positions, {} rotations, {} points; expected {frames}, {frames}, \
                 {points}",
                o.positions.len(),
                o.rotations.len(),
                o.reference_points.len()
            )));
        }
    }
    let n = objects.len();
    let mut offsets = Vec::with_capacity(scenes.len() + 1);
    let mut acc = 0i64;
    offsets.push(acc);
    for s in scenes {
        acc += s.objects.len() as i64;
        offsets.push(acc);
    }
    let buffers: Vec<TensorBytes<'_>> = vec![
        (
            "scene_object_offsets",
            Dtype::I64,
            vec![scenes.len() + 1],
            offsets.iter().flat_map(|v| v.to_le_bytes()).collect(),
        ),
        (
            "positions",
            Dtype::F32,
            vec![n, frames, 3],
            f32_bytes(objects.iter().flat_map(|o| o.positions.iter().flatten())),
        ),
        (
            "rotations",
            Dtype::F32,
            vec![n, frames, 4],
            f32_bytes(objects.iter().flat_map(|o| o.rotations.iter().flatten())),
        ),
        (
            "reference_points",
            Dtype::F32,
            vec![n, points, 3],
            f32_bytes(
                objects
                    .iter()
                    .flat_map(|o| o.reference_points.iter().flatten()),
            ),
        ),
        (
            "mass",
            Dtype::F32,
            vec![n],
            f32_bytes(objects.iter().map(|o| &o.mass)),
        ),
        (
            "friction",
            Dtype::F32,
            vec![n],
            f32_bytes(objects.iter().map(|o| &o.friction)),
        ),
        (
            "restitution",
            Dtype::F32,
            vec![n],
            f32_bytes(objects.iter().map(|o| &o.restitution)),
        ),
        (
            "scale",
            Dtype::F32,
            vec![n, 3],
            f32_bytes(objects.iter().flat_map(|o| o.scale.iter())),
        ),
        (
            "shape_id",
            Dtype::I32,
            vec![n],
            objects
                .iter()
                .flat_map(|o| o.shape_id.to_le_bytes())
                .collect(),
        ),
        (
            "material",
            Dtype::I32,
            vec![n],
            objects
                .iter()
                .flat_map(|o| o.material.to_le_bytes())
                .collect(),
        ),
    ];
    serialize_tensors(&buffers)
}

/// One tensor of a shard: name, dtype, shape and its values as little-endian bytes.
pub(crate) type TensorBytes<'a> = (&'a str, Dtype, Vec<usize>, Vec<u8>);

/// Serialises a shard's tensors into safetensors bytes whose header carries the one metadata
/// entry `format: dynaserve-sim/<version>`. One entry, because safetensors writes its metadata
/// map in hash order: with two entries the same shard would not be the same bytes on every
/// thread and run.
pub(crate) fn serialize_tensors(buffers: &[TensorBytes<'_>]) -> Result<Vec<u8>> {
    let views = buffers
        .iter()
        .map(|(name, dtype, shape, data)| {
            TensorView::new(*dtype, shape.clone(), data)
                .map(|v| (name.to_string(), v))
                .map_err(|e| SimError::Invalid(format!("tensor {name}: {e}")))
        })
        .collect::<Result<Vec<_>>>()?;
    let meta = HashMap::from([("format".to_string(), format!("{FORMAT}/{FORMAT_VERSION}"))]);
    safetensors::serialize(views, Some(meta))
        .map_err(|e| SimError::Invalid(format!("safetensors: {e}")))
}

/// A shard's tensors with checked accessors; errors name the shard file.
pub(crate) struct ShardTensors<'a> {
    st: SafeTensors<'a>,
    path: &'a Path,
}

impl<'a> ShardTensors<'a> {
    /// Parses the safetensors bytes of the shard at `path`.
    pub(crate) fn deserialize(bytes: &'a [u8], path: &'a Path) -> Result<Self> {
        let st = SafeTensors::deserialize(bytes).map_err(|e| SimError::Shard {
            path: path.to_path_buf(),
            message: format!("not a safetensors file: {e}"),
        })?;
        Ok(Self { st, path })
    }

    /// A [`SimError::Shard`] naming this shard.
    pub(crate) fn bad(&self, message: String) -> SimError {
        SimError::Shard {
            path: self.path.to_path_buf(),
            message,
        }
    }

    /// The tensor's bytes after checking its dtype and shape.
    pub(crate) fn get(&self, name: &str, dtype: Dtype, shape: &[usize]) -> Result<&'a [u8]> {
        let t = self
            .st
            .tensor(name)
            .map_err(|e| self.bad(format!("tensor {name}: {e}")))?;
        if t.dtype() != dtype {
            return Err(self.bad(format!(
                "tensor {name} has dtype {:?}, expected {dtype:?}",
                t.dtype()
            )));
        }
        if t.shape() != shape {
            return Err(self.bad(format!(
                "tensor {name} has shape {:?}, expected {shape:?}",
                t.shape()
            )));
        }
        Ok(t.data())
    }

    /// A float tensor of the given shape, refusing non-finite values.
    pub(crate) fn f32s(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>> {
        let data = self.get(name, Dtype::F32, shape)?;
        let values: Vec<f32> = data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        if values.iter().any(|v| !v.is_finite()) {
            return Err(self.bad(format!("tensor {name} holds non-finite values")));
        }
        Ok(values)
    }

    /// An int32 tensor of the given shape.
    pub(crate) fn i32s(&self, name: &str, shape: &[usize]) -> Result<Vec<i32>> {
        Ok(self
            .get(name, Dtype::I32, shape)?
            .chunks_exact(4)
            .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }

    /// An int64 offsets tensor `[len]` (any length when `None`) that starts at 0 and never
    /// decreases.
    pub(crate) fn offsets(&self, name: &str, len: Option<usize>) -> Result<Vec<usize>> {
        let len = match len {
            Some(n) => n,
            None => match self
                .st
                .tensor(name)
                .map_err(|e| self.bad(format!("tensor {name}: {e}")))?
                .shape()
            {
                [n] => *n,
                other => {
                    return Err(self.bad(format!(
                        "tensor {name} has shape {other:?}, expected one dimension"
                    )));
                }
            },
        };
        let v: Vec<i64> = self
            .get(name, Dtype::I64, &[len])?
            .chunks_exact(8)
            .map(|c| i64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
            .collect();
        if v.first() != Some(&0) || v.windows(2).any(|w| w[1] < w[0]) {
            return Err(self.bad(format!("{name} must start at 0 and not decrease")));
        }
        Ok(v.into_iter().map(|x| x as usize).collect())
    }
}

/// Decodes one shard against the manifest's frame and point counts.
pub fn decode_shard(
    bytes: &[u8],
    path: &Path,
    frames: usize,
    points: usize,
    dt_frame: f32,
) -> Result<Vec<SceneRecord>> {
    let sh = ShardTensors::deserialize(bytes, path)?;
    let offsets = sh.offsets("scene_object_offsets", None)?;
    let n = *offsets.last().unwrap_or(&0);
    let positions = sh.f32s("positions", &[n, frames, 3])?;
    let rotations = sh.f32s("rotations", &[n, frames, 4])?;
    let reference = sh.f32s("reference_points", &[n, points, 3])?;
    let mass = sh.f32s("mass", &[n])?;
    let friction = sh.f32s("friction", &[n])?;
    let restitution = sh.f32s("restitution", &[n])?;
    let scale = sh.f32s("scale", &[n, 3])?;
    let shape_id = sh.i32s("shape_id", &[n])?;
    let material = sh.i32s("material", &[n])?;
    let object = |i: usize| ObjectRecord {
        positions: positions[i * frames * 3..(i + 1) * frames * 3]
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        rotations: rotations[i * frames * 4..(i + 1) * frames * 4]
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect(),
        reference_points: reference[i * points * 3..(i + 1) * points * 3]
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        mass: mass[i],
        friction: friction[i],
        restitution: restitution[i],
        scale: [scale[3 * i], scale[3 * i + 1], scale[3 * i + 2]],
        shape_id: shape_id[i],
        material: material[i],
    };
    Ok(offsets
        .windows(2)
        .map(|w| SceneRecord {
            objects: (w[0]..w[1]).map(object).collect(),
            dt_frame,
        })
        .collect())
}

/// Reads a split directory: the manifest up front, shards on demand.
#[derive(Clone, Debug)]
pub struct DatasetReader {
    dir: PathBuf,
    manifest: Manifest,
}

impl DatasetReader {
    /// Opens a split directory and validates its manifest (format, version, counts).
    pub fn open(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        let (path, value) = read_manifest_json(&dir)?;
        if crate::mesh_scenes::reader::is_mesh_manifest(&value) {
            return Err(SimError::Manifest {
                path,
                message: "a mesh dataset (\"content\": \"mesh\"); read it with \
                          mesh_scenes::MeshDatasetReader"
                    .into(),
            });
        }
        let manifest: Manifest = parse_manifest(&path, value)?;
        manifest.validate(&path)?;
        Ok(Self { dir, manifest })
    }

    /// The manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The split directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Number of scenes.
    pub fn len(&self) -> usize {
        self.manifest.scenes
    }

    /// Whether the split holds no scene.
    pub fn is_empty(&self) -> bool {
        self.manifest.scenes == 0
    }

    /// Reads and decodes shard `k`, checking it against the manifest.
    pub fn read_shard(&self, k: usize) -> Result<Vec<SceneRecord>> {
        let info = shard_entry(&self.manifest.shards, k)?;
        let path = self.dir.join(&info.file);
        let bytes = std::fs::read(&path).map_err(io_err(&path))?;
        let m = &self.manifest;
        let scenes = decode_shard(&bytes, &path, m.frames, m.reference_points, m.dt_frame)?;
        let objects: usize = scenes.iter().map(|s| s.objects.len()).sum();
        if scenes.len() != info.scenes || objects != info.objects {
            return Err(SimError::Shard {
                path,
                message: format!(
                    "holds {} scenes and {objects} objects, the manifest says {} and {}",
                    scenes.len(),
                    info.scenes,
                    info.objects
                ),
            });
        }
        Ok(scenes)
    }

    /// Streams all scenes in order, one shard in memory at a time. After an error the iterator
    /// ends.
    pub fn iter(&self) -> SceneIter<'_> {
        SceneIter::new(self.manifest.shards.len(), |k| self.read_shard(k))
    }

    /// Scene `i` (reads its whole shard).
    pub fn get(&self, i: usize) -> Result<SceneRecord> {
        let ranges = self
            .manifest
            .shards
            .iter()
            .map(|s| (s.first_scene, s.scenes));
        scene_in_shards(ranges, i, self.len(), |k| self.read_shard(k))
    }
}

/// Iterator over the scenes (of type `T`) of a split, one shard in memory at a time (see
/// [`DatasetReader::iter`]); after an error it ends.
pub struct SceneIter<'a, T = SceneRecord> {
    read_shard: Box<dyn Fn(usize) -> Result<Vec<T>> + 'a>,
    shards: usize,
    next_shard: usize,
    current: std::vec::IntoIter<T>,
    failed: bool,
}

impl<'a, T> SceneIter<'a, T> {
    /// Streams the scenes of `shards` shards, reading shard `k` with `read_shard(k)`.
    pub(crate) fn new(shards: usize, read_shard: impl Fn(usize) -> Result<Vec<T>> + 'a) -> Self {
        Self {
            read_shard: Box::new(read_shard),
            shards,
            next_shard: 0,
            current: Vec::new().into_iter(),
            failed: false,
        }
    }
}

impl<T> Iterator for SceneIter<'_, T> {
    type Item = Result<T>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        loop {
            if let Some(s) = self.current.next() {
                return Some(Ok(s));
            }
            if self.next_shard >= self.shards {
                return None;
            }
            match (self.read_shard)(self.next_shard) {
                Ok(scenes) => {
                    self.next_shard += 1;
                    self.current = scenes.into_iter();
                }
                Err(e) => {
                    self.failed = true;
                    return Some(Err(e));
                }
            }
        }
    }
}
