//! Closed triangle meshes: area, volume, centre of mass, seeded surface sampling, unit primitives
//! and convex hulls.
//!
//! Coordinates are metres (`[f32; 3]`), faces are vertex index triples ordered counter-clockwise
//! seen from outside, so the divergence theorem gives a positive volume. Integrals (area, volume,
//! centroid) are accumulated in `f64`.
//!
//! Unit primitives follow Kubric's convention: they span `[-0.5, 0.5]^3` (or fit inside it, for
//! flat shapes such as the torus), with the z axis as the axis of symmetry. Their origin is the
//! centre of their bounding box, which is not always the centre of mass (the cone's is at
//! `z = -0.25`): use [`TriMesh::centroid`] and [`TriMesh::translated`] to recentre.
//!
//! [`TriMesh`] itself (this module) measures and transforms a mesh; [`primitives`] builds the
//! unit shapes, `hull` the convex hull of a point set and `sampling` draws points from a
//! surface (both re-exported here).

mod hull;
pub mod primitives;
mod sampling;
#[cfg(test)]
mod tests;
mod vec3;

use std::collections::HashMap;

use crate::{GeometryError, Point};
use vec3::{cross, dot, norm, sub, to64};

pub use hull::convex_hull;
pub use primitives::{
    cone, cube, cylinder, gear_outline, gear_prism, prism, sphere, torus, torus_slab,
};
pub use sampling::{sample_surface, sample_surface_with};

/// A triangle mesh: vertices in metres and faces as counter-clockwise (outward) index triples.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct TriMesh {
    /// Vertex positions, metres.
    pub vertices: Vec<Point>,
    /// Triangles as indices into `vertices`, counter-clockwise seen from outside.
    pub faces: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Builds a mesh after checking that every coordinate is finite and every index is in range.
    pub fn new(vertices: Vec<Point>, faces: Vec<[u32; 3]>) -> Result<Self, GeometryError> {
        if vertices.iter().flatten().any(|c| !c.is_finite()) {
            return Err(GeometryError::NonFinite("mesh vertices"));
        }
        let n = vertices.len();
        if let Some(f) = faces.iter().find(|f| f.iter().any(|&i| i as usize >= n)) {
            return Err(GeometryError::Invalid(format!(
                "face {f:?} refers to a vertex outside 0..{n}"
            )));
        }
        Ok(Self { vertices, faces })
    }

    pub(super) fn corners(&self, face: &[u32; 3]) -> [[f64; 3]; 3] {
        [
            to64(self.vertices[face[0] as usize]),
            to64(self.vertices[face[1] as usize]),
            to64(self.vertices[face[2] as usize]),
        ]
    }

    /// Area of each face, square metres, in face order.
    pub fn face_areas(&self) -> Vec<f64> {
        self.faces
            .iter()
            .map(|f| {
                let [a, b, c] = self.corners(f);
                0.5 * norm(cross(sub(b, a), sub(c, a)))
            })
            .collect()
    }

    /// Total surface area, square metres.
    pub fn area(&self) -> f64 {
        self.face_areas().iter().sum()
    }

    /// Signed volume enclosed by the mesh, cubic metres (positive for a closed mesh with outward
    /// faces). Meaningless for an open mesh.
    pub fn volume(&self) -> f64 {
        let Some(&o) = self.vertices.first() else {
            return 0.0;
        };
        let o = to64(o);
        self.faces
            .iter()
            .map(|f| {
                let [a, b, c] = self.corners(f);
                dot(sub(a, o), cross(sub(b, o), sub(c, o))) / 6.0
            })
            .sum()
    }

    /// Centre of the enclosed volume (the centre of mass at uniform density), metres. Falls back
    /// to the vertex mean when the volume is (near) zero.
    pub fn centroid(&self) -> [f64; 3] {
        let Some(&o) = self.vertices.first() else {
            return [0.0; 3];
        };
        let o = to64(o);
        let mut total = 0.0;
        let mut acc = [0.0f64; 3];
        for f in &self.faces {
            let [a, b, c] = self.corners(f);
            let (a, b, c) = (sub(a, o), sub(b, o), sub(c, o));
            let v = dot(a, cross(b, c)) / 6.0;
            total += v;
            for k in 0..3 {
                acc[k] += v * (a[k] + b[k] + c[k]) / 4.0;
            }
        }
        let scale = self
            .vertices
            .iter()
            .flatten()
            .fold(0.0f64, |m, &x| m.max((x as f64).abs()))
            .max(1e-30);
        if total.abs() <= 1e-12 * scale * scale * scale {
            let n = self.vertices.len() as f64;
            let mut mean = [0.0; 3];
            for v in &self.vertices {
                for k in 0..3 {
                    mean[k] += v[k] as f64 / n;
                }
            }
            return mean;
        }
        [
            o[0] + acc[0] / total,
            o[1] + acc[1] / total,
            o[2] + acc[2] / total,
        ]
    }

    /// Axis-aligned bounding box `(min, max)` in metres; `([0; 3], [0; 3])` for an empty mesh.
    pub fn aabb(&self) -> (Point, Point) {
        if self.vertices.is_empty() {
            return ([0.0; 3], [0.0; 3]);
        }
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for v in &self.vertices {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        (lo, hi)
    }

    /// The mesh moved by `offset` (metres).
    pub fn translated(&self, offset: Point) -> TriMesh {
        TriMesh {
            vertices: self
                .vertices
                .iter()
                .map(|v| [v[0] + offset[0], v[1] + offset[1], v[2] + offset[2]])
                .collect(),
            faces: self.faces.clone(),
        }
    }

    /// The mesh scaled per axis about the origin. A negative product of the factors mirrors the
    /// mesh, so the face order is reversed to keep faces outward.
    pub fn scaled(&self, factors: [f32; 3]) -> TriMesh {
        let mirror = factors[0] * factors[1] * factors[2] < 0.0;
        TriMesh {
            vertices: self
                .vertices
                .iter()
                .map(|v| [v[0] * factors[0], v[1] * factors[1], v[2] * factors[2]])
                .collect(),
            faces: if mirror {
                self.faces.iter().map(|f| [f[0], f[2], f[1]]).collect()
            } else {
                self.faces.clone()
            },
        }
    }

    /// The mesh with every vertex mapped through `f` (e.g. a rotation). `f` must preserve
    /// orientation (no mirroring) for the faces to stay outward.
    pub fn mapped(&self, f: impl Fn(Point) -> Point) -> TriMesh {
        TriMesh {
            vertices: self.vertices.iter().map(|&v| f(v)).collect(),
            faces: self.faces.clone(),
        }
    }

    /// Concatenates meshes into one (vertex indices of later meshes are offset).
    pub fn merged(meshes: &[TriMesh]) -> TriMesh {
        let mut out = TriMesh::default();
        for m in meshes {
            let base = out.vertices.len() as u32;
            out.vertices.extend_from_slice(&m.vertices);
            out.faces.extend(
                m.faces
                    .iter()
                    .map(|f| [f[0] + base, f[1] + base, f[2] + base]),
            );
        }
        out
    }

    /// Whether every directed edge has exactly one opposite edge, i.e. the mesh is closed and
    /// consistently oriented (a 2-manifold without boundary).
    pub fn is_closed(&self) -> bool {
        let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.faces.len() * 3);
        for f in &self.faces {
            for k in 0..3 {
                *edges.entry((f[k], f[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        edges
            .iter()
            .all(|(&(a, b), &count)| count == 1 && edges.get(&(b, a)) == Some(&1))
    }
}
