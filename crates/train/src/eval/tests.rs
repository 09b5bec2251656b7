//! Tests of the evaluation core and the baselines on hand-checkable trajectories, a random
//! RigidFormer and real simulated data.

use std::sync::Arc;

use super::*;
use dynaserve_model::{Device, ModelConfig, Pose, RigidFormer, SceneState, WorldModel};
use dynaserve_sim::{DatasetReader, ObjectRecord, SceneRecord};
use nalgebra::{UnitQuaternion, Vector3};

const DT: f32 = 1.0 / 24.0;

/// Corners of a unit cube (body frame).
fn cube_points() -> Vec<[f32; 3]> {
    let mut v = Vec::new();
    for x in [-0.5, 0.5] {
        for y in [-0.5, 0.5] {
            for z in [-0.5, 0.5] {
                v.push([x, y, z]);
            }
        }
    }
    v
}

/// A scene whose object `j` follows `pose(j, t_seconds)` for `frames` frames.
fn scene(objects: usize, frames: usize, pose: impl Fn(usize, f64) -> Pose) -> SceneRecord {
    SceneRecord {
        objects: (0..objects)
            .map(|j| {
                let poses: Vec<Pose> = (0..frames)
                    .map(|t| pose(j, t as f64 * f64::from(DT)))
                    .collect();
                ObjectRecord {
                    positions: poses.iter().map(|p| p.translation).collect(),
                    rotations: poses.iter().map(|p| p.rotation).collect(),
                    reference_points: cube_points(),
                    mass: 1.0,
                    friction: 0.5,
                    restitution: 0.5,
                    scale: [1.0; 3],
                    shape_id: 0,
                    material: 0,
                    kinematic: false,
                }
            })
            .collect(),
        dt_frame: DT,
    }
}

fn pose(p: Vector3<f64>, q: UnitQuaternion<f64>) -> Pose {
    let c = q.coords;
    Pose {
        translation: [p.x as f32, p.y as f32, p.z as f32],
        rotation: [c.x as f32, c.y as f32, c.z as f32, c.w as f32],
    }
}

fn entry(report: &EvalReport, k: u32, horizon_s: f64) -> &HorizonReport {
    report
        .step_sizes
        .iter()
        .find(|s| s.dt_steps == k)
        .and_then(|s| s.horizons.iter().find(|h| h.horizon_s == horizon_s))
        .expect("entry present")
}

#[test]
fn static_error_is_pooled_over_objects_not_averaged_over_scenes() {
    // Scene A: two objects at 1 and 2 m/s, the first spinning at 0.5 rad/s about z.
    // Scene B: one object at 3 m/s. Static error at horizon H: |v| H and 0.5 H rad.
    let velocities = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]];
    let a = scene(2, 101, |j, t| {
        let v = Vector3::from(velocities[j]);
        let spin = if j == 0 { 0.5 * t } else { 0.0 };
        pose(
            Vector3::new(0.0, 0.0, 5.0) + v * t,
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), spin),
        )
    });
    let b = scene(1, 101, |_, t| {
        pose(Vector3::new(3.0 * t, 0.0, 5.0), UnitQuaternion::identity())
    });
    let report = evaluate_scenes(&Static, &[a, b], &EvalOptions::default()).unwrap();
    assert_eq!(report.scenes, 2);
    assert_eq!(report.objects, 3);
    for k in DEFAULT_STEP_SIZES {
        for h in DEFAULT_HORIZONS_S {
            let e = entry(&report, k, h);
            assert_eq!(e.missing, None, "k={k} h={h}");
            assert_eq!(e.objects, 3);
            // Pool: sqrt((1 + 4 + 9) / 3) H; the mean of scene RMSEs would be
            // (sqrt(2.5) + 3) H / 2, about 6% lower.
            let want = (14.0f64 / 3.0).sqrt() * h;
            let got = e.translation_rmse_m.unwrap();
            assert!((got - want).abs() < 1e-4 * want.max(1.0), "{got} vs {want}");
            let want_deg = (0.5 * h).to_degrees() / 3f64.sqrt();
            let got_deg = e.orientation_rmse_deg.unwrap();
            assert!((got_deg - want_deg).abs() < 1e-2, "{got_deg} vs {want_deg}");
        }
    }
}

