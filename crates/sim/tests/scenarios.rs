//! The physics scenario generators, checked on real rapier simulations: each scenario shows
//! the behaviour it is meant to isolate.

use dynaserve_sim::dataset::DatasetReader;
use dynaserve_sim::generators::{GenerateOptions, GeneratedScene, generate_scene};
use dynaserve_sim::scenarios::{
    MaterialRanges, Materials, RestVariant, Scenario, ScenarioParameters,
};
use dynaserve_sim::shapes::ShapeKind;
use dynaserve_sim::stats::posed_cloud;
use dynaserve_sim::writer::generate_dataset;
use dynaserve_sim::{Generator, ObjectRecord};

fn options(generator: Generator, seed: u64, scenes: usize) -> GenerateOptions {
    let mut opts = GenerateOptions::new(generator, seed, "scenario-test", scenes);
    opts.points = 128;
    opts
}

fn scenes(generator: Generator, seed: u64, n: usize) -> Vec<GeneratedScene> {
    let opts = options(generator, seed, n);
    (0..n as u64)
        .map(|i| generate_scene(&opts, i).unwrap())
        .collect()
}

fn distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f32>().sqrt()
}

fn lowest(o: &ObjectRecord, t: usize) -> f32 {
    posed_cloud(o, t)
        .iter()
        .map(|p| p[2])
        .fold(f32::INFINITY, f32::min)
}

/// Largest centre displacement from frame 0 over the recording, metres.
fn drift(o: &ObjectRecord) -> f32 {
    o.positions
        .iter()
        .map(|&p| distance(p, o.positions[0]))
        .fold(0.0, f32::max)
}

/// Centre speed between frames `t - 1` and `t`, m/s.
fn speed(o: &ObjectRecord, t: usize, dt: f32) -> f32 {
    distance(o.positions[t], o.positions[t - 1]) / dt
}

#[test]
fn rest_scenes_are_still_from_frame_zero() {
    let mut seen = std::collections::HashSet::new();
    for g in scenes(Generator::scenario(Scenario::Rest), 1, 9) {
        let label = g.label.expect("scenario scenes are labelled");
        assert_eq!(label.scenario, "rest");
        seen.insert(label.variant.clone());
        // Towers: within 1 mm for the whole recording; piles and singles: 2 mm.
        let bound = if label.variant == "tower" { 1e-3 } else { 2e-3 };
        for (i, o) in g.record.objects.iter().enumerate() {
            let d = drift(o);
            assert!(d < bound, "{label:?} object {i} moved {d} m");
            assert!(
                lowest(o, 0) > -3e-3,
                "{label:?} object {i} starts in the floor"
            );
        }
        if label.variant == "tower" {
            assert!(g.record.objects.len() >= 2);
            assert!(
                g.spec
                    .objects
                    .iter()
                    .all(|o| o.shape.kind == ShapeKind::Cube)
            );
        }
    }
    assert_eq!(seen.len(), 3, "all rest variants drawn: {seen:?}");
}

#[test]
fn rest_towers_of_small_cubes_follow_tower_scale_and_stand() {
    let mut p = ScenarioParameters::new(vec![Scenario::Rest]);
    p.rest_variants = vec![RestVariant::Tower];
    p.tower_scale = [0.3, 0.5];
    for g in scenes(Generator::Scenario(Box::new(p.clone())), 4, 3) {
        assert!(g.record.objects.len() >= 2);
        for (i, o) in g.spec.objects.iter().enumerate() {
            assert!(
                (0.3..=0.5).contains(&o.scale),
                "cube {i} has side {} m",
                o.scale
            );
        }
        for (i, o) in g.record.objects.iter().enumerate() {
            let d = drift(o);
            assert!(d < 1e-3, "small tower cube {i} moved {d} m");
        }
    }
    p.tower_scale = [0.5, 0.3];
    let opts = options(Generator::Scenario(Box::new(p)), 4, 1);
    assert!(
        generate_scene(&opts, 0).is_err(),
        "an empty range is rejected"
    );
}

