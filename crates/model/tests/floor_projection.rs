//! `ModelConfig::floor_projection`: after the Kabsch fit an object that would end with a
//! point deeper below the floor than the allowed depth is raised along z until its lowest
//! point is at that depth, rotation and horizontal position kept; objects that end above it
//! and kinematic objects are untouched.
mod common;

use dynaserve_model::{Device, ModelConfig, Pose, RigidFormer, SceneState, WorldModel};
use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const H: f32 = 0.15; // cube half extent, metres

/// Height of the lowest of `cloud`'s points (body frame, metres) at `pose`, metres.
fn lowest(cloud: &[[f32; 3]], pose: &Pose) -> f32 {
    let (q, t) = (pose.unit_quaternion(), Vector3::from(pose.translation));
    cloud
        .iter()
        .map(|p| (q * Vector3::from(*p) + t).z)
        .fold(f32::INFINITY, f32::min)
}

/// Object 0 falls fast onto the floor (the step ends inside it), object 1 flies high, object
/// 2 (kinematic when `pusher`) is already half inside the floor and keeps sinking.
fn step(projection: Option<f32>, pusher: bool, k: u32) -> (Vec<Vec<[f32; 3]>>, Vec<Pose>) {
    let mut cfg = ModelConfig::tiny();
    cfg.floor_projection = projection;
    let model = RigidFormer::new(cfg, 4, &Device::Cpu).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let clouds: Vec<Vec<[f32; 3]>> = (0..3)
        .map(|_| common::box_cloud(&mut rng, 96, [H; 3]))
        .collect();
    let objects = clouds
        .iter()
        .enumerate()
        .map(|(i, c)| dynaserve_model::ObjectInput {
            reference: c.clone(),
            mass: 1.0,
            friction: 0.5,
            restitution: 0.3,
            kinematic: pusher && i == 2,
        })
        .collect();
    let scene = model.prepare(objects).unwrap();
    let turn = UnitQuaternion::from_euler_angles(0.2, -0.1, 0.4);
    let pose = |x: f32, z: f32| Pose::from_parts(Vector3::new(x, 0.0, z), turn);
    let state = SceneState {
        previous: vec![pose(0.0, H + 0.9), pose(3.0, 2.0), pose(-3.0, 0.05)],
        current: vec![pose(0.0, H + 0.4), pose(3.0, 2.0), pose(-3.0, 0.0)],
        earlier: None,
        carry: Default::default(),
    };
    (clouds, common::step_one(&model, &scene, &state, k))
}

#[test]
fn objects_end_on_the_floor_not_in_it() {
    for k in [1u32, 4] {
        let (clouds, free) = step(None, false, k);
        let (_, raised) = step(Some(0.0), false, k);
        let (_, slop) = step(Some(0.02), false, k);
        // Without the projection the falling cube and the sinking one end inside the floor.
        assert!(lowest(&clouds[0], &free[0]) < -0.05, "k {k}: {:?}", free[0]);
        assert!(lowest(&clouds[2], &free[2]) < -0.05, "k {k}: {:?}", free[2]);
        for j in [0, 2] {
            // With it, their lowest point is on the floor, and only their height changed.
            assert!(
                lowest(&clouds[j], &raised[j]).abs() < 1e-5,
                "k {k}: object {j}"
            );
            assert_eq!(raised[j].rotation, free[j].rotation);
            assert_eq!(raised[j].translation[..2], free[j].translation[..2]);
            assert!(raised[j].translation[2] > free[j].translation[2]);
            // With an allowed depth, to that depth.
            assert!(
                (lowest(&clouds[j], &slop[j]) + 0.02).abs() < 1e-5,
                "k {k}: object {j}"
            );
            assert_eq!(slop[j].rotation, free[j].rotation);
        }
        // The cube in flight ends above the floor and is left exactly where it was.
        assert!(lowest(&clouds[1], &free[1]) > 0.5);
        assert_eq!(raised[1], free[1]);
        assert_eq!(slop[1], free[1]);
    }
}

#[test]
fn kinematic_objects_are_not_raised() {
    let (clouds, free) = step(None, true, 1);
    let (_, raised) = step(Some(0.0), true, 1);
    assert!(lowest(&clouds[2], &free[2]) < -0.05);
    assert_eq!(raised[2], free[2]);
    assert!(lowest(&clouds[0], &raised[0]).abs() < 1e-5);
}

#[test]
fn a_negative_depth_is_refused_and_an_older_config_means_off() {
    let mut cfg = ModelConfig::tiny();
    let dir = common::tmp_dir("floor", "depth");
    RigidFormer::new(cfg.clone(), 4, &Device::Cpu)
        .unwrap()
        .save(&dir)
        .unwrap();
    // Saved without the projection, config.json does not name it, and it loads as off.
    let text = std::fs::read_to_string(dir.join("config.json")).unwrap();
    assert!(!text.contains("floor_projection"));
    let loaded = dynaserve_model::load_rigidformer(&dir, &Device::Cpu, false).unwrap();
    assert_eq!(loaded.config().floor_projection, None);
    cfg.floor_projection = Some(-0.001);
    std::fs::write(
        dir.join("config.json"),
        serde_json::to_string(&cfg).unwrap(),
    )
    .unwrap();
    let err = common::load_error(&dir);
    assert!(err.contains("floor_projection"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
