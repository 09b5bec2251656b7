//! How each unit shape's parts are built: polygonal cylinder and cone, torus slabs, gear,
//! torus knot, sponge, mug and random hulls, normalised to the unit box.

use std::f64::consts::{PI, TAU};

use dynaserve_geometry::Point;
use dynaserve_geometry::mesh;
use rand::Rng;

use super::kind::ShapeKind;
use super::part::{Part, Polytope, cross, dot, normalize, unit_vector};
use crate::SimError;

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

/// The convex parts of the fixed unit shape `kind`, before recentring (every kind but
/// [`ShapeKind::Hull`]).
pub(super) fn fixed_parts(kind: ShapeKind) -> Result<Vec<Part>, SimError> {
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
    Ok(parts)
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

/// A random hull of 8 to 24 points (anisotropic), normalised to the unit box, before
/// recentring; slivers are drawn again.
pub(super) fn random_hull<R: Rng + ?Sized>(rng: &mut R) -> Part {
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
        return Part::Polytope(poly);
    }
}
