//! The mesh templates of the mesh scene sets: 15 small convex polyhedra (4-20 vertices) and 7
//! concave prisms (12-24 vertices), each with the tetrahedra an elastic copy is simulated with
//! and the convex parts a rigid copy collides with.
//!
//! Every unit template is centred on its centre of volume (the centre of mass at uniform
//! density) and scaled so that its farthest vertex is 1 from it. Faces are counter-clockwise
//! seen from outside. Convex templates are tetrahedralised as a fan from the centre of volume
//! (one interior particle that the recorded mesh does not hold); concave prisms split each
//! triangular column of their cross-section into three tetrahedra over the mesh vertices only,
//! with the diagonals chosen by vertex index so neighbouring columns agree.

use std::sync::OnceLock;

use dynaserve_geometry::{Point, TriMesh, convex_hull};

use crate::{Result, SimError};

/// One mesh template (unit size: farthest vertex at distance 1 from the centre of volume).
#[derive(Clone, Debug)]
pub struct MeshTemplate {
    /// Short name, e.g. `cube` or `l_prism`.
    pub name: &'static str,
    /// Whether the solid is convex.
    pub convex: bool,
    /// The closed outward surface (the vertices a dataset records), origin at the centre of
    /// volume.
    pub mesh: TriMesh,
    /// Extra particles inside the solid used only by the elastic simulation; particle
    /// `mesh.vertices.len() + k` is `interior[k]`.
    pub interior: Vec<Point>,
    /// Positively oriented tetrahedra over the particles (mesh vertices then interior points)
    /// filling the solid exactly.
    pub tets: Vec<[u32; 4]>,
    /// Convex parts (point sets) whose union is the solid, for the rigid collider.
    pub parts: Vec<Vec<Point>>,
}

impl MeshTemplate {
    /// Number of recorded vertices.
    pub fn vertices(&self) -> usize {
        self.mesh.vertices.len()
    }

    /// All particles of an elastic copy: mesh vertices then interior points.
    pub fn particles(&self) -> Vec<Point> {
        let mut p = self.mesh.vertices.clone();
        p.extend_from_slice(&self.interior);
        p
    }
}

fn sub(a: Point, b: Point) -> [f64; 3] {
    [
        (a[0] - b[0]) as f64,
        (a[1] - b[1]) as f64,
        (a[2] - b[2]) as f64,
    ]
}

/// Six times the signed volume of the tetrahedron `a b c d`, cubic metres.
pub fn tet_volume6(a: Point, b: Point, c: Point, d: Point) -> f64 {
    let (u, v, w) = (sub(b, a), sub(c, a), sub(d, a));
    u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
        + u[2] * (v[0] * w[1] - v[1] * w[0])
}

/// Orients `t` positively over `pts` (swaps two vertices when its volume is negative).
fn oriented(pts: &[Point], t: [u32; 4]) -> [u32; 4] {
    let p = |i: u32| pts[i as usize];
    if tet_volume6(p(t[0]), p(t[1]), p(t[2]), p(t[3])) < 0.0 {
        [t[0], t[2], t[1], t[3]]
    } else {
        t
    }
}

/// Recentres every point set on the mesh's centre of volume and scales to unit circumradius.
fn normalise(t: &mut MeshTemplate) {
    let c = t.mesh.centroid();
    let c = [c[0] as f32, c[1] as f32, c[2] as f32];
    let r = t
        .mesh
        .vertices
        .iter()
        .map(|v| {
            let d = sub(*v, c);
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
        })
        .fold(0.0f64, f64::max) as f32;
    let f = |p: &mut Point| {
        for k in 0..3 {
            p[k] = (p[k] - c[k]) / r;
        }
    };
    t.mesh.vertices.iter_mut().for_each(f);
    t.interior.iter_mut().for_each(f);
    t.parts.iter_mut().flatten().for_each(f);
}

