//! Contact features against brute force on two reference scenes, plus Kabsch on K = 8 anchors.
//!
//! - `movi_10x512`: 10 objects of about 1 m (boxes and spheres, 512 surface points each)
//!   resting on the ground, scattered over a 10 m x 10 m area; three pairs touch.
//! - `wrecking_216x64`: a 6 x 6 x 6 stack of touching unit cubes on the ground, 64 surface
//!   points per cube.
//!
//! `fast` is the default entry point (parallel from `PARALLEL_MIN_POINTS` points, so for both
//! scenes), `fast_parallel` the same search forced onto rayon's pool, `brute` the exhaustive
//! reference.
//! `contact/threshold/*` compares serial and parallel on growing touching stacks;
//! `normals/box/*` times surface normal estimation on one object's cloud.
//!
//! Run: `cargo bench -p dynaserve-geometry --bench contact`

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use dynaserve_geometry::contact::ContactWorkspace;
use dynaserve_geometry::{
    ContactConfig, DEFAULT_NORMAL_NEIGHBOURS, Point, contact_features,
    contact_features_brute_force, estimate_normals, kabsch,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

/// Uniform points on the surface of an axis-aligned box centred at `c` with half extents `h`.
fn box_surface(rng: &mut ChaCha8Rng, c: Point, h: Point, n: usize, out: &mut Vec<Point>) {
    let areas = [h[1] * h[2], h[0] * h[2], h[0] * h[1]];
    let total: f32 = areas.iter().sum();
    for _ in 0..n {
        let pick = rng.random_range(0.0..total);
        let axis = if pick < areas[0] {
            0
        } else if pick < areas[0] + areas[1] {
            1
        } else {
            2
        };
        let mut p = [0.0f32; 3];
        for (d, v) in p.iter_mut().enumerate() {
            *v = if d == axis {
                if rng.random::<bool>() { h[d] } else { -h[d] }
            } else {
                rng.random_range(-h[d]..h[d])
            };
        }
        out.push([c[0] + p[0], c[1] + p[1], c[2] + p[2]]);
    }
}

/// Uniform points on a sphere of radius `r` centred at `c`.
fn sphere_surface(rng: &mut ChaCha8Rng, c: Point, r: f32, n: usize, out: &mut Vec<Point>) {
    for _ in 0..n {
        let z: f32 = rng.random_range(-1.0..1.0);
        let phi: f32 = rng.random_range(0.0..std::f32::consts::TAU);
        let s = (1.0 - z * z).sqrt();
        out.push([
            c[0] + r * s * phi.cos(),
            c[1] + r * s * phi.sin(),
            c[2] + r * z,
        ]);
    }
}

fn movi_scene() -> (Vec<Point>, Vec<usize>) {
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let mut points = Vec::new();
    let mut offsets = vec![0];
    // Three touching pairs (side by side) and four loose objects, all resting on z = 0.
    let mut centres: Vec<(Point, f32)> = Vec::new();
    for pair in 0..3 {
        let x = -4.0 + 3.5 * pair as f32;
        let y = rng.random_range(-4.0..4.0);
        let half = rng.random_range(0.35..0.7);
        let half2 = rng.random_range(0.35..0.7);
        centres.push(([x, y, half], half));
        centres.push(([x + half + half2, y, half2], half2));
    }
    for k in 0..4 {
        let half = rng.random_range(0.35..0.7);
        centres.push((
            [
                -4.0 + 2.7 * k as f32,
                rng.random_range(-4.5..-2.5) + 6.5 * (k % 2) as f32,
                half,
            ],
            half,
        ));
    }
    for (k, (c, half)) in centres.into_iter().enumerate() {
        if k % 3 == 2 {
            sphere_surface(&mut rng, c, half, 512, &mut points);
        } else {
            box_surface(&mut rng, c, [half; 3], 512, &mut points);
        }
        offsets.push(points.len());
    }
    (points, offsets)
}

fn cube_stack(n: usize, per_cube: usize) -> (Vec<Point>, Vec<usize>) {
    let mut rng = ChaCha8Rng::seed_from_u64(216);
    let mut points = Vec::new();
    let mut offsets = vec![0];
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                let c = [i as f32, j as f32, k as f32 + 0.5];
                box_surface(&mut rng, c, [0.5; 3], per_cube, &mut points);
                offsets.push(points.len());
            }
        }
    }
    (points, offsets)
}

