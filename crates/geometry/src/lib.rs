//! Point clouds and rigid motion for Dynaserve.
//!
//! Units are metres throughout; the z axis points up. Points are `[f32; 3]` unless a routine
//! needs double precision (Kabsch works in `f64`). Quaternions stored as arrays are
//! `[x, y, z, w]` (scalar last).

pub mod contact;
pub mod fps;
pub mod kabsch;
pub mod mesh;
pub mod metrics;
pub mod normals;
pub mod quat;

pub use contact::{
    ContactConfig, ContactHit, ContactSource, contact_features, contact_features_brute_force,
    contact_hits, contact_hits_brute_force,
};
pub use fps::farthest_point_sampling;
pub use kabsch::{KabschSolution, kabsch, kabsch_backward};
pub use mesh::{TriMesh, convex_hull, sample_surface};
pub use metrics::{
    RmseAccumulator, momentum_drift_ratio, orientation_rmse_deg, rigidity_residual,
    translation_rmse,
};
pub use normals::{DEFAULT_NORMAL_NEIGHBOURS, estimate_normals};
pub use quat::geodesic_angle;

/// A point or displacement in metres.
pub type Point = [f32; 3];

/// Errors from geometry routines; each names what was wrong.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum GeometryError {
    /// An input that must hold at least one element was empty.
    #[error("{0} is empty")]
    Empty(&'static str),
    /// Two inputs that must have the same length do not.
    #[error("{what}: expected {expected} elements, got {got}")]
    LengthMismatch {
        /// Which input.
        what: &'static str,
        /// Required length.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// An input held NaN or an infinity (or a value outside its valid range).
    #[error("{0} must be finite")]
    NonFinite(&'static str),
    /// A numerical routine failed.
    #[error("numerical failure: {0}")]
    Numerical(&'static str),
    /// An argument was outside its valid range.
    #[error("invalid argument: {0}")]
    Invalid(String),
}