fn convex(name: &'static str, points: &[Point]) -> Result<MeshTemplate> {
    let mesh = convex_hull(points)?;
    if mesh.vertices.len() != points.len() {
        return Err(SimError::Shape(format!(
            "template {name}: the hull keeps {} of {} points",
            mesh.vertices.len(),
            points.len()
        )));
    }
    let mut t = MeshTemplate {
        name,
        convex: true,
        parts: vec![mesh.vertices.clone()],
        mesh,
        interior: vec![],
        tets: vec![],
    };
    normalise(&mut t);
    // Fan from the centre of volume (now the origin), particle index n.
    let n = t.mesh.vertices.len() as u32;
    t.interior = vec![[0.0; 3]];
    let pts = t.particles();
    t.tets = t
        .mesh
        .faces
        .iter()
        .map(|f| oriented(&pts, [f[0], f[1], f[2], n]))
        .collect();
    Ok(t)
}

/// Ear-clipping triangulation of a simple counter-clockwise polygon (counter-clockwise
/// triangles).
fn triangulate(poly: &[[f32; 2]]) -> Result<Vec<[u32; 3]>> {
    let cross = |o: [f32; 2], a: [f32; 2], b: [f32; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut idx: Vec<u32> = (0..poly.len() as u32).collect();
    let mut tris = Vec::new();
    while idx.len() > 3 {
        let n = idx.len();
        let ear = (0..n).find(|&i| {
            let (a, b, c) = (idx[(i + n - 1) % n], idx[i], idx[(i + 1) % n]);
            let (pa, pb, pc) = (poly[a as usize], poly[b as usize], poly[c as usize]);
            cross(pa, pb, pc) > 1e-9
                && idx.iter().all(|&j| {
                    j == a
                        || j == b
                        || j == c
                        || !(cross(pa, pb, poly[j as usize]) >= 0.0
                            && cross(pb, pc, poly[j as usize]) >= 0.0
                            && cross(pc, pa, poly[j as usize]) >= 0.0)
                })
        });
        let Some(i) = ear else {
            return Err(SimError::Shape("polygon is not simple".into()));
        };
        tris.push([idx[(i + n - 1) % n], idx[i], idx[(i + 1) % n]]);
        idx.remove(i);
    }
    tris.push([idx[0], idx[1], idx[2]]);
    Ok(tris)
}

/// A prism over a simple counter-clockwise polygon, `z` in `[-thickness / 2, thickness / 2]`.
fn prism(name: &'static str, poly: &[[f32; 2]], thickness: f32) -> Result<MeshTemplate> {
    let n = poly.len() as u32;
    let h = 0.5 * thickness;
    let mut vertices: Vec<Point> = poly.iter().map(|p| [p[0], p[1], -h]).collect();
    vertices.extend(poly.iter().map(|p| [p[0], p[1], h]));
    let caps = triangulate(poly)?;
    let mut faces = Vec::new();
    for &[a, b, c] in &caps {
        faces.push([a, c, b]);
        faces.push([n + a, n + b, n + c]);
    }
    for i in 0..n {
        let j = (i + 1) % n;
        faces.push([i, j, n + j]);
        faces.push([i, n + j, n + i]);
    }
    let mut tets = Vec::new();
    let mut parts = Vec::new();
    for cap in &caps {
        let mut s = *cap;
        s.sort_unstable();
        let [a, b, c] = s;
        // Each side quad (i, j) with i < j is split along (i, top j): the same in both columns.
        for t in [
            [a, b, c, n + c],
            [a, b, n + b, n + c],
            [a, n + a, n + b, n + c],
        ] {
            tets.push(oriented(&vertices, t));
        }
        parts.push(
            [a, b, c, n + a, n + b, n + c]
                .iter()
                .map(|&i| vertices[i as usize])
                .collect(),
        );
    }
    let mut t = MeshTemplate {
        name,
        convex: false,
        mesh: TriMesh::new(vertices, faces)?,
        interior: vec![],
        tets,
        parts,
    };
    normalise(&mut t);
    Ok(t)
}

fn ring(k: usize, radius: f32, z: f32, phase: f32) -> Vec<Point> {
    (0..k)
        .map(|i| {
            let a = phase + std::f32::consts::TAU * i as f32 / k as f32;
            [radius * a.cos(), radius * a.sin(), z]
        })
        .collect()
}

fn ring2(k: usize, radius: f32, phase: f32) -> Vec<[f32; 2]> {
    ring(k, radius, 0.0, phase)
        .into_iter()
        .map(|p| [p[0], p[1]])
        .collect()
}

fn pyramid(k: usize) -> Vec<Point> {
    let mut p = ring(k, 1.0, 0.0, 0.0);
    p.push([0.0, 0.0, 1.2]);
    p
}

fn prism_points(k: usize, height: f32) -> Vec<Point> {
    let mut p = ring(k, 1.0, 0.0, 0.0);
    p.extend(ring(k, 1.0, height, 0.0));
    p
}

fn box_points(x: f32, y: f32, z: f32) -> Vec<Point> {
    (0..8)
        .map(|c| {
            [
                if c & 1 == 0 { -x } else { x },
                if c & 2 == 0 { -y } else { y },
                if c & 4 == 0 { -z } else { z },
            ]
        })
        .collect()
}

fn convex_set() -> Result<Vec<MeshTemplate>> {
    let phi = (1.0 + 5f32.sqrt()) / 2.0;
    let mut icosahedron = Vec::new();
    for s1 in [-1.0f32, 1.0] {
        for s2 in [-1.0f32, 1.0] {
            icosahedron.push([0.0, s1, s2 * phi]);
            icosahedron.push([s1, s2 * phi, 0.0]);
            icosahedron.push([s2 * phi, 0.0, s1]);
        }
    }
    let mut dodecahedron = box_points(1.0, 1.0, 1.0);
    for s1 in [-1.0f32, 1.0] {
        for s2 in [-1.0f32, 1.0] {
            dodecahedron.push([0.0, s1 / phi, s2 * phi]);
            dodecahedron.push([s1 / phi, s2 * phi, 0.0]);
            dodecahedron.push([s2 * phi, 0.0, s1 / phi]);
        }
    }
    let mut cuboctahedron = Vec::new();
    for s1 in [-1.0f32, 1.0] {
        for s2 in [-1.0f32, 1.0] {
            cuboctahedron.push([s1, s2, 0.0]);
            cuboctahedron.push([s1, 0.0, s2]);
            cuboctahedron.push([0.0, s1, s2]);
        }
    }
    let mut bipyramid = ring(3, 1.0, 0.0, 0.0);
    bipyramid.extend([[0.0, 0.0, 1.1], [0.0, 0.0, -1.1]]);
    let mut octahedron = ring(4, 1.0, 0.0, 0.0);
    octahedron.extend([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]);
    let mut antiprism = ring(4, 1.0, 0.0, 0.0);
    antiprism.extend(ring(4, 1.0, 0.9, std::f32::consts::FRAC_PI_4));
    [
        ("tetrahedron", pyramid(3)),
        ("square_pyramid", pyramid(4)),
        ("pentagonal_pyramid", pyramid(5)),
        ("triangular_bipyramid", bipyramid),
        ("octahedron", octahedron),
        ("triangular_prism", prism_points(3, 1.2)),
        ("cube", box_points(1.0, 1.0, 1.0)),
        ("slab", box_points(1.0, 0.7, 0.35)),
        ("square_antiprism", antiprism),
        ("pentagonal_prism", prism_points(5, 1.0)),
        ("hexagonal_prism", prism_points(6, 0.8)),
        ("icosahedron", icosahedron),
        ("cuboctahedron", cuboctahedron),
        ("octagonal_prism", prism_points(8, 0.6)),
        ("dodecahedron", dodecahedron),
    ]
    .iter()
    .map(|(name, pts)| convex(name, pts))
    .collect()
}

fn concave_set() -> Result<Vec<MeshTemplate>> {
    let mut star = Vec::new();
    for (i, p) in ring2(10, 1.0, std::f32::consts::FRAC_PI_2)
        .into_iter()
        .enumerate()
    {
        let r = if i % 2 == 0 { 1.0 } else { 0.45 };
        star.push([p[0] * r, p[1] * r]);
    }
    let mut crescent: Vec<[f32; 2]> = (0..5)
        .map(|i| {
            let a = -2.0 + 4.0 * i as f32 / 4.0;
            [a.cos(), a.sin()]
        })
        .collect();
    crescent.extend((0..5).rev().map(|i| {
        let a = -1.6 + 3.2 * i as f32 / 4.0;
        [0.2 + 0.55 * a.cos(), 0.6 * a.sin()]
    }));
    let shapes: [(&'static str, Vec<[f32; 2]>, f32); 7] = [
        (
            "l_prism",
            vec![[0., 0.], [2., 0.], [2., 1.], [1., 1.], [1., 2.], [0., 2.]],
            0.8,
        ),
        (
            "chevron_prism",
            vec![[0., 0.], [1., 0.8], [2., 0.], [2., 1.], [1., 1.8], [0., 1.]],
            0.8,
        ),
        (
            "t_prism",
            vec![
                [-0.5, 0.],
                [0.5, 0.],
                [0.5, 1.],
                [1.5, 1.],
                [1.5, 2.],
                [-1.5, 2.],
                [-1.5, 1.],
                [-0.5, 1.],
            ],
            0.9,
        ),
        (
            "u_prism",
            vec![
                [0., 0.],
                [3., 0.],
                [3., 2.],
                [2., 2.],
                [2., 1.],
                [1., 1.],
                [1., 2.],
                [0., 2.],
            ],
            1.0,
        ),
        ("star_prism", star, 0.6),
        ("crescent_prism", crescent, 0.6),
        (
            "cross_prism",
            vec![
                [1., 0.],
                [2., 0.],
                [2., 1.],
                [3., 1.],
                [3., 2.],
                [2., 2.],
                [2., 3.],
                [1., 3.],
                [1., 2.],
                [0., 2.],
                [0., 1.],
                [1., 1.],
            ],
            1.0,
        ),
    ];
    shapes
        .iter()
        .map(|(name, poly, thickness)| prism(name, poly, *thickness))
        .collect()
}

/// Number of convex templates; template ids `0..CONVEX_TEMPLATES` are convex, the rest concave.
pub const CONVEX_TEMPLATES: usize = 15;

/// The template library, built once: the 15 convex templates (ids 0-14) then the 7 concave
/// prisms (ids 15-21).
pub fn templates() -> Result<&'static [MeshTemplate]> {
    static LIB: OnceLock<std::result::Result<Vec<MeshTemplate>, String>> = OnceLock::new();
    let lib = LIB.get_or_init(|| {
        let mut all = convex_set().map_err(|e| e.to_string())?;
        all.extend(concave_set().map_err(|e| e.to_string())?);
        Ok(all)
    });
    lib.as_deref()
        .map_err(|e| SimError::Shape(format!("mesh templates: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn templates_are_closed_unit_solids_filled_by_their_tets() {
        let lib = templates().unwrap();
        assert_eq!(lib.len(), 22);
        for (i, t) in lib.iter().enumerate() {
            assert_eq!(t.convex, i < CONVEX_TEMPLATES, "{}", t.name);
            let n = t.vertices();
            if t.convex {
                assert!((4..=20).contains(&n), "{} has {n} vertices", t.name);
            }
            assert!(t.mesh.is_closed(), "{}", t.name);
            let vol = t.mesh.volume();
            assert!(vol > 0.05, "{} volume {vol}", t.name);
            let pts = t.particles();
            let tet_vol: f64 = t
                .tets
                .iter()
                .map(|c| {
                    let v = tet_volume6(
                        pts[c[0] as usize],
                        pts[c[1] as usize],
                        pts[c[2] as usize],
                        pts[c[3] as usize],
                    );
                    assert!(v > 1e-6, "{}: degenerate or inverted tet {c:?}", t.name);
                    v / 6.0
                })
                .sum();
            assert!(
                (tet_vol - vol).abs() < 1e-4 * vol,
                "{}: {tet_vol} vs {vol}",
                t.name
            );
            let c = t.mesh.centroid();
            assert!(
                c.iter().all(|x| x.abs() < 1e-4),
                "{}: centroid {c:?}",
                t.name
            );
            let r = t
                .mesh
                .vertices
                .iter()
                .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
                .fold(0.0f32, f32::max);
            assert!((r - 1.0).abs() < 1e-5, "{}: radius {r}", t.name);
        }
    }
}
