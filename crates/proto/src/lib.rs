//! The Dynaserve wire contract.
//!
//! - [`v1`]: types and gRPC service stubs generated from `proto/dynaserve/v1/world_model.proto`
//!   (package `dynaserve.v1`), plus [`v1::FILE_DESCRIPTOR_SET`] for server reflection.
//! - [`json`]: the same messages as JSON documents (HTTP API bodies and scene files), with
//!   lossless conversions to and from the gRPC types.
//!
//! Units and conventions (metres, seconds, kilograms, z up, quaternions `[x, y, z, w]`) are
//! documented on every field of the `.proto` file and of [`json`].

pub mod json;

/// Generated protobuf messages and gRPC client/server code for `dynaserve.v1`.
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod v1 {
    tonic::include_proto!("dynaserve.v1");

    /// Encoded `FileDescriptorSet` of `dynaserve.v1`, for gRPC server reflection.
    pub const FILE_DESCRIPTOR_SET: &[u8] =
        tonic::include_file_descriptor_set!("dynaserve_v1_descriptor");
}
