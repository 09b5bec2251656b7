//! The training entry point: gradients reach every parameter, the Kabsch op's gradient is
//! right, and the loss behaves.
mod common;

use candle_core::{Tensor, Var};
use common::random_scene;
use dynaserve_model::{
    Device, KabschOp, ModelConfig, Pose, PreparedScene, RigidFormer, SceneState, TrainItem,
    WorldModel,
};
use nalgebra::{UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Ground-truth-like next poses: constant velocity plus a little gravity and spin.
fn next_poses(state: &SceneState) -> Vec<Pose> {
    state
        .previous
        .iter()
        .zip(&state.current)
        .map(|(p, c)| {
            let t: Vec<f32> = (0..3)
                .map(|d| 2.0 * c.translation[d] - p.translation[d])
                .collect();
            let dq = c.unit_quaternion() * p.unit_quaternion().inverse();
            Pose::from_parts(
                Vector3::new(t[0], t[1], t[2] - 0.01),
                UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.02))
                    * dq
                    * c.unit_quaternion(),
            )
        })
        .collect()
}

#[test]
fn every_parameter_receives_a_gradient() {
    let model = RigidFormer::new(ModelConfig::tiny(), 3, &Device::Cpu).unwrap();
    let (o1, s1) = random_scene(1, 3, 64);
    let (o2, s2) = random_scene(2, 5, 40);
    let (sc1, sc2) = (model.prepare(o1).unwrap(), model.prepare(o2).unwrap());
    let (t1, t2) = (next_poses(&s1), next_poses(&s2));
    let out = model
        .train_forward(&[
            TrainItem {
                scene: &sc1,
                state: &s1,
                target: &t1,
                dt_steps: 2,
                kinematic: &[],
            },
            TrainItem {
                scene: &sc2,
                state: &s2,
                target: &t2,
                dt_steps: 4,
                kinematic: &[],
            },
        ])
        .unwrap();
    let loss = out.loss.to_scalar::<f32>().unwrap();
    assert!(loss.is_finite() && loss > 0.0);
    assert_eq!(out.positions_pre.dims(), &[8, 4, 3]);
    assert_eq!(out.transforms.dims(), &[8, 12]);
    let grads = out.loss.backward().unwrap();
    let vars = model.varmap().data().lock().unwrap().clone();
    assert!(vars.len() > 40);
    let missing = common::params_without_gradient(&grads, &vars);
    assert!(
        missing.is_empty(),
        "parameters without gradient: {missing:?}"
    );
}

#[test]
fn projection_is_exact_for_rigid_targets_and_loss_terms_agree() {
    // With the post-projection positions equal to R A_ref + p, and pre-projection positions
    // A_pre, the post accelerations follow from positions: check the bookkeeping.
    let model = RigidFormer::new(ModelConfig::tiny(), 4, &Device::Cpu).unwrap();
    let (objs, st) = random_scene(5, 3, 50);
    let sc = model.prepare(objs).unwrap();
    let tg = next_poses(&st);
    let out = model
        .train_forward(&[TrainItem {
            scene: &sc,
            state: &st,
            target: &tg,
            dt_steps: 1,
            kinematic: &[],
        }])
        .unwrap();
    let d = (&out.accel_post - &out.accel_pre).unwrap();
    let d2 = (&out.positions_post - &out.positions_pre).unwrap();
    let diff = (d - d2)
        .unwrap()
        .abs()
        .unwrap()
        .max_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
    assert!(diff < 1e-5);
    // Post-projection anchors are a rigid image of the reference anchors.
    let post: Vec<Vec<Vec<f32>>> = out.positions_post.to_vec3().unwrap();
    for (j, obj_post) in post.iter().enumerate() {
        let refs = sc.reference(j).unwrap();
        let idx = sc.anchor_indices(j).unwrap();
        for a in 0..idx.len() {
            for b in 0..idx.len() {
                let dr: f32 = (0..3)
                    .map(|k| (refs[idx[a]][k] - refs[idx[b]][k]).powi(2))
                    .sum::<f32>()
                    .sqrt();
                let dp: f32 = (0..3)
                    .map(|k| (obj_post[a][k] - obj_post[b][k]).powi(2))
                    .sum::<f32>()
                    .sqrt();
                assert!((dr - dp).abs() < 1e-4);
            }
        }
    }
}

