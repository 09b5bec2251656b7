//! The on-disk format of mesh datasets: the same split layout as the rigid datasets
//! (`manifest.json` and `shard-00000.safetensors`, ...) with the mesh tensors.
//!
//! With `S` scenes, `O` objects, `V` vertices, `F` faces and `T` frames in a shard:
//!
//! | tensor | dtype | shape | meaning |
//! |---|---|---|---|
//! | `scene_object_offsets` | i64 | `[S + 1]` | objects of scene `s` are rows `offsets[s]..offsets[s+1]` |
//! | `vertex_offsets` | i64 | `[O + 1]` | vertices of object `o` are rows `offsets[o]..offsets[o+1]` of `vertex_positions` |
//! | `vertex_positions` | f32 | `[V, T, 3]` | world frame, metres |
//! | `initial_vertex_velocities` | f32 | `[V, 3]` | velocity at frame 0, m/s |
//! | `face_offsets` | i64 | `[O + 1]` | faces of object `o` are rows `offsets[o]..offsets[o+1]` of `faces` |
//! | `faces` | i32 | `[F, 3]` | vertex indices local to the object (0 is its first vertex), counter-clockwise seen from outside |
//! | `material` | i32 | `[O]` | 0 rigid, 1 elastic |
//! | `template_id` | i32 | `[O]` | index into the manifest's `templates` |
//! | `scale` | f32 | `[O]` | circumradius of the object, metres |
//! | `mass` | f32 | `[O]` | kilograms |
//! | `friction`, `restitution` | f32 | `[O]` | coefficients |

use std::path::Path;

use safetensors::tensor::Dtype;
use serde::{Deserialize, Serialize};

use super::record::{MeshMaterial, MeshObject, MeshScene};
use crate::dataset::{
    FORMAT, MESH_CONTENT, ShardTensors, TensorBytes, TensorDoc, Units, check_format_version,
    check_shard_layout, doc, serialize_tensors,
};
use crate::{Result, SimError};

/// One shard file of a mesh dataset.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshShardInfo {
    /// File name inside the split directory.
    pub file: String,
    /// Scenes in the shard.
    pub scenes: usize,
    /// Objects in the shard.
    pub objects: usize,
    /// Vertices in the shard.
    pub vertices: usize,
    /// Faces in the shard.
    pub faces: usize,
    /// Index (in the split) of the shard's first scene.
    pub first_scene: usize,
}

/// One entry of the template list.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TemplateInfo {
    /// The `template_id` of objects made from this template.
    pub id: i32,
    /// Short name.
    pub name: String,
    /// Whether the solid is convex.
    pub convex: bool,
    /// Vertices of the mesh.
    pub vertices: usize,
    /// Triangles of the mesh.
    pub faces: usize,
    /// Tetrahedra of an elastic copy.
    pub tetrahedra: usize,
}

/// How a scene starts, recorded per scene in the manifest's `scene_starts`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SceneStart {
    /// `floor` (resting on the floor, some launched along it) or `airborne`.
    pub start: String,
    /// Whether the objects start with a nonzero angular velocity.
    pub spin: bool,
}

/// The `manifest.json` of a mesh split directory.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshManifest {
    /// Always `dynaserve-sim`.
    pub format: String,
    /// Format version.
    pub format_version: u32,
    /// Always `mesh` (rigid-pose datasets have no `content`).
    pub content: String,
    /// Generator name (`mesh-d1` ... `mesh-d4`).
    pub generator: String,
    /// Every parameter the generator used (object counts, templates, scales, starts, speeds).
    pub generator_parameters: serde_json::Value,
    /// Dataset seed.
    pub seed: u64,
    /// Split name.
    pub split: String,
    /// Physics engine and its settings.
    pub engine: String,
    /// The physics: box, gravity, timing, density, friction, restitution, Young's modulus.
    pub physics: serde_json::Value,
    /// Units.
    pub units: Units,
    /// Up axis (`z`).
    pub axis: String,
    /// Gravity, metres per second squared.
    pub gravity: [f32; 3],
    /// The closed box, `[min, max]` corners, metres.
    pub bounds: [[f32; 3]; 2],
    /// Interval between frames, seconds.
    pub dt_frame: f32,
    /// Physics steps per second.
    pub physics_hz: u32,
    /// Physics steps per frame.
    pub substeps_per_frame: u32,
    /// Frames per scene (`T`), including the initial state.
    pub frames: usize,
    /// Scenes in the split.
    pub scenes: usize,
    /// Objects in the split.
    pub objects: usize,
    /// Vertices in the split.
    pub vertices: usize,
    /// Faces in the split.
    pub faces: usize,
    /// Shard files in order.
    pub shards: Vec<MeshShardInfo>,
    /// Template list; `template_id` indexes it.
    pub templates: Vec<TemplateInfo>,
    /// Material list; `material` indexes it (`rigid`, `elastic`).
    pub materials: Vec<String>,
    /// How each scene starts, in scene order.
    pub scene_starts: Vec<SceneStart>,
    /// The tensors of every shard.
    pub tensors: Vec<TensorDoc>,
}

