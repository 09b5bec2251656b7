//! Gradients of a driven rollout's cost with the shipped RigidFormer (`docs/gradients.md`): a
//! box resting on the floor and a kinematic pusher driven into it. The gradient pass rolls a
//! path out as driven steps do and its cost is the host's; its gradients agree with central
//! finite differences of the cost along the path's translations and rotations.

mod common;

use std::path::Path;

use common::box_cloud;
use dynaserve_model::{
    CostTarget, Device, Drive, GradientItem, ObjectInput, PathCost, Pose, RigidFormer, SceneState,
    StepItem, WorldModel, load_rigidformer, path_cost,
};
use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const BOX: usize = 0;
const PUSHER: usize = 1;
const STEPS: usize = 6;

fn model() -> RigidFormer {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rigidformer-small");
    load_rigidformer(&dir, &Device::Cpu, false).expect("the shipped checkpoint loads")
}

fn at(x: f32, y: f32, z: f32) -> Pose {
    Pose {
        translation: [x, y, z],
        rotation: [0.0, 0.0, 0.0, 1.0],
    }
}

/// A 0.2 m box at rest on the floor and a 0.12 m pusher 2 cm behind it, at rest.
fn scene() -> (Vec<ObjectInput>, SceneState) {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let objects = vec![
        ObjectInput {
            reference: box_cloud(&mut rng, 128, [0.1; 3]),
            mass: 1.0,
            friction: 0.5,
            restitution: 0.2,
            kinematic: false,
        },
        ObjectInput {
            reference: box_cloud(&mut rng, 96, [0.06; 3]),
            mass: 5.0,
            friction: 0.5,
            restitution: 0.2,
            kinematic: true,
        },
    ];
    let poses = vec![at(0.0, 0.0, 0.1), at(-0.18, 0.01, 0.06)];
    (objects, SceneState::new(poses.clone(), poses))
}

/// The pusher moving along +x at `speed` m per step (from its start), slightly turning.
fn path(speed: f32) -> Vec<Vec<Pose>> {
    (1..=STEPS)
        .map(|s| {
            let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.01 * s as f32);
            vec![Pose::from_parts(
                Vector3::new(-0.18 + speed * s as f32, 0.01 + 0.002 * s as f32, 0.06),
                turn,
            )]
        })
        .collect()
}

fn cost() -> PathCost {
    PathCost {
        targets: vec![
            CostTarget {
                object: BOX,
                step: STEPS,
                position: [0.35, 0.15, 0.1],
                position_weight: 1.0,
                rotation: Some([0.0, 0.0, 0.0, 1.0]),
                rotation_weight: 0.5,
            },
            CostTarget {
                object: PUSHER,
                step: STEPS / 2,
                position: [0.0, 0.0, 0.06],
                position_weight: 0.3,
                rotation: None,
                rotation_weight: 0.0,
            },
        ],
        smoothness: 2.0,
    }
}

/// The same path through the model's plain driven steps, `[steps][objects]`.
fn driven(
    model: &RigidFormer,
    objects: &[ObjectInput],
    state: &SceneState,
    path: &[Vec<Pose>],
) -> Vec<Vec<Pose>> {
    let scene = model.prepare(objects.to_vec()).unwrap();
    let kinematic: Vec<bool> = objects.iter().map(|o| o.kinematic).collect();
    let mut state = state.clone();
    let mut out = Vec::new();
    for poses in path {
        let targets = vec![(PUSHER, poses[0])];
        let drive = Drive::new(&kinematic, &targets);
        let input = drive.input(&state, false);
        let next = model
            .step(&[StepItem {
                scene: &scene,
                state: &input,
                dt_steps: 1,
            }])
            .unwrap()
            .pop()
            .unwrap();
        out.push(drive.finish(&mut state, next).to_vec());
    }
    out
}

fn gradient(
    model: &RigidFormer,
    objects: &[ObjectInput],
    state: &SceneState,
    paths: &[Vec<Vec<Pose>>],
) -> Vec<dynaserve_model::PathGradient> {
    gradient_of(model, objects, state, paths, &cost())
}

fn gradient_of(
    model: &RigidFormer,
    objects: &[ObjectInput],
    state: &SceneState,
    paths: &[Vec<Vec<Pose>>],
    cost: &PathCost,
) -> Vec<dynaserve_model::PathGradient> {
    let scene = model.prepare(objects.to_vec()).unwrap();
    let kinematic: Vec<bool> = objects.iter().map(|o| o.kinematic).collect();
    model
        .path_gradients(&[GradientItem {
            scene: &scene,
            state,
            kinematic: &kinematic,
            paths,
            dt_steps: 1,
            cost,
            deadline: None,
        }])
        .unwrap()
        .pop()
        .unwrap()
}

