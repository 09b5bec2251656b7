//! The grid search against the brute force, bit for bit, on random and edge-case scenes.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::Point;

fn assert_bit_identical(fast: &[Point], brute: &[Point], what: &str) {
    assert_eq!(fast.len(), brute.len(), "{what}: length");
    for (k, (a, b)) in fast.iter().zip(brute).enumerate() {
        let same = (0..3).all(|d| a[d].to_bits() == b[d].to_bits());
        assert!(same, "{what}: point {k}: fast {a:?} vs brute force {b:?}");
    }
}

/// Random objects: blobs of points around random centres; some scenes are crowded so that
/// objects touch and overlap, some objects sit below or straddle the ground.
fn random_scene(rng: &mut ChaCha8Rng) -> (Vec<Point>, Vec<usize>) {
    let objects = rng.random_range(1..12);
    let area = rng.random_range(0.5..6.0f32);
    let mut points = Vec::new();
    let mut offsets = vec![0];
    for _ in 0..objects {
        let c = [
            rng.random_range(-area..area),
            rng.random_range(-area..area),
            rng.random_range(-0.6..2.0f32),
        ];
        let size = rng.random_range(0.05..0.8f32);
        let n = rng.random_range(1..80);
        for _ in 0..n {
            points.push([
                c[0] + rng.random_range(-size..size),
                c[1] + rng.random_range(-size..size),
                c[2] + rng.random_range(-size..size),
            ]);
        }
        offsets.push(points.len());
    }
    (points, offsets)
}

#[test]
fn equals_brute_force_on_random_scenes() {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let configs = [
        ContactConfig::default(),
        ContactConfig {
            radius: 0.5,
            ground_z: None,
        },
        ContactConfig {
            radius: 0.1,
            ground_z: Some(0.3),
        },
    ];
    for s in 0..300 {
        let (points, offsets) = random_scene(&mut rng);
        for cfg in &configs {
            let fast = contact_features(&points, &offsets, cfg);
            let brute = contact_features_brute_force(&points, &offsets, cfg);
            assert_bit_identical(&fast, &brute, &format!("scene {s}, {cfg:?}"));
            // Every displacement is within the radius.
            for v in &fast {
                let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                assert!(len <= cfg.radius * 1.0001, "{v:?}");
            }
        }
    }
}

#[test]
fn distant_groups_in_one_scene_still_match() {
    // Two copies of a crowded scene 300 m apart.
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for s in 0..40 {
        let (mut points, mut offsets) = random_scene(&mut rng);
        let n = points.len();
        let copy: Vec<Point> = points
            .iter()
            .map(|p| [p[0] + 300.0, p[1] - 200.0, p[2] + 100.0])
            .collect();
        points.extend(copy);
        let more: Vec<usize> = offsets[1..].iter().map(|o| o + n).collect();
        offsets.extend(more);
        let cfg = ContactConfig::default();
        assert_bit_identical(
            &contact_features(&points, &offsets, &cfg),
            &contact_features_brute_force(&points, &offsets, &cfg),
            &format!("sparse scene {s}"),
        );
    }
}

#[test]
fn sparse_large_object_grows_its_cells_and_still_matches() {
    // A 40 m x 40 m sheet of 400 points would need 150 x 150 cells of the radius; its grid
    // coarsens instead. Small blobs lie on it and below it.
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let mut points: Vec<Point> = (0..400)
        .map(|_| {
            [
                rng.random_range(-20.0..20.0f32),
                rng.random_range(-20.0..20.0f32),
                0.1,
            ]
        })
        .collect();
    let mut offsets = vec![0, points.len()];
    for _ in 0..30 {
        let c = [
            rng.random_range(-20.0..20.0f32),
            rng.random_range(-20.0..20.0f32),
            rng.random_range(-0.1..0.4f32),
        ];
        for _ in 0..20 {
            points.push([
                c[0] + rng.random_range(-0.3..0.3f32),
                c[1] + rng.random_range(-0.3..0.3f32),
                c[2] + rng.random_range(-0.1..0.1f32),
            ]);
        }
        offsets.push(points.len());
    }
    for cfg in [
        ContactConfig::default(),
        ContactConfig {
            radius: 2.0,
            ground_z: None,
        },
    ] {
        assert_bit_identical(
            &contact_features(&points, &offsets, &cfg),
            &contact_features_brute_force(&points, &offsets, &cfg),
            "sheet",
        );
    }
}