#[test]
fn ballistic_is_exact_for_free_flight_with_constant_spin() {
    // High enough never to reach the floor within 4.2 s.
    let g = Vector3::new(0.0, 0.0, -10.0);
    let w = Vector3::new(0.3, -1.1, 0.7);
    let q0 = UnitQuaternion::from_euler_angles(0.2, -0.4, 1.0);
    let s = scene(2, 101, |j, t| {
        let v0 = if j == 0 {
            Vector3::new(2.0, -1.0, 3.0)
        } else {
            Vector3::new(-0.5, 0.0, 0.0)
        };
        pose(
            Vector3::new(j as f64, 0.0, 120.0) + v0 * t + 0.5 * g * t * t,
            UnitQuaternion::from_scaled_axis(w * t) * q0,
        )
    });
    let ballistic = Ballistic {
        gravity: [0.0, 0.0, -10.0],
        floor_z: Some(0.0),
    };
    let opts = EvalOptions::default();
    let b = evaluate_scenes(&ballistic, std::slice::from_ref(&s), &opts).unwrap();
    let st = evaluate_scenes(&Static, &[s], &opts).unwrap();
    for k in DEFAULT_STEP_SIZES {
        for h in DEFAULT_HORIZONS_S {
            let e = entry(&b, k, h);
            assert!(e.translation_rmse_m.unwrap() < 5e-3, "k={k} h={h}: {e:?}");
            assert!(e.orientation_rmse_deg.unwrap() < 0.05, "k={k} h={h}: {e:?}");
            // Static is far off: the objects fall metres.
            assert!(entry(&st, k, h).translation_rmse_m.unwrap() > 1.0);
        }
    }
}

#[test]
fn ballistic_lands_on_the_floor_and_slides() {
    // A unit cube falling from z = 2 while moving at 1 m/s along x.
    let s = scene(1, 101, |_, t| {
        pose(
            Vector3::new(t, 0.0, 2.0 - 5.0 * t * t),
            UnitQuaternion::identity(),
        )
    });
    let ballistic = Ballistic {
        gravity: [0.0, 0.0, -10.0],
        floor_z: Some(0.0),
    };
    let observed = observed_state(&s, 4, 1).unwrap();
    let out = ballistic.rollout(&s, &observed, 1, 96).unwrap();
    for step in &out {
        assert!(step[0].translation[2] >= 0.5 - 1e-6, "{:?}", step[0]);
    }
    let last = out[95][0].translation;
    assert!((last[2] - 0.5).abs() < 1e-6, "rests on the floor: {last:?}");
    // x keeps 1 m/s: frame 100 is 100/24 s.
    assert!((f64::from(last[0]) - 100.0 / 24.0).abs() < 1e-3, "{last:?}");
    // A tilted cube rests on its lowest corner: rotate 45 degrees about x.
    let tilted = scene(1, 101, |_, _| {
        pose(
            Vector3::new(0.0, 0.0, 0.1),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_4),
        )
    });
    let observed = observed_state(&tilted, 4, 2).unwrap();
    let out = ballistic.rollout(&tilted, &observed, 2, 3).unwrap();
    let z = f64::from(out[2][0].translation[2]);
    assert!((z - 0.5f64.sqrt()).abs() < 1e-6, "{z}");
}

