//! A solid as a union of convex parts: the unit shape of a kind (recentred on its centre of
//! mass), its collider, mass properties and surface samples.

use std::sync::OnceLock;

use dynaserve_geometry::Point;
use rand::Rng;
use rapier3d::math::Pose;
use rapier3d::prelude::SharedShape;

use super::builders::{fixed_parts, random_hull};
use super::kind::ShapeKind;
use super::part::Part;
use crate::SimError;

/// A solid as a union of non-overlapping convex parts, in its body frame (origin at the centre
/// of mass for shapes built by [`Shape::unit`]).
#[derive(Clone, Debug)]
pub struct Shape {
    /// Which shape this is.
    pub kind: ShapeKind,
    /// The convex parts, metres, body frame.
    pub parts: Vec<Part>,
}

impl Shape {
    /// The unit shape of `kind`, recentred on its centre of mass. Only [`ShapeKind::Hull`]
    /// draws from `rng`; the other shapes are built once and cloned.
    pub fn unit<R: Rng + ?Sized>(kind: ShapeKind, rng: &mut R) -> Result<Shape, SimError> {
        if kind == ShapeKind::Hull {
            let parts = vec![random_hull(rng)];
            return Shape { kind, parts }.recentred();
        }
        static CACHE: OnceLock<Vec<Result<Shape, String>>> = OnceLock::new();
        let cache = CACHE.get_or_init(|| {
            ShapeKind::MOVI_B
                .iter()
                .map(|&k| {
                    if k == ShapeKind::Hull {
                        Err("random".to_string())
                    } else {
                        fixed_parts(k)
                            .and_then(|parts| Shape { kind: k, parts }.recentred())
                            .map_err(|e| e.to_string())
                    }
                })
                .collect()
        });
        let i = ShapeKind::MOVI_B
            .iter()
            .position(|&k| k == kind)
            .ok_or_else(|| SimError::Shape(format!("unknown shape {kind:?}")))?;
        cache[i].clone().map_err(SimError::Shape)
    }

    /// The shape uniformly scaled by `s` about its body origin.
    pub fn scaled(&self, s: f32) -> Shape {
        Shape {
            kind: self.kind,
            parts: self.parts.iter().map(|p| p.scaled(s)).collect(),
        }
    }

    fn translated(&self, d: [f32; 3]) -> Shape {
        Shape {
            kind: self.kind,
            parts: self.parts.iter().map(|p| p.translated(d)).collect(),
        }
    }

    /// The shape for rapier and parry: its pose in the body frame and the (possibly compound)
    /// parry shape.
    pub fn collider(&self) -> Result<(Pose, SharedShape), SimError> {
        let mut parts = self
            .parts
            .iter()
            .map(Part::collider)
            .collect::<Result<Vec<_>, _>>()?;
        if parts.len() == 1 {
            return parts
                .pop()
                .ok_or_else(|| SimError::Shape("shape without parts".into()));
        }
        if parts.is_empty() {
            return Err(SimError::Shape("shape without parts".into()));
        }
        Ok((Pose::IDENTITY, SharedShape::compound(parts)))
    }

    /// Volume (cubic metres) and centre of mass (metres, body frame) at uniform density, as
    /// rapier computes them from the colliders.
    pub fn volume_and_centroid(&self) -> Result<(f32, [f32; 3]), SimError> {
        let (pose, shape) = self.collider()?;
        let mp = shape.mass_properties(1.0).transform_by(&pose);
        let c = mp.local_com;
        Ok((mp.mass(), [c.x, c.y, c.z]))
    }

    /// Total surface area of the parts (including faces shared between parts), square metres.
    pub fn parts_area(&self) -> f64 {
        self.parts.iter().map(Part::area).sum()
    }

    /// `n` points uniformly distributed over the outer surface of the union of the parts
    /// (faces shared between touching parts are excluded), metres, body frame.
    pub fn sample_surface<R: Rng + ?Sized>(
        &self,
        n: usize,
        rng: &mut R,
    ) -> Result<Vec<Point>, SimError> {
        let areas: Vec<f64> = self.parts.iter().map(Part::area).collect();
        let total: f64 = areas.iter().sum();
        if self.parts.is_empty() || total.is_nan() || total <= 0.0 {
            return Err(SimError::Shape("cannot sample a shape without area".into()));
        }
        let extent = self.parts.iter().map(Part::area).fold(0.0, f64::max).sqrt();
        let eps = 1e-5 * extent;
        let mut out = Vec::with_capacity(n);
        let mut attempts = 0usize;
        while out.len() < n {
            attempts += 1;
            if attempts > 1000 * n.max(1) {
                return Err(SimError::Shape(format!(
                    "{}: surface sampling rejected too many points",
                    self.kind.name()
                )));
            }
            let mut u = rng.random::<f64>() * total;
            let mut i = 0;
            while i + 1 < areas.len() && u >= areas[i] {
                u -= areas[i];
                i += 1;
            }
            let p = self.parts[i].sample(rng);
            let hidden = self.parts.len() > 1
                && self
                    .parts
                    .iter()
                    .enumerate()
                    .any(|(j, q)| j != i && q.contains(p, eps));
            if !hidden {
                out.push([p[0] as f32, p[1] as f32, p[2] as f32]);
            }
        }
        Ok(out)
    }

    /// Moves the shape so the centre of mass is the origin; returns the recentred shape.
    fn recentred(&self) -> Result<Shape, SimError> {
        let (_, c) = self.volume_and_centroid()?;
        Ok(self.translated([-c[0], -c[1], -c[2]]))
    }
}