#[test]
fn equals_brute_force_on_large_scene_in_parallel() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut points = Vec::new();
    let mut offsets = vec![0];
    for i in 0..6 {
        for j in 0..6 {
            for _ in 0..150 {
                points.push([
                    i as f32 + rng.random_range(-0.5..0.5f32),
                    j as f32 + rng.random_range(-0.5..0.5f32),
                    rng.random_range(0.0..1.0f32),
                ]);
            }
            offsets.push(points.len());
        }
    }
    let cfg = ContactConfig::default();
    let brute = contact_features_brute_force(&points, &offsets, &cfg);
    // The default threshold (serial here), and the rayon path forced on, in a two-thread
    // pool so that it really splits even on a one-core machine.
    assert_bit_identical(
        &contact_features(&points, &offsets, &cfg),
        &brute,
        "grid of touching blobs",
    );
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let mut ws = ContactWorkspace::with_parallel_threshold(0);
    let mut out = Vec::new();
    pool.install(|| ws.compute(&points, &offsets, &cfg, &mut out));
    assert_bit_identical(&out, &brute, "grid of touching blobs, parallel");
    // The workspace is reused without leftovers from the previous scene.
    pool.install(|| ws.compute(&points[..300], &[0, 150, 300], &cfg, &mut out));
    assert_bit_identical(
        &out,
        &contact_features_brute_force(&points[..300], &[0, 150, 300], &cfg),
        "reused workspace",
    );
}

#[test]
fn touching_cubes_and_ties() {
    // Two lattices 0.1 m apart along x, on a 0.1 m lattice: many exactly tied distances.
    let mut points = Vec::new();
    for i in 0..4 {
        for j in 0..4 {
            points.push([0.0, i as f32 * 0.1, j as f32 * 0.1 + 0.5]);
        }
    }
    let split = points.len();
    for i in 0..4 {
        for j in 0..4 {
            points.push([0.1, i as f32 * 0.1, j as f32 * 0.1 + 0.5]);
        }
    }
    let offsets = vec![0, split, points.len()];
    let cfg = ContactConfig::default();
    let fast = contact_features(&points, &offsets, &cfg);
    assert_bit_identical(
        &fast,
        &contact_features_brute_force(&points, &offsets, &cfg),
        "lattice",
    );
    for (k, v) in fast.iter().enumerate() {
        let expect = if k < split { 0.1f32 } else { -0.1 };
        assert!((v[0] - expect).abs() < 1e-6 && v[1] == 0.0 && v[2] == 0.0);
    }
}

#[test]
fn exact_ties_pick_the_smallest_index() {
    // The query point sits exactly between two points of other objects; whatever order the
    // grid visits them in, the smaller index into `points` wins, as in the brute force.
    let cfg = ContactConfig::default();
    let points = vec![[0.1, 0.0, 1.0], [-0.1, 0.0, 1.0], [0.0, 0.0, 1.0]];
    for offsets in [vec![0, 1, 2, 3], vec![0, 2, 3]] {
        let got = contact_features(&points, &offsets, &cfg);
        assert_eq!(got[2], [0.1, 0.0, 0.0]);
        assert_bit_identical(
            &got,
            &contact_features_brute_force(&points, &offsets, &cfg),
            "tie",
        );
    }
    // A point exactly as near as the ground loses to the ground.
    let points = vec![[0.0, 0.0, 0.125], [0.125, 0.0, 0.125]];
    let got = contact_features(&points, &[0, 1, 2], &cfg);
    assert_eq!(got[0], [0.0, 0.0, -0.125]);
}

/// The variant that names its source finds the same displacements as the plain search
/// and the same sources as the brute force, including for non-finite and empty inputs.
#[test]
fn hits_equal_brute_force_and_plain_features() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let configs = [
        ContactConfig::default(),
        ContactConfig {
            radius: 0.5,
            ground_z: None,
        },
    ];
    let mut seen = [0usize; 3];
    for s in 0..150 {
        let (mut points, offsets) = random_scene(&mut rng);
        if s % 10 == 0 && !points.is_empty() {
            points[0] = [f32::NAN, 0.0, 0.0];
        }
        for cfg in &configs {
            let hits = contact_hits(&points, &offsets, cfg);
            let brute = contact_hits_brute_force(&points, &offsets, cfg);
            let plain = contact_features(&points, &offsets, cfg);
            let disp: Vec<Point> = hits.iter().map(|h| h.displacement).collect();
            assert_bit_identical(&disp, &plain, &format!("scene {s}, {cfg:?}"));
            for (k, (h, b)) in hits.iter().zip(&brute).enumerate() {
                assert_eq!(h.source, b.source, "scene {s}, point {k}, {cfg:?}");
                match h.source {
                    ContactSource::Point(j) => {
                        let y = points[j as usize];
                        let x = points[k];
                        let d = [y[0] - x[0], y[1] - x[1], y[2] - x[2]];
                        assert_eq!(d, h.displacement);
                        seen[0] += 1;
                    }
                    ContactSource::Ground => seen[1] += 1,
                    ContactSource::Free => seen[2] += 1,
                }
            }
        }
    }
    assert!(
        seen.iter().all(|&c| c > 100),
        "every source occurs: {seen:?}"
    );
}