fn kabsch_loss(reference: &[Vec<[f64; 3]>], target: &[Vec<[f64; 3]>], g: &[f64]) -> f64 {
    let mut l = 0.0;
    for (o, (r, t)) in reference.iter().zip(target).enumerate() {
        let s = dynaserve_geometry::kabsch(r, t, None).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                l += g[o * 12 + i * 3 + j] * s.rotation[(i, j)];
            }
            l += g[o * 12 + 9 + i] * s.translation[i];
        }
    }
    l
}

#[test]
fn kabsch_op_gradient_matches_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let (objects, k) = (3, 6);
    let reference: Vec<Vec<[f64; 3]>> = (0..objects)
        .map(|_| {
            (0..k)
                .map(|_| [0; 3].map(|_: i32| rng.random_range(-0.5..0.5)))
                .collect()
        })
        .collect();
    let target: Vec<Vec<[f64; 3]>> = reference
        .iter()
        .map(|r| {
            r.iter()
                .map(|p| {
                    [
                        p[1] + rng.random_range(-0.1..0.1),
                        -p[0] + 1.0,
                        p[2] + rng.random_range(-0.1..0.1),
                    ]
                })
                .collect()
        })
        .collect();
    let g: Vec<f64> = (0..objects * 12)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let flat: Vec<f32> = target
        .iter()
        .flatten()
        .flatten()
        .map(|v| *v as f32)
        .collect();
    let x = Var::from_tensor(
        &Tensor::from_vec(flat, (objects, k, 3), &candle_core::Device::Cpu).unwrap(),
    )
    .unwrap();
    let op = KabschOp::new(reference.clone());
    let out = op.apply(x.as_tensor()).unwrap();
    // Forward equals the geometry routine.
    let rows: Vec<Vec<f32>> = out.to_vec2().unwrap();
    let t32: Vec<Vec<[f64; 3]>> = target
        .iter()
        .map(|o| o.iter().map(|p| p.map(|v| v as f32 as f64)).collect())
        .collect();
    for o in 0..objects {
        let s = dynaserve_geometry::kabsch(&reference[o], &t32[o], None).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                assert!((rows[o][i * 3 + j] as f64 - s.rotation[(i, j)]).abs() < 1e-6);
            }
            assert!((rows[o][9 + i] as f64 - s.translation[i]).abs() < 1e-6);
        }
    }
    let gt = Tensor::from_vec(
        g.iter().map(|v| *v as f32).collect::<Vec<_>>(),
        (objects, 12),
        &candle_core::Device::Cpu,
    )
    .unwrap();
    let loss = (out * gt).unwrap().sum_all().unwrap();
    let grads = loss.backward().unwrap();
    let grad: Vec<Vec<Vec<f32>>> = grads.get(x.as_tensor()).unwrap().to_vec3().unwrap();
    let h = 1e-6;
    let mut worst = 0f64;
    for o in 0..objects {
        for i in 0..k {
            for d in 0..3 {
                let mut plus = t32.clone();
                let mut minus = t32.clone();
                plus[o][i][d] += h;
                minus[o][i][d] -= h;
                let fd = (kabsch_loss(&reference, &plus, &g) - kabsch_loss(&reference, &minus, &g))
                    / (2.0 * h);
                worst = worst.max((fd - grad[o][i][d] as f64).abs() / (1.0 + fd.abs()));
            }
        }
    }
    assert!(
        worst < 1e-4,
        "Kabsch op gradient differs from finite differences by {worst}"
    );
}