#[test]
fn dropped_objects_fall_bounce_and_end_on_the_floor() {
    // Shapes that cannot roll away, so each must end at rest.
    let mut p = ScenarioParameters::new(vec![Scenario::Drop]);
    p.shapes = vec![
        ShapeKind::Cube,
        ShapeKind::Sponge,
        ShapeKind::Gear,
        ShapeKind::Hull,
    ];
    p.rest_shapes = p.shapes.clone();
    p.floor_shapes = p.shapes.clone();
    for g in scenes(Generator::Scenario(Box::new(p.clone())), 2, 6) {
        let o = &g.record.objects[0];
        let t_end = o.positions.len() - 1;
        let h0 = lowest(o, 0);
        assert!(
            // The sampled cloud's lowest point is at or a little above the solid's.
            (p.drop_height[0] - 1e-3..=p.drop_height[1] + 0.1).contains(&h0),
            "released at {h0} m"
        );
        assert!(
            g.spec.objects[0].angvel.iter().any(|&w| w != 0.0),
            "no spin"
        );
        for t in 0..=t_end {
            assert!(
                lowest(o, t) > -0.05,
                "sank {} m at frame {t}",
                -lowest(o, t)
            );
        }
        let end = lowest(o, t_end);
        assert!(end.abs() < 5e-3, "ends with its lowest point at {end} m");
        assert!(speed(o, t_end, g.record.dt_frame) < 0.02, "still moving");
    }
}

#[test]
fn sliding_objects_are_stopped_by_friction() {
    for g in scenes(Generator::scenario(Scenario::Slide), 3, 6) {
        let dt = g.record.dt_frame;
        for (o, spec) in g.record.objects.iter().zip(&g.spec.objects) {
            let t_end = o.positions.len() - 1;
            let v0 = spec.linvel;
            assert_eq!(v0[2], 0.0);
            let launch = v0[0].hypot(v0[1]);
            assert!((1.0..=5.0).contains(&launch), "launched at {launch} m/s");
            // Starts on the floor, slides along the launch direction, stops.
            let h = lowest(o, 0);
            assert!(
                (-3e-3..0.05).contains(&h),
                "{:?} starts at {h} m",
                spec.shape.kind
            );
            let moved = [
                o.positions[t_end][0] - o.positions[0][0],
                o.positions[t_end][1] - o.positions[0][1],
            ];
            let along = (moved[0] * v0[0] + moved[1] * v0[1]) / launch;
            assert!(along > 0.1, "slid only {along} m");
            assert!(speed(o, t_end, dt) < 0.01, "still moving at the end");
            for t in 0..=t_end {
                assert!(lowest(o, t) < 0.05, "left the floor at frame {t}");
            }
        }
    }
}

#[test]
fn round_objects_roll_on_their_side_and_slow_down() {
    let mut stopped = 0;
    for g in scenes(Generator::scenario(Scenario::Roll), 5, 6) {
        let dt = g.record.dt_frame;
        for (o, spec) in g.record.objects.iter().zip(&g.spec.objects) {
            let kind = spec.shape.kind;
            assert!(
                matches!(kind, ShapeKind::Cylinder | ShapeKind::Cone | ShapeKind::Mug),
                "{kind:?}"
            );
            let t_end = o.positions.len() - 1;
            // Launched rolling: horizontal, and spinning about a horizontal axis at the
            // speed over the centre's height (no slipping at the contact).
            let v0 = spec.linvel;
            let launch = v0[0].hypot(v0[1]);
            assert_eq!(v0[2], 0.0);
            assert!((0.2..=1.5).contains(&launch), "launched at {launch} m/s");
            let w = spec.angvel;
            assert_eq!(w[2], 0.0);
            let spin = w[0].hypot(w[1]);
            let slip = (spin * spec.position[2] - launch).abs();
            assert!(slip < 1e-3 * launch.max(1.0), "slips at {slip} m/s");
            // On the floor throughout, and slower at the end than at the start.
            for t in 0..=t_end {
                assert!(lowest(o, t) < 0.05, "{kind:?} left the floor at frame {t}");
            }
            let end = speed(o, t_end, dt);
            assert!(end < 0.8 * speed(o, 1, dt), "{kind:?} keeps {end} m/s");
            if end < 0.02 {
                stopped += 1;
            }
        }
    }
    assert!(stopped > 0, "no rolling object came to rest");
    // Roll shapes outside the shape list are refused where roll scenes are drawn, and do not
    // matter where they are not.
    let narrow = |scenario: Scenario| {
        let mut p = ScenarioParameters::new(vec![scenario]);
        p.shapes = vec![ShapeKind::Cube, ShapeKind::Cylinder];
        p.rest_shapes = p.shapes.clone();
        p.floor_shapes = p.shapes.clone();
        generate_scene(&options(Generator::scenarios(p), 5, 1), 0)
    };
    let err = narrow(Scenario::Roll).expect_err("cone and mug are not in the list");
    assert!(err.to_string().contains("roll shapes"), "{err}");
    assert!(narrow(Scenario::Drop).is_ok());
}

