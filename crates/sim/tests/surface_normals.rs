//! Surface normals estimated from the clouds the training data holds: MOVi-B cubes and spheres
//! at the scales and sparsity a training window draws (96 and 256 points sampled uniformly on
//! the scaled shape), against their true normals. Prints the figures the model documentation
//! quotes (`docs/rigidformer.md`, "Why surface normals").

use dynaserve_geometry::{DEFAULT_NORMAL_NEIGHBOURS, Point, estimate_normals};
use dynaserve_sim::{Shape, ShapeKind};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The true outward normal of `p` on a cube (the axis it lies furthest along) or a sphere
/// (radial), body frame.
fn true_normal(kind: ShapeKind, p: Point) -> [f32; 3] {
    match kind {
        ShapeKind::Cube => {
            let axis = (0..3)
                .max_by(|&a, &b| p[a].abs().total_cmp(&p[b].abs()))
                .expect("three axes");
            let mut n = [0.0; 3];
            n[axis] = p[axis].signum();
            n
        }
        _ => {
            let len = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            p.map(|v| v / len)
        }
    }
}

/// Angle errors in degrees over `objects` objects of `kind` at `points` points each.
fn errors(kind: ShapeKind, points: usize, objects: usize) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(points as u64);
    let mut out = Vec::new();
    for _ in 0..objects {
        let shape = Shape::unit(kind, &mut rng)
            .unwrap()
            .scaled(rng.random_range(0.7..1.4));
        let cloud = shape.sample_surface(points, &mut rng).unwrap();
        let normals = estimate_normals(&cloud, DEFAULT_NORMAL_NEIGHBOURS).unwrap();
        for (p, n) in cloud.iter().zip(&normals) {
            let t = true_normal(kind, *p);
            let cos = (n[0] * t[0] + n[1] * t[1] + n[2] * t[2]).clamp(-1.0, 1.0);
            out.push(cos.acos().to_degrees());
        }
    }
    out.sort_by(f32::total_cmp);
    out
}

#[test]
fn training_clouds_get_usable_normals() {
    // (shape, points, largest median error in degrees)
    for (kind, points, median_limit) in [
        (ShapeKind::Cube, 96, 8.0),
        (ShapeKind::Cube, 256, 3.0),
        (ShapeKind::Sphere, 96, 15.0),
        (ShapeKind::Sphere, 256, 10.0),
    ] {
        let e = errors(kind, points, 20);
        let median = e[e.len() / 2];
        let share = |limit: f32| e.iter().filter(|&&a| a < limit).count() as f32 / e.len() as f32;
        let flipped = 1.0 - share(90.0);
        println!(
            "{} at {points} points: median {median:.1} deg, {:.0}% within 10 deg, {:.0}% within 30, {:.1}% flipped",
            kind.name(),
            100.0 * share(10.0),
            100.0 * share(30.0),
            100.0 * flipped
        );
        assert!(
            median < median_limit,
            "{} at {points}: median {median}",
            kind.name()
        );
        assert!(
            flipped < 0.05,
            "{} at {points}: {flipped} flipped",
            kind.name()
        );
    }
}
