//! The procedural shape set: unit shapes as unions of convex parts, their rapier colliders and
//! exact surface samples.
//!
//! Every unit shape fits `[-0.5, 0.5]^3` with its longest bounding-box side equal to 1 (Kubric's
//! convention) and is then moved so that its centre of mass (uniform density) is the origin of
//! its body frame. Curved primitives (sphere, cylinder, cone) are rapier's exact shapes; every
//! other shape is a union of convex polyhedra that touch but do not overlap, so its volume (and
//! hence its mass) is the sum of its parts'. Reference clouds are sampled from the surface of
//! exactly the solid the physics engine simulates.

use std::f64::consts::{PI, TAU};
use std::sync::OnceLock;

use dynaserve_geometry::mesh::{self, TriMesh};
use dynaserve_geometry::{Point, convex_hull};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use rapier3d::math::{Pose, Rotation, Vector};
use rapier3d::prelude::SharedShape;
use serde::Serialize;

use crate::SimError;

/// The shapes the generators can place. Their index in a dataset's manifest `shapes` list is the
/// `shape_id` of an object.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ShapeKind {
    /// Cube of side 1.
    Cube,
    /// Cylinder of radius 0.5 and height 1 about z: 32-sided prism.
    Cylinder,
    /// Sphere of radius 0.5 (exact).
    Sphere,
    /// Cone of base radius 0.5 and height 1 about z, apex up: 32-sided pyramid.
    Cone,
    /// Polyhedral torus, tube radius 0.15 on a circle of radius 0.35: 24 convex slabs.
    Torus,
    /// Spur-gear-like prism, 10 teeth, thickness 0.3: root prism plus one prism per tooth.
    Gear,
    /// Trefoil knot tube: 48 convex tube segments.
    TorusKnot,
    /// Level-1 Menger sponge: 20 cubes of side 1/3.
    Sponge,
    /// Mug: open cylindrical cup with a curved handle, 25 convex parts.
    Mug,
    /// Random convex polyhedron (hull of 8 to 24 random points), different for every object.
    Hull,
}

impl ShapeKind {
    /// The MOVi-A shape set (Kubric's: cube, cylinder, sphere).
    pub const MOVI_A: [ShapeKind; 3] = [ShapeKind::Cube, ShapeKind::Cylinder, ShapeKind::Sphere];
    /// The procedural stand-in for MOVi-B's eleven assets.
    pub const MOVI_B: [ShapeKind; 10] = [
        ShapeKind::Cube,
        ShapeKind::Cylinder,
        ShapeKind::Sphere,
        ShapeKind::Cone,
        ShapeKind::Torus,
        ShapeKind::Gear,
        ShapeKind::TorusKnot,
        ShapeKind::Sponge,
        ShapeKind::Mug,
        ShapeKind::Hull,
    ];

    /// Short snake_case name, as written in manifests.
    pub fn name(self) -> &'static str {
        match self {
            ShapeKind::Cube => "cube",
            ShapeKind::Cylinder => "cylinder",
            ShapeKind::Sphere => "sphere",
            ShapeKind::Cone => "cone",
            ShapeKind::Torus => "torus",
            ShapeKind::Gear => "gear",
            ShapeKind::TorusKnot => "torus_knot",
            ShapeKind::Sponge => "sponge",
            ShapeKind::Mug => "mug",
            ShapeKind::Hull => "convex_hull",
        }
    }

    /// One-line description of the unit shape and how it is built.
    pub fn description(self) -> &'static str {
        match self {
            ShapeKind::Cube => "cube of side 1 (rapier cuboid)",
            ShapeKind::Cylinder => "cylinder, radius 0.5, height 1, axis z: convex 32-sided prism",
            ShapeKind::Sphere => "sphere of radius 0.5 (rapier ball)",
            ShapeKind::Cone => {
                "cone, base radius 0.5, height 1, apex +z: convex 32-sided pyramid; centre of \
                 mass a quarter of the height above the base"
            }
            ShapeKind::Torus => {
                "torus, tube radius 0.15 on a circle of radius 0.35 (24 x 12 facets), union of 24 \
                 convex slabs"
            }
            ShapeKind::Gear => {
                "spur-gear-like prism, 10 teeth, root radius 0.4, tip radius 0.5, thickness 0.3: \
                 convex root prism plus 10 convex teeth"
            }
            ShapeKind::TorusKnot => {
                "trefoil (2,3) knot tube with 8-sided cross-section, union of 48 convex segments \
                 (hulls of consecutive cross-sections)"
            }
            ShapeKind::Sponge => "level-1 Menger sponge: 20 cubes of side 1/3",
            ShapeKind::Mug => {
                "mug: 16-sided cylindrical cup open at the top (wall 0.1, floor 0.1) and a \
                 semicircular handle; 25 convex parts; stands in for the teapot"
            }
            ShapeKind::Hull => {
                "convex hull of 8 to 24 random points (anisotropic), a different solid for every \
                 object; stands in for the irregular scanned assets"
            }
        }
    }
}

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

