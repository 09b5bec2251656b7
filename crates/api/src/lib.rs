//! The Dynaserve API: one vocabulary for both protocols.
//!
//! Wire forms (always built):
//! - [`v1`]: types and gRPC service stubs generated from `proto/dynaserve/v1/*.proto` (package
//!   `dynaserve.v1`: the `WorldModel` and `Sessions` services), plus
//!   [`v1::FILE_DESCRIPTOR_SET`] for server reflection;
//! - [`json`]: the same messages as JSON documents (HTTP bodies and scene files);
//! - [`json_body`]: an HTTP body read into a JSON document, errors naming the field;
//! - [`wire`]: JSON form <-> gRPC, what a client sends and receives;
//! - [`listening`]: the start-up line a server prints, and its parser;
//! - [`FieldError`]: a malformed or out-of-range field, named by its path; [`code_name`]: the
//!   names of gRPC status codes.
//!
//! With the `model` feature (the server, the load tester's in-process mode, the tests):
//! - [`spec`]: the protocol-neutral requests and results the engine takes and emits, with
//!   conversions from and to each wire form ([`spec::json`], [`spec::v1`]) that check what the
//!   wire form's structure demands and name the field;
//! - [`limits`]: every request limit, defined once (the extents are the model's).
//!
//! What a request's values must satisfy beyond that (scene building, session inputs, Generate
//! scenes) is the server's to check, with the model family that uses them.
//!
//! Units and conventions (metres, seconds, kilograms, z up, quaternions `[x, y, z, w]`) are
//! documented on every field of the `.proto` file and of [`json`].

mod error;
pub mod json;
pub mod json_body;
#[cfg(feature = "model")]
pub mod limits;
pub mod listening;
#[cfg(feature = "model")]
pub mod spec;
pub mod wire;

pub use error::{FieldError, code_name};

/// Response header (HTTP) and metadata key (gRPC) of each server warning about a request: one
/// line per object parameter outside the range the model was trained on.
pub const WARNING_HEADER: &str = "x-dynaserve-warning";

/// Generated protobuf messages and gRPC client/server code for `dynaserve.v1`.
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod v1 {
    tonic::include_proto!("dynaserve.v1");

    /// Encoded `FileDescriptorSet` of `dynaserve.v1`, for gRPC server reflection.
    pub const FILE_DESCRIPTOR_SET: &[u8] =
        tonic::include_file_descriptor_set!("dynaserve_v1_descriptor");
}