fn bench_contact(c: &mut Criterion) {
    let cfg = ContactConfig::default();
    for (name, (points, offsets)) in [
        ("movi_10x512", movi_scene()),
        ("wrecking_216x64", cube_stack(6, 64)),
    ] {
        assert_eq!(
            contact_features(&points, &offsets, &cfg),
            contact_features_brute_force(&points, &offsets, &cfg)
        );
        let mut group = c.benchmark_group(format!("contact/{name}"));
        group.bench_function("fast", |b| {
            b.iter(|| contact_features(black_box(&points), black_box(&offsets), &cfg))
        });
        let mut ws = ContactWorkspace::with_parallel_threshold(0);
        let mut out = Vec::new();
        group.bench_function("fast_parallel", |b| {
            b.iter(|| ws.compute(black_box(&points), black_box(&offsets), &cfg, &mut out))
        });
        group.sample_size(10);
        group.bench_function("brute", |b| {
            b.iter(|| contact_features_brute_force(black_box(&points), black_box(&offsets), &cfg))
        });
        group.finish();
    }
}

/// Serial against parallel for growing touching stacks, to place the parallel threshold.
fn bench_threshold(c: &mut Criterion) {
    let cfg = ContactConfig::default();
    let serial_pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("one-thread pool");
    let parallel_pool = rayon::ThreadPoolBuilder::new()
        .build()
        .expect("default pool");
    let mut group = c.benchmark_group("contact/threshold");
    for n in [2usize, 4, 6, 8] {
        let (points, offsets) = cube_stack(n, 64);
        for (label, pool) in [("serial", &serial_pool), ("parallel", &parallel_pool)] {
            let mut ws = ContactWorkspace::with_parallel_threshold(0);
            let mut out = Vec::new();
            group.bench_with_input(BenchmarkId::new(label, points.len()), &points, |b, pts| {
                pool.install(|| b.iter(|| ws.compute(black_box(pts), &offsets, &cfg, &mut out)))
            });
        }
    }
    group.finish();
}

fn bench_kabsch(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let reference: Vec<[f64; 3]> = (0..8)
        .map(|_| {
            [
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
            ]
        })
        .collect();
    let target: Vec<[f64; 3]> = reference
        .iter()
        .map(|p| [p[1] + 1.0, -p[0], p[2] + 0.01 * p[0]])
        .collect();
    c.bench_function("kabsch/k8", |b| {
        b.iter(|| kabsch(black_box(&reference), black_box(&target), None).expect("kabsch"))
    });
}

/// Normal estimation on one box of 1 m x 0.6 m x 0.4 m at the point counts training draws
/// (96, 256), a client's usual count (512) and a dense cloud (2048).
fn bench_normals(c: &mut Criterion) {
    let mut group = c.benchmark_group("normals/box");
    for n in [96usize, 256, 512, 2048] {
        let mut rng = ChaCha8Rng::seed_from_u64(n as u64);
        let mut points = Vec::new();
        box_surface(&mut rng, [0.0; 3], [0.5, 0.3, 0.2], n, &mut points);
        group.bench_with_input(BenchmarkId::from_parameter(n), &points, |b, pts| {
            b.iter(|| estimate_normals(black_box(pts), DEFAULT_NORMAL_NEIGHBOURS).expect("normals"))
        });
    }
    group.finish();
}

criterion_group!(
    benches,
    bench_contact,
    bench_threshold,
    bench_kabsch,
    bench_normals
);
criterion_main!(benches);
