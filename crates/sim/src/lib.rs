//! Ground-truth rigid-body trajectories from rapier3d for Dynaserve: MOVi-like and WreckingBall
//! scene generators and the safetensors dataset format.
//!
//! Units are SI (metres, seconds, kilograms), the z axis points up and the floor's top is the
//! plane `z = 0`. Poses are the centre of mass translation and a unit quaternion `[x, y, z, w]`
//! mapping the body frame (origin at the centre of mass) to the world: `x = R x_body + p`.
//!
//! The layers point one way: shapes, scenes, materials, seeding and the dataset format at the
//! bottom; the scene generators and scenarios above them; writing a split above those; the
//! command line on top.
//!
//! - [`shapes`]: the procedural shape set (unions of convex parts) and surface sampling;
//! - [`scene`]: scene descriptions and their simulation with rapier;
//! - [`materials`], [`random`]: Kubric's materials and floor; per-scene seeding and uniform
//!   rotations;
//! - [`dataset`]: records, manifest, shards, the shard-writing loop and the streaming reader;
//! - [`generators`]: `movi-a`, `movi-b` and `wrecking-ball` scene samplers and the generation
//!   of one scene (sampled, simulated, recorded);
//! - [`scenarios`]: physics scenario scenes (`rest`, `drop`, `slide`, `collide`,
//!   `stack-hit`, `physics-mix`, and `push` with a kinematic pusher), each isolating one
//!   behaviour;
//! - [`writer`]: a pose dataset split written to disk (`dynaserve sim generate`);
//! - [`stats`], [`preview`]: what `dynaserve sim inspect` and `dynaserve sim preview` print and
//!   draw;
//! - [`replay`]: a scene file in the server's JSON format replayed in rapier, kinematic
//!   objects driven along given paths (`dynaserve sim replay`);
//! - [`mesh_scenes`]: rigid and elastic triangle meshes in a closed box, recorded per vertex
//!   (sets `mesh-d1` to `mesh-d4`), with their own shard format and reader;
//! - [`cli`]: the `dynaserve sim` subcommand.

pub mod cli;
pub mod dataset;
pub mod generators;
pub mod materials;
pub mod mesh_scenes;
pub mod preview;
pub mod random;
pub mod replay;
pub mod scenarios;
pub mod scene;
pub mod shapes;
pub mod stats;
pub mod writer;

pub use dataset::{DatasetReader, Manifest, ObjectRecord, SceneLabel, SceneRecord};
pub use generators::{GenerateOptions, Generator};
pub use scenarios::{MaterialRanges, Materials, Scenario, ScenarioParameters};
pub use scene::{KinematicPath, ObjectSpec, SceneSpec, SimConfig};
pub use shapes::{Shape, ShapeKind};

use std::path::PathBuf;

/// Errors from scene generation and dataset I/O; each names the file or argument at fault.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A manifest is missing, unreadable or inconsistent.
    #[error("manifest {path}: {message}")]
    Manifest {
        /// The manifest file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A shard is unreadable or does not match its manifest.
    #[error("shard {path}: {message}")]
    Shard {
        /// The shard file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A shape could not be built or sampled.
    #[error("shape: {0}")]
    Shape(String),
    /// A geometry routine failed.
    #[error(transparent)]
    Geometry(#[from] dynaserve_geometry::GeometryError),
    /// An argument was outside its valid range.
    #[error("invalid argument: {0}")]
    Invalid(String),
    /// The physics produced a non-finite state.
    #[error("simulation diverged: {0}")]
    Diverged(String),
}

/// Result alias for this crate.
pub type Result<T, E = SimError> = std::result::Result<T, E>;