#[test]
fn a_few_adamw_steps_reduce_the_loss() {
    use candle_nn::Optimizer;
    let model = RigidFormer::new(ModelConfig::tiny(), 8, &Device::Cpu).unwrap();
    let (objs, st) = random_scene(9, 3, 48);
    let sc = model.prepare(objs).unwrap();
    let tg = next_poses(&st);
    let item = [TrainItem {
        scene: &sc,
        state: &st,
        target: &tg,
        dt_steps: 1,
        kinematic: &[],
    }];
    let mut opt = candle_nn::AdamW::new(
        model.varmap().all_vars(),
        candle_nn::ParamsAdamW {
            lr: 3e-3,
            weight_decay: 0.0,
            ..Default::default()
        },
    )
    .unwrap();
    let first = model
        .train_forward(&item)
        .unwrap()
        .loss
        .to_scalar::<f32>()
        .unwrap();
    for _ in 0..30 {
        let out = model.train_forward(&item).unwrap();
        opt.backward_step(&out.loss).unwrap();
    }
    let last = model
        .train_forward(&item)
        .unwrap()
        .loss
        .to_scalar::<f32>()
        .unwrap();
    assert!(last < 0.5 * first, "loss {first} -> {last}");
    // The trained weights are what `step` uses.
    let out = model
        .step(&[dynaserve_model::StepItem {
            scene: &sc,
            state: &st,
            dt_steps: 1,
        }])
        .unwrap();
    assert_eq!(out[0].len(), 3);
}

/// With the gravity residual and per-frame units, exact free fall (constant velocity, gravity,
/// constant spin is left out) needs a zero acceleration output at every step size, and the
/// Verlet base reproduces the true next anchors; without them the target is `g (k dt)^2`.
#[test]
fn free_fall_is_the_zero_output_with_a_gravity_residual() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for residual in [true, false] {
        let mut cfg = ModelConfig::tiny();
        if !residual {
            // Only the parametrisation switches off; the inputs stay those of the preset.
            cfg.dynamics = dynaserve_model::DynamicsConfig {
                contact_velocity: cfg.dynamics.contact_velocity,
                ..Default::default()
            };
        }
        let model = RigidFormer::new(cfg.clone(), 5, &Device::Cpu).unwrap();
        let (objs, _) = random_scene(6, 2, 40);
        let sc = model.prepare(objs).unwrap();
        for k in [1u32, 2, 4] {
            let h = k as f32 * cfg.dt_frame;
            // Positions at t - k, t, t + k of a body thrown upwards, rotation fixed.
            let at = |s: f32, p0: Vector3<f32>, v: Vector3<f32>| -> Pose {
                let g = Vector3::from(cfg.gravity);
                Pose::from_parts(p0 + v * s + g * (0.5 * s * s), UnitQuaternion::identity())
            };
            let starts: Vec<(Vector3<f32>, Vector3<f32>)> = (0..2)
                .map(|_| {
                    (
                        Vector3::new(rng.random_range(-2.0..2.0), 0.5, 3.0),
                        Vector3::new(1.0, -0.5, rng.random_range(0.0..3.0)),
                    )
                })
                .collect();
            let state = SceneState {
                previous: starts.iter().map(|&(p, v)| at(-h, p, v)).collect(),
                current: starts.iter().map(|&(p, v)| at(0.0, p, v)).collect(),
                earlier: None,
                carry: Default::default(),
            };
            let target: Vec<Pose> = starts.iter().map(|&(p, v)| at(h, p, v)).collect();
            let out = model
                .train_forward(&[TrainItem {
                    scene: &sc,
                    state: &state,
                    target: &target,
                    dt_steps: k,
                    kinematic: &[],
                }])
                .unwrap();
            let acc: Vec<f32> = out.target_accel.flatten_all().unwrap().to_vec1().unwrap();
            let expected_z = if residual {
                0.0
            } else {
                cfg.gravity[2] * h * h
            };
            for a in acc.chunks(3) {
                assert!(a[0].abs() < 1e-4 && a[1].abs() < 1e-4, "k={k}: {a:?}");
                assert!(
                    (a[2] - expected_z).abs() < 1e-4,
                    "k={k}: {a:?} vs {expected_z}"
                );
            }
        }
    }
}

