//! Unit primitives (cube, prism, cylinder, cone, sphere, torus and its convex slabs, gear) in
//! the `[-0.5, 0.5]^3` convention of [`crate::mesh`].

use std::collections::HashMap;

use super::TriMesh;
use super::vec3::norm;
use crate::Point;

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
