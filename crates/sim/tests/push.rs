//! The `push` scenario with real rapier worlds: the pusher (the last object) is marked
//! kinematic, follows its path exactly, and the objects it runs through start at rest and are
//! pushed; a written split stores the kinematic flags and documents them.

use dynaserve_sim::generators::{GenerateOptions, Generator, generate_scene};
use dynaserve_sim::scenarios::{Scenario, ScenarioParameters};
use dynaserve_sim::writer::generate_dataset;
use dynaserve_sim::{DatasetReader, SceneLabel};

fn options(scenes: usize) -> GenerateOptions {
    let mut opts = GenerateOptions::new(Generator::scenario(Scenario::Push), 0, "test", scenes);
    opts.points = 64;
    opts
}

fn distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    (0..3).map(|c| (a[c] - b[c]).powi(2)).sum::<f32>().sqrt()
}

#[test]
fn the_pusher_follows_its_path_exactly_and_pushes_the_objects_it_meets() {
    let opts = options(4);
    for index in 0..4 {
        let g = generate_scene(&opts, index).unwrap();
        let objects = &g.record.objects;
        let n = objects.len();
        assert!((2..=4).contains(&n), "scene {index}: {n} objects");
        let label = g.label.clone().unwrap();
        assert_eq!(label.scenario, "push");
        assert_eq!(label.variant, if n == 2 { "single" } else { "group" });
        let flags: Vec<bool> = objects.iter().map(|o| o.kinematic).collect();
        assert_eq!(flags, [vec![false; n - 1], vec![true]].concat());
        let [path] = g.spec.kinematic.as_slice() else {
            panic!("scene {index}: not one kinematic path")
        };
        assert_eq!(path.object, n - 1);
        let pusher = &objects[n - 1];
        for (t, (p, q)) in path.poses.iter().enumerate() {
            let (rp, rq) = (pusher.positions[t + 1], pusher.rotations[t + 1]);
            assert!(
                distance(*p, rp) < 1e-5,
                "scene {index} frame {}: pusher at {rp:?}, path {p:?}",
                t + 1
            );
            let dot: f32 = (0..4).map(|c| q[c] * rq[c]).sum();
            assert!(
                dot.abs() > 1.0 - 1e-6,
                "scene {index}: rotation {rq:?} vs {q:?}"
            );
        }
        // It moves: at least 1.5 m over the scene's 4.17 s.
        let travel = distance(pusher.positions[0], pusher.positions[100]);
        assert!(travel > 1.5, "scene {index}: pusher travelled {travel} m");
        for (j, o) in objects[..n - 1].iter().enumerate() {
            let first = distance(o.positions[0], o.positions[1]);
            assert!(
                first < 1e-3,
                "scene {index}: object {j} not at rest ({first} m)"
            );
            assert!(o.positions.iter().flatten().all(|c| c.is_finite()));
        }
        // The path starts behind the first object and runs through it.
        let pushed = distance(objects[0].positions[0], objects[0].positions[100]);
        assert!(
            pushed > 0.2,
            "scene {index}: first object pushed {pushed} m"
        );
    }
}

/// With jitter the pusher's velocity is drawn afresh every frame within the jitter of its
/// smooth path's, so from frame to frame it changes by more than the jitter somewhere and never
/// by more than twice it plus the path's own change (far less); the scene is otherwise drawn
/// the same, and the pusher still pushes.
#[test]
fn a_jittered_pusher_changes_velocity_every_frame_within_its_bound() {
    let mut p = ScenarioParameters::new(vec![Scenario::Push]);
    p.push_jitter = 0.8;
    let mut jittered = GenerateOptions::new(Generator::scenarios(p), 0, "test", 2);
    jittered.points = 64;
    let smooth = options(2);
    let dt = 1.0 / 24.0;
    // The largest frame-to-frame change of the pusher's horizontal velocity, m/s.
    let largest_change = |positions: &[[f32; 3]]| -> f32 {
        (2..positions.len())
            .flat_map(|t| {
                (0..2).map(move |c| {
                    let v1 = (positions[t][c] - positions[t - 1][c]) / dt;
                    let v0 = (positions[t - 1][c] - positions[t - 2][c]) / dt;
                    (v1 - v0).abs()
                })
            })
            .fold(0.0, f32::max)
    };
    for index in 0..2 {
        let (a, b) = (
            generate_scene(&smooth, index).unwrap(),
            generate_scene(&jittered, index).unwrap(),
        );
        let n = a.record.objects.len();
        assert_eq!(b.record.objects.len(), n);
        for j in 0..n - 1 {
            assert_eq!(
                a.record.objects[j].positions[0],
                b.record.objects[j].positions[0]
            );
        }
        let (ps, pj) = (
            &a.record.objects[n - 1].positions,
            &b.record.objects[n - 1].positions,
        );
        let (cs, cj) = (largest_change(ps), largest_change(pj));
        assert!(cs < 0.3, "scene {index}: smooth path changes by {cs} m/s");
        assert!(
            cj > 0.8 && cj <= 2.0 * 0.8 + cs + 1e-3,
            "scene {index}: jittered pusher changes by {cj} m/s"
        );
        let pushed = distance(
            b.record.objects[0].positions[0],
            b.record.objects[0].positions[100],
        );
        assert!(
            pushed > 0.2,
            "scene {index}: first object pushed {pushed} m"
        );
    }
}

#[test]
fn a_written_push_split_keeps_the_kinematic_flags() {
    let dir = std::env::temp_dir().join(format!("dynaserve-push-{}", std::process::id()));
    let opts = options(2);
    let summary = generate_dataset(&opts, &dir, true, &|| {}).unwrap();
    let m = &summary.manifest;
    assert_eq!(m.generator, "push");
    assert!(m.tensors.iter().any(|t| t.name == "kinematic"));
    let reader = DatasetReader::open(&dir).unwrap();
    for (i, scene) in reader.iter().enumerate() {
        let scene = scene.unwrap();
        let expected = generate_scene(&opts, i as u64).unwrap().record;
        assert_eq!(scene, expected, "scene {i} reads back as simulated");
        assert!(scene.objects.last().unwrap().kinematic);
        let label: &SceneLabel = &reader.manifest().scenarios.as_ref().unwrap()[i];
        assert_eq!(label.scenario, "push");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