/// With the floor-aware base a box at rest on the floor needs a zero output (without it, the
/// base lets it fall `g (k dt)^2` into the floor), a box that would land within the step is
/// based with its lowest point on the floor, and a box far above the floor is not lifted.
#[test]
fn floor_base_holds_a_resting_body_and_stops_a_landing_one_on_the_floor() {
    let h = 0.15f32; // half extent, metres
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let cube = dynaserve_model::ObjectInput {
        reference: common::box_cloud(&mut rng, 64, [h; 3]),
        mass: 1.0,
        friction: 0.5,
        restitution: 0.5,
        kinematic: false,
    };
    let at = |z: f32| Pose::from_parts(Vector3::new(0.3, -0.2, z), UnitQuaternion::identity());
    for floor_base in [true, false] {
        let mut cfg = ModelConfig::tiny();
        cfg.dynamics.floor_base = floor_base;
        let model = RigidFormer::new(cfg.clone(), 4, &Device::Cpu).unwrap();
        let sc = model.prepare(vec![cube.clone()]).unwrap();
        for k in [1u32, 4] {
            let fall = cfg.gravity[2] * (k as f32 * cfg.dt_frame).powi(2);
            // (previous z, current z, where the base puts the centre).
            let landing = h + 0.01;
            let cases = [
                (h, h, if floor_base { h } else { h + fall }),
                (
                    landing + 0.1,
                    landing,
                    if floor_base { h } else { landing - 0.1 + fall },
                ),
                (3.0, 2.9, 2.8 + fall),
            ];
            for (before, now, base_z) in cases {
                let state = SceneState {
                    previous: vec![at(before)],
                    current: vec![at(now)],
                    earlier: None,
                    carry: Default::default(),
                };
                let target = vec![at(now)];
                let out = model
                    .train_forward(&[TrainItem {
                        scene: &sc,
                        state: &state,
                        target: &target,
                        dt_steps: k,
                        kinematic: &[],
                    }])
                    .unwrap();
                let acc: Vec<f32> = out.target_accel.flatten_all().unwrap().to_vec1().unwrap();
                // The base centre is the target centre minus the target acceleration.
                for a in acc.chunks(3) {
                    let got = now - a[2];
                    assert!(
                        (got - base_z).abs() < 1e-4 && a[0].abs() < 1e-5 && a[1].abs() < 1e-5,
                        "floor_base {floor_base}, k {k}, z {before} -> {now}: base centre {got}, expected {base_z}"
                    );
                }
            }
        }
    }
}

/// A kinematic object's target does not reach the loss: moving it changes nothing when the
/// object is flagged kinematic and raises the loss when it is not; a flag list of the wrong
/// length is refused.
#[test]
fn kinematic_objects_add_nothing_to_the_loss() {
    let model = RigidFormer::new(ModelConfig::tiny(), 6, &Device::Cpu).unwrap();
    let (objs, st) = random_scene(9, 3, 40);
    let sc = model.prepare(objs).unwrap();
    let target = next_poses(&st);
    let mut moved = target.clone();
    let p = moved[2].translation;
    moved[2] = Pose::from_parts(
        Vector3::new(p[0] + 0.5, p[1], p[2] - 0.3),
        moved[2].unit_quaternion(),
    );
    let loss = |target: &[Pose], kinematic: &[bool]| {
        model
            .train_forward(&[TrainItem {
                scene: &sc,
                state: &st,
                target,
                dt_steps: 2,
                kinematic,
            }])
            .map(|o| o.loss.to_scalar::<f32>().unwrap())
    };
    let flags = [false, false, true];
    let (kept, shifted) = (
        loss(&target, &flags).unwrap(),
        loss(&moved, &flags).unwrap(),
    );
    assert!(kept > 0.0);
    assert_eq!(kept, shifted, "a kinematic target moved the loss");
    let learned = loss(&moved, &[]).unwrap();
    assert!(learned > 1.5 * loss(&target, &[]).unwrap(), "{learned}");
    let err = loss(&target, &[true]).unwrap_err().to_string();
    assert!(err.contains("kinematic flags"), "{err}");
}

