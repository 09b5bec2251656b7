//! The normalisation constants of the per-point input features a checkpoint was trained with.

use serde::{Deserialize, Serialize};

use super::dynamics::DynamicsConfig;
use super::feature_layout::{CONTACT_VELOCITY_FEATURES, HISTORY_FEATURES};

/// Affine normalisation of the per-point input features: `(raw - mean) / std`, one value per
/// feature ([`DynamicsConfig::point_features`]: 12, plus 3 with the contact velocity, plus 7
/// with the surface normals, plus 3 with the history, plus 3 with the approach).
///
/// Layout: `[contact_x, contact_y, contact_z, v_x, v_y, v_z, r_x, r_y, r_z, ln(mass / 1 kg),
/// friction, restitution]`, then `[cv_x, cv_y, cv_z]` with the contact velocity, then `[n_x,
/// n_y, n_z, m_x, m_y, m_z, gap]` with the surface normals (unit vectors; the gap in metres), then
/// `[a_x, a_y, a_z]` with the history (metres per frame^2 with per-frame units), then
/// `[closing, reach, depth]` with the approach (metres per frame, a fraction of the step,
/// metres per frame with per-frame units). Contact
/// displacement, increment, offset and contact velocity are in metres (increments per step of
/// `dt_steps` frames, or per frame with per-frame units); mass enters as its natural logarithm.
/// The trainer fits these from data; the defaults are sensible for MOVi-like scenes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeatureNormalization {
    /// Per-feature mean subtracted first, `[features]`.
    pub mean: Vec<f32>,
    /// Per-feature scale divided by afterwards (must be finite and > 0), `[features]`.
    pub std: Vec<f32>,
}

impl Default for FeatureNormalization {
    /// The 12 base features' defaults.
    fn default() -> Self {
        FeatureNormalization {
            mean: vec![
                0.0, 0.0, -0.1, // contact (the ground pulls the mean down)
                0.0, 0.0, 0.0, // per-step increment
                0.0, 0.0, 1.0, // offset from the reference cloud ~ world position
                0.5, 0.6, 0.5, // ln mass, friction, restitution
            ],
            std: vec![
                0.1, 0.1, 0.1, //
                0.05, 0.05, 0.05, //
                2.5, 2.5, 1.0, //
                1.0, 0.2, 0.2,
            ],
        }
    }
}

impl FeatureNormalization {
    /// Default constants for the features `dynamics` selects (the contact velocity, if on,
    /// gets mean 0 and the increment's scale; the surface normals mean 0 and scale 0.5, their
    /// gap the contact feature's; the approach's speeds the increment's scale; the contact
    /// partner's flag and materials centred near zero, since most points touch no object).
    pub fn defaults_for(dynamics: &DynamicsConfig) -> FeatureNormalization {
        let mut n = FeatureNormalization::default();
        if dynamics.contact_velocity {
            n.mean.extend([0.0; CONTACT_VELOCITY_FEATURES]);
            n.std.extend([0.05; CONTACT_VELOCITY_FEATURES]);
        }
        if dynamics.surface_normals {
            n.mean.extend([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.1]);
            n.std.extend([0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.1]);
        }
        if dynamics.history {
            n.mean.extend([0.0; HISTORY_FEATURES]);
            n.std.extend([0.01; HISTORY_FEATURES]);
        }
        if dynamics.approach {
            n.mean.extend([0.0, 1.0, 0.0]);
            n.std.extend([0.05, 0.3, 0.05]);
        }
        if dynamics.contact_partner {
            // Most points touch no other object: the flag and the rest are mostly zero.
            n.mean.extend([0.1, 0.0, 0.05, 0.05]);
            n.std.extend([0.3, 0.5, 0.2, 0.2]);
        }
        n
    }

    /// Number of features these constants normalise.
    pub fn len(&self) -> usize {
        self.mean.len()
    }

    /// True when there are no constants at all (never valid).
    pub fn is_empty(&self) -> bool {
        self.mean.is_empty()
    }
}
