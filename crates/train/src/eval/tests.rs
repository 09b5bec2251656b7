//! Tests of the evaluation core and the baselines on hand-checkable trajectories, a random
//! RigidFormer and real simulated data.

use std::sync::Arc;

use super::*;
use dynaserve_model::{Device, ModelConfig, RigidFormer, WorldModel};
use dynaserve_sim::ObjectRecord;
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
        max_scenes: None,
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
    // The JSON form round-trips.
    let json = serde_json::to_string(&report).unwrap();
    let back: EvalReport = serde_json::from_str(&json).unwrap();
    assert_eq!(back, report);
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
    assert_eq!(report.predictor, model.name());
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
    use dynaserve_sim::generators::{GenerateOptions, Generator, generate_dataset};
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
