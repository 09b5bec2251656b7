//! rapier restarted from two observed frames, on generated suite scenes: a tower held, free
//! flight exact, landings and collisions met far closer than ballistic motion; and clear errors
//! for scenes it cannot rebuild.

use super::*;
use crate::eval::physics_suite::generate_suite;
use dynaserve_sim::Materials;

/// Per step of a k = 1 rollout from frame `s`: the largest centre distance (m) to the truth.
fn errors(p: &dyn Predictor, scene: &SceneRecord, s: usize, steps: usize) -> Vec<f32> {
    let observed = SceneState::new(poses_at(scene, s - 1).unwrap(), poses_at(scene, s).unwrap());
    let out = p.rollout(scene, &observed, 1, steps).unwrap();
    assert_eq!(out.len(), steps);
    out.iter()
        .enumerate()
        .map(|(i, poses)| {
            let truth = poses_at(scene, s + i + 1).unwrap();
            poses
                .iter()
                .zip(truth)
                .map(|(a, b)| {
                    (0..3)
                        .map(|c| (a.translation[c] - b.translation[c]).powi(2))
                        .sum::<f32>()
                        .sqrt()
                })
                .fold(0.0, f32::max)
        })
        .collect()
}

#[test]
fn rapier_restarted_from_two_frames_holds_rest_and_free_flight_and_meets_the_contact() {
    let scenes = generate_suite(3, "test", 1, 64, Materials::Kubric).unwrap();
    let gravity = [0.0, 0.0, -10.0];
    let rapier = RapierRestart::movi(gravity);
    let ballistic = Ballistic {
        gravity,
        floor_z: Some(0.0),
    };
    let find = |scenario: &str, variant: &str| {
        &scenes
            .iter()
            .find(|s| {
                s.label
                    .as_ref()
                    .is_some_and(|l| l.scenario == scenario && l.variant == variant)
            })
            .unwrap_or_else(|| panic!("no {scenario} {variant} scene"))
            .scene
    };
    // A resting tower stays where it stands (ballistic motion knows only the floor).
    let tower = errors(&rapier, find("rest", "tower"), 1, 40);
    assert!(tower.iter().all(|&e| e < 1e-3), "{tower:?}");
    // Dropped, and thrown at each other: exact in free flight, with the velocity at the end of
    // the observed frame recovered through rapier's integration substeps (a step's worth of
    // gravity off would be millimetres within 12 frames); at the first frame where ballistic
    // motion is a centimetre off (the landing, the collision), the restart is ten times closer.
    for (scenario, variant) in [("drop", "drop"), ("collide", "air")] {
        let restart = errors(&rapier, find(scenario, variant), 1, 40);
        let free = errors(&ballistic, find(scenario, variant), 1, 40);
        let contact = free.iter().position(|&e| e > 0.01).expect("a contact");
        assert!(contact >= 5, "{scenario}: contact at step {contact}");
        for i in 0..contact {
            if free[i] < 1e-4 {
                assert!(restart[i] < 1e-4, "{scenario} step {i}: {restart:?}");
            }
        }
        assert!(
            restart[contact] * 10.0 < free[contact],
            "{scenario} {variant}: restart {restart:?} ballistic {free:?}"
        );
    }
}

#[test]
fn rapier_restart_names_what_it_cannot_rebuild() {
    let falling = scene(1, 10, |_, t| {
        pose(
            Vector3::new(0.0, 0.0, 2.0 - 5.0 * t * t),
            UnitQuaternion::identity(),
        )
    });
    let observed = SceneState::new(
        poses_at(&falling, 0).unwrap(),
        poses_at(&falling, 1).unwrap(),
    );
    let rapier = RapierRestart::movi([0.0, 0.0, -10.0]);
    assert_eq!(rapier.rollout(&falling, &observed, 1, 3).unwrap().len(), 3);
    let refused = |edit: &dyn Fn(&mut ObjectRecord), want: &str| {
        let mut bad = falling.clone();
        edit(&mut bad.objects[0]);
        let e = rapier
            .rollout(&bad, &observed, 1, 3)
            .unwrap_err()
            .to_string();
        assert!(e.contains(want), "{want:?} not in {e}");
    };
    refused(&|o| o.shape_id = 10, "shape_id 10 is not in the shape list");
    refused(&|o| o.material = 1, "only rigid objects");
    refused(&|o| o.scale = [1.0, 2.0, 1.0], "not uniform");
    refused(&|o| o.mass = 0.0, "mass must be positive (0 kg)");
}

/// Rebuilt from the first points of each cloud instead of the exact shapes, the restart is a
/// different simulation: in free flight it stays within millimetres (the hull's mass
/// properties are near the shape's), at the landing the 64-point hull is much farther off than
/// the exact shape (where it touches the floor is known only to the sample's spacing); asking
/// for more points than a cloud has uses all of them.
#[test]
fn rapier_restart_from_the_clouds_uses_their_hulls() {
    let scenes = generate_suite(3, "test", 1, 64, Materials::Kubric).unwrap();
    let gravity = [0.0, 0.0, -10.0];
    let drop = &scenes
        .iter()
        .find(|s| s.label.as_ref().is_some_and(|l| l.scenario == "drop"))
        .expect("a drop scene")
        .scene;
    let exact = RapierRestart::movi(gravity);
    let cloud = exact.clone().with_cloud_points(Some(64));
    let every = exact.clone().with_cloud_points(Some(10_000));
    let ballistic = Ballistic {
        gravity,
        floor_z: Some(0.0),
    };
    let (e, c) = (errors(&exact, drop, 1, 40), errors(&cloud, drop, 1, 40));
    assert_eq!(c, errors(&every, drop, 1, 40));
    assert_eq!(
        (exact.name(), cloud.name()),
        ("rapier-restart".to_string(), "rapier-hull-64".to_string())
    );
    let free = errors(&ballistic, drop, 1, 40);
    let contact = free.iter().position(|&x| x > 0.01).expect("a landing");
    assert!(c[..contact].iter().all(|&x| x < 5e-3), "cloud {c:?}");
    assert!(e[contact] * 2.0 < c[contact], "exact {e:?} cloud {c:?}");
}
