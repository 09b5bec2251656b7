//! Tests of the mesh integrals, the primitives, surface sampling and the convex hull.

use super::*;
use std::f64::consts::PI;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

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
    let root_area =
        0.5 * (2 * teeth) as f64 * (root as f64).powi(2) * (2.0 * PI / (2 * teeth) as f64).sin();
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
    assert!((c[0] - 1.0).abs() < 1e-9 && (c[1] + 2.0).abs() < 1e-9 && (c[2] - 5.0).abs() < 1e-9);
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
