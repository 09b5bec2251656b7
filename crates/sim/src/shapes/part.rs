//! Convex parts of a shape (boxes, balls, convex polyhedra): their colliders, areas, surface
//! samples and inside tests, in the body frame (metres).

use std::f64::consts::PI;

use dynaserve_geometry::mesh::{self, TriMesh};
use dynaserve_geometry::{Point, convex_hull};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use rapier3d::math::{Pose, Rotation, Vector};
use rapier3d::prelude::SharedShape;

use crate::SimError;

/// One convex piece of a shape, in the body frame (metres).
#[derive(Clone, Debug)]
pub enum Part {
    /// Box with half extents `half`, centred at `center`, axis-aligned.
    Cuboid {
        /// Half extents, metres.
        half: [f32; 3],
        /// Centre, metres.
        center: [f32; 3],
    },
    /// Ball of radius `radius` centred at `center`.
    Ball {
        /// Radius, metres.
        radius: f32,
        /// Centre, metres.
        center: [f32; 3],
    },
    /// Convex polyhedron given as its hull mesh (outward faces).
    Polytope(Polytope),
}

/// A convex polyhedron with its face planes, for surface sampling and inside tests.
#[derive(Clone, Debug)]
pub struct Polytope {
    /// The hull mesh, metres.
    pub mesh: TriMesh,
    /// Face planes `(unit outward normal, offset)`: inside iff `n . p <= offset` for all.
    planes: Vec<([f64; 3], f64)>,
}

impl Polytope {
    /// Convex hull of `points` (metres).
    pub fn hull(points: &[Point]) -> Result<Self, SimError> {
        Ok(Self::from_mesh(convex_hull(points)?))
    }

    fn from_mesh(mesh: TriMesh) -> Self {
        let planes = mesh
            .faces
            .iter()
            .filter_map(|f| {
                let [a, b, c] = f.map(|i| {
                    let v = mesh.vertices[i as usize];
                    [v[0] as f64, v[1] as f64, v[2] as f64]
                });
                let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
                let w = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
                let n = [
                    u[1] * w[2] - u[2] * w[1],
                    u[2] * w[0] - u[0] * w[2],
                    u[0] * w[1] - u[1] * w[0],
                ];
                let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                (l > 1e-14).then(|| {
                    let n = [n[0] / l, n[1] / l, n[2] / l];
                    (n, n[0] * a[0] + n[1] * a[1] + n[2] * a[2])
                })
            })
            .collect();
        Self { mesh, planes }
    }

    fn signed_distance_bound(&self, p: [f64; 3]) -> f64 {
        self.planes
            .iter()
            .map(|(n, d)| n[0] * p[0] + n[1] * p[1] + n[2] * p[2] - d)
            .fold(f64::NEG_INFINITY, f64::max)
    }
}

pub(super) fn f64v(p: [f32; 3]) -> [f64; 3] {
    [p[0] as f64, p[1] as f64, p[2] as f64]
}

impl Part {
    pub(super) fn translated(&self, d: [f32; 3]) -> Part {
        let add = |c: &[f32; 3]| [c[0] + d[0], c[1] + d[1], c[2] + d[2]];
        match self {
            Part::Cuboid { half, center } => Part::Cuboid {
                half: *half,
                center: add(center),
            },
            Part::Ball { radius, center } => Part::Ball {
                radius: *radius,
                center: add(center),
            },
            Part::Polytope(p) => Part::Polytope(Polytope::from_mesh(p.mesh.translated(d))),
        }
    }

    pub(super) fn scaled(&self, s: f32) -> Part {
        let mul = |c: &[f32; 3]| [c[0] * s, c[1] * s, c[2] * s];
        match self {
            Part::Cuboid { half, center } => Part::Cuboid {
                half: mul(half),
                center: mul(center),
            },
            Part::Ball { radius, center } => Part::Ball {
                radius: radius * s,
                center: mul(center),
            },
            Part::Polytope(p) => Part::Polytope(Polytope::from_mesh(p.mesh.scaled([s, s, s]))),
        }
    }

    /// The part as a parry shape and its pose in the body frame.
    pub(super) fn collider(&self) -> Result<(Pose, SharedShape), SimError> {
        let at = |c: &[f32; 3], r: Rotation| Pose::from_parts(Vector::new(c[0], c[1], c[2]), r);
        Ok(match self {
            Part::Cuboid { half, center } => (
                at(center, Rotation::IDENTITY),
                SharedShape::cuboid(half[0], half[1], half[2]),
            ),
            Part::Ball { radius, center } => {
                (at(center, Rotation::IDENTITY), SharedShape::ball(*radius))
            }
            Part::Polytope(p) => {
                let pts: Vec<Vector> = p
                    .mesh
                    .vertices
                    .iter()
                    .map(|v| Vector::new(v[0], v[1], v[2]))
                    .collect();
                let shape = SharedShape::convex_hull(&pts).ok_or_else(|| {
                    SimError::Shape("rapier rejected a convex part (degenerate hull)".into())
                })?;
                (Pose::IDENTITY, shape)
            }
        })
    }

    /// Surface area, square metres.
    pub(super) fn area(&self) -> f64 {
        match self {
            Part::Cuboid { half, .. } => {
                let [a, b, c] = half.map(|h| 2.0 * h as f64);
                2.0 * (a * b + b * c + c * a)
            }
            Part::Ball { radius, .. } => 4.0 * PI * (*radius as f64).powi(2),
            Part::Polytope(p) => p.mesh.area(),
        }
    }

    /// A uniformly distributed point on the part's surface.
    pub(super) fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> [f64; 3] {
        let add = |c: &[f32; 3], p: [f64; 3]| {
            [c[0] as f64 + p[0], c[1] as f64 + p[1], c[2] as f64 + p[2]]
        };
        match self {
            Part::Cuboid { half, center } => {
                let m = mesh::cube().scaled(half.map(|h| 2.0 * h));
                let p = mesh::sample_surface_with(&m, 1, rng)[0];
                add(center, f64v(p))
            }
            Part::Ball { radius, center } => {
                let d = unit_vector(rng);
                let r = *radius as f64;
                add(center, [r * d[0], r * d[1], r * d[2]])
            }
            Part::Polytope(p) => f64v(mesh::sample_surface_with(&p.mesh, 1, rng)[0]),
        }
    }

    /// Whether `p` lies inside the part or within `eps` of its boundary.
    pub(super) fn contains(&self, p: [f64; 3], eps: f64) -> bool {
        let rel = |c: &[f32; 3]| [p[0] - c[0] as f64, p[1] - c[1] as f64, p[2] - c[2] as f64];
        match self {
            Part::Cuboid { half, center } => {
                let q = rel(center);
                (0..3).all(|k| q[k].abs() <= half[k] as f64 + eps)
            }
            Part::Ball { radius, center } => {
                let q = rel(center);
                (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() <= *radius as f64 + eps
            }
            Part::Polytope(poly) => poly.signed_distance_bound(p) <= eps,
        }
    }
}

pub(super) fn unit_vector<R: Rng + ?Sized>(rng: &mut R) -> [f64; 3] {
    loop {
        let v: [f64; 3] = [
            StandardNormal.sample(rng),
            StandardNormal.sample(rng),
            StandardNormal.sample(rng),
        ];
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if l > 1e-9 {
            return [v[0] / l, v[1] / l, v[2] / l];
        }
    }
}

pub(super) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(super) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

pub(super) fn normalize(a: [f64; 3]) -> [f64; 3] {
    let l = dot(a, a).sqrt();
    [a[0] / l, a[1] / l, a[2] / l]
}