#[test]
fn the_gradient_pass_rolls_out_what_driven_steps_roll_out() {
    let model = model();
    let (objects, state) = scene();
    let paths = vec![path(0.03), path(0.05)];
    let answers = gradient(&model, &objects, &state, &paths);
    assert_eq!(answers.len(), 2);
    let kinematic: Vec<bool> = objects.iter().map(|o| o.kinematic).collect();
    for (a, p) in answers.iter().zip(&paths) {
        let want = driven(&model, &objects, &state, p);
        let mut worst = 0f32;
        for (x, y) in a.poses.iter().zip(&want) {
            worst = worst.max(common::max_pose_diff(x, y));
        }
        assert!(worst < 1e-4, "gradient rollout off driven steps by {worst}");
        let reference = path_cost(&cost(), &state, &kinematic, &want);
        assert!(
            (a.cost - reference).abs() < 1e-4 * reference.max(1.0),
            "{} vs {reference}",
            a.cost
        );
        // The box moved: the paths were in contact.
        let moved = a.poses[STEPS - 1][BOX].translation[0];
        assert!(moved > 0.005, "the box did not move: {moved}");
    }
}

/// A smooth case: the box falling freely and the pusher moving and turning 0.3 m beside it,
/// both in the air, so that no contact search result, clamp or branch changes under the
/// perturbations (the pusher reaches the box only through attention).
fn smooth_case() -> (Vec<ObjectInput>, SceneState, Vec<Vec<Pose>>) {
    let (objects, mut state) = scene();
    let lift = 0.5f32;
    // Both tilted, so that each has one lowest point by a margin (the object summary's
    // lowest point is a discrete choice).
    let tilt = |angle: f32| {
        UnitQuaternion::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(0.4, -0.7, 0.2)),
            angle,
        )
    };
    for s in [&mut state.previous, &mut state.current] {
        s[PUSHER] = Pose::from_parts(Vector3::new(-0.52, 0.01, 0.06 + lift), tilt(0.5));
        s[BOX] = Pose::from_parts(Vector3::new(0.0, 0.0, 0.1 + lift), tilt(-0.4));
    }
    state.previous[BOX].translation[2] += 0.01;
    let path = (1..=STEPS)
        .map(|s| {
            let s = s as f32;
            let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.02 * s) * tilt(0.5);
            vec![Pose::from_parts(
                Vector3::new(-0.52 - 0.004 * s, 0.01 + 0.01 * s, 0.06 + lift),
                turn,
            )]
        })
        .collect();
    (objects, state, path)
}

/// The path moved by `h` times `direction` (`[steps][3 translation, 3 rotation]`: metres and
/// radians of a world-axis rotation).
fn moved(path: &[Vec<Pose>], direction: &[[f64; 6]], h: f64) -> Vec<Vec<Pose>> {
    path.iter()
        .zip(direction)
        .map(|(poses, d)| {
            let p = poses[0];
            let t = Vector3::from(p.translation)
                + Vector3::new(d[0], d[1], d[2]).cast::<f32>() * h as f32;
            let w = Vector3::new(d[3], d[4], d[5]).cast::<f32>() * h as f32;
            let q = UnitQuaternion::from_scaled_axis(w) * p.unit_quaternion();
            vec![Pose::from_parts(t, q)]
        })
        .collect()
}

#[test]
fn gradients_agree_with_central_differences() {
    let model = model();
    let (objects, state, base) = smooth_case();
    // The whole cost, and the box's terms alone (which reach the path only through the
    // network).
    let mut through_network = cost();
    through_network.targets.retain(|t| t.object == BOX);
    through_network.smoothness = 0.0;
    for cost in [cost(), through_network] {
        let gradient = |objects: &[ObjectInput], state: &SceneState, paths: &[Vec<Vec<Pose>>]| {
            gradient_of(&model, objects, state, paths, &cost)
        };
        let g = gradient(&objects, &state, std::slice::from_ref(&base))
            .pop()
            .unwrap();
        let grad: Vec<[f64; 6]> = (0..STEPS)
            .map(|s| {
                let (t, r) = (g.translation[s][0], g.rotation[s][0]);
                [t[0], t[1], t[2], r[0], r[1], r[2]].map(f64::from)
            })
            .collect();
        let norm = grad.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
        let cost_of = |p: Vec<Vec<Pose>>| gradient(&objects, &state, &[p]).pop().unwrap().cost;
        let h = 1e-2;
        // Along the gradient itself, and along two fixed mixed directions.
        let mut directions = vec![grad.iter().map(|d| d.map(|v| v / norm)).collect::<Vec<_>>()];
        for salt in [1.0f64, 2.0] {
            let d: Vec<[f64; 6]> = (0..STEPS)
                .map(|s| std::array::from_fn(|i| ((s * 6 + i) as f64 * 0.7 + salt).sin()))
                .collect();
            let n = d.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
            directions.push(d.iter().map(|v| v.map(|x| x / n)).collect());
        }
        for (i, d) in directions.iter().enumerate() {
            let analytic: f64 = grad
                .iter()
                .flatten()
                .zip(d.iter().flatten())
                .map(|(a, b)| a * b)
                .sum();
            let fd = (cost_of(moved(&base, d, h)) - cost_of(moved(&base, d, -h))) / (2.0 * h);
            println!("direction {i}: gradient {analytic:.4e}, central difference {fd:.4e}");
            // Along the gradient the error relative to the derivative; along the others relative
            // to the gradient's norm (their derivatives may be near zero).
            let scale = if i == 0 { analytic.abs() } else { norm };
            assert!(
                (fd - analytic).abs() < 1e-2 * scale,
                "direction {i}: gradient {analytic:e}, central difference {fd:e}"
            );
        }
    }
}
