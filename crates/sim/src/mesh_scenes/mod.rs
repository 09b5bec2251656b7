//! Mesh scenes: rigid and elastic triangle meshes bouncing in a closed box, recorded as
//! per-vertex trajectories (the ground truth of mesh-trajectory models such as PhysiFormer).
//!
//! - [`mod@templates`]: the convex and concave unit meshes objects are made of;
//! - [`record`]: a scene in memory ([`MeshScene`]), as written and as read back;
//! - [`simulate`]: the rapier world (box, rigid bodies, FEM soft bodies) and its recording;
//! - [`sets`]: the curriculum sets `mesh-d1` ... `mesh-d4` and their scene samplers;
//! - [`mod@format`], [`writer`], [`reader`]: shards and manifest, generation of a split, and
//!   [`MeshDatasetReader`], which returns scenes as `[V, T, 3]` vertex trajectories with faces,
//!   per-object vertex ranges and materials;
//! - [`stats`], [`preview`], [`cli`]: `dynaserve sim inspect`, `sim preview` and the
//!   `sim mesh-d1` ... `mesh-d4` commands.

pub mod cli;
pub mod format;
pub mod preview;
pub mod reader;
pub mod record;
pub mod sets;
pub mod simulate;
pub mod stats;
pub mod templates;
pub mod writer;

pub use format::{MeshManifest, SceneStart};
pub use reader::{MeshDatasetReader, is_mesh_dataset};
pub use record::{MeshMaterial, MeshObject, MeshScene};
pub use sets::MeshSet;
pub use simulate::{MeshObjectSpec, MeshPhysics, MeshSceneSpec, simulate_mesh_scene};
pub use templates::{MeshTemplate, templates};
pub use writer::{MeshGenerateOptions, generate_mesh_dataset, generate_mesh_scene};
