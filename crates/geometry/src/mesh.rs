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

use std::collections::HashMap;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::{GeometryError, Point};

/// A triangle mesh: vertices in metres and faces as counter-clockwise (outward) index triples.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct TriMesh {
    /// Vertex positions, metres.
    pub vertices: Vec<Point>,
    /// Triangles as indices into `vertices`, counter-clockwise seen from outside.
    pub faces: Vec<[u32; 3]>,
}

fn to64(p: Point) -> [f64; 3] {
    [p[0] as f64, p[1] as f64, p[2] as f64]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
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

    fn corners(&self, face: &[u32; 3]) -> [[f64; 3]; 3] {
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

/// `n` points drawn uniformly (area-weighted) from the surface of `mesh`, deterministic for a
/// given `seed` (ChaCha8). Faces are chosen with probability proportional to their area, then a
/// point uniformly inside the chosen triangle. A mesh without area yields copies of its first
/// vertex; a mesh without vertices yields an empty vector.
pub fn sample_surface(mesh: &TriMesh, n: usize, seed: u64) -> Vec<Point> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    sample_surface_with(mesh, n, &mut rng)
}

/// [`sample_surface`] drawing from a caller's random number generator.
pub fn sample_surface_with<R: Rng + ?Sized>(mesh: &TriMesh, n: usize, rng: &mut R) -> Vec<Point> {
    let Some(&first) = mesh.vertices.first() else {
        return Vec::new();
    };
    let mut cumulative = Vec::with_capacity(mesh.faces.len());
    let mut total = 0.0f64;
    for a in mesh.face_areas() {
        total += a;
        cumulative.push(total);
    }
    if total.is_nan() || total <= 0.0 {
        return vec![first; n];
    }
    (0..n)
        .map(|_| {
            let u = rng.random::<f64>() * total;
            let i = cumulative
                .partition_point(|&c| c <= u)
                .min(cumulative.len() - 1);
            let [a, b, c] = mesh.corners(&mesh.faces[i]);
            let r1 = rng.random::<f64>().sqrt();
            let r2 = rng.random::<f64>();
            let (wa, wb, wc) = (1.0 - r1, r1 * (1.0 - r2), r1 * r2);
            [
                (wa * a[0] + wb * b[0] + wc * c[0]) as f32,
                (wa * a[1] + wb * b[1] + wc * c[1]) as f32,
                (wa * a[2] + wb * b[2] + wc * c[2]) as f32,
            ]
        })
        .collect()
}

/// Unit cube spanning `[-0.5, 0.5]^3`: 8 vertices, 12 triangles. Volume 1, area 6.
pub fn cube() -> TriMesh {
    let mut vertices = Vec::with_capacity(8);
    for i in 0..8u32 {
        vertices.push([
            if i & 1 == 0 { -0.5 } else { 0.5 },
            if i & 2 == 0 { -0.5 } else { 0.5 },
            if i & 4 == 0 { -0.5 } else { 0.5 },
        ]);
    }
    // Quads listed counter-clockwise seen from outside.
    let quads: [[u32; 4]; 6] = [
        [0, 2, 3, 1], // z = -0.5
        [4, 5, 7, 6], // z = +0.5
        [0, 1, 5, 4], // y = -0.5
        [2, 6, 7, 3], // y = +0.5
        [0, 4, 6, 2], // x = -0.5
        [1, 3, 7, 5], // x = +0.5
    ];
    let faces = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    TriMesh { vertices, faces }
}

/// Closed prism over a polygon given counter-clockwise in the xy plane (star-shaped about the
/// origin, so the caps can be fanned from a centre vertex), spanning `z` in `[z0, z1]`.
pub fn prism(outline: &[[f32; 2]], z0: f32, z1: f32) -> TriMesh {
    let n = outline.len() as u32;
    let mut vertices = Vec::with_capacity(2 * outline.len() + 2);
    for p in outline {
        vertices.push([p[0], p[1], z0]);
    }
    for p in outline {
        vertices.push([p[0], p[1], z1]);
    }
    let (cb, ct) = (2 * n, 2 * n + 1);
    vertices.push([0.0, 0.0, z0]);
    vertices.push([0.0, 0.0, z1]);
    let mut faces = Vec::with_capacity(4 * outline.len());
    for i in 0..n {
        let j = (i + 1) % n;
        faces.push([i, j, n + j]);
        faces.push([i, n + j, n + i]);
        faces.push([cb, j, i]);
        faces.push([ct, n + i, n + j]);
    }
    TriMesh { vertices, faces }
}

/// Regular polygon of `segments` vertices with the given radius, counter-clockwise, first
/// vertex on the +x axis.
fn circle(segments: usize, radius: f32) -> Vec<[f32; 2]> {
    (0..segments)
        .map(|i| {
            let t = std::f64::consts::TAU * i as f64 / segments as f64;
            [
                (radius as f64 * t.cos()) as f32,
                (radius as f64 * t.sin()) as f32,
            ]
        })
        .collect()
}

/// Unit cylinder (radius 0.5, z in `[-0.5, 0.5]`) approximated by a prism over a regular
/// polygon with `segments` sides (at least 3).
pub fn cylinder(segments: usize) -> TriMesh {
    prism(&circle(segments.max(3), 0.5), -0.5, 0.5)
}

/// Unit cone: base disc of radius 0.5 at `z = -0.5`, apex at `(0, 0, 0.5)`; the base is a
/// regular polygon with `segments` sides (at least 3). Its centre of mass is at `z = -0.25`.
pub fn cone(segments: usize) -> TriMesh {
    let ring = circle(segments.max(3), 0.5);
    let n = ring.len() as u32;
    let mut vertices: Vec<Point> = ring.iter().map(|p| [p[0], p[1], -0.5]).collect();
    vertices.push([0.0, 0.0, 0.5]);
    vertices.push([0.0, 0.0, -0.5]);
    let (apex, base) = (n, n + 1);
    let mut faces = Vec::with_capacity(2 * ring.len());
    for i in 0..n {
        let j = (i + 1) % n;
        faces.push([i, j, apex]);
        faces.push([base, j, i]);
    }
    TriMesh { vertices, faces }
}

/// Unit sphere (radius 0.5) as an icosphere: an icosahedron subdivided `subdivisions` times,
/// vertices projected onto the sphere (20 * 4^subdivisions triangles).
pub fn sphere(subdivisions: u32) -> TriMesh {
    let t = (1.0 + 5.0f64.sqrt()) / 2.0;
    let raw = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ];
    let mut verts: Vec<[f64; 3]> = raw
        .iter()
        .map(|v| {
            let l = norm(*v);
            [v[0] / l, v[1] / l, v[2] / l]
        })
        .collect();
    let mut faces: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdivisions {
        let mut cache: HashMap<(u32, u32), u32> = HashMap::new();
        let mut midpoint = |a: u32, b: u32, verts: &mut Vec<[f64; 3]>| -> u32 {
            let key = (a.min(b), a.max(b));
            *cache.entry(key).or_insert_with(|| {
                let (p, q) = (verts[a as usize], verts[b as usize]);
                let m = [p[0] + q[0], p[1] + q[1], p[2] + q[2]];
                let l = norm(m);
                verts.push([m[0] / l, m[1] / l, m[2] / l]);
                (verts.len() - 1) as u32
            })
        };
        let mut next = Vec::with_capacity(faces.len() * 4);
        for f in &faces {
            let ab = midpoint(f[0], f[1], &mut verts);
            let bc = midpoint(f[1], f[2], &mut verts);
            let ca = midpoint(f[2], f[0], &mut verts);
            next.push([f[0], ab, ca]);
            next.push([f[1], bc, ab]);
            next.push([f[2], ca, bc]);
            next.push([ab, bc, ca]);
        }
        faces = next;
    }
    TriMesh {
        vertices: verts
            .iter()
            .map(|v| {
                [
                    (0.5 * v[0]) as f32,
                    (0.5 * v[1]) as f32,
                    (0.5 * v[2]) as f32,
                ]
            })
            .collect(),
        faces,
    }
}