#[test]
fn colliding_objects_exchange_momentum() {
    let (mut air, mut floor) = (0, 0);
    for g in scenes(Generator::scenario(Scenario::Collide), 4, 10) {
        let label = g.label.unwrap();
        let [a, b] = [&g.record.objects[0], &g.record.objects[1]];
        let dt = g.record.dt_frame;
        let velocity = |o: &ObjectRecord, t: usize| -> [f32; 2] {
            std::array::from_fn(|k| (o.positions[t][k] - o.positions[t - 1][k]) / dt)
        };
        // The first frame at which a's horizontal velocity jumps: the impact.
        let impact = (2..a.positions.len())
            .find(|&t| {
                let (u, v) = (velocity(a, t - 1), velocity(a, t));
                (u[0] - v[0]).hypot(u[1] - v[1]) > 0.3
            })
            .expect("the objects meet");
        let after = (impact + 1).min(a.positions.len() - 1);
        let momentum = |t: usize| -> [f32; 4] {
            let (va, vb) = (velocity(a, t), velocity(b, t));
            [
                a.mass * va[0],
                a.mass * va[1],
                b.mass * vb[0],
                b.mass * vb[1],
            ]
        };
        let (before, later) = (momentum(1), momentum(after));
        let exchanged = (later[0] - before[0]).hypot(later[1] - before[1]);
        let scale = before[0].hypot(before[1]) + before[2].hypot(before[3]);
        // Even a glancing hit, or one through a torus's hole, exchanges some momentum.
        assert!(
            exchanged > 0.02 * scale,
            "{label:?}: exchanged {exchanged} of {scale}"
        );
        if label.variant == "air" {
            air += 1;
            // No floor contact up to the impact, and horizontal momentum is conserved.
            for t in 0..=after {
                assert!(
                    lowest(a, t).min(lowest(b, t)) > 0.05,
                    "{label:?} on the floor"
                );
            }
            let total = |m: [f32; 4]| [m[0] + m[2], m[1] + m[3]];
            let (p0, p1) = (total(before), total(later));
            let lost = (p1[0] - p0[0]).hypot(p1[1] - p0[1]);
            assert!(lost < 0.05 * scale, "{label:?}: momentum changed by {lost}");
        } else {
            floor += 1;
            for o in [a, b] {
                assert!(
                    (-3e-3..0.05).contains(&lowest(o, 0)),
                    "{label:?} not on the floor"
                );
            }
        }
    }
    assert!(air > 0 && floor > 0, "air {air}, floor {floor}");
}

#[test]
fn stack_hit_towers_stand_until_the_thrown_object_arrives() {
    let mut toppled = 0;
    let all = scenes(Generator::scenario(Scenario::StackHit), 5, 4);
    for g in &all {
        let n = g.record.objects.len();
        assert!((3..=5).contains(&n), "{n} objects");
        assert!(g.spec.objects[n - 1].held_until_settled);
        let thrown = &g.record.objects[n - 1];
        let tower = &g.record.objects[..n - 1];
        let reach = 1.5;
        let untouched = thrown
            .positions
            .iter()
            .take_while(|p| p[0].hypot(p[1]) > reach)
            .count();
        assert!(untouched >= 3, "arrives after {untouched} frames");
        for o in tower {
            for p in &o.positions[..untouched] {
                assert!(distance(*p, o.positions[0]) < 1e-3, "tower moved early");
            }
        }
        let moved = tower.iter().map(drift).fold(0.0, f32::max);
        if moved > 0.05 {
            toppled += 1;
        }
    }
    assert!(toppled >= all.len() - 1, "only {toppled} towers were hit");
}