/// The training loss of one sample at step size 1.
fn step_loss(
    model: &RigidFormer,
    scene: &PreparedScene,
    state: &SceneState,
    target: &[Pose],
) -> f32 {
    model
        .train_forward(&[TrainItem {
            scene,
            state,
            target,
            dt_steps: 1,
            kinematic: &[],
        }])
        .unwrap()
        .loss
        .to_scalar::<f32>()
        .unwrap()
}

/// `loss` on the tiny configuration fails validation.
fn refused(loss: dynaserve_model::LossConfig) -> bool {
    ModelConfig {
        loss,
        ..ModelConfig::tiny()
    }
    .validate()
    .is_err()
}

/// Two tiny models from weight seed `seed`, the second with `setting` applied to its loss, and
/// a prepared three-object scene from `scene_seed` with its state.
fn plain_and_weighted(
    seed: u64,
    setting: impl Fn(&mut dynaserve_model::LossConfig),
    scene_seed: u64,
) -> (RigidFormer, RigidFormer, PreparedScene, SceneState) {
    let plain = RigidFormer::new(ModelConfig::tiny(), seed, &Device::Cpu).unwrap();
    let weighted = RigidFormer::new(ModelConfig::tiny(), seed, &Device::Cpu)
        .unwrap()
        .with_settings(|_, l| setting(l))
        .unwrap();
    let (objs, state) = random_scene(scene_seed, 3, 40);
    let scene = plain.prepare(objs).unwrap();
    (plain, weighted, scene, state)
}

#[test]
fn rest_weight_scales_only_objects_at_rest() {
    let (plain, weighted, sc, st) = plain_and_weighted(7, |l| l.rest_weight = 4.0, 10);
    // Object 0 rests (three equal poses); the others move.
    let mut resting = st.clone();
    resting.previous[0] = resting.current[0];
    let mut target = next_poses(&resting);
    target[0] = resting.current[0];
    let loss = |model: &RigidFormer, state: &SceneState, target: &[Pose]| {
        step_loss(model, &sc, state, target)
    };
    let moving_target = next_poses(&st);
    assert_eq!(
        loss(&plain, &st, &moving_target),
        loss(&weighted, &st, &moving_target),
        "no object rests: the weight must change nothing"
    );
    let (a, b) = (
        loss(&plain, &resting, &target),
        loss(&weighted, &resting, &target),
    );
    assert!(b > a * 1.05, "resting object weighted: {a} -> {b}");
    assert!(refused(dynaserve_model::LossConfig {
        rest_weight: 0.0,
        ..Default::default()
    }));
}

