//! What a contact search is given: its [`ContactConfig`] (radius, ground) and the object
//! `offsets`, with their checks.

use crate::GeometryError;

/// Parameters of the contact features.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct ContactConfig {
    /// Contact radius in metres (finite, > 0): displacements are clipped to this length.
    pub radius: f32,
    /// Height of the ground plane's top (metres), or `None` for no ground.
    pub ground_z: Option<f32>,
}

impl Default for ContactConfig {
    /// Radius 0.25 m, ground at z = 0.
    fn default() -> Self {
        ContactConfig {
            radius: 0.25,
            ground_z: Some(0.0),
        }
    }
}

impl ContactConfig {
    /// Checks that the radius is finite and positive and the ground height finite.
    pub fn validate(&self) -> Result<(), GeometryError> {
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return Err(GeometryError::Invalid(format!(
                "contact radius must be finite and > 0, got {}",
                self.radius
            )));
        }
        if let Some(z) = self.ground_z
            && !z.is_finite()
        {
            return Err(GeometryError::NonFinite("contact ground_z"));
        }
        Ok(())
    }

    /// The radius, or 0 when it is not finite and positive.
    pub(super) fn effective_radius(&self) -> f32 {
        if self.radius.is_finite() && self.radius > 0.0 {
            self.radius
        } else {
            0.0
        }
    }
}

/// Checks that `offsets` (`[objects + 1]`) splits `n_points` points into contiguous objects:
/// starts at 0, never decreases, ends at `n_points`.
pub fn validate_offsets(n_points: usize, offsets: &[usize]) -> Result<(), GeometryError> {
    if offsets.is_empty() {
        return Err(GeometryError::Empty("object offsets"));
    }
    if offsets[0] != 0 {
        return Err(GeometryError::Invalid(format!(
            "object offsets must start at 0, got {}",
            offsets[0]
        )));
    }
    if offsets.windows(2).any(|w| w[1] < w[0]) {
        return Err(GeometryError::Invalid(
            "object offsets must not decrease".into(),
        ));
    }
    let last = offsets[offsets.len() - 1];
    if last != n_points {
        return Err(GeometryError::LengthMismatch {
            what: "points (object offsets end)",
            expected: last,
            got: n_points,
        });
    }
    if n_points > u32::MAX as usize || offsets.len() > u32::MAX as usize {
        return Err(GeometryError::Invalid(
            "too many points or objects for contact features".into(),
        ));
    }
    Ok(())
}
