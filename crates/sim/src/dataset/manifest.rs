//! A split's `manifest.json`: the [`Manifest`] of pose datasets, the parts it shares with the
//! mesh manifest (format name and version, units, tensor docs), and reading one from disk.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use super::io_err;
use super::records::SceneLabel;
use crate::{Result, SimError};

/// Name written in every manifest's `format` field.
pub const FORMAT: &str = "dynaserve-sim";
/// Current format version.
pub const FORMAT_VERSION: u32 = 1;
/// The manifest's `content` value of a mesh dataset (pose datasets have no `content`).
pub const MESH_CONTENT: &str = "mesh";
/// Tensor names reserved for mesh trajectories.
pub const RESERVED_TENSORS: [&str; 4] = [
    "vertex_offsets",
    "vertex_positions",
    "faces",
    "face_offsets",
];

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
    /// The name of shape `id` in [`Manifest::shapes`], or `shape {id}` when it is not listed.
    pub fn shape_name(&self, id: i32) -> String {
        self.shapes
            .iter()
            .find(|s| s.id == id)
            .map(|s| s.name.clone())
            .unwrap_or_else(|| format!("shape {id}"))
    }

    /// Checks format, version, counts and shard names; errors name `path`.
    pub(crate) fn validate(&self, path: &Path) -> Result<()> {
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
        check_format_version(self.format_version).map_err(bad)?;
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
        check_shard_layout(
            self.shards
                .iter()
                .map(|s| (s.file.as_str(), s.first_scene, s.scenes)),
        )
        .map_err(bad)?;
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

/// Checks a manifest's `format_version` against the versions this reader knows; the error is
/// the message for the manifest's error.
pub(crate) fn check_format_version(version: u32) -> Result<(), String> {
    if version == 0 || version > FORMAT_VERSION {
        return Err(format!(
            "format version {version} is not supported (this reader knows 1..={FORMAT_VERSION})"
        ));
    }
    Ok(())
}

/// Checks a manifest's shard list, given as `(file, first_scene, scenes)` in order: the shards
/// follow each other from scene 0 and their file names are plain (no directory, not hidden).
/// The error is the message for the manifest's error.
pub(crate) fn check_shard_layout<'a>(
    shards: impl IntoIterator<Item = (&'a str, usize, usize)>,
) -> Result<(), String> {
    let mut next = 0;
    for (file, first_scene, scenes) in shards {
        if first_scene != next {
            return Err(format!(
                "shard {file} starts at scene {first_scene} instead of {next}"
            ));
        }
        if file.contains('/') || file.contains('\\') || file.starts_with('.') {
            return Err(format!("shard file name {file:?} is not plain"));
        }
        next += scenes;
    }
    Ok(())
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

/// Whether a manifest (as JSON) is that of a mesh dataset: its `content` is [`MESH_CONTENT`].
pub(crate) fn is_mesh_manifest(manifest: &serde_json::Value) -> bool {
    manifest.get("content").and_then(|c| c.as_str()) == Some(MESH_CONTENT)
}

/// Reads `dir/manifest.json` as the manifest type `M` of a mesh dataset (`mesh`) or a pose
/// dataset (not `mesh`); a manifest of the other kind is refused with `other_kind` as the
/// message. Returns the manifest's path and the parsed manifest (not yet validated).
pub(crate) fn read_manifest_of_kind<M: DeserializeOwned>(
    dir: &Path,
    mesh: bool,
    other_kind: &str,
) -> Result<(PathBuf, M)> {
    let (path, value) = read_manifest_json(dir)?;
    if is_mesh_manifest(&value) != mesh {
        return Err(SimError::Manifest {
            path,
            message: other_kind.into(),
        });
    }
    let manifest = parse_manifest(&path, value)?;
    Ok((path, manifest))
}

/// Parses a manifest read by [`read_manifest_json`] into its type; errors name `path`.
fn parse_manifest<M: DeserializeOwned>(path: &Path, value: serde_json::Value) -> Result<M> {
    serde_json::from_value(value).map_err(|e| SimError::Manifest {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}
