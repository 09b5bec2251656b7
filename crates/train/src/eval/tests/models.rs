//! A world model through the same evaluation path, on simulated data and in batches.

use super::*;

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
    // The rapier restart reads the shapes by name, the floor and the timing from the manifest.
    let rapier = RapierRestart::from_manifest(reader.manifest()).unwrap();
    assert_eq!(rapier.shapes, dynaserve_sim::ShapeKind::MOVI_A.to_vec());
    use dynaserve_sim::materials::MOVI_FLOOR;
    assert_eq!(rapier.floor, MOVI_FLOOR);
    assert_eq!(
        (
            rapier.physics_hz,
            rapier.substeps_per_frame,
            rapier.solver_iterations
        ),
        (240, 10, 4)
    );
    let mut rough = reader.manifest().clone();
    rough.generator_parameters["floor"]["friction"] = serde_json::json!(0.9);
    let floor = RapierRestart::from_manifest(&rough).unwrap().floor;
    assert_eq!(
        (floor.friction, floor.restitution),
        (0.9, MOVI_FLOOR.restitution)
    );
    let mut unknown = reader.manifest().clone();
    unknown.shapes[1].name = "teapot".into();
    let err = RapierRestart::from_manifest(&unknown).unwrap_err();
    assert!(err.to_string().contains("\"teapot\""), "{err}");
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

/// The observed state carries frame `s - 2k` when the scene has it, and withholds it for
/// `two_frames` (a client that sends two poses).
#[test]
fn observed_frames_carry_the_frame_before_unless_two_are_asked_for() {
    let s = scene(2, 12, |j, t| {
        pose(
            Vector3::new(j as f64, 0.0, 2.0 - 0.05 * t * t),
            UnitQuaternion::identity(),
        )
    });
    let three = observed_frames(&s, 4, 2, false).unwrap();
    assert_eq!(three.earlier, Some(poses_at(&s, 0).unwrap()));
    assert_eq!(three.previous, poses_at(&s, 2).unwrap());
    assert_eq!(observed_frames(&s, 4, 2, true).unwrap().earlier, None);
    // Frame 4 - 2 * 4 does not exist: two frames, whatever is asked.
    assert_eq!(observed_frames(&s, 4, 4, false).unwrap().earlier, None);
    assert_eq!(
        observed_frames(&s, 4, 2, true).unwrap().current,
        three.current
    );
}
