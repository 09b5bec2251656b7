//! The shape set against closed forms and against the colliders rapier simulates.

use std::f64::consts::{PI, TAU};

use dynaserve_geometry::mesh;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rapier3d::math::Vector;

use super::*;

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
