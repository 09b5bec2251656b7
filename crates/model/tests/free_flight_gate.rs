//! `dynamics.free_flight_gate`: an object out of reach of the floor and of every other object
//! for the whole step moves exactly as a rigid body in free flight, whatever the network says;
//! one near the floor, one about to meet another, and every object of a scene with a
//! kinematic object are left to the network. A flat plate flying low, whose bounding sphere
//! would reach the floor, is out of reach by its lowest point.
mod common;

use dynaserve_model::{
    Device, ModelConfig, ObjectInput, Pose, RigidFormer, SceneState, WorldModel,
};
use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const H: f32 = 0.15; // cube half extent, metres

fn cube(rng: &mut ChaCha8Rng, kinematic: bool) -> ObjectInput {
    ObjectInput {
        reference: common::box_cloud(rng, 64, [H; 3]),
        mass: 1.0,
        friction: 0.5,
        restitution: 0.5,
        kinematic,
    }
}

/// A plate of half extents 0.6 x 0.6 x 0.04 m (bounding radius 0.85 m).
fn plate(rng: &mut ChaCha8Rng) -> ObjectInput {
    ObjectInput {
        reference: common::box_cloud(rng, 128, [0.6, 0.6, 0.04]),
        ..cube(rng, false)
    }
}

/// Where a rigid body in free flight goes over a step of `k` frames from `previous` and
/// `current` (constant linear and angular velocity, free fall), as `(centre, rotation)`.
fn ballistic(cfg: &ModelConfig, previous: &Pose, current: &Pose, k: u32) -> Pose {
    let rot = Pose::unit_quaternion;
    let (p0, p1) = (
        Vector3::from(previous.translation),
        Vector3::from(current.translation),
    );
    let h = k as f32 * cfg.dt_frame;
    let centre = p1 * 2.0 - p0 + Vector3::from(cfg.gravity) * h * h;
    Pose::from_parts(
        centre,
        rot(current) * rot(previous).inverse() * rot(current),
    )
}

/// Largest distance between the centres (metres) or rotation angle (radians) of two poses.
fn pose_gap(a: &Pose, b: &Pose) -> f32 {
    let t = (Vector3::from(a.translation) - Vector3::from(b.translation)).norm();
    t.max(a.unit_quaternion().angle_to(&b.unit_quaternion()))
}

/// Object 0 flies high and alone, object 1 rests on the floor far away, object 2 flies next
/// to object 3 and is about to meet it, object 4 (the plate) flies level 0.5 m above the
/// floor, far from the others.
fn state() -> SceneState {
    let turn = |a: f32| UnitQuaternion::from_euler_angles(0.1 * a, -0.2 * a, 0.3 * a);
    let pose = |x: f32, y: f32, z: f32, a: f32| Pose::from_parts(Vector3::new(x, y, z), turn(a));
    SceneState {
        previous: vec![
            pose(0.0, 0.0, 2.0, 0.0),
            pose(4.0, 0.0, H, 0.0),
            pose(-4.0, 0.0, 2.0, 0.0),
            pose(-3.0, 0.0, 2.0, 0.0),
            pose(0.0, 4.0, 0.5, 0.0),
        ],
        current: vec![
            pose(0.05, 0.02, 2.01, 0.1),
            pose(4.0, 0.0, H, 0.0),
            pose(-3.9, 0.0, 2.0, 0.1),
            pose(-3.1, 0.0, 2.0, 0.0),
            pose(0.05, 4.0, 0.5, 0.1),
        ],
        earlier: None,
        carry: Default::default(),
    }
}

fn step(gate: bool, kinematic: bool, k: u32) -> (ModelConfig, Vec<Pose>) {
    let mut cfg = ModelConfig::tiny();
    cfg.dynamics.free_flight_gate = gate;
    let model = RigidFormer::new(cfg.clone(), 4, &Device::Cpu).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut objects: Vec<ObjectInput> = (0..4)
        .map(|i| cube(&mut rng, kinematic && i == 1))
        .collect();
    objects.push(plate(&mut rng));
    let scene = model.prepare(objects).unwrap();
    let state = state();
    (cfg, common::step_one(&model, &scene, &state, k))
}

#[test]
fn only_objects_out_of_reach_fly_ballistically() {
    let s = state();
    for k in [1u32, 4] {
        let gaps = |gate: bool, kinematic: bool| -> Vec<f32> {
            let (cfg, out) = step(gate, kinematic, k);
            (0..5)
                .map(|i| pose_gap(&out[i], &ballistic(&cfg, &s.previous[i], &s.current[i], k)))
                .collect()
        };
        let gated = gaps(true, false);
        let free = gaps(false, false);
        let with_pusher = gaps(true, true);
        // The untrained network moves every object off its ballistic path...
        assert!(free.iter().all(|&g| g > 1e-4), "k {k}: {free:?}");
        // ...except, with the gate, the two out of reach of everything.
        assert!(gated[0] < 1e-5 && gated[4] < 1e-5, "k {k}: {gated:?}");
        for i in 1..4 {
            assert_eq!(
                gated[i], free[i],
                "k {k}, object {i}: {gated:?} vs {free:?}"
            );
        }
        // A kinematic object anywhere in the scene switches the gate off.
        assert_eq!(with_pusher[0], free[0], "k {k}: {with_pusher:?}");
        assert_eq!(with_pusher[4], free[4], "k {k}: {with_pusher:?}");
    }
}