#[test]
fn hits_name_the_ground_the_point_and_nothing() {
    let cfg = ContactConfig::default();
    // Object 0: one point high up, one near the ground; object 1: a point 0.05 m beside
    // the high one.
    let points = vec![[0.0, 0.0, 2.0], [3.0, 0.0, 0.1], [0.05, 0.0, 2.0]];
    let hits = contact_hits(&points, &[0, 2, 3], &cfg);
    assert_eq!(hits[0].source, ContactSource::Point(2));
    assert_eq!(hits[1].source, ContactSource::Ground);
    assert_eq!(hits[1].displacement, [0.0, 0.0, -0.1]);
    assert_eq!(hits[2].source, ContactSource::Point(0));
    let alone = contact_hits(&points[..1], &[0, 1], &cfg);
    assert_eq!(alone[0].source, ContactSource::Free);
    assert_eq!(alone[0].displacement, [0.0, 0.0, -0.25]);
}

#[test]
fn ground_and_clipping() {
    let cfg = ContactConfig::default();
    // One object: high above, near, exactly on and below the ground.
    let points = vec![
        [0.0, 0.0, 3.0],
        [0.0, 0.0, 0.1],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, -0.5],
    ];
    let offsets = vec![0, points.len()];
    let got = contact_features(&points, &offsets, &cfg);
    assert_eq!(got[0], [0.0, 0.0, -0.25]);
    assert_eq!(got[1], [0.0, 0.0, -0.1]);
    assert_eq!(got[2], [0.0, 0.0, 0.0]);
    assert_eq!(got[3], [0.0, 0.0, 0.25]);
    // No ground: a lone object has no candidates at all.
    let none = ContactConfig {
        ground_z: None,
        ..cfg
    };
    assert!(
        contact_features(&points, &offsets, &none)
            .iter()
            .all(|v| *v == [0.0; 3])
    );
}

#[test]
fn nearer_object_beats_ground_and_own_points_are_ignored() {
    let cfg = ContactConfig::default();
    // Object 0 at z = 0.2 (ground 0.2 away); object 1 just 0.05 m to its side.
    let points = vec![[0.0, 0.0, 0.2], [0.01, 0.0, 0.2], [0.05, 0.0, 0.2]];
    let offsets = vec![0, 2, 3];
    let got = contact_features(&points, &offsets, &cfg);
    assert!((got[0][0] - 0.05).abs() < 1e-7 && got[0][2] == 0.0);
    assert!((got[1][0] - 0.04).abs() < 1e-7);
    // Object 1's nearest other point is object 0's second point.
    assert!((got[2][0] + 0.04).abs() < 1e-7);
    assert_bit_identical(
        &got,
        &contact_features_brute_force(&points, &offsets, &cfg),
        "small",
    );
}

#[test]
fn empty_objects_and_non_finite_points() {
    let cfg = ContactConfig::default();
    let points = vec![
        [0.0, 0.0, 0.5],
        [f32::NAN, 0.0, 0.5],
        [0.1, 0.0, 0.5],
        [f32::INFINITY, 0.0, 0.5],
    ];
    let offsets = vec![0, 0, 2, 2, 4, 4];
    let fast = contact_features(&points, &offsets, &cfg);
    assert_bit_identical(
        &fast,
        &contact_features_brute_force(&points, &offsets, &cfg),
        "empty objects",
    );
    assert!((fast[0][0] - 0.1).abs() < 1e-7);
    assert!(contact_features(&[], &[0], &cfg).is_empty());
    assert!(contact_features(&[], &[0, 0, 0], &cfg).is_empty());
}

#[test]
fn bad_radius_gives_zero_vectors_and_validation_reports() {
    let points = vec![[0.0, 0.0, 0.5], [0.1, 0.0, 0.5]];
    for radius in [0.0, -1.0, f32::NAN] {
        let cfg = ContactConfig {
            radius,
            ground_z: Some(0.0),
        };
        assert!(cfg.validate().is_err());
        let got = contact_features(&points, &[0, 1, 2], &cfg);
        assert!(got.iter().flatten().all(|v| *v == 0.0));
    }
    assert!(ContactConfig::default().validate().is_ok());
    assert!(validate_offsets(2, &[0, 1]).is_err());
    assert!(validate_offsets(2, &[1, 2]).is_err());
    assert!(validate_offsets(2, &[0, 2, 1, 2]).is_err());
    assert!(validate_offsets(2, &[]).is_err());
    assert!(validate_offsets(2, &[0, 2]).is_ok());
}

#[test]
fn far_apart_large_coordinates_still_match() {
    // Large coordinates force a coarser grid (cell cap); results must not change.
    let cfg = ContactConfig::default();
    let points = vec![
        [0.0, 0.0, 0.3],
        [0.2, 0.0, 0.3],
        [50_000.0, 0.0, 0.3],
        [50_000.1, 0.0, 0.3],
    ];
    let offsets = vec![0, 1, 2, 3, 4];
    assert_bit_identical(
        &contact_features(&points, &offsets, &cfg),
        &contact_features_brute_force(&points, &offsets, &cfg),
        "large coordinates",
    );
}