#[test]
fn missing_horizons_are_reported_never_shifted() {
    let s = scene(1, 30, |_, t| {
        pose(Vector3::new(t, 0.0, 1.0), UnitQuaternion::identity())
    });
    let opts = EvalOptions {
        start_frame: 8,
        step_sizes: vec![1, 3, 5, 9],
        horizons_s: vec![0.5, 1.0, 0.51],
        ..EvalOptions::default()
    };
    let report = evaluate_scenes(&Static, &[s], &opts).unwrap();
    // 0.5 s = 12 frames: 8 + 12 = 20 <= 29 fits for k = 1 and 3 (4 steps).
    for k in [1, 3] {
        let e = entry(&report, k, 0.5);
        assert_eq!(e.frames, Some(12));
        assert_eq!(e.steps, Some(12 / k as usize));
        assert!((e.translation_rmse_m.unwrap() - 0.5).abs() < 1e-5);
        assert_eq!(e.missing, None);
    }
    // k = 5: 12 frames is not a multiple of 5.
    let e = entry(&report, 5, 0.5);
    assert!(
        e.missing.as_deref().unwrap().contains("not a multiple"),
        "{e:?}"
    );
    assert_eq!(e.translation_rmse_m, None);
    // 1 s = 24 frames: 8 + 24 > 29.
    let e = entry(&report, 1, 1.0);
    assert!(e.missing.as_deref().unwrap().contains("beyond"), "{e:?}");
    assert_eq!(e.orientation_rmse_deg, None);
    // 0.51 s = 12.24 frames.
    let e = entry(&report, 1, 0.51);
    assert_eq!(e.frames, None);
    assert!(
        e.missing.as_deref().unwrap().contains("whole number"),
        "{e:?}"
    );
    // k = 9 > s = 8: no observed frame s - k.
    let e = entry(&report, 9, 0.5);
    assert!(e.missing.as_deref().unwrap().contains("< 0"), "{e:?}");
    let table = format_table(&report);
    assert!(table.contains("missing (never shifted"), "{table}");
    assert!(table.contains("0.5 s (12 fr)"), "{table}");
    assert!(table.contains(" -"), "{table}");
    // The JSON form round-trips (floats up to the last bit of the parser).
    let json = serde_json::to_string(&report).unwrap();
    let back: EvalReport = serde_json::from_str(&json).unwrap();
    assert!(
        json_close(
            &serde_json::to_value(&back).unwrap(),
            &serde_json::to_value(&report).unwrap()
        ),
        "{json}"
    );
}

/// Equal JSON trees, numbers to 1e-12 relative.
pub(crate) fn json_close(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            (x - y).abs() <= 1e-12 * x.abs().max(1.0)
        }
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(x, y)| json_close(x, y))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| json_close(v, w)))
        }
        _ => a == b,
    }
}

#[test]
fn invalid_options_are_rejected() {
    let s = scene(1, 30, |_, _| Pose::IDENTITY);
    let bad = [
        EvalOptions {
            step_sizes: vec![0],
            ..EvalOptions::default()
        },
        EvalOptions {
            horizons_s: vec![-1.0],
            ..EvalOptions::default()
        },
        EvalOptions {
            start_frame: 30,
            ..EvalOptions::default()
        },
        EvalOptions {
            step_sizes: vec![],
            ..EvalOptions::default()
        },
    ];
    for opts in bad {
        assert!(matches!(
            evaluate_scenes(&Static, std::slice::from_ref(&s), &opts),
            Err(EvalError::Invalid(_))
        ));
    }
    assert!(evaluate_scenes(&Static, &[], &EvalOptions::default()).is_err());
    // Scenes with different frame counts or frame intervals cannot be pooled.
    let short = scene(1, 20, |_, _| Pose::IDENTITY);
    assert!(evaluate_scenes(&Static, &[s.clone(), short], &EvalOptions::default()).is_err());
    let mut other_dt = s.clone();
    other_dt.dt_frame = 0.01;
    assert!(evaluate_scenes(&Static, &[s, other_dt], &EvalOptions::default()).is_err());
}

/// A predictor that misbehaves in a chosen way.
struct Broken {
    short: bool,
}

impl Predictor for Broken {
    fn name(&self) -> String {
        "broken".into()
    }

    fn rollout(
        &self,
        _scene: &SceneRecord,
        observed: &SceneState,
        _dt_steps: u32,
        steps: usize,
    ) -> Result<Vec<Vec<Pose>>, EvalError> {
        if self.short {
            return Ok(vec![observed.current.clone(); steps - 1]);
        }
        let mut nan = observed.current.clone();
        nan[0].translation[0] = f32::NAN;
        Ok(vec![nan; steps])
    }
}

#[test]
fn misbehaving_predictors_are_errors_not_numbers() {
    let s = scene(2, 101, |_, _| Pose::IDENTITY);
    for short in [true, false] {
        let err = evaluate_scenes(
            &Broken { short },
            std::slice::from_ref(&s),
            &EvalOptions::default(),
        )
        .unwrap_err();
        assert!(matches!(err, EvalError::Predictor { .. }), "{err}");
    }
}