/// Vertex `k` of ring `j` of a polyhedral torus about the z axis.
fn torus_vertex(major: f64, minor: f64, theta: f64, phi: f64) -> Point {
    let rho = major + minor * phi.cos();
    [
        (rho * theta.cos()) as f32,
        (rho * theta.sin()) as f32,
        (minor * phi.sin()) as f32,
    ]
}

/// Polyhedral torus about the z axis: tube centre circle of radius `major_radius`, tube radius
/// `minor_radius`, `major_segments` x `minor_segments` quads. The unit torus of the MOVi-like
/// shape set uses 0.35 and 0.15 (outer radius 0.5). Each slab between two consecutive rings is a
/// convex polyhedron, so the torus is an exact union of `major_segments` convex parts (see
/// [`torus_slab`]).
pub fn torus(
    major_radius: f32,
    minor_radius: f32,
    major_segments: usize,
    minor_segments: usize,
) -> TriMesh {
    let (nj, nk) = (major_segments.max(3), minor_segments.max(3));
    let (major, minor) = (major_radius as f64, minor_radius as f64);
    let mut vertices = Vec::with_capacity(nj * nk);
    for j in 0..nj {
        let theta = std::f64::consts::TAU * j as f64 / nj as f64;
        for k in 0..nk {
            let phi = std::f64::consts::TAU * k as f64 / nk as f64;
            vertices.push(torus_vertex(major, minor, theta, phi));
        }
    }
    let idx = |j: usize, k: usize| ((j % nj) * nk + (k % nk)) as u32;
    let mut faces = Vec::with_capacity(2 * nj * nk);
    for j in 0..nj {
        for k in 0..nk {
            let (a, b, c, d) = (idx(j, k), idx(j + 1, k), idx(j + 1, k + 1), idx(j, k + 1));
            faces.push([a, b, c]);
            faces.push([a, c, d]);
        }
    }
    TriMesh { vertices, faces }
}