/// Descriptions of the tensors of a mesh shard, for the manifest.
pub fn tensor_docs() -> Vec<TensorDoc> {
    vec![
        doc(
            "scene_object_offsets",
            "I64",
            "[S+1]",
            "objects of scene s are rows offsets[s]..offsets[s+1]",
        ),
        doc(
            "vertex_offsets",
            "I64",
            "[O+1]",
            "vertices of object o are rows offsets[o]..offsets[o+1] of vertex_positions",
        ),
        doc(
            "vertex_positions",
            "F32",
            "[V,T,3]",
            "vertex positions, world frame, m",
        ),
        doc(
            "initial_vertex_velocities",
            "F32",
            "[V,3]",
            "vertex velocities at frame 0, m/s",
        ),
        doc(
            "face_offsets",
            "I64",
            "[O+1]",
            "faces of object o are rows offsets[o]..offsets[o+1] of faces",
        ),
        doc(
            "faces",
            "I32",
            "[F,3]",
            "triangles, vertex indices local to the object, counter-clockwise from outside",
        ),
        doc("material", "I32", "[O]", "0 rigid, 1 elastic"),
        doc("template_id", "I32", "[O]", "index into templates"),
        doc("scale", "F32", "[O]", "circumradius of the object, m"),
        doc("mass", "F32", "[O]", "kg"),
        doc("friction", "F32", "[O]", "friction coefficient"),
        doc("restitution", "F32", "[O]", "restitution coefficient"),
    ]
}

impl MeshManifest {
    /// Checks format, version, content and counts; `path` names the manifest in errors.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let bad = |message: String| SimError::Manifest {
            path: path.to_path_buf(),
            message,
        };
        if self.format != FORMAT || self.content != MESH_CONTENT {
            return Err(bad(format!(
                "format {:?} content {:?} is not a mesh dataset (expected {FORMAT:?}, {:?})",
                self.format, self.content, MESH_CONTENT
            )));
        }
        check_format_version(self.format_version).map_err(bad)?;
        if self.frames == 0 || !(self.dt_frame.is_finite() && self.dt_frame > 0.0) {
            return Err(bad("frames and dt_frame must be positive".into()));
        }
        let total: usize = self.shards.iter().map(|s| s.scenes).sum();
        if total != self.scenes || self.scene_starts.len() != self.scenes {
            return Err(bad(format!(
                "shards hold {total} scenes and {} start labels but the manifest says {}",
                self.scene_starts.len(),
                self.scenes
            )));
        }
        check_shard_layout(
            self.shards
                .iter()
                .map(|s| (s.file.as_str(), s.first_scene, s.scenes)),
        )
        .map_err(bad)?;
        Ok(())
    }
}

fn le_bytes<T: Copy, const N: usize>(values: &[T], f: impl Fn(T) -> [u8; N]) -> Vec<u8> {
    values.iter().flat_map(|&v| f(v)).collect()
}

/// Serialises scenes into one shard (safetensors bytes). Every scene must have `frames` frames.
pub fn encode_mesh_shard(scenes: &[MeshScene], frames: usize) -> Result<Vec<u8>> {
    let mut scene_offsets = vec![0i64];
    let mut vertex_offsets = vec![0i64];
    let mut face_offsets = vec![0i64];
    let (mut positions, mut velocities, mut faces) = (Vec::new(), Vec::new(), Vec::new());
    let (mut material, mut template, mut scale) = (Vec::new(), Vec::new(), Vec::new());
    let (mut mass, mut friction, mut restitution) = (Vec::new(), Vec::new(), Vec::new());
    for (si, s) in scenes.iter().enumerate() {
        let v = s.num_vertices();
        if s.frames != frames || s.positions.len() != v * frames * 3 {
            return Err(SimError::Invalid(format!(
                "scene {si}: {} frames and {} position values for {v} vertices; expected \
                 {frames} frames",
                s.frames,
                s.positions.len()
            )));
        }
        let base = *vertex_offsets.last().unwrap_or(&0);
        let mut next = 0;
        for (oi, o) in s.objects.iter().enumerate() {
            if o.vertices.start != next || o.vertices.end > v || o.faces.end > s.faces.len() {
                return Err(SimError::Invalid(format!(
                    "scene {si} object {oi}: vertex range {:?} or face range {:?} out of order",
                    o.vertices, o.faces
                )));
            }
            next = o.vertices.end;
            vertex_offsets.push(base + o.vertices.end as i64);
            for f in &s.faces[o.faces.clone()] {
                let local = f.map(|k| k as i64 - o.vertices.start as i64);
                if local.iter().any(|&k| k < 0 || k >= o.vertices.len() as i64) {
                    return Err(SimError::Invalid(format!(
                        "scene {si} object {oi}: face {f:?} leaves the object's vertices"
                    )));
                }
                faces.extend(local.map(|k| k as i32));
            }
            face_offsets.push(face_offsets.last().unwrap_or(&0) + o.faces.len() as i64);
            material.push(o.material.code());
            template.push(o.template_id);
            scale.push(o.scale);
            mass.push(o.mass);
            friction.push(o.friction);
            restitution.push(o.restitution);
        }
        if next != v {
            return Err(SimError::Invalid(format!(
                "scene {si}: objects cover {next} of {v} vertices"
            )));
        }
        positions.extend_from_slice(&s.positions);
        velocities.extend_from_slice(&s.initial_velocities);
        scene_offsets.push(scene_offsets.last().unwrap_or(&0) + s.objects.len() as i64);
    }
    let (o, v, f) = (material.len(), velocities.len() / 3, faces.len() / 3);
    let f32b = |x: &[f32]| le_bytes(x, f32::to_le_bytes);
    let i32b = |x: &[i32]| le_bytes(x, i32::to_le_bytes);
    let i64b = |x: &[i64]| le_bytes(x, i64::to_le_bytes);
    let buffers: Vec<TensorBytes<'_>> = vec![
        (
            "scene_object_offsets",
            Dtype::I64,
            vec![scenes.len() + 1],
            i64b(&scene_offsets),
        ),
        (
            "vertex_offsets",
            Dtype::I64,
            vec![o + 1],
            i64b(&vertex_offsets),
        ),
        (
            "vertex_positions",
            Dtype::F32,
            vec![v, frames, 3],
            f32b(&positions),
        ),
        (
            "initial_vertex_velocities",
            Dtype::F32,
            vec![v, 3],
            f32b(&velocities),
        ),
        ("face_offsets", Dtype::I64, vec![o + 1], i64b(&face_offsets)),
        ("faces", Dtype::I32, vec![f, 3], i32b(&faces)),
        ("material", Dtype::I32, vec![o], i32b(&material)),
        ("template_id", Dtype::I32, vec![o], i32b(&template)),
        ("scale", Dtype::F32, vec![o], f32b(&scale)),
        ("mass", Dtype::F32, vec![o], f32b(&mass)),
        ("friction", Dtype::F32, vec![o], f32b(&friction)),
        ("restitution", Dtype::F32, vec![o], f32b(&restitution)),
    ];
    serialize_tensors(&buffers)
}

