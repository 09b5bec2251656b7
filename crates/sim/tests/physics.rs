//! Physics sanity of generated scenes, checked with real rapier worlds and parry queries.

use dynaserve_sim::generators::{GenerateOptions, Generator, generate_scene};
use dynaserve_sim::materials::{METAL, MOVI_FLOOR, RUBBER};
use dynaserve_sim::random::scene_rng;
use dynaserve_sim::scene::{ObjectSpec, SceneSpec, SimConfig, SimWorld, simulate_observed};
use dynaserve_sim::shapes::{Shape, ShapeKind};
use dynaserve_sim::stats::{posed_cloud, rotate};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rapier3d::parry::query::{contact, intersection_test};

/// Largest penetration between any two objects at the current state of `w`, metres.
fn max_penetration(w: &SimWorld) -> f32 {
    let n = w.bodies.len();
    let mut worst = 0.0f32;
    for a in 0..n {
        for b in a + 1..n {
            let pa = w.pose(a) * w.shapes[a].0;
            let pb = w.pose(b) * w.shapes[b].0;
            let c = contact(
                &pa,
                w.shapes[a].1.as_ref(),
                &pb,
                w.shapes[b].1.as_ref(),
                0.0,
            )
            .expect("parry supports every shape pair used here");
            if let Some(c) = c {
                worst = worst.max(-c.dist);
            }
        }
    }
    worst
}

struct Sanity {
    penetration: f32,
    penetration_end: f32,
    lowest: f32,
    lowest_end: f32,
    energy_growth: f64,
    energy_start: f64,
}

fn check_scene(opts: &GenerateOptions, index: u64) -> Sanity {
    let g = generate_scene(opts, index).unwrap();
    let frames = opts.sim.frames;
    let mut s = Sanity {
        penetration: 0.0,
        penetration_end: 0.0,
        lowest: f32::INFINITY,
        lowest_end: f32::INFINITY,
        energy_growth: f64::NEG_INFINITY,
        energy_start: 0.0,
    };
    let mut previous = None;
    let traj = simulate_observed(&g.spec, &opts.sim, |frame, w| {
        let pen = max_penetration(w);
        s.penetration = s.penetration.max(pen);
        if frame == frames - 1 {
            s.penetration_end = pen;
        }
        let e = w.energy();
        if frame == 0 {
            s.energy_start = e;
        }
        if let Some(p) = previous {
            s.energy_growth = s.energy_growth.max(e - p);
        }
        previous = Some(e);
        if frame == 0 {
            for &h in &w.bodies {
                let com = w.world.bodies[h].local_center_of_mass();
                assert!(
                    com.length() < 1e-4,
                    "body origin is off the centre of mass: {com:?}"
                );
            }
        }
    })
    .unwrap();
    // The dataset record is exactly the observed simulation.
    for (o, pos) in g.record.objects.iter().zip(&traj.positions) {
        assert_eq!(&o.positions, pos);
    }
    for o in &g.record.objects {
        for t in 0..frames {
            let low = posed_cloud(o, t)
                .iter()
                .map(|p| p[2])
                .fold(f32::INFINITY, f32::min);
            s.lowest = s.lowest.min(low);
            if t == frames - 1 {
                s.lowest_end = s.lowest_end.min(low);
            }
        }
    }
    s
}

#[test]
fn movi_scenes_are_physically_sane() {
    let cases = [(Generator::movi_b(), 6u64), (Generator::movi_a(), 3)];
    for (generator, count) in cases {
        let opts = GenerateOptions::new(generator, 7, "physics-test", count as usize);
        for i in 0..count {
            let s = check_scene(&opts, i);
            let what = format!("{} scene {i}", opts.generator.name());
            // No object ends below the floor by more than 1 cm. During impacts rapier's soft
            // contacts (60 Hz against the fixed floor, 30 Hz between bodies) give way by about
            // impact speed / (2 pi f), more under a single sharp vertex: cone tips landing at
            // 7-12 m/s dip up to 4 cm in the 200-scene test split. Transients are bounded by
            // 5 cm against the floor and 3 cm between objects.
            assert!(
                s.lowest_end >= -0.01,
                "{what}: ends {} m below the floor",
                -s.lowest_end
            );
            assert!(
                s.lowest >= -0.05,
                "{what}: dips {} m below the floor",
                -s.lowest
            );
            // At the end, overlaps are within rapier's 5 mm slop.
            assert!(
                s.penetration_end <= 0.005,
                "{what}: final overlap {}",
                s.penetration_end
            );
            assert!(
                s.penetration <= 0.03,
                "{what}: overlap {} during impacts",
                s.penetration
            );
            // Energy (kinetic + gravitational) never grows across a frame by more than
            // 1e-4 of the initial energy (integration round-off), plus 1 mJ.
            let tol = 1e-4 * s.energy_start.abs() + 1e-3;
            assert!(s.energy_start > 1.0, "{what}: energy {}", s.energy_start);
            assert!(
                s.energy_growth <= tol,
                "{what}: energy grew by {} J in one frame (tolerance {tol})",
                s.energy_growth
            );
        }
    }
}

