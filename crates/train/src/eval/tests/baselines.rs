//! Pooled errors, the static and ballistic baselines, horizons, options, misbehaving
//! predictors and curves.

use super::*;

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
    // The objects fly without gravity (the contact split's impulse test must know it).
    let opts = EvalOptions {
        gravity: [0.0; 3],
        ..EvalOptions::default()
    };
    let report = evaluate_scenes(&Static, &[a, b], &opts).unwrap();
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
            // Per object: 1, 2 and 3 m/s times H; only the first object turns.
            let t = e.translation_m.expect("translation spread");
            assert_eq!(t.count, 3);
            for (got, want) in [(t.mean, 2.0 * h), (t.median, 2.0 * h), (t.max, 3.0 * h)] {
                assert!((got - want).abs() < 1e-4 * want.max(1.0), "{got} vs {want}");
            }
            let r = e.orientation_deg.expect("orientation spread");
            let turned = (0.5 * h).to_degrees();
            assert!(
                r.median.abs() < 1e-2 && (r.max - turned).abs() < 1e-2,
                "{r:?}"
            );
            assert!((r.mean - turned / 3.0).abs() < 1e-2, "{r:?}");
            // Scene A's two objects start in one place (in contact), scene B's is alone and
            // high above the floor.
            let classes: Vec<_> = e.by_contact.iter().map(|c| c.contact).collect();
            assert_eq!(classes, [ContactHistory::Object, ContactHistory::None]);
            let (touching, alone) = (&e.by_contact[0], &e.by_contact[1]);
            assert_eq!(
                (touching.translation_m.count, alone.translation_m.count),
                (2, 1)
            );
            for (got, want) in [
                (touching.translation_rmse_m, 2.5f64.sqrt() * h),
                (alone.translation_rmse_m, 3.0 * h),
                (touching.orientation_rmse_deg, turned / 2f64.sqrt()),
                (alone.orientation_rmse_deg, 0.0),
            ] {
                assert!((got - want).abs() < 1e-2 * want.max(1.0), "{got} vs {want}");
            }
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

#[test]
fn the_contact_split_tells_the_floor_from_free_fall() {
    // Object 0 rests on the floor (its lowest corner at z = 0); object 1 falls freely from
    // 100 m, 10 m away, under the default gravity: its acceleration is gravity's, so the
    // impulse test sees no contact.
    let s = scene(2, 101, |j, t| {
        let p = match j {
            0 => Vector3::new(0.0, 0.0, 0.5),
            _ => Vector3::new(10.0, 0.0, 100.0 - 5.0 * t * t),
        };
        pose(p, UnitQuaternion::identity())
    });
    let report = evaluate_scenes(&Static, &[s], &EvalOptions::default()).unwrap();
    for h in DEFAULT_HORIZONS_S {
        let e = entry(&report, 1, h);
        let classes: Vec<_> = e
            .by_contact
            .iter()
            .map(|c| (c.contact, c.translation_m.count))
            .collect();
        assert_eq!(
            classes,
            [(ContactHistory::FloorOnly, 1), (ContactHistory::None, 1)],
            "h = {h}"
        );
        // Static is exact for the resting object and off by the fall for the other.
        let fall = 5.0 * ((4.0 / 24.0 + h).powi(2) - (4.0f64 / 24.0).powi(2));
        assert!(e.by_contact[0].translation_rmse_m < 1e-6, "{e:?}");
        let got = e.by_contact[1].translation_rmse_m;
        assert!((got - fall).abs() < 1e-3 * fall, "{got} vs {fall}");
    }
}