#[test]
fn a_world_model_runs_through_the_same_path() {
    let model = RigidFormer::new(ModelConfig::tiny(), 7, &Device::Cpu).unwrap();
    let model: Arc<dyn WorldModel> = Arc::new(model);
    let predictor = ModelPredictor::new(model.clone()).with_points_per_object(8);
    let s = scene(2, 20, |j, t| {
        pose(
            Vector3::new(2.0 * j as f64, 0.0, 0.5 + 0.1 * t),
            UnitQuaternion::identity(),
        )
    });
    let opts = EvalOptions {
        step_sizes: vec![1, 2],
        horizons_s: vec![0.25, 0.5],
        ..EvalOptions::default()
    };
    let report = evaluate_scenes(&predictor, std::slice::from_ref(&s), &opts).unwrap();
    assert_eq!(report.predictor, format!("{} (8 points)", model.name()));
    for k in [1, 2] {
        for h in [0.25, 0.5] {
            let e = entry(&report, k, h);
            assert!(e.translation_rmse_m.unwrap().is_finite(), "{e:?}");
            assert_eq!(e.objects, 2);
        }
    }
    // A model stepping at another frame rate is refused.
    let mut other = s;
    other.dt_frame = 0.01;
    let fits = EvalOptions {
        horizons_s: vec![0.1],
        ..opts
    };
    let err = evaluate_scenes(&predictor, &[other], &fits).unwrap_err();
    assert!(err.to_string().contains("frames of"), "{err}");
}

#[test]
fn dataset_evaluation_on_real_simulated_scenes() {
    use dynaserve_sim::writer::generate_dataset;
    use dynaserve_sim::{GenerateOptions, Generator};
    let dir = std::env::temp_dir().join(format!("dynaserve-eval-test-{}", std::process::id()));
    let mut gen_opts = GenerateOptions::new(Generator::movi_a(), 11, "test", 3);
    gen_opts.points = 64;
    generate_dataset(&gen_opts, &dir, true, &|| {}).unwrap();
    let reader = DatasetReader::open(&dir).unwrap();
    let ballistic = Ballistic::from_manifest(reader.manifest());
    assert_eq!(ballistic.gravity, [0.0, 0.0, -10.0]);
    let opts = EvalOptions::default();
    let calls = std::sync::atomic::AtomicUsize::new(0);
    let progress = |_done: usize| {
        calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    };
    let b = evaluate_dataset(&ballistic, &reader, &opts, &progress).unwrap();
    let st = evaluate_dataset(&Static, &reader, &opts, &|_| {}).unwrap();
    std::fs::remove_dir_all(&dir).ok();
    assert!(calls.load(std::sync::atomic::Ordering::Relaxed) >= 1);
    assert_eq!(b.scenes, 3);
    assert_eq!(b.frames, 101);
    assert_eq!(b.dataset.as_ref().unwrap().generator, "movi-a");
    // Every horizon fits 101 frames from s = 4 for k = 1, 2, 4 (96 = 4 * 24).
    for k in DEFAULT_STEP_SIZES {
        for h in DEFAULT_HORIZONS_S {
            assert!(entry(&b, k, h).translation_rmse_m.is_some());
            assert_eq!(entry(&b, k, h).objects as usize, b.objects);
        }
    }
    // Objects spawn 1-5 m up and fall: over half a second, free flight beats standing still.
    let (tb, ts) = (
        entry(&b, 1, 0.5).translation_rmse_m.unwrap(),
        entry(&st, 1, 0.5).translation_rmse_m.unwrap(),
    );
    assert!(tb < ts, "ballistic {tb} vs static {ts}");
}

#[test]
fn curves_cover_every_step_inside_the_data() {
    // One object at 2 m/s: static error after i frames is 2 i dt.
    let s = scene(1, 101, |_, t| {
        pose(Vector3::new(2.0 * t, 0.0, 1.0), UnitQuaternion::identity())
    });
    let report = evaluate_scenes(&Static, &[s], &EvalOptions::default()).unwrap();
    for k in &report.step_sizes {
        // From s = 4, frames 4 + k, ..., 100.
        assert_eq!(k.curve.len(), 96 / k.dt_steps as usize, "k={}", k.dt_steps);
        for c in &k.curve {
            assert_eq!(c.frames % k.dt_steps as usize, 0);
            let want = 2.0 * c.frames as f64 * f64::from(DT);
            assert!((c.translation_rmse_m - want).abs() < 1e-4, "{c:?}");
            assert!((c.time_s - c.frames as f64 * f64::from(DT)).abs() < 1e-9);
        }
        // The horizons are points of the curve.
        let h = k.horizons.iter().find(|h| h.horizon_s == 1.0).unwrap();
        let c = k.curve.iter().find(|c| c.frames == 24).unwrap();
        assert_eq!(h.translation_rmse_m, Some(c.translation_rmse_m));
    }
}

