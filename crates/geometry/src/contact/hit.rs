//! One point's result: what its displacement reaches ([`ContactSource`], [`ContactHit`]), the
//! ground fallback every search starts from, and the squared distance both searches share.

use crate::Point;

#[inline(always)]
pub(super) fn dist2(a: &Point, b: &Point) -> f32 {
    let dx = b[0] - a[0];
    let dy = b[1] - a[1];
    let dz = b[2] - a[2];
    dx * dx + dy * dy + dz * dz
}

/// What a point's contact displacement points at (see [`contact_hits`](super::contact_hits)).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ContactSource {
    /// The nearest point of another object, by its index into `points`.
    Point(u32),
    /// The ground plane, within the radius and nearer than every other object's point.
    Ground,
    /// Nothing within the radius: the displacement is the clipped (or zero) fallback.
    Free,
}

/// One point's contact feature together with what it points at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactHit {
    /// The contact displacement of [`contact_features`](super::contact_features), metres, world frame.
    pub displacement: Point,
    /// The surface the displacement reaches.
    pub source: ContactSource,
}

impl ContactHit {
    #[inline(always)]
    pub(super) fn new(displacement: Point, source: ContactSource) -> ContactHit {
        ContactHit {
            displacement,
            source,
        }
    }
}

/// The squared distance a point candidate must beat, the result when none does and what
/// that result points at.
#[inline(always)]
pub(super) fn ground_fallback(
    x: &Point,
    r: f32,
    ground_z: Option<f32>,
) -> (f32, Point, ContactSource) {
    let r2 = r * r;
    match ground_z {
        None => (r2, [0.0; 3], ContactSource::Free),
        Some(gz) => {
            let g = gz - x[2];
            let g2 = g * g;
            if g2 < r2 {
                (g2, [0.0, 0.0, g], ContactSource::Ground)
            } else {
                (r2, [0.0, 0.0, r.copysign(g)], ContactSource::Free)
            }
        }
    }
}
