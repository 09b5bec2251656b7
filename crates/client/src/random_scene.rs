//! Seeded random scenes for load and tests: boxes sent as point clouds, placed so that their
//! bounding spheres never overlap and no point starts below the ground.

use dynaserve_api::json;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A random unit quaternion `[x, y, z, w]` (uniform on the sphere, Shoemake's method).
fn random_rotation(rng: &mut ChaCha8Rng) -> [f32; 4] {
    let (u1, u2, u3): (f32, f32, f32) = (rng.random(), rng.random(), rng.random());
    let tau = std::f32::consts::TAU;
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let q = [
        a * (tau * u2).sin(),
        a * (tau * u2).cos(),
        b * (tau * u3).sin(),
        b * (tau * u3).cos(),
    ];
    let n = q.iter().map(|c| c * c).sum::<f32>().sqrt();
    q.map(|c| c / n)
}

/// A seeded scene of `objects` boxes (half extents 0.1..0.3 m), `points` surface samples each,
/// given as point clouds in the body frame (origin at the centre of mass). About half rest
/// flat on the ground (z = half height, turned about z only, at rest); the others start
/// 5 cm to 1 m above the ground, randomly oriented, with horizontal velocities up to 1 m/s.
/// Bounding spheres never overlap, and no point starts below the ground. Mass follows a
/// density of 500 kg/m³ (clamped to 0.05..100 kg).
pub fn generate(seed: u64, objects: usize, points: usize) -> json::Scene {
    generate_with(seed, objects, points, RESTING_SHARE)
}

/// Like [`generate`], but every object starts in the air and moving (none rests), so that
/// every object's trajectory says something about the model.
pub fn generate_moving(seed: u64, objects: usize, points: usize) -> json::Scene {
    generate_with(seed, objects, points, 0.0)
}

/// Share of objects [`generate`] puts at rest on the ground.
pub const RESTING_SHARE: f32 = 0.5;

/// [`generate`] with `resting_share` of the objects (in expectation) at rest on the ground.
pub fn generate_with(seed: u64, objects: usize, points: usize, resting_share: f32) -> json::Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut placed: Vec<([f32; 3], f32)> = Vec::with_capacity(objects);
    let mut side = (objects as f32).sqrt() * 1.2 + 1.0;
    let mut out = Vec::with_capacity(objects);
    for j in 0..objects {
        let half = [
            rng.random_range(0.1f32..0.3),
            rng.random_range(0.1f32..0.3),
            rng.random_range(0.1f32..0.3),
        ];
        let radius = half.iter().map(|h| h * h).sum::<f32>().sqrt();
        let resting = rng.random::<f32>() < resting_share;
        let (pose, velocity) = loop {
            let mut found = None;
            for _ in 0..200 {
                let x = rng.random_range(-side / 2.0..side / 2.0);
                let y = rng.random_range(-side / 2.0..side / 2.0);
                let (z, rotation) = if resting {
                    let yaw = rng.random_range(0.0f32..std::f32::consts::TAU);
                    (half[2], [0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()])
                } else {
                    (
                        radius + rng.random_range(0.05f32..1.0),
                        random_rotation(&mut rng),
                    )
                };
                let c = [x, y, z];
                let clear = placed.iter().all(|(p, r)| {
                    let d2: f32 = (0..3).map(|k| (p[k] - c[k]) * (p[k] - c[k])).sum();
                    d2.sqrt() > r + radius + 0.02
                });
                if clear {
                    found = Some((c, rotation));
                    break;
                }
            }
            match found {
                Some((c, rotation)) => {
                    let velocity = if resting {
                        json::Velocity {
                            linear: [0.0; 3],
                            angular: [0.0; 3],
                        }
                    } else {
                        json::Velocity {
                            linear: [
                                rng.random_range(-1.0f32..1.0),
                                rng.random_range(-1.0f32..1.0),
                                0.0,
                            ],
                            angular: [
                                rng.random_range(-1.0f32..1.0),
                                rng.random_range(-1.0f32..1.0),
                                rng.random_range(-1.0f32..1.0),
                            ],
                        }
                    };
                    placed.push((c, radius));
                    break (
                        json::Pose {
                            translation: c,
                            rotation,
                        },
                        velocity,
                    );
                }
                // Crowded: spread the scene out and try again.
                None => side *= 1.25,
            }
        };
        let cube = dynaserve_geometry::mesh::cube().scaled(half.map(|h| 2.0 * h));
        let pts = dynaserve_geometry::sample_surface(
            &cube,
            points.max(1),
            seed.wrapping_mul(1_000_003).wrapping_add(j as u64),
        );
        let volume = 8.0 * half[0] * half[1] * half[2];
        out.push(json::ObjectSpec {
            points: Some(pts),
            mesh: None,
            pose,
            previous_pose: None,
            velocity: Some(velocity),
            mass: (500.0 * volume).clamp(0.05, 100.0),
            friction: rng.random_range(0.2f32..0.9),
            restitution: rng.random_range(0.1f32..0.6),
        });
    }
    json::Scene { objects: out }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rotate(q: [f32; 4], v: [f32; 3]) -> [f32; 3] {
        let [x, y, z, w] = q;
        let u = [x, y, z];
        let cross = |a: [f32; 3], b: [f32; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let t = cross(u, v).map(|c| 2.0 * c);
        let ut = cross(u, t);
        [0, 1, 2].map(|k| v[k] + w * t[k] + ut[k])
    }

    #[test]
    fn generated_scenes_are_seeded_above_ground_and_disjoint() {
        let a = generate(7, 10, 64);
        assert_eq!(a, generate(7, 10, 64));
        assert_ne!(a, generate(8, 10, 64));
        assert_eq!(a.objects.len(), 10);
        let mut resting = 0;
        for o in &a.objects {
            let pts = o.points.as_ref().unwrap();
            assert_eq!(pts.len(), 64);
            let q = o.pose.rotation;
            assert!((q.iter().map(|c| c * c).sum::<f32>() - 1.0).abs() < 1e-5);
            let lowest = pts
                .iter()
                .map(|p| rotate(q, *p)[2] + o.pose.translation[2])
                .fold(f32::INFINITY, f32::min);
            assert!(lowest >= -1e-4, "a point starts below the ground: {lowest}");
            if lowest < 0.01 {
                resting += 1;
            }
            assert!(o.mass > 0.0 && (0.0..=1.0).contains(&o.restitution));
        }
        assert!(resting > 0, "no object rests on the ground");
        // Convex boxes whose bounding spheres are apart cannot overlap.
        assert_disjoint(&a);
    }

    /// Largest distance of a body-frame point from the centre of mass: a bounding radius.
    fn radius(o: &json::ObjectSpec) -> f32 {
        o.points
            .as_ref()
            .unwrap()
            .iter()
            .map(|p| p.iter().map(|c| c * c).sum::<f32>().sqrt())
            .fold(0.0, f32::max)
    }

    /// Panics unless every two objects' bounding spheres are apart (so the boxes are too).
    fn assert_disjoint(s: &json::Scene) {
        for (i, a) in s.objects.iter().enumerate() {
            for b in &s.objects[i + 1..] {
                let (ra, rb) = (radius(a), radius(b));
                let d: f32 = (0..3)
                    .map(|k| (a.pose.translation[k] - b.pose.translation[k]).powi(2))
                    .sum::<f32>()
                    .sqrt();
                assert!(d > ra + rb, "objects overlap: {d} <= {ra} + {rb}");
            }
        }
    }

    #[test]
    fn crowded_scenes_still_place_every_object() {
        // 200 boxes do not fit the first square tried: the scene must spread out rather than
        // place objects into each other.
        let s = generate(1, 200, 8);
        assert_eq!(s.objects.len(), 200);
        assert_disjoint(&s);
    }

    #[test]
    fn moving_scenes_have_every_object_in_the_air_and_moving() {
        let m = generate_moving(5, 12, 16);
        assert_eq!(m, generate_moving(5, 12, 16));
        assert_disjoint(&m);
        for o in &m.objects {
            let v = o.velocity.unwrap();
            assert!(v.linear != [0.0; 3], "{v:?}");
            assert!(o.pose.translation[2] > radius(o) + 0.04, "{:?}", o.pose);
        }
    }
}
