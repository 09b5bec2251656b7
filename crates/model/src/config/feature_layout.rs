//! The per-point and per-object input layout every RigidFormer shares: how many features each
//! input group adds and where the `ln` mass sits. Which groups a model has is its
//! [`DynamicsConfig`](super::DynamicsConfig).

/// Number of per-point input features every model has: contact displacement (3), per-step
/// increment (3), offset from the reference cloud (3), physical parameters (3).
pub const BASE_POINT_FEATURES: usize = 12;

/// Features appended after the base ones when
/// [`DynamicsConfig::contact_velocity`](super::DynamicsConfig::contact_velocity) is on: the contact
/// surface's increment relative to the point's own (3).
pub const CONTACT_VELOCITY_FEATURES: usize = 3;

/// Features appended after the base ones and the contact velocity (if on) when
/// [`DynamicsConfig::surface_normals`](super::DynamicsConfig::surface_normals) is on: the point's
/// own outward normal (3), the normal of the surface its contact feature reaches (3) and its height
/// above that surface's tangent plane (1).
pub const SURFACE_NORMAL_FEATURES: usize = 7;

/// Features appended after the base ones, the contact velocity and the surface normals (each if on)
/// when [`DynamicsConfig::history`](super::DynamicsConfig::history) is on: the point's acceleration
/// over the previous two steps beyond free fall (3).
pub const HISTORY_FEATURES: usize = 3;

/// Features appended after every other optional group (each if on) when
/// [`DynamicsConfig::approach`](super::DynamicsConfig::approach) is on: the speed at which the
/// point closes on the surface its contact feature reaches (1), the fraction of the step before it
/// would reach it (1) and how far behind it a free step would carry it (1).
pub const APPROACH_FEATURES: usize = 3;

/// Features appended after every other optional group (each if on) when
/// [`DynamicsConfig::contact_partner`](super::DynamicsConfig::contact_partner) is on: whether the
/// surface the point's contact feature reaches belongs to another object (1) or not (0: the floor,
/// or nothing within the contact radius), and that object's `ln` mass less the point's own object's
/// (clamped to [`CONTACT_PARTNER_MAX_LN_RATIO`]), friction and restitution (3; zero when it is not
/// an object).
pub const CONTACT_PARTNER_FEATURES: usize = 4;

/// Largest magnitude of the `ln` mass ratio among the contact partner features (a factor of
/// about 150 either way).
pub const CONTACT_PARTNER_MAX_LN_RATIO: f32 = 5.0;

/// Numbers per object in the object state summary
/// ([`DynamicsConfig::object_summary`](super::DynamicsConfig::object_summary)).
pub const OBJECT_SUMMARY_FEATURES: usize = 14;

/// Numbers per object in the contact summary
/// ([`DynamicsConfig::contact_summary`](super::DynamicsConfig::contact_summary)).
pub const CONTACT_SUMMARY_FEATURES: usize = 11;

/// Index of the `ln(mass / kg)` feature among the per-point features (see
/// [`FeatureNormalization`](super::FeatureNormalization)).
pub const LN_MASS_FEATURE: usize = 9;