#[test]
fn physics_mix_records_every_scene_label_in_the_manifest() {
    let dir = std::env::temp_dir().join(format!("dynaserve-scenarios-{}", std::process::id()));
    let mut opts = options(Generator::physics_mix(), 6, 10);
    opts.scenes_per_shard = 4;
    let summary = generate_dataset(&opts, &dir, true, &|| {}).unwrap();
    let labels = summary.manifest.scenarios.clone().expect("labels written");
    assert_eq!(labels.len(), 10);
    assert!(
        labels
            .iter()
            .all(|l| Scenario::from_name(&l.scenario).is_some())
    );
    let kinds: std::collections::HashSet<_> = labels.iter().map(|l| &l.scenario).collect();
    assert!(kinds.len() >= 3, "{kinds:?}");
    // Scene i's label is the one its generation reports, whatever the sharding.
    for (i, l) in labels.iter().enumerate() {
        assert_eq!(
            generate_scene(&opts, i as u64).unwrap().label.as_ref(),
            Some(l)
        );
    }
    let reader = DatasetReader::open(&dir).unwrap();
    assert_eq!(reader.manifest().scenarios.as_ref(), Some(&labels));
    // A manifest without labels (older datasets, other generators) still reads.
    let path = dir.join("manifest.json");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    json.as_object_mut().unwrap().remove("scenarios");
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    assert_eq!(
        DatasetReader::open(&dir).unwrap().manifest().scenarios,
        None
    );
    // A label list of the wrong length is refused.
    json["scenarios"] = serde_json::json!([{"scenario": "rest", "variant": "tower"}]);
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    assert!(DatasetReader::open(&dir).is_err());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn scenario_scenes_are_deterministic_and_parameters_are_checked() {
    let opts = options(Generator::physics_mix(), 7, 2);
    let (a, b) = (
        generate_scene(&opts, 1).unwrap(),
        generate_scene(&opts, 1).unwrap(),
    );
    assert_eq!(a.record, b.record);
    assert_eq!(a.label, b.label);
    let mut p = ScenarioParameters::new(vec![Scenario::Rest]);
    p.rest_variants = vec![RestVariant::Tower];
    p.tower_boxes = [4, 4];
    let g = generate_scene(&options(Generator::Scenario(Box::new(p.clone())), 7, 1), 0).unwrap();
    assert_eq!(g.record.objects.len(), 4);
    p.tower_boxes = [0, 3];
    assert!(generate_scene(&options(Generator::Scenario(Box::new(p)), 7, 1), 0).is_err());
    let mut p = ScenarioParameters::new(vec![]);
    assert!(generate_scene(&options(Generator::Scenario(Box::new(p.clone())), 7, 1), 0).is_err());
    p.scenarios = vec![Scenario::Drop];
    p.drop_height = [2.0, 1.0];
    assert!(generate_scene(&options(Generator::Scenario(Box::new(p)), 7, 1), 0).is_err());
}

#[test]
fn uniform_materials_vary_each_coefficient_on_its_own_and_scenes_still_behave() {
    let r = MaterialRanges::UNIFORM;
    let within = |v: f32, range: [f32; 2]| (range[0]..=range[1]).contains(&v);
    let mut drawn = Vec::new();
    for scenario in [Scenario::Rest, Scenario::Collide, Scenario::StackHit] {
        let p = ScenarioParameters::new(vec![scenario]).with_materials(Materials::Uniform);
        for g in scenes(Generator::Scenario(Box::new(p)), 11, 3) {
            for (spec, rec) in g.spec.objects.iter().zip(&g.record.objects) {
                let m = spec.material;
                assert!(within(m.friction, r.friction), "friction {}", m.friction);
                assert!(
                    within(m.restitution, r.restitution),
                    "restitution {}",
                    m.restitution
                );
                assert!(within(m.density, r.density), "density {}", m.density);
                // The record carries what was simulated.
                assert_eq!((rec.friction, rec.restitution), (m.friction, m.restitution));
                drawn.push((m.friction, m.restitution));
            }
            // Rest scenes stand with any material: low friction does not set them sliding.
            if scenario == Scenario::Rest {
                for (i, o) in g.record.objects.iter().enumerate() {
                    assert!(drift(o) < 2e-3, "rest object {i} moved {} m", drift(o));
                }
            }
        }
    }
    // Continuous, and friction says nothing about restitution (in Kubric's two materials
    // they move together: correlation 1).
    let n = drawn.len() as f32;
    let mut distinct: Vec<f32> = drawn.iter().map(|d| d.0).collect();
    distinct.sort_by(f32::total_cmp);
    distinct.dedup();
    assert_eq!(
        distinct.len(),
        drawn.len(),
        "every object draws its own friction"
    );
    let mean = |f: fn(&(f32, f32)) -> f32| drawn.iter().map(f).sum::<f32>() / n;
    let (mf, mr) = (mean(|d| d.0), mean(|d| d.1));
    let cov = |f: &dyn Fn(&(f32, f32)) -> f32| drawn.iter().map(f).sum::<f32>() / n;
    let c = cov(&|d| (d.0 - mf) * (d.1 - mr))
        / (cov(&|d| (d.0 - mf).powi(2)) * cov(&|d| (d.1 - mr).powi(2))).sqrt();
    assert!(c.abs() < 0.6, "friction and restitution correlate: {c}");
    // The default keeps Kubric's two materials.
    let kubric: std::collections::BTreeSet<(u32, u32)> =
        scenes(Generator::scenario(Scenario::Collide), 11, 3)
            .iter()
            .flat_map(|g| g.spec.objects.iter())
            .map(|o| {
                (
                    o.material.friction.to_bits(),
                    o.material.restitution.to_bits(),
                )
            })
            .collect();
    assert!(kubric.len() <= 2, "kubric draws {kubric:?}");
    // Ranges outside what rapier accepts are refused.
    let mut p = ScenarioParameters::new(vec![Scenario::Drop]);
    p.material_ranges = Some(MaterialRanges {
        restitution: [0.5, 1.2],
        ..r
    });
    assert!(generate_scene(&options(Generator::Scenario(Box::new(p)), 7, 1), 0).is_err());
}