fn resting_object(kind: ShapeKind, scale: f32, rotation: [f32; 4]) -> ObjectSpec {
    let shape = Shape::unit(kind, &mut ChaCha8Rng::seed_from_u64(0)).unwrap();
    // Lowest point of the rotated, scaled collider: place it exactly on the floor.
    let (pose, s) = shape.scaled(scale).collider().unwrap();
    let rot = dynaserve_sim::scene::pose_from_arrays([0.0; 3], rotation);
    let aabb = s.compute_aabb(&(rot * pose));
    ObjectSpec {
        shape,
        shape_id: 0,
        scale,
        material: METAL,
        material_kind: 0,
        position: [0.0, 0.0, -aabb.mins.z],
        rotation,
        linvel: [0.0; 3],
        angvel: [0.0; 3],
        held_until_settled: false,
    }
}

#[test]
fn resting_objects_stay_at_rest() {
    let upright = [0.0, 0.0, 0.0, 1.0];
    // On its side, resting on one of the 32 facets (not on an edge, an unstable equilibrium).
    let side = rapier3d::math::Rotation::from_rotation_x(std::f32::consts::FRAC_PI_2)
        * rapier3d::math::Rotation::from_rotation_z(
            std::f32::consts::PI / dynaserve_sim::shapes::ROUND_SEGMENTS as f32,
        );
    let side = [side.x, side.y, side.z, side.w];
    let cases = [
        (ShapeKind::Cube, 1.0, upright),
        (ShapeKind::Sphere, 1.0, upright),
        (ShapeKind::Cylinder, 0.7, upright),
        (ShapeKind::Cylinder, 1.4, side),
        (ShapeKind::Cone, 1.2, upright),
        (ShapeKind::Torus, 1.0, upright),
        (ShapeKind::Sponge, 1.0, upright),
        (ShapeKind::Mug, 0.9, upright),
        (ShapeKind::Gear, 1.0, upright),
    ];
    for (kind, scale, rotation) in cases {
        for material in [METAL, RUBBER] {
            let mut o = resting_object(kind, scale, rotation);
            o.material = material;
            let start = (o.position, o.rotation);
            let spec = SceneSpec {
                objects: vec![o],
                floor: MOVI_FLOOR,
                gravity: [0.0, 0.0, -10.0],
                settle_steps: 0,
                kinematic: Vec::new(),
            };
            let traj = simulate_observed(&spec, &SimConfig::default(), |_, _| {}).unwrap();
            for (t, (p, q)) in traj.positions[0].iter().zip(&traj.rotations[0]).enumerate() {
                let d = ((p[0] - start.0[0]).powi(2)
                    + (p[1] - start.0[1]).powi(2)
                    + (p[2] - start.0[2]).powi(2))
                .sqrt();
                let dot: f32 = (0..4).map(|k| q[k] * start.1[k]).sum();
                let angle = 2.0 * dot.abs().min(1.0).acos();
                assert!(d < 2e-3, "{kind:?} x{scale} moved {d} m by frame {t}");
                assert!(
                    angle < 2e-3,
                    "{kind:?} x{scale} turned {angle} rad by frame {t}"
                );
            }
        }
    }
}

