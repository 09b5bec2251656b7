//! The scenes the step benchmarks run on: MOVi-like scenes of boxes, the 216-cube wrecking
//! ball, and training windows, built from fixed seeds.

use dynaserve_model::{
    ObjectInput, Pose, PreparedScene, RigidFormer, SceneState, StepItem, TrainItem, WorldModel,
};
use nalgebra::{UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `n` points uniformly on the faces of a box of half extents `h` (metres), body frame.
pub fn box_cloud(rng: &mut ChaCha8Rng, n: usize, h: [f32; 3]) -> Vec<[f32; 3]> {
    (0..n)
        .map(|_| {
            let face = rng.random_range(0..6);
            let axis = face / 2;
            let sign = if face % 2 == 0 { 1.0 } else { -1.0 };
            std::array::from_fn(|d| {
                if d == axis {
                    sign * h[d]
                } else {
                    rng.random_range(-h[d]..h[d])
                }
            })
        })
        .collect()
}

/// `n` points uniformly on a sphere of radius `r` (metres), body frame.
pub fn sphere_cloud(rng: &mut ChaCha8Rng, n: usize, r: f32) -> Vec<[f32; 3]> {
    (0..n)
        .map(|_| {
            let v = Vector3::new(
                rng.random_range(-1.0f32..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            )
            .normalize()
                * r;
            [v.x, v.y, v.z]
        })
        .collect()
}

/// A MOVi-like scene: `m` boxes of `n` points spread over the floor, moving.
pub fn movi_scene(rng: &mut ChaCha8Rng, m: usize, n: usize) -> (Vec<ObjectInput>, SceneState) {
    let objects = (0..m)
        .map(|_| {
            let s = rng.random_range(0.35..0.7);
            ObjectInput {
                reference: box_cloud(rng, n, [s, s * 0.8, s * 0.9]),
                mass: rng.random_range(0.5..8.0),
                friction: 0.4,
                restitution: 0.3,
                kinematic: false,
            }
        })
        .collect();
    let current: Vec<Pose> = (0..m)
        .map(|j| {
            Pose::from_parts(
                Vector3::new(
                    -4.0 + 0.9 * j as f32,
                    rng.random_range(-3.0..3.0),
                    rng.random_range(0.5..3.0),
                ),
                UnitQuaternion::from_euler_angles(rng.random_range(-3.0..3.0), 0.3, 1.0),
            )
        })
        .collect();
    let lin: Vec<[f32; 3]> = (0..m)
        .map(|_| [rng.random_range(-3.0..3.0), 1.0, -0.5])
        .collect();
    let ang = vec![[0.5, 0.0, 0.2]; m];
    let state =
        SceneState::from_velocities(current, &lin, &ang, 1.0 / 24.0).expect("valid velocities");
    (objects, state)
}

/// 6 x 6 x 6 stack of 0.5 m cubes on the floor and a ball swinging into it.
pub fn wrecking_ball(n: usize) -> (Vec<ObjectInput>, SceneState) {
    let mut rng = ChaCha8Rng::seed_from_u64(216);
    let mut objects = Vec::new();
    let mut current = Vec::new();
    let side = 0.5f32;
    for i in 0..6 {
        for j in 0..6 {
            for k in 0..6 {
                objects.push(ObjectInput {
                    reference: box_cloud(&mut rng, n, [side / 2.0; 3]),
                    mass: 0.3,
                    friction: 0.5,
                    restitution: 0.1,
                    kinematic: false,
                });
                current.push(Pose {
                    translation: [
                        i as f32 * side,
                        j as f32 * side,
                        side / 2.0 + k as f32 * side,
                    ],
                    rotation: [0.0, 0.0, 0.0, 1.0],
                });
            }
        }
    }
    objects.push(ObjectInput {
        reference: sphere_cloud(&mut rng, 4 * n, 0.6),
        mass: 50.0,
        friction: 0.5,
        restitution: 0.2,
        kinematic: false,
    });
    current.push(Pose {
        translation: [-1.5, 1.25, 1.5],
        rotation: [0.0, 0.0, 0.0, 1.0],
    });
    let m = current.len();
    let mut lin = vec![[0.0f32; 3]; m];
    lin[m - 1] = [8.0, 0.0, 0.0];
    let ang = vec![[0.0f32; 3]; m];
    (
        objects,
        SceneState::from_velocities(current, &lin, &ang, 1.0 / 24.0).expect("valid velocities"),
    )
}

/// `b` MOVi-like scenes of `m` objects of `n` points ([`movi_scene`]), prepared for `model`;
/// `seed` fixes them.
pub fn prepared_batch(
    model: &RigidFormer,
    b: usize,
    m: usize,
    n: usize,
    seed: u64,
) -> Vec<(PreparedScene, SceneState)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..b)
        .map(|_| {
            let (o, s) = movi_scene(&mut rng, m, n);
            (model.prepare(o).expect("valid scene"), s)
        })
        .collect()
}

/// One step of size 1 for every scene of `scenes`.
pub fn items(scenes: &[(PreparedScene, SceneState)]) -> Vec<StepItem<'_>> {
    scenes
        .iter()
        .map(|(scene, state)| StepItem {
            scene,
            state,
            dt_steps: 1,
        })
        .collect()
}

/// 16 MOVi-like training windows of 3 to 10 objects of 256 points, prepared for `model`, each
/// with a constant-velocity target under a small drop; `seed` fixes them.
pub fn train_batch(model: &RigidFormer, seed: u64) -> Vec<(PreparedScene, SceneState, Vec<Pose>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..16)
        .map(|_| {
            let m = rng.random_range(3..=10);
            let (o, s) = movi_scene(&mut rng, m, 256);
            let target: Vec<Pose> = s
                .previous
                .iter()
                .zip(&s.current)
                .map(|(p, c)| Pose {
                    translation: std::array::from_fn(|d| {
                        2.0 * c.translation[d] - p.translation[d] - if d == 2 { 0.017 } else { 0.0 }
                    }),
                    rotation: c.rotation,
                })
                .collect();
            (model.prepare(o).expect("scene"), s, target)
        })
        .collect()
}

/// The training items of [`train_batch`]'s windows (step sizes 1, 2, 4 in turn).
pub fn train_items(data: &[(PreparedScene, SceneState, Vec<Pose>)]) -> Vec<TrainItem<'_>> {
    data.iter()
        .enumerate()
        .map(|(i, (scene, state, target))| TrainItem {
            scene,
            state,
            target,
            dt_steps: [1, 2, 4][i % 3],
            kinematic: &[],
        })
        .collect()
}