/// Vertices of slab `j` of [`torus`] (rings `j` and `j + 1`): a convex polyhedron whose hull is
/// the slab, for building the torus as a compound of convex parts.
pub fn torus_slab(
    major_radius: f32,
    minor_radius: f32,
    major_segments: usize,
    minor_segments: usize,
    j: usize,
) -> Vec<Point> {
    let (nj, nk) = (major_segments.max(3), minor_segments.max(3));
    let (major, minor) = (major_radius as f64, minor_radius as f64);
    let mut out = Vec::with_capacity(2 * nk);
    for jj in [j % nj, (j + 1) % nj] {
        let theta = std::f64::consts::TAU * jj as f64 / nj as f64;
        for k in 0..nk {
            let phi = std::f64::consts::TAU * k as f64 / nk as f64;
            out.push(torus_vertex(major, minor, theta, phi));
        }
    }
    out
}

/// Outline of a spur-gear-like polygon, counter-clockwise: `teeth` trapezoidal teeth reaching
/// radius 0.5 on a regular root polygon of `2 * teeth` vertices at `root_radius`. Each tooth is
/// the quad `[root_a, tip_a, tip_b, root_b]`, which lies outside the root polygon and shares the
/// root edge `root_a -> root_b`: the gear is the exact union of the convex root prism and one
/// convex prism per tooth.
pub fn gear_outline(teeth: usize, root_radius: f32) -> Vec<[f32; 2]> {
    let n = teeth.max(3);
    let (r, big) = (root_radius as f64, 0.5f64);
    let step = std::f64::consts::TAU / (2 * n) as f64;
    let mut out = Vec::with_capacity(4 * n);
    for i in 0..n {
        // The tooth occupies the root edge from angle a0 to a1; the tip is narrower.
        let a0 = (2 * i) as f64 * step;
        let a1 = a0 + step;
        let mid = 0.5 * (a0 + a1);
        let half_tip = 0.3 * step;
        out.push([(r * a0.cos()) as f32, (r * a0.sin()) as f32]);
        out.push([
            (big * (mid - half_tip).cos()) as f32,
            (big * (mid - half_tip).sin()) as f32,
        ]);
        out.push([
            (big * (mid + half_tip).cos()) as f32,
            (big * (mid + half_tip).sin()) as f32,
        ]);
        out.push([(r * a1.cos()) as f32, (r * a1.sin()) as f32]);
    }
    out
}

/// Gear-like prism: [`gear_outline`] extruded over `z` in `[-height / 2, height / 2]`.
pub fn gear_prism(teeth: usize, root_radius: f32, height: f32) -> TriMesh {
    prism(
        &gear_outline(teeth, root_radius),
        -0.5 * height,
        0.5 * height,
    )
}