/// Decodes one mesh shard against the manifest's frame count and frame interval.
pub fn decode_mesh_shard(
    bytes: &[u8],
    path: &Path,
    frames: usize,
    dt_frame: f32,
) -> Result<Vec<MeshScene>> {
    let sh = ShardTensors::deserialize(bytes, path)?;
    let scene_off = sh.offsets("scene_object_offsets", None)?;
    let o = *scene_off.last().unwrap_or(&0);
    let vert_off = sh.offsets("vertex_offsets", Some(o + 1))?;
    let v = *vert_off.last().unwrap_or(&0);
    let face_off = sh.offsets("face_offsets", Some(o + 1))?;
    let f = *face_off.last().unwrap_or(&0);
    let positions = sh.f32s("vertex_positions", &[v, frames, 3])?;
    let velocities = sh.f32s("initial_vertex_velocities", &[v, 3])?;
    let faces = sh.i32s("faces", &[f, 3])?;
    let material = sh.i32s("material", &[o])?;
    let template = sh.i32s("template_id", &[o])?;
    let scale = sh.f32s("scale", &[o])?;
    let mass = sh.f32s("mass", &[o])?;
    let friction = sh.f32s("friction", &[o])?;
    let restitution = sh.f32s("restitution", &[o])?;
    let mut scenes = Vec::with_capacity(scene_off.len().saturating_sub(1));
    for w in scene_off.windows(2) {
        let (v0, v1) = (vert_off[w[0]], vert_off[w[1]]);
        let f0 = face_off[w[0]];
        let mut objects = Vec::with_capacity(w[1] - w[0]);
        let mut scene_faces = Vec::with_capacity(face_off[w[1]] - f0);
        for i in w[0]..w[1] {
            let n = vert_off[i + 1] - vert_off[i];
            let start = vert_off[i] - v0;
            let faces_start = scene_faces.len();
            for tri in faces[3 * face_off[i]..3 * face_off[i + 1]].chunks_exact(3) {
                if tri.iter().any(|&k| k < 0 || k as usize >= n) {
                    return Err(sh.bad(format!(
                        "object {i}: face {tri:?} refers to a vertex outside 0..{n}"
                    )));
                }
                scene_faces.push([0, 1, 2].map(|j| (start + tri[j] as usize) as u32));
            }
            let m = MeshMaterial::from_code(material[i])
                .ok_or_else(|| sh.bad(format!("object {i}: unknown material {}", material[i])))?;
            objects.push(MeshObject {
                vertices: start..start + n,
                faces: faces_start..scene_faces.len(),
                material: m,
                template_id: template[i],
                scale: scale[i],
                mass: mass[i],
                friction: friction[i],
                restitution: restitution[i],
            });
        }
        scenes.push(MeshScene {
            frames,
            dt_frame,
            positions: positions[v0 * frames * 3..v1 * frames * 3].to_vec(),
            initial_velocities: velocities[v0 * 3..v1 * 3].to_vec(),
            faces: scene_faces,
            objects,
        });
    }
    Ok(scenes)
}
