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
//! | `kinematic` | i32 | `[O]` | 1 for an object whose poses were given (a pusher), else 0; written only when some object of the shard is kinematic |
//!
//! Reserved for mesh trajectories (not written by the rigid generators): `vertex_offsets` i64
//! `[O + 1]`, `vertex_positions` f32 `[V, T, 3]`, `faces` i32 `[F, 3]`, `face_offsets` i64
//! `[O + 1]`. Readers ignore tensors they do not know.

mod manifest;
mod reader;
mod records;
mod shard;
mod write;

pub use manifest::{
    FORMAT, FORMAT_VERSION, MESH_CONTENT, Manifest, RESERVED_TENSORS, ShapeInfo, ShardInfo,
    TensorDoc, Units,
};
pub(crate) use manifest::{
    check_format_version, check_shard_layout, doc, is_mesh_manifest, read_manifest_json,
    read_manifest_of_kind,
};
pub use reader::{DatasetReader, SceneIter};
pub(crate) use reader::{scene_in_shards, shard_entry};
pub use records::{ObjectRecord, SceneLabel, SceneRecord};
pub use shard::{ObjectParameters, decode_shard, encode_shard};
pub(crate) use shard::{ShardTensors, TensorBytes, serialize_tensors};
pub(crate) use write::write_shards;
pub use write::{PoseShards, prepare_dir, shard_file, write_file, write_manifest};

use std::path::Path;

use crate::SimError;

/// Maps an I/O error to [`SimError::Io`] naming `path`.
pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SimError + '_ {
    move |source| SimError::Io {
        path: path.to_path_buf(),
        source,
    }
}