#[test]
fn wrecking_ball_stack_stands_until_hit_and_settles_sanely() {
    let opts = GenerateOptions::new(Generator::wrecking_ball(4).unwrap(), 3, "physics-test", 1);
    let g = generate_scene(&opts, 0).unwrap();
    // The ball, held out while the stack settles, flies with its full mass once released.
    simulate_observed(&g.spec, &opts.sim, |frame, w| {
        if frame == 1 {
            for (&b, &c) in w.bodies.iter().zip(&w.colliders) {
                let (mb, mc) = (w.world.bodies[b].mass(), w.world.colliders[c].mass());
                assert!(
                    (mb - mc).abs() <= 1e-5 * mc,
                    "body mass {mb}, collider mass {mc}"
                );
            }
        }
    })
    .unwrap();
    let n = g.record.objects.len();
    assert_eq!(n, 65);
    let ball = &g.record.objects[n - 1];
    // Frames before the ball comes within 0.5 m of the stack's bounding box.
    let half = 0.5 * (4.0 * 0.402 - 0.002) + 0.5;
    let untouched = ball
        .positions
        .iter()
        .take_while(|p| p[0].abs() > half + 0.5 || p[1].abs() > half + 0.5)
        .count();
    assert!(
        untouched >= 3,
        "the ball arrives too early ({untouched} frames)"
    );
    for o in &g.record.objects[..n - 1] {
        let p0 = o.positions[0];
        for p in &o.positions[..untouched] {
            let d =
                ((p[0] - p0[0]).powi(2) + (p[1] - p0[1]).powi(2) + (p[2] - p0[2]).powi(2)).sqrt();
            assert!(d < 2e-3, "a cube moved {d} m before the ball arrived");
        }
    }
    // The ball hits: some cubes end far from where they started.
    let moved = g.record.objects[..n - 1]
        .iter()
        .filter(|o| {
            let (a, b) = (o.positions[0], o.positions[opts.sim.frames - 1]);
            (a[0] - b[0]).hypot(a[1] - b[1]) > 0.2
        })
        .count();
    assert!(moved >= 4, "only {moved} cubes moved");
    for o in &g.record.objects {
        let low = posed_cloud(o, opts.sim.frames - 1)
            .iter()
            .map(|p| p[2])
            .fold(f32::INFINITY, f32::min);
        assert!(low >= -0.01, "an object ends {} m below the floor", -low);
    }
}

#[test]
fn mass_is_unit_volume_times_density_times_scale_cubed() {
    let opts = GenerateOptions::new(Generator::movi_b(), 1, "physics-test", 1);
    let mut rng = scene_rng(1, "physics-test", "movi-b", 0);
    let spec = opts.generator.sample(&mut rng).unwrap();
    let g = generate_scene(&opts, 0).unwrap();
    assert_eq!(spec.objects.len(), g.record.objects.len());
    for (o, r) in spec.objects.iter().zip(&g.record.objects) {
        let (unit_volume, _) = o.shape.volume_and_centroid().unwrap();
        let want = unit_volume * o.material.density * o.scale.powi(3);
        assert!(
            (r.mass - want).abs() <= 1e-4 * want,
            "{:?}: mass {} vs {want}",
            o.shape.kind,
            r.mass
        );
        assert!(o.material == METAL || o.material == RUBBER);
        assert_eq!(r.friction, o.material.friction);
        assert_eq!(r.restitution, o.material.restitution);
    }
}

/// An object built from its mass gets the density that gives that mass in rapier, and a
/// mass that is not positive or a shape without volume is refused by name.
#[test]
fn an_object_of_a_given_mass_weighs_that_in_the_simulation() {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let cube = Shape::unit(ShapeKind::Cube, &mut rng).unwrap();
    let o = ObjectSpec::rigid_of_mass(cube.clone(), 0, 0.5, 2.0, 0.4, 0.3).unwrap();
    // A cube of side 0.5 m holds 0.125 m^3: 16 kg per m^3 makes it 2 kg.
    assert!((o.material.density - 16.0).abs() < 1e-3, "{:?}", o.material);
    assert_eq!((o.material.friction, o.material.restitution), (0.4, 0.3));
    let spec = SceneSpec {
        objects: vec![ObjectSpec {
            position: [0.0, 0.0, 1.0],
            ..o
        }],
        floor: MOVI_FLOOR,
        gravity: [0.0, 0.0, -10.0],
        settle_steps: 0,
        kinematic: Vec::new(),
    };
    let traj = simulate_observed(&spec, &SimConfig::default(), |_, _| {}).unwrap();
    assert!((traj.masses[0] - 2.0).abs() < 1e-3, "{:?}", traj.masses);
    for mass in [0.0, -1.0, f32::NAN] {
        let e = ObjectSpec::rigid_of_mass(cube.clone(), 0, 0.5, mass, 0.4, 0.3).unwrap_err();
        assert!(e.to_string().contains("mass must be positive"), "{e}");
    }
    let e = ObjectSpec::rigid_of_mass(cube, 0, 0.0, 1.0, 0.4, 0.3).unwrap_err();
    assert!(e.to_string().contains("spans no volume"), "{e}");
}