fn f64v(p: [f32; 3]) -> [f64; 3] {
    [p[0] as f64, p[1] as f64, p[2] as f64]
}

impl Part {
    fn translated(&self, d: [f32; 3]) -> Part {
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

    fn scaled(&self, s: f32) -> Part {
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
    fn collider(&self) -> Result<(Pose, SharedShape), SimError> {
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
    fn area(&self) -> f64 {
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
    fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> [f64; 3] {
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
    fn contains(&self, p: [f64; 3], eps: f64) -> bool {
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

fn unit_vector<R: Rng + ?Sized>(rng: &mut R) -> [f64; 3] {
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
            return random_hull(rng);
        }
        static CACHE: OnceLock<Vec<Result<Shape, String>>> = OnceLock::new();
        let cache = CACHE.get_or_init(|| {
            ShapeKind::MOVI_B
                .iter()
                .map(|&k| {
                    if k == ShapeKind::Hull {
                        Err("random".to_string())
                    } else {
                        build_fixed(k).map_err(|e| e.to_string())
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

fn polytopes(point_sets: Vec<Vec<Point>>) -> Result<Vec<Part>, SimError> {
    point_sets
        .iter()
        .map(|pts| Ok(Part::Polytope(Polytope::hull(pts)?)))
        .collect()
}

/// Scales and centres point sets so their joint bounding box is centred on the origin with its
/// longest side 1.
fn normalise(point_sets: &mut [Vec<Point>]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in point_sets.iter().flatten() {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let size = (0..3).map(|k| hi[k] - lo[k]).fold(0.0f32, f32::max);
    let mid = [
        0.5 * (lo[0] + hi[0]),
        0.5 * (lo[1] + hi[1]),
        0.5 * (lo[2] + hi[2]),
    ];
    for p in point_sets.iter_mut().flatten() {
        for k in 0..3 {
            p[k] = (p[k] - mid[k]) / size;
        }
    }
}

/// Sides of the polygonal cylinder and cone.
pub const ROUND_SEGMENTS: usize = 32;

fn build_fixed(kind: ShapeKind) -> Result<Shape, SimError> {
    let parts = match kind {
        ShapeKind::Cube => vec![Part::Cuboid {
            half: [0.5; 3],
            center: [0.0; 3],
        }],
        // rapier's exact cylinder starts rolling by itself when lying on its side, so cylinder
        // and cone are 32-sided polyhedra, like the meshes Kubric simulates. (More sides make
        // rapier's face-face contacts creep: 64-gons slide centimetres when standing still.)
        ShapeKind::Cylinder => polytopes(vec![mesh::cylinder(ROUND_SEGMENTS).vertices])?,
        ShapeKind::Sphere => vec![Part::Ball {
            radius: 0.5,
            center: [0.0; 3],
        }],
        ShapeKind::Cone => polytopes(vec![mesh::cone(ROUND_SEGMENTS).vertices])?,
        ShapeKind::Torus => {
            let (nj, nk) = (24, 12);
            polytopes(
                (0..nj)
                    .map(|j| mesh::torus_slab(0.35, 0.15, nj, nk, j))
                    .collect(),
            )?
        }
        ShapeKind::Gear => {
            let (teeth, root, half_h) = (10usize, 0.4f32, 0.15f32);
            let outline = mesh::gear_outline(teeth, root);
            let extrude = |pts: &[[f32; 2]]| -> Vec<Point> {
                pts.iter()
                    .flat_map(|p| [[p[0], p[1], -half_h], [p[0], p[1], half_h]])
                    .collect()
            };
            // Root polygon: the first and last outline vertex of every tooth.
            let root_poly: Vec<[f32; 2]> = outline.chunks(4).flat_map(|c| [c[0], c[3]]).collect();
            let mut sets = vec![extrude(&root_poly)];
            sets.extend(outline.chunks(4).map(extrude));
            polytopes(sets)?
        }
        ShapeKind::TorusKnot => polytopes(torus_knot_segments(48, 8, 0.42))?,
        ShapeKind::Sponge => {
            let mut parts = Vec::with_capacity(20);
            for i in -1i32..=1 {
                for j in -1i32..=1 {
                    for k in -1i32..=1 {
                        let zeros = [i, j, k].iter().filter(|&&c| c == 0).count();
                        if zeros <= 1 {
                            parts.push(Part::Cuboid {
                                half: [1.0 / 6.0; 3],
                                center: [i as f32 / 3.0, j as f32 / 3.0, k as f32 / 3.0],
                            });
                        }
                    }
                }
            }
            parts
        }
        ShapeKind::Mug => polytopes(mug_parts())?,
        ShapeKind::Hull => {
            return Err(SimError::Shape("random hulls are built per object".into()));
        }
    };
    Shape { kind, parts }.recentred()
}

/// Cross-sections of the trefoil knot tube, one 8-gon per sample of the curve, then the hulls
/// of consecutive cross-sections (normalised to the unit box).
fn torus_knot_segments(segments: usize, sides: usize, tube: f64) -> Vec<Vec<Point>> {
    let curve = |t: f64| {
        let r = 2.0 + (3.0 * t).cos();
        [r * (2.0 * t).cos(), r * (2.0 * t).sin(), (3.0 * t).sin()]
    };
    let centres: Vec<[f64; 3]> = (0..segments)
        .map(|i| curve(TAU * i as f64 / segments as f64))
        .collect();
    let tangent = |i: usize| {
        let a = centres[(i + segments - 1) % segments];
        let b = centres[(i + 1) % segments];
        normalize([b[0] - a[0], b[1] - a[1], b[2] - a[2]])
    };
    // Parallel-transported normal, with the closing twist spread evenly along the curve.
    let mut normals = Vec::with_capacity(segments + 1);
    let t0 = tangent(0);
    let mut n = normalize(cross(t0, [0.0, 0.0, 1.0]));
    normals.push(n);
    for i in 1..=segments {
        let t = tangent(i % segments);
        let proj = dot(n, t);
        n = normalize([n[0] - proj * t[0], n[1] - proj * t[1], n[2] - proj * t[2]]);
        normals.push(n);
    }
    let closing = {
        let (a, b) = (normals[0], normals[segments]);
        let t = t0;
        dot(cross(b, a), t).atan2(dot(a, b))
    };
    let rings: Vec<Vec<Point>> = (0..segments)
        .map(|i| {
            let t = tangent(i);
            let twist = closing * i as f64 / segments as f64;
            let n0 = normals[i];
            let b0 = cross(t, n0);
            let (c, s) = (twist.cos(), twist.sin());
            let nn = [
                c * n0[0] + s * b0[0],
                c * n0[1] + s * b0[1],
                c * n0[2] + s * b0[2],
            ];
            let bb = cross(t, nn);
            (0..sides)
                .map(|k| {
                    let a = TAU * k as f64 / sides as f64;
                    let (ca, sa) = (a.cos() * tube, a.sin() * tube);
                    let p = centres[i];
                    [
                        (p[0] + ca * nn[0] + sa * bb[0]) as f32,
                        (p[1] + ca * nn[1] + sa * bb[1]) as f32,
                        (p[2] + ca * nn[2] + sa * bb[2]) as f32,
                    ]
                })
                .collect()
        })
        .collect();
    let mut sets: Vec<Vec<Point>> = (0..segments)
        .map(|i| {
            let mut s = rings[i].clone();
            s.extend_from_slice(&rings[(i + 1) % segments]);
            s
        })
        .collect();
    normalise(&mut sets);
    sets
}

/// Point sets of the mug's convex parts (floor plug, 16 wall sectors, 8 handle segments),
/// normalised to the unit box.
fn mug_parts() -> Vec<Vec<Point>> {
    let sides = 16usize;
    let (r_in, r_out, floor) = (0.3f64, 0.4f64, 0.1f64);
    let (z0, z1) = (-0.5f64, 0.5f64);
    // Polygon vertices at half-step angles so that one wall face is centred on +x.
    let ang = |k: usize| (k as f64 + 0.5) * TAU / sides as f64;
    let at = |r: f64, a: f64, z: f64| [(r * a.cos()) as f32, (r * a.sin()) as f32, z as f32];
    let mut sets = Vec::new();
    let mut plug = Vec::new();
    for k in 0..sides {
        plug.push(at(r_in, ang(k), z0));
        plug.push(at(r_in, ang(k), z0 + floor));
    }
    sets.push(plug);
    for k in 0..sides {
        let (a, b) = (ang(k), ang(k + 1));
        let mut wall = Vec::new();
        for z in [z0, z1] {
            wall.push(at(r_in, a, z));
            wall.push(at(r_out, a, z));
            wall.push(at(r_out, b, z));
            wall.push(at(r_in, b, z));
        }
        sets.push(wall);
    }
    // Handle: semicircle in the xz plane whose end cross-sections lie in the outer face of the
    // wall sector centred on +x, so the handle touches the cup without overlapping it.
    let xc = r_out * (PI / sides as f64).cos();
    let (arc, tube, pieces, ring_sides) = (0.25f64, 0.05f64, 8usize, 8usize);
    let ring = |i: usize| -> Vec<Point> {
        let phi = -PI / 2.0 + PI * i as f64 / pieces as f64;
        let c = [xc + arc * phi.cos(), 0.0, arc * phi.sin()];
        let radial = [phi.cos(), 0.0, phi.sin()];
        (0..ring_sides)
            .map(|k| {
                let a = TAU * k as f64 / ring_sides as f64;
                let (u, v) = (tube * a.cos(), tube * a.sin());
                [
                    (c[0] + v * radial[0]) as f32,
                    u as f32,
                    (c[2] + v * radial[2]) as f32,
                ]
            })
            .collect()
    };
    for i in 0..pieces {
        let mut s = ring(i);
        s.extend(ring(i + 1));
        sets.push(s);
    }
    normalise(&mut sets);
    sets
}

fn random_hull<R: Rng + ?Sized>(rng: &mut R) -> Result<Shape, SimError> {
    loop {
        let n = rng.random_range(8..=24usize);
        let stretch = [
            rng.random_range(0.5..1.0f64),
            rng.random_range(0.5..1.0f64),
            rng.random_range(0.5..1.0f64),
        ];
        let mut pts: Vec<Point> = (0..n)
            .map(|_| {
                let d = unit_vector(rng);
                let r = rng.random_range(0.6..1.0f64);
                [
                    (d[0] * r * stretch[0]) as f32,
                    (d[1] * r * stretch[1]) as f32,
                    (d[2] * r * stretch[2]) as f32,
                ]
            })
            .collect();
        normalise(std::slice::from_mut(&mut pts));
        let Ok(poly) = Polytope::hull(&pts) else {
            continue;
        };
        // Reject slivers: the solid should fill a reasonable part of its box.
        if poly.mesh.volume() < 0.08 {
            continue;
        }
        return Shape {
            kind: ShapeKind::Hull,
            parts: vec![Part::Polytope(poly)],
        }
        .recentred();
    }
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize(a: [f64; 3]) -> [f64; 3] {
    let l = dot(a, a).sqrt();
    [a[0] / l, a[1] / l, a[2] / l]
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn rng() -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(5)
    }

    #[test]
    fn unit_volumes_match_closed_forms() {
        let mut r = rng();
        let mut vol = |k| {
            Shape::unit(k, &mut r)
                .unwrap()
                .volume_and_centroid()
                .unwrap()
                .0 as f64
        };
        let close = |got: f64, want: f64, what: &str| {
            assert!(
                (got - want).abs() < 1e-4 * want.max(1.0),
                "{what}: {got} vs {want}"
            );
        };
        close(vol(ShapeKind::Cube), 1.0, "cube");
        close(vol(ShapeKind::Sphere), PI / 6.0, "sphere");
        // Prism and pyramid over a regular n-gon of circumradius r: area n/2 sin(2 pi / n) r^2.
        let n = ROUND_SEGMENTS as f64;
        let polygon = 0.5 * n * 0.25 * (TAU / n).sin();
        close(vol(ShapeKind::Cylinder), polygon, "cylinder");
        close(vol(ShapeKind::Cone), polygon / 3.0, "cone");
        assert!((polygon - PI / 4.0).abs() < 7e-3 * PI / 4.0);
        close(vol(ShapeKind::Sponge), 20.0 / 27.0, "sponge");
        // The polyhedral torus equals the mesh primitive's volume (the slabs tile it).
        close(
            vol(ShapeKind::Torus),
            mesh::torus(0.35, 0.15, 24, 12).volume(),
            "torus",
        );
        close(
            vol(ShapeKind::Gear),
            mesh::gear_prism(10, 0.4, 0.3).volume(),
            "gear",
        );
    }

    #[test]
    fn shapes_are_centred_on_their_centre_of_mass_and_fit_the_unit_box() {
        let mut r = rng();
        for &kind in &ShapeKind::MOVI_B {
            let s = Shape::unit(kind, &mut r).unwrap();
            let (v, c) = s.volume_and_centroid().unwrap();
            assert!(v > 0.05, "{kind:?} volume {v}");
            assert!(c.iter().all(|x| x.abs() < 1e-5), "{kind:?} com {c:?}");
            let (pose, shape) = s.collider().unwrap();
            let aabb = shape.compute_aabb(&pose);
            let size = aabb.maxs - aabb.mins;
            let longest = size.x.max(size.y).max(size.z);
            assert!((longest - 1.0).abs() < 0.02, "{kind:?} box {size:?}");
        }
    }

    #[test]
    fn compound_parts_do_not_overlap() {
        // The volume of a union equals the sum of part volumes only if they do not overlap:
        // estimate the union volume by Monte Carlo inside-tests and compare.
        let mut r = rng();
        for kind in [
            ShapeKind::Torus,
            ShapeKind::Gear,
            ShapeKind::TorusKnot,
            ShapeKind::Sponge,
            ShapeKind::Mug,
        ] {
            let s = Shape::unit(kind, &mut r).unwrap();
            let (v, _) = s.volume_and_centroid().unwrap();
            let n = 200_000;
            let mut inside = 0usize;
            let mut multiple = 0usize;
            for _ in 0..n {
                let p = [
                    r.random_range(-0.6..0.6),
                    r.random_range(-0.6..0.6),
                    r.random_range(-0.6..0.6),
                ];
                let c = s.parts.iter().filter(|q| q.contains(p, 0.0)).count();
                inside += (c > 0) as usize;
                multiple += (c > 1) as usize;
            }
            let union = inside as f64 / n as f64 * 1.2f64.powi(3);
            assert_eq!(multiple, 0, "{kind:?}: parts overlap");
            assert!(
                (union - v as f64).abs() < 0.03 * v as f64 + 0.002,
                "{kind:?}: union {union} vs sum of parts {v}"
            );
        }
    }

    #[test]
    fn surface_samples_lie_on_the_collider_surface() {
        let mut r = rng();
        for &kind in &ShapeKind::MOVI_B {
            let s = Shape::unit(kind, &mut r).unwrap().scaled(1.3);
            let (pose, shape) = s.collider().unwrap();
            let pts = s.sample_surface(1024, &mut r).unwrap();
            assert_eq!(pts.len(), 1024);
            for p in &pts {
                let q = Vector::new(p[0], p[1], p[2]);
                let proj = shape.project_point(&pose, q, false);
                let d = (proj.point - q).length();
                assert!(d < 2e-4, "{kind:?}: {p:?} is {d} m from the surface");
                assert!(!proj.is_inside || d < 2e-4);
            }
        }
    }

    #[test]
    fn sampling_is_seeded() {
        let s = Shape::unit(ShapeKind::Mug, &mut rng()).unwrap();
        let a = s
            .sample_surface(256, &mut ChaCha8Rng::seed_from_u64(1))
            .unwrap();
        let b = s
            .sample_surface(256, &mut ChaCha8Rng::seed_from_u64(1))
            .unwrap();
        let c = s
            .sample_surface(256, &mut ChaCha8Rng::seed_from_u64(2))
            .unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
        let h1 = Shape::unit(ShapeKind::Hull, &mut ChaCha8Rng::seed_from_u64(9)).unwrap();
        let h2 = Shape::unit(ShapeKind::Hull, &mut ChaCha8Rng::seed_from_u64(9)).unwrap();
        let (v1, _) = h1.volume_and_centroid().unwrap();
        let (v2, _) = h2.volume_and_centroid().unwrap();
        assert_eq!(v1, v2);
    }
}
