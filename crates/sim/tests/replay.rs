//! The rapier replay of scene files (`dynaserve sim replay`) with real rapier worlds: a
//! kinematic pusher follows its path exactly and pushes the box it drives through; a pusher
//! that moves away leaves it still; bad input gives errors naming what is wrong.

use std::path::PathBuf;

use dynaserve_sim::replay::cli::{ReplayArgs, replay_args};
use dynaserve_sim::replay::{PathDoc, ReplayOptions, parse_scene, replay};

/// The 8 corners and the 6 face centres of a box with half extent `h`, metres.
fn box_points(h: f32) -> Vec<[f32; 3]> {
    let mut p = Vec::new();
    for x in [-h, h] {
        for y in [-h, h] {
            for z in [-h, h] {
                p.push([x, y, z]);
            }
        }
    }
    for a in 0..3 {
        for s in [-h, h] {
            let mut c = [0.0; 3];
            c[a] = s;
            p.push(c);
        }
    }
    p
}

/// A 0.2 m box of 1 kg resting on the floor at the origin and a 0.12 m pusher (object 1)
/// 0.02 m behind it on the -x side, as a session create body.
fn scene_doc() -> String {
    serde_json::json!({
        "scene": {"objects": [
            {"points": box_points(0.1), "pose": {"translation": [0.0, 0.0, 0.1]},
             "mass": 1.0, "friction": 0.5},
            {"points": box_points(0.06), "pose": {"translation": [-0.18, 0.0, 0.06]},
             "mass": 5.0, "friction": 0.5},
        ]},
        "kinematic": [1],
    })
    .to_string()
}

/// The pusher moving along x at `speed` m/s from its start for `steps` steps of 1/24 s, with
/// a slow yaw so that the rotation is followed too.
fn path(speed: f32, steps: usize) -> PathDoc {
    let poses = (1..=steps)
        .map(|i| {
            let t = i as f32 / 24.0;
            let (s, c) = (0.1 * t).sin_cos();
            [-0.18 + speed * t, 0.0, 0.06, 0.0, 0.0, s, c]
        })
        .collect();
    PathDoc { object: 1, poses }
}

#[test]
fn pusher_follows_its_path_exactly_and_pushes_the_box() {
    let file = parse_scene(&scene_doc()).unwrap();
    let drive = path(0.6, 24);
    let r = replay(
        &file.scene,
        std::slice::from_ref(&drive),
        24,
        &ReplayOptions::default(),
    )
    .unwrap();
    assert_eq!(r.poses.len(), 25);
    assert_eq!(r.poses[0][1][0], -0.18);
    for (i, want) in drive.poses.iter().enumerate() {
        let got = r.poses[i + 1][1];
        let sign = if got[6] * want[6] < 0.0 { -1.0 } else { 1.0 };
        for c in 0..7 {
            let w = if c >= 3 { sign * want[c] } else { want[c] };
            assert!(
                (got[c] - w).abs() < 1e-5,
                "step {}: pusher at {got:?}, path {want:?}",
                i + 1
            );
        }
    }
    // The pusher travels 0.6 m, 0.02 m of it before touching the box: the box is pushed by
    // about 0.58 m along x and stays on the floor.
    let last = r.poses[24][0];
    assert!(last[0] > 0.45, "box pushed only to {last:?}");
    assert!((last[2] - 0.1).abs() < 0.01, "box left the floor: {last:?}");
    assert!(r.poses.iter().flatten().flatten().all(|c| c.is_finite()));
    assert!((r.masses[0] - 1.0).abs() < 1e-4, "mass {}", r.masses[0]);
}

#[test]
fn a_pusher_moving_away_leaves_the_box_still() {
    let file = parse_scene(&scene_doc()).unwrap();
    let r = replay(
        &file.scene,
        &[path(-0.6, 24)],
        24,
        &ReplayOptions::default(),
    )
    .unwrap();
    let (first, last) = (r.poses[0][0], r.poses[24][0]);
    let moved = (0..3)
        .map(|c| (last[c] - first[c]).powi(2))
        .sum::<f32>()
        .sqrt();
    assert!(moved < 1e-3, "box moved {moved} m");
    assert!(r.poses[24][1][0] < -0.7);
}

#[test]
fn bad_input_gives_errors() {
    let file = parse_scene(&scene_doc()).unwrap();
    let opts = ReplayOptions::default();
    let err = |paths: &[PathDoc], steps: usize| {
        replay(&file.scene, paths, steps, &opts)
            .unwrap_err()
            .to_string()
    };
    let mut wrong = path(0.6, 24);
    wrong.object = 2;
    assert!(err(&[wrong], 24).contains("does not exist"));
    assert!(err(&[path(0.6, 10)], 24).contains("10 poses"));
    assert!(err(&[path(0.6, 24), path(0.6, 24)], 24).contains("two kinematic paths"));
    let mut nan = path(0.6, 24);
    nan.poses[3][0] = f32::NAN;
    assert!(err(&[nan], 24).contains("pose 3"));
    assert!(err(&[], 0).contains("at least one step"));
    let flat = r#"{"objects": [{"points": [[0,0,0],[1,0,0],[0,1,0],[1,1,0]],
        "pose": {"translation": [0, 0, 1]}, "mass": 1}]}"#;
    let e = replay(&parse_scene(flat).unwrap().scene, &[], 2, &opts).unwrap_err();
    assert!(e.to_string().contains("objects[0]"), "{e}");
    assert!(
        parse_scene("{")
            .unwrap_err()
            .to_string()
            .contains("not JSON")
    );
    let odd = ReplayOptions {
        dt_frame: 0.03,
        ..ReplayOptions::default()
    };
    let e = replay(&file.scene, &[], 2, &odd).unwrap_err();
    assert!(e.to_string().contains("whole number"), "{e}");
}

#[test]
fn the_cli_replays_an_example_scene_file() {
    let scene =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/scenes/collision.json");
    let args = ReplayArgs {
        scene,
        paths: None,
        steps: Some(12),
        dt_steps: None,
        dt_frame: 1.0 / 24.0,
        out: None,
    };
    let r = replay_args(&args).unwrap();
    assert_eq!(r.poses.len(), 13);
    // Object 0 is thrown at 3 m/s along +x: it moves that way.
    assert!(
        r.poses[12][0][0] > r.poses[0][0][0] + 0.5,
        "{:?}",
        r.poses[12][0]
    );
    assert!(r.poses.iter().flatten().flatten().all(|c| c.is_finite()));
}