#[test]
fn spawns_follow_kubric_rules() {
    let p = match Generator::movi_b() {
        Generator::MoviB(p) => p,
        _ => unreachable!("movi_b builds MoviB"),
    };
    let generator = Generator::movi_b();
    let mut shapes_seen = [false; 10];
    let mut metals = 0;
    let mut total = 0;
    for i in 0..40 {
        let mut rng = scene_rng(4, "spawn-test", "movi-b", i);
        let spec = generator.sample(&mut rng).unwrap();
        let n = spec.objects.len();
        assert!((3..=10).contains(&n), "{n} objects");
        let placed: Vec<_> = spec
            .objects
            .iter()
            .map(|o| {
                let (off, s) = o.scaled_shape().collider().unwrap();
                (o.initial_pose() * off, s)
            })
            .collect();
        for a in 0..n {
            let (pose, s) = &placed[a];
            let aabb = s.compute_aabb(pose);
            for k in 0..3 {
                assert!(
                    aabb.mins[k] >= p.spawn_min[k] - 1e-4,
                    "outside the spawn box"
                );
                assert!(
                    aabb.maxs[k] <= p.spawn_max[k] + 1e-4,
                    "outside the spawn box"
                );
            }
            for (b, (other_pose, other)) in placed.iter().enumerate().skip(a + 1) {
                let hit = intersection_test(pose, s.as_ref(), other_pose, other.as_ref())
                    .unwrap()
                    .intersecting;
                assert!(!hit, "objects {a} and {b} overlap at spawn");
            }
            let o = &spec.objects[a];
            // v = U([-4,-4,0],[4,4,0]) - [x, y, 0]
            let u = [o.linvel[0] + o.position[0], o.linvel[1] + o.position[1]];
            assert!(
                u.iter().all(|c| c.abs() <= 4.0 + 1e-4),
                "velocity draw {u:?}"
            );
            assert_eq!(o.linvel[2], 0.0);
            assert_eq!(o.angvel, [0.0; 3]);
            assert!((0.7..=1.4).contains(&o.scale));
            let q = o.rotation;
            let norm = q.iter().map(|c| c * c).sum::<f32>().sqrt();
            assert!((norm - 1.0).abs() < 1e-5);
            shapes_seen[o.shape_id as usize] = true;
            metals += (o.material == METAL) as usize;
            total += 1;
        }
        assert_eq!(spec.gravity, [0.0, 0.0, -10.0]);
    }
    assert!(
        shapes_seen.iter().all(|&s| s),
        "shapes seen: {shapes_seen:?}"
    );
    let frac = metals as f64 / total as f64;
    assert!((0.35..0.65).contains(&frac), "metal fraction {frac}");
    // MOVi-A: only two scales.
    let a = Generator::movi_a();
    for i in 0..5 {
        let spec = a
            .sample(&mut scene_rng(4, "spawn-test", "movi-a", i))
            .unwrap();
        for o in &spec.objects {
            assert!(o.scale == 0.7 || o.scale == 1.4);
            assert!(o.shape_id < 3);
        }
    }
}

#[test]
fn reference_clouds_ride_with_the_body() {
    // A reference point posed with the recorded pose equals the body frame point transformed by
    // the rapier body pose at that frame.
    let opts = GenerateOptions::new(Generator::movi_b(), 11, "physics-test", 1);
    let g = generate_scene(&opts, 0).unwrap();
    let mut checked = 0;
    simulate_observed(&g.spec, &opts.sim, |frame, w| {
        if frame % 25 != 0 {
            return;
        }
        for (i, o) in g.record.objects.iter().enumerate() {
            let pose = w.pose(i);
            for &r in o.reference_points.iter().take(8) {
                let want = pose * rapier3d::math::Vector::new(r[0], r[1], r[2]);
                let q = o.rotations[frame];
                let got = rotate(q, r);
                let p = o.positions[frame];
                let got = [got[0] + p[0], got[1] + p[1], got[2] + p[2]];
                let err = ((got[0] - want.x).powi(2)
                    + (got[1] - want.y).powi(2)
                    + (got[2] - want.z).powi(2))
                .sqrt();
                assert!(err < 1e-5, "posed point off by {err}");
                checked += 1;
            }
        }
    })
    .unwrap();
    assert!(checked > 0);
}