/// Static, but every object moves up at `speed` m/s, and from step `bad_after` on the
/// quaternions are scaled by `scale` (not unit any more).
struct Creeping {
    speed: f64,
    bad_after: usize,
    scale: f32,
}

impl Predictor for Creeping {
    fn name(&self) -> String {
        "creeping".into()
    }

    fn rollout(
        &self,
        scene: &SceneRecord,
        observed: &SceneState,
        dt_steps: u32,
        steps: usize,
    ) -> Result<Vec<Vec<Pose>>, EvalError> {
        let dt = f64::from(dt_steps) * f64::from(scene.dt_frame);
        Ok((1..=steps)
            .map(|i| {
                observed
                    .current
                    .iter()
                    .map(|p| {
                        let mut q = *p;
                        q.translation[2] += (self.speed * dt * i as f64) as f32;
                        if i > self.bad_after {
                            q.rotation = q.rotation.map(|v| v * self.scale);
                        }
                        q
                    })
                    .collect()
            })
            .collect())
    }
}

#[test]
fn resting_drift_counts_only_objects_at_rest_in_the_truth() {
    // Object 0 rests on the floor the whole time; object 1 slides at 1 m/s; object 2 rests
    // but spins at 10 deg/s (not at rest by the angular threshold).
    let s = scene(3, 101, |j, t| match j {
        0 => pose(Vector3::new(0.0, 0.0, 0.5), UnitQuaternion::identity()),
        1 => pose(Vector3::new(3.0 + t, 0.0, 0.5), UnitQuaternion::identity()),
        _ => pose(
            Vector3::new(-3.0, 0.0, 0.5),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 10f64.to_radians() * t),
        ),
    });
    let st = evaluate_scenes(&Static, std::slice::from_ref(&s), &EvalOptions::default()).unwrap();
    let r = st.resting.as_ref().unwrap();
    assert_eq!((r.first_frame, r.last_frame), (76, 100));
    assert_eq!(r.objects_at_rest, 1);
    assert_eq!(r.objects, 3);
    assert!(r.truth.translation_m.unwrap().max < 1e-9);
    for d in &r.predicted {
        assert_eq!(d.missing, None);
        assert_eq!(d.translation_m.unwrap().max, 0.0);
        assert_eq!(d.translation_m.unwrap().count, 1);
    }
    // A prediction creeping up at 5 cm/s drifts 5 cm over the 1 s window, at every k.
    let creeping = Creeping {
        speed: 0.05,
        bad_after: usize::MAX,
        scale: 1.0,
    };
    let cr = evaluate_scenes(&creeping, &[s], &EvalOptions::default()).unwrap();
    for d in &cr.resting.as_ref().unwrap().predicted {
        let t = d.translation_m.unwrap();
        assert!(
            (t.mean - 0.05).abs() < 1e-5 && (t.max - 0.05).abs() < 1e-5,
            "{d:?}"
        );
        assert!(d.rotation_deg.unwrap().max < 1e-3, "{d:?}");
    }
    // A window that does not fit after the start frame gives no resting report.
    let short = scene(1, 20, |_, _| Pose::IDENTITY);
    let opts = EvalOptions {
        horizons_s: vec![0.25],
        ..EvalOptions::default()
    };
    assert!(
        evaluate_scenes(&Static, &[short], &opts)
            .unwrap()
            .resting
            .is_none()
    );
}