/// Convex hull of a point set (metres) as a closed, outward-oriented triangle mesh whose
/// vertices are a subset of the input (3D quickhull in `f64`). Points within a relative
/// tolerance of a hull face are treated as lying on it, so coplanar faces come out triangulated
/// and interior or coplanar points are dropped. Errors on fewer than four points, non-finite
/// coordinates, or a flat (coplanar, collinear or coincident) set.
pub fn convex_hull(points: &[Point]) -> Result<TriMesh, GeometryError> {
    if points.len() < 4 {
        return Err(GeometryError::Invalid(format!(
            "convex hull needs at least 4 points, got {}",
            points.len()
        )));
    }
    if points.iter().flatten().any(|c| !c.is_finite()) {
        return Err(GeometryError::NonFinite("convex hull points"));
    }
    Quickhull::new(points)?.run()
}

struct HullFace {
    v: [u32; 3],
    normal: [f64; 3],
    offset: f64,
    outside: Vec<u32>,
    alive: bool,
}

struct Quickhull {
    pts: Vec<[f64; 3]>,
    faces: Vec<HullFace>,
    edges: HashMap<(u32, u32), usize>,
    eps: f64,
}

impl Quickhull {
    fn new(points: &[Point]) -> Result<Self, GeometryError> {
        let pts: Vec<[f64; 3]> = points.iter().map(|&p| to64(p)).collect();
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        let mut extent = 0.0f64;
        for p in &pts {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
                extent = extent.max(p[k].abs());
            }
        }
        let diag = norm(sub(hi, lo));
        // Points closer than this to a face plane count as on it.
        let eps = 1e-9 * extent.max(diag).max(1e-30) * 3.0;
        if diag <= eps {
            return Err(GeometryError::Invalid(
                "convex hull of coincident points".into(),
            ));
        }
        Ok(Self {
            pts,
            faces: Vec::new(),
            edges: HashMap::new(),
            eps,
        })
    }

    fn plane(&self, v: [u32; 3]) -> ([f64; 3], f64) {
        let [a, b, c] = v.map(|i| self.pts[i as usize]);
        let n = cross(sub(b, a), sub(c, a));
        let l = norm(n);
        let n = if l > 0.0 {
            [n[0] / l, n[1] / l, n[2] / l]
        } else {
            [0.0; 3]
        };
        (n, dot(n, a))
    }

    fn dist(&self, f: usize, p: u32) -> f64 {
        let face = &self.faces[f];
        dot(face.normal, self.pts[p as usize]) - face.offset
    }

    fn add_face(&mut self, v: [u32; 3]) -> usize {
        let (normal, offset) = self.plane(v);
        let id = self.faces.len();
        self.faces.push(HullFace {
            v,
            normal,
            offset,
            outside: Vec::new(),
            alive: true,
        });
        for k in 0..3 {
            self.edges.insert((v[k], v[(k + 1) % 3]), id);
        }
        id
    }

    fn initial_simplex(&self) -> Result<[u32; 4], GeometryError> {
        let n = self.pts.len() as u32;
        // Extreme points along the axes; the farthest pair among them starts the simplex.
        let mut extremes = Vec::with_capacity(6);
        for k in 0..3 {
            let (mut imin, mut imax) = (0u32, 0u32);
            for i in 0..n {
                if self.pts[i as usize][k] < self.pts[imin as usize][k] {
                    imin = i;
                }
                if self.pts[i as usize][k] > self.pts[imax as usize][k] {
                    imax = i;
                }
            }
            extremes.push(imin);
            extremes.push(imax);
        }
        let (mut a, mut b, mut best) = (0u32, 0u32, -1.0f64);
        for &i in &extremes {
            for &j in &extremes {
                let d = norm(sub(self.pts[i as usize], self.pts[j as usize]));
                if d > best {
                    (a, b, best) = (i, j, d);
                }
            }
        }
        let pa = self.pts[a as usize];
        let ab = sub(self.pts[b as usize], pa);
        let lab = norm(ab);
        let (mut c, mut best) = (0u32, -1.0f64);
        for i in 0..n {
            let d = norm(cross(ab, sub(self.pts[i as usize], pa))) / lab;
            if d > best {
                (c, best) = (i, d);
            }
        }
        if best <= self.eps {
            return Err(GeometryError::Invalid(
                "convex hull of collinear points".into(),
            ));
        }
        let nrm = cross(ab, sub(self.pts[c as usize], pa));
        let lnrm = norm(nrm);
        let (mut d, mut best) = (0u32, -1.0f64);
        for i in 0..n {
            let h = (dot(nrm, sub(self.pts[i as usize], pa)) / lnrm).abs();
            if h > best {
                (d, best) = (i, h);
            }
        }
        if best <= self.eps {
            return Err(GeometryError::Invalid(
                "convex hull of coplanar points".into(),
            ));
        }
        Ok([a, b, c, d])
    }

    fn run(mut self) -> Result<TriMesh, GeometryError> {
        let [a, b, c, d] = self.initial_simplex()?;
        // Orient the base so the fourth point lies behind it.
        let (normal, offset) = self.plane([a, b, c]);
        let (a, b) = if dot(normal, self.pts[d as usize]) - offset > 0.0 {
            (b, a)
        } else {
            (a, b)
        };
        let initial = [
            self.add_face([a, b, c]),
            self.add_face([a, d, b]),
            self.add_face([b, d, c]),
            self.add_face([c, d, a]),
        ];
        let simplex = [a, b, c, d];
        for p in 0..self.pts.len() as u32 {
            if simplex.contains(&p) {
                continue;
            }
            if let Some(&f) = initial.iter().find(|&&f| self.dist(f, p) > self.eps) {
                self.faces[f].outside.push(p);
            }
        }
        let mut cursor = 0usize;
        loop {
            while cursor < self.faces.len()
                && (!self.faces[cursor].alive || self.faces[cursor].outside.is_empty())
            {
                cursor += 1;
            }
            if cursor >= self.faces.len() {
                break;
            }
            let start = cursor;
            let eye = *self.faces[start]
                .outside
                .iter()
                .max_by(|&&p, &&q| self.dist(start, p).total_cmp(&self.dist(start, q)))
                .ok_or(GeometryError::Numerical("empty outside set"))?;
            // Faces visible from the eye, by flood fill from the starting face.
            let mut visible = vec![start];
            let mut is_visible: HashMap<usize, bool> = HashMap::from([(start, true)]);
            let mut i = 0;
            while i < visible.len() {
                let f = visible[i];
                i += 1;
                let v = self.faces[f].v;
                for k in 0..3 {
                    let Some(&g) = self.edges.get(&(v[(k + 1) % 3], v[k])) else {
                        return Err(GeometryError::Numerical("convex hull lost an edge"));
                    };
                    if let std::collections::hash_map::Entry::Vacant(e) = is_visible.entry(g) {
                        let vis = self.dist(g, eye) > self.eps;
                        e.insert(vis);
                        if vis {
                            visible.push(g);
                        }
                    }
                }
            }
            // Horizon: edges of visible faces whose neighbour is not visible.
            let mut horizon = Vec::new();
            for &f in &visible {
                let v = self.faces[f].v;
                for k in 0..3 {
                    let (p, q) = (v[k], v[(k + 1) % 3]);
                    let g = self.edges[&(q, p)];
                    if !is_visible[&g] {
                        horizon.push((p, q));
                    }
                }
            }
            let mut orphans = Vec::new();
            for &f in &visible {
                self.faces[f].alive = false;
                orphans.append(&mut self.faces[f].outside);
                let v = self.faces[f].v;
                for k in 0..3 {
                    let key = (v[k], v[(k + 1) % 3]);
                    if self.edges.get(&key) == Some(&f) {
                        self.edges.remove(&key);
                    }
                }
            }
            let new_faces: Vec<usize> = horizon
                .iter()
                .map(|&(p, q)| self.add_face([p, q, eye]))
                .collect();
            for p in orphans {
                if p == eye {
                    continue;
                }
                if let Some(&f) = new_faces.iter().find(|&&f| self.dist(f, p) > self.eps) {
                    self.faces[f].outside.push(p);
                }
            }
            cursor = 0;
        }
        // Keep the vertices used by live faces, in input order.
        let mut remap = vec![u32::MAX; self.pts.len()];
        let live: Vec<[u32; 3]> = self.faces.iter().filter(|f| f.alive).map(|f| f.v).collect();
        for f in &live {
            for &i in f {
                remap[i as usize] = 0;
            }
        }
        let mut vertices = Vec::new();
        for (i, r) in remap.iter_mut().enumerate() {
            if *r == 0 {
                *r = vertices.len() as u32;
                let p = self.pts[i];
                vertices.push([p[0] as f32, p[1] as f32, p[2] as f32]);
            }
        }
        let faces = live.iter().map(|f| f.map(|i| remap[i as usize])).collect();
        Ok(TriMesh { vertices, faces })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// Signed distance from `p` to the nearest face plane, max over faces: <= 0 inside a
    /// convex mesh.
    fn convex_signed_distance(mesh: &TriMesh, p: Point) -> f64 {
        mesh.faces
            .iter()
            .map(|f| {
                let [a, b, c] = mesh.corners(f);
                let n = cross(sub(b, a), sub(c, a));
                let l = norm(n);
                dot(n, sub(to64(p), a)) / l
            })
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// Distance from `p` to triangle `abc`.
    fn point_triangle_distance(p: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
        let n = cross(sub(b, a), sub(c, a));
        let ln = norm(n);
        let n = [n[0] / ln, n[1] / ln, n[2] / ln];
        let h = dot(n, sub(p, a));
        let q = [p[0] - h * n[0], p[1] - h * n[1], p[2] - h * n[2]];
        let inside = [(a, b), (b, c), (c, a)]
            .iter()
            .all(|&(u, v)| dot(cross(sub(v, u), sub(q, u)), n) >= -1e-12);
        if inside {
            return h.abs();
        }
        let seg = |u: [f64; 3], v: [f64; 3]| {
            let d = sub(v, u);
            let t = (dot(sub(p, u), d) / dot(d, d)).clamp(0.0, 1.0);
            norm(sub(p, [u[0] + t * d[0], u[1] + t * d[1], u[2] + t * d[2]]))
        };
        seg(a, b).min(seg(b, c)).min(seg(c, a))
    }

    fn distance_to_mesh(mesh: &TriMesh, p: Point) -> f64 {
        mesh.faces
            .iter()
            .map(|f| {
                let [a, b, c] = mesh.corners(f);
                point_triangle_distance(to64(p), a, b, c)
            })
            .fold(f64::INFINITY, f64::min)
    }

    fn assert_close(got: f64, want: f64, rel: f64, what: &str) {
        assert!(
            (got - want).abs() <= rel * want.abs(),
            "{what}: got {got}, want {want} (rel tol {rel})"
        );
    }

    #[test]
    fn cube_volume_area_centroid() {
        let m = cube();
        assert!(m.is_closed());
        assert_close(m.volume(), 1.0, 1e-12, "cube volume");
        assert_close(m.area(), 6.0, 1e-12, "cube area");
        let c = m.centroid();
        assert!(c.iter().all(|x| x.abs() < 1e-12), "{c:?}");
        assert_eq!(m.aabb(), ([-0.5; 3], [0.5; 3]));
    }

    #[test]
    fn primitive_volumes_match_closed_forms() {
        // Polygonal approximations: compare with the exact volume of the same polygonal solid
        // and with the smooth limit.
        let n = 64;
        let poly_area = |r: f64| 0.5 * n as f64 * r * r * (2.0 * PI / n as f64).sin();
        let cyl = cylinder(n);
        assert!(cyl.is_closed());
        assert_close(cyl.volume(), poly_area(0.5), 1e-6, "cylinder");
        assert_close(cyl.volume(), PI * 0.25, 2e-3, "cylinder vs smooth");
        let con = cone(n);
        assert!(con.is_closed());
        assert_close(con.volume(), poly_area(0.5) / 3.0, 1e-6, "cone");
        assert!(
            (con.centroid()[2] + 0.25).abs() < 1e-6,
            "cone centre of mass"
        );
        let sph = sphere(4);
        assert!(sph.is_closed());
        assert_close(sph.volume(), 4.0 / 3.0 * PI * 0.125, 5e-3, "sphere");
        assert_close(sph.area(), PI, 5e-3, "sphere area");
        let tor = torus(0.35, 0.15, 96, 48);
        assert!(tor.is_closed());
        // Pappus: V = 2 pi R * pi r^2, A = 2 pi R * 2 pi r.
        assert_close(
            tor.volume(),
            2.0 * PI * 0.35 * PI * 0.15 * 0.15,
            5e-3,
            "torus",
        );
        assert_close(tor.area(), 4.0 * PI * PI * 0.35 * 0.15, 5e-3, "torus area");
        let c = tor.centroid();
        assert!(c.iter().all(|x| x.abs() < 1e-6), "{c:?}");
        let (lo, hi) = tor.aabb();
        assert!((hi[0] - 0.5).abs() < 1e-6 && (lo[0] + 0.5).abs() < 1e-6);
    }

    #[test]
    fn gear_is_root_prism_plus_teeth() {
        let (teeth, root, h) = (12, 0.4f32, 0.3f32);
        let gear = gear_prism(teeth, root, h);
        assert!(gear.is_closed());
        let outline = gear_outline(teeth, root);
        // Shoelace area of the outline times the height.
        let mut area = 0.0f64;
        for i in 0..outline.len() {
            let (p, q) = (outline[i], outline[(i + 1) % outline.len()]);
            area += 0.5 * (p[0] as f64 * q[1] as f64 - q[0] as f64 * p[1] as f64);
        }
        assert_close(gear.volume(), area * h as f64, 1e-6, "gear volume");
        // Root polygon (2 * teeth sides) plus teeth: the union is at least the root prism.
        let root_area = 0.5
            * (2 * teeth) as f64
            * (root as f64).powi(2)
            * (2.0 * PI / (2 * teeth) as f64).sin();
        assert!(area > root_area);
        let (lo, hi) = gear.aabb();
        assert!(hi[0] <= 0.5 + 1e-6 && lo[2] == -0.15 && hi[2] == 0.15);
    }

    #[test]
    fn torus_slabs_are_convex_and_tile_the_torus() {
        let (nj, nk) = (24, 12);
        let tor = torus(0.35, 0.15, nj, nk);
        let mut total = 0.0;
        for j in 0..nj {
            let slab = convex_hull(&torus_slab(0.35, 0.15, nj, nk, j)).unwrap();
            assert_eq!(slab.vertices.len(), 2 * nk, "every ring vertex is extreme");
            total += slab.volume();
        }
        assert_close(total, tor.volume(), 1e-5, "slab volumes sum to the torus");
    }

    #[test]
    fn samples_lie_on_surface_and_are_deterministic() {
        for (name, mesh) in [
            ("cube", cube()),
            ("cone", cone(16)),
            ("torus", torus(0.35, 0.15, 16, 8)),
            ("gear", gear_prism(8, 0.4, 0.3)),
        ] {
            let pts = sample_surface(&mesh, 500, 7);
            assert_eq!(pts.len(), 500);
            for p in &pts {
                let d = distance_to_mesh(&mesh, *p);
                assert!(d < 1e-6, "{name}: sample {p:?} is {d} m off the surface");
            }
            assert_eq!(pts, sample_surface(&mesh, 500, 7), "{name}: same seed");
            assert_ne!(pts, sample_surface(&mesh, 500, 8), "{name}: other seed");
        }
        assert!(sample_surface(&cube(), 0, 1).is_empty());
        assert!(sample_surface(&TriMesh::default(), 5, 1).is_empty());
    }

    #[test]
    fn samples_are_area_weighted() {
        // A box 4 x 1 x 1: the two 4 x 1 faces normal to y hold 4 / 18 of the area each.
        let mesh = cube().scaled([4.0, 1.0, 1.0]);
        let pts = sample_surface(&mesh, 20_000, 3);
        let on_plus_y = pts.iter().filter(|p| (p[1] - 0.5).abs() < 1e-6).count();
        let frac = on_plus_y as f64 / pts.len() as f64;
        assert!((frac - 4.0 / 18.0).abs() < 0.015, "fraction {frac}");
        let on_plus_x = pts.iter().filter(|p| (p[0] - 2.0).abs() < 1e-6).count();
        let frac = on_plus_x as f64 / pts.len() as f64;
        assert!((frac - 1.0 / 18.0).abs() < 0.01, "fraction {frac}");
    }

    #[test]
    fn transforms_keep_orientation() {
        let m = cube().scaled([2.0, 3.0, 0.5]).translated([1.0, -2.0, 5.0]);
        assert_close(m.volume(), 3.0, 1e-9, "scaled volume");
        let c = m.centroid();
        assert!(
            (c[0] - 1.0).abs() < 1e-9 && (c[1] + 2.0).abs() < 1e-9 && (c[2] - 5.0).abs() < 1e-9
        );
        let mirrored = cube().scaled([-1.0, 1.0, 1.0]);
        assert_close(mirrored.volume(), 1.0, 1e-12, "mirrored volume");
        let both = TriMesh::merged(&[cube(), cube().translated([3.0, 0.0, 0.0])]);
        assert_close(both.volume(), 2.0, 1e-12, "merged volume");
        assert!(both.is_closed());
        assert!(TriMesh::new(vec![[0.0; 3]], vec![[0, 0, 1]]).is_err());
        assert!(TriMesh::new(vec![[f32::NAN, 0.0, 0.0]], vec![]).is_err());
    }

    #[test]
    fn hull_of_cube_points_with_interior_and_coplanar_points() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut pts = cube().vertices;
        for _ in 0..200 {
            pts.push([
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
            ]);
        }
        // Points on faces and edges of the cube.
        for _ in 0..50 {
            let (u, v) = (rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5));
            pts.push([u, v, 0.5]);
            pts.push([0.5, u, v]);
            pts.push([u, -0.5, -0.5]);
        }
        let hull = convex_hull(&pts).unwrap();
        assert!(hull.is_closed());
        assert_close(hull.volume(), 1.0, 1e-6, "hull volume");
        assert_close(hull.area(), 6.0, 1e-6, "hull area");
        for p in &pts {
            assert!(convex_signed_distance(&hull, *p) < 1e-6);
        }
    }

    #[test]
    fn hull_of_random_points_contains_them_and_is_convex() {
        for seed in 0..20u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let n = 4 + (seed as usize * 7) % 60;
            let pts: Vec<Point> = (0..n)
                .map(|_| {
                    [
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-0.3..0.3),
                        rng.random_range(-2.0..2.0),
                    ]
                })
                .collect();
            let hull = convex_hull(&pts).unwrap();
            assert!(hull.is_closed(), "seed {seed}");
            assert!(hull.volume() > 0.0);
            let (v, f) = (hull.vertices.len() as i64, hull.faces.len() as i64);
            assert_eq!(v - f * 3 / 2 + f, 2, "Euler characteristic, seed {seed}");
            for p in &pts {
                assert!(convex_signed_distance(&hull, *p) < 1e-5, "seed {seed}");
            }
            // Convexity: every hull vertex is behind or on every face plane.
            for p in &hull.vertices {
                assert!(convex_signed_distance(&hull, *p) < 1e-5);
            }
            // The hull of the hull vertices is the same solid.
            let again = convex_hull(&hull.vertices).unwrap();
            assert_close(again.volume(), hull.volume(), 1e-6, "idempotent");
        }
    }

    #[test]
    fn hull_of_sphere_points_approaches_sphere() {
        let pts = sphere(3).vertices;
        let hull = convex_hull(&pts).unwrap();
        assert_eq!(hull.vertices.len(), pts.len());
        assert_close(hull.volume(), sphere(3).volume(), 1e-6, "icosphere hull");
    }

    #[test]
    fn hull_rejects_degenerate_sets() {
        assert!(convex_hull(&[[0.0; 3]; 3]).is_err());
        assert!(convex_hull(&[[1.0, 2.0, 3.0]; 10]).is_err());
        let collinear: Vec<Point> = (0..10).map(|i| [i as f32, 2.0 * i as f32, 0.0]).collect();
        assert!(convex_hull(&collinear).is_err());
        let planar: Vec<Point> = (0..10)
            .map(|i| [(i % 3) as f32, (i / 3) as f32, 1.0])
            .collect();
        assert!(convex_hull(&planar).is_err());
        assert!(
            convex_hull(&[
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, f32::NAN]
            ])
            .is_err()
        );
    }
}