/// The rotation term is off by default; switched on, it raises the loss, ignores a translation
/// of every target (it sees only what rotation moves) and grows with a rotation of the targets;
/// a negative weight is refused.
#[test]
fn rotation_weight_adds_a_term_on_rotation_only() {
    let (plain, weighted, sc, st) = plain_and_weighted(9, |l| l.rotation_weight = 2.0, 12);
    let term = |target: &[Pose]| {
        step_loss(&weighted, &sc, &st, target) - step_loss(&plain, &sc, &st, target)
    };
    let target = next_poses(&st);
    let base = term(&target);
    assert!(base > 0.0, "rotation term {base}");
    // The term is reported on its own, before its weight, and only when it is on.
    let reported = |m: &RigidFormer| {
        let item = TrainItem {
            scene: &sc,
            state: &st,
            target: &target,
            dt_steps: 1,
            kinematic: &[],
        };
        let out = m.train_forward(&[item]).unwrap();
        out.rotation.map(|t| t.to_scalar::<f32>().unwrap())
    };
    assert_eq!(reported(&plain), None);
    let alone = reported(&weighted).expect("rotation term reported");
    assert!(
        (2.0 * alone - base).abs() <= 1e-3 * base,
        "reported term {alone} x weight 2 against the loss difference {base}"
    );
    let moved: Vec<Pose> = target
        .iter()
        .map(|p| Pose {
            translation: [
                p.translation[0] + 0.01,
                p.translation[1] - 0.02,
                p.translation[2] + 0.005,
            ],
            ..*p
        })
        .collect();
    let shifted = term(&moved);
    assert!(
        (shifted - base).abs() <= 1e-3 * base.abs().max(1e-3),
        "a translation changed the rotation term: {base} -> {shifted}"
    );
    let spin = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.2);
    let turned: Vec<Pose> = target
        .iter()
        .map(|p| {
            let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                p.rotation[3],
                p.rotation[0],
                p.rotation[1],
                p.rotation[2],
            ));
            let r = spin * q;
            Pose {
                rotation: [r.i, r.j, r.k, r.w],
                ..*p
            }
        })
        .collect();
    let rotated = term(&turned);
    assert!(
        rotated > 2.0 * base,
        "a rotation of the targets: {base} -> {rotated}"
    );
    // The term reaches the weights: the gradient changes with it.
    let gradient = |m: &RigidFormer| -> Vec<f32> {
        let item = TrainItem {
            scene: &sc,
            state: &st,
            target: &turned,
            dt_steps: 1,
            kinematic: &[],
        };
        let grads = m.train_forward(&[item]).unwrap().loss.backward().unwrap();
        let vars = m.varmap().data().lock().unwrap().clone();
        let mut names: Vec<&String> = vars.keys().collect();
        names.sort();
        names
            .iter()
            .filter_map(|n| grads.get(vars[*n].as_tensor()))
            .flat_map(|g| g.flatten_all().unwrap().to_vec1::<f32>().unwrap())
            .collect()
    };
    let (g0, g1) = (gradient(&plain), gradient(&weighted));
    let norm = |v: &mut dyn Iterator<Item = f32>| v.map(|x| f64::from(x).powi(2)).sum::<f64>();
    let change = norm(&mut g0.iter().zip(&g1).map(|(a, b)| b - a));
    let size = norm(&mut g0.iter().copied());
    assert!(
        change > 1e-4 * size,
        "gradient unchanged by the term: |change|^2 {change} against |g|^2 {size}"
    );
    assert!(refused(dynaserve_model::LossConfig {
        rotation_weight: -1.0,
        ..Default::default()
    }));
}

/// The object-contact weight raises the loss only when a moving object has a point within
/// 0.1 m of another object's: the same scene with its objects apart is unchanged.
#[test]
fn object_contact_weight_scales_only_objects_touching_another() {
    let (plain, weighted, sc, apart) = plain_and_weighted(8, |l| l.object_contact_weight = 4.0, 11);
    let place = |state: &SceneState, positions: [[f32; 3]; 3]| {
        let mut s = state.clone();
        for (j, p) in positions.iter().enumerate() {
            let (c, q) = (s.current[j], s.previous[j]);
            let shift: Vec<f32> = (0..3).map(|d| p[d] - c.translation[d]).collect();
            let moved = |pose: Pose| {
                let t = pose.translation;
                Pose::from_parts(
                    Vector3::new(t[0] + shift[0], t[1] + shift[1], t[2] + shift[2]),
                    pose.unit_quaternion(),
                )
            };
            (s.current[j], s.previous[j]) = (moved(c), moved(q));
        }
        s
    };
    // Boxes of half extents 0.2-0.6 m: 4 m apart nothing touches; centres 0.3 m apart the
    // first two overlap.
    let apart = place(&apart, [[0.0, 0.0, 2.0], [4.0, 0.0, 2.0], [0.0, 4.0, 2.0]]);
    let touching = place(&apart, [[0.0, 0.0, 2.0], [0.3, 0.0, 2.0], [0.0, 4.0, 2.0]]);
    let loss =
        |model: &RigidFormer, state: &SceneState| step_loss(model, &sc, state, &next_poses(state));
    assert_eq!(
        loss(&plain, &apart),
        loss(&weighted, &apart),
        "no object touches another: the weight must change nothing"
    );
    let (a, b) = (loss(&plain, &touching), loss(&weighted, &touching));
    assert!(b > a * 1.5, "two of three objects touching: {a} -> {b}");
    assert!(refused(dynaserve_model::LossConfig {
        object_contact_weight: 0.0,
        ..Default::default()
    }));
}