#[test]
fn long_rollout_counts_failures_past_the_data() {
    let s = scene(2, 101, |j, _| {
        pose(
            Vector3::new(2.0 * j as f64, 0.0, 0.5),
            UnitQuaternion::identity(),
        )
    });
    let ok = evaluate_scenes(&Static, std::slice::from_ref(&s), &EvalOptions::default()).unwrap();
    let l = ok.long_rollout.as_ref().unwrap();
    assert_eq!((l.steps, l.objects, l.failed_objects), (100, 2, 0));
    assert!(l.max_pairwise_deviation_m < 1e-6, "{l:?}");
    assert_eq!(l.projection_residual_m, None);
    // Quaternions scaled by 1.01 after step 97, i.e. beyond the data's last frame (s + 96):
    // the errors are unaffected, the stability check counts both objects, and the pairwise
    // distances of the cube corners (up to sqrt(3) m apart) grow by 1.01^2 - 1.
    let bad = Creeping {
        speed: 0.0,
        bad_after: 97,
        scale: 1.01,
    };
    let r = evaluate_scenes(&bad, &[s], &EvalOptions::default()).unwrap();
    let l = r.long_rollout.as_ref().unwrap();
    assert_eq!(
        (l.failed_objects, l.failed_scenes, l.non_finite_objects),
        (2, 1, 0)
    );
    assert!((l.max_quaternion_norm_error - 0.01).abs() < 1e-5, "{l:?}");
    let want = (1.01f64.powi(2) - 1.0) * 3f64.sqrt();
    assert!((l.max_pairwise_deviation_m - want).abs() < 1e-5, "{l:?}");
    assert_eq!(entry(&r, 1, 4.0).translation_rmse_m, Some(0.0));
    // Without a k = 1 step size the stability rollout still runs (as its own request).
    let opts = EvalOptions {
        step_sizes: vec![2],
        ..EvalOptions::default()
    };
    let s2 = scene(1, 101, |_, _| Pose::IDENTITY);
    let r = evaluate_scenes(&bad, &[s2], &opts).unwrap();
    assert_eq!(r.long_rollout.as_ref().unwrap().failed_objects, 1);
}

#[test]
fn occlusion_removes_a_seeded_half_space_patch() {
    let mut cloud: Vec<[f32; 3]> = Vec::new();
    for i in 0..400 {
        let a = i as f32 * 0.61;
        let b = i as f32 * 0.23;
        cloud.push([a.cos() * b.sin(), a.sin() * b.sin(), b.cos()]);
    }
    let occ = Occlusion {
        fraction: 0.25,
        seed: 3,
    };
    let mut kept = cloud.clone();
    occ.apply(&mut kept);
    assert_eq!(kept.len(), 300);
    let mut again = cloud.clone();
    occ.apply(&mut again);
    assert_eq!(kept, again, "deterministic");
    // The kept points keep their order, and the plane normal to the cut direction separates
    // them from the removed ones.
    let removed: Vec<[f32; 3]> = cloud
        .iter()
        .filter(|p| !kept.contains(p))
        .copied()
        .collect();
    assert_eq!(removed.len(), 100);
    let mut it = kept.iter();
    assert!(
        cloud
            .iter()
            .filter(|p| !removed.contains(p))
            .all(|p| Some(p) == it.next())
    );
    let u = occ.direction(&cloud);
    assert!((u.norm() - 1.0).abs() < 1e-5);
    let max_kept = kept
        .iter()
        .map(|p| Vector3::from(*p).dot(&u))
        .fold(f32::MIN, f32::max);
    let min_removed = removed
        .iter()
        .map(|p| Vector3::from(*p).dot(&u))
        .fold(f32::MAX, f32::min);
    assert!(max_kept <= min_removed, "{max_kept} vs {min_removed}");
    // Another seed cuts elsewhere.
    let mut other = cloud.clone();
    Occlusion {
        fraction: 0.25,
        seed: 4,
    }
    .apply(&mut other);
    assert_ne!(other, kept);
    // Nothing to remove, and at least one point is always kept.
    let mut one = vec![[0.0f32; 3]];
    occ.apply(&mut one);
    assert_eq!(one.len(), 1);
}

#[test]
fn model_batches_match_single_rollouts_and_report_the_projection() {
    let rf = Arc::new(RigidFormer::new(ModelConfig::tiny(), 11, &Device::Cpu).unwrap());
    let predictor = ModelPredictor::from_rigidformer(rf.clone()).with_points_per_object(8);
    let a = scene(2, 30, |j, t| {
        pose(
            Vector3::new(2.0 * j as f64, 0.0, 0.5 + 0.2 * t),
            UnitQuaternion::identity(),
        )
    });
    let b = scene(3, 30, |j, t| {
        pose(
            Vector3::new(0.0, 2.0 * j as f64, 1.0 - 0.1 * t),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), t),
        )
    });
    let requests = [
        RolloutRequest {
            scene: &a,
            observed: observed_state(&a, 4, 1).unwrap(),
            dt_steps: 1,
            steps: 5,
        },
        RolloutRequest {
            scene: &b,
            observed: observed_state(&b, 4, 2).unwrap(),
            dt_steps: 2,
            steps: 3,
        },
    ];
    let batched = predictor.rollout_batch(&requests).unwrap();
    assert_eq!((batched[0].len(), batched[1].len()), (5, 3));
    for (r, got) in requests.iter().zip(&batched) {
        let alone = predictor
            .rollout(r.scene, &r.observed, r.dt_steps, r.steps)
            .unwrap();
        for (x, y) in alone.iter().flatten().zip(got.iter().flatten()) {
            for d in 0..3 {
                assert!(
                    (x.translation[d] - y.translation[d]).abs() < 1e-4,
                    "{x:?} {y:?}"
                );
            }
        }
    }
    // A random network's anchors are far from rigid before the projection.
    let opts = EvalOptions {
        step_sizes: vec![1],
        horizons_s: vec![0.25],
        long_rollout_steps: 8,
        projection_every: 4,
        ..EvalOptions::default()
    };
    let report = evaluate_scenes(&predictor, std::slice::from_ref(&a), &opts).unwrap();
    let l = report.long_rollout.unwrap();
    let res = l.projection_residual_m.unwrap();
    assert_eq!(res.count, 2 * 2, "2 windows (steps 0 and 4) x 2 objects");
    assert!(
        res.mean.is_finite() && res.mean > 0.0 && res.max >= res.mean,
        "{res:?}"
    );
    assert_eq!(l.failed_objects, 0);
    assert!(l.max_pairwise_deviation_m < 1e-5, "{l:?}");
    // Through the trait object alone the residual is not available.
    let plain = ModelPredictor::new(rf).with_points_per_object(8);
    let report = evaluate_scenes(&plain, &[a], &opts).unwrap();
    assert_eq!(report.long_rollout.unwrap().projection_residual_m, None);
}

#[test]
fn suite_reports_print_and_plot() {
    let s = scene(2, 101, |j, t| {
        pose(
            Vector3::new(j as f64 * 2.0, t, 0.5 + (1.0 - t).max(0.0)),
            UnitQuaternion::identity(),
        )
    });
    let opts = EvalOptions::default();
    let ballistic = Ballistic {
        gravity: [0.0, 0.0, -10.0],
        floor_z: Some(0.0),
    };
    let suite = SuiteReport {
        entries: vec![
            SuiteEntry {
                label: "static".into(),
                input: None,
                report: evaluate_scenes(&Static, std::slice::from_ref(&s), &opts).unwrap(),
            },
            SuiteEntry {
                label: "ballistic".into(),
                input: None,
                report: evaluate_scenes(&ballistic, std::slice::from_ref(&s), &opts).unwrap(),
            },
        ],
        elapsed_s: 0.0,
    };
    let text = format_suite(&suite);
    for want in [
        "translation RMSE (m)",
        "orientation RMSE (deg)",
        "stability: k = 1, 100 steps",
        "resting drift over frames 76..100",
        "ground truth",
        "0.5 s (12 fr)",
    ] {
        assert!(text.contains(want), "{want:?} missing from\n{text}");
    }
    let md = format_markdown(&suite);
    assert!(md.contains("| horizon | k | static | ballistic |"), "{md}");
    assert!(md.contains("| 4 s (96 fr) | 4 |"), "{md}");
    assert!(md.contains("**Resting drift**"), "{md}");
    let json = serde_json::to_string(&suite).unwrap();
    let back: SuiteReport = serde_json::from_str(&json).unwrap();
    assert_eq!(back.entries.len(), 2);
    let png = std::env::temp_dir().join(format!("dynaserve-eval-plot-{}.png", std::process::id()));
    plot_errors(
        &png,
        "test",
        &[
            ("static", &suite.entries[0].report, PlotStyle::EveryStepSize),
            ("ballistic", &suite.entries[1].report, PlotStyle::Baseline),
        ],
    )
    .unwrap();
    let bytes = std::fs::read(&png).unwrap();
    std::fs::remove_file(&png).ok();
    assert_eq!(&bytes[1..4], b"PNG");
    assert!(bytes.len() > 5000);
}
