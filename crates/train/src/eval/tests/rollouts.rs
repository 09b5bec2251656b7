//! Resting drift, long rollouts past the data and occlusion.

use super::*;

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
    let cr = evaluate_scenes(&creeping, std::slice::from_ref(&s), &EvalOptions::default()).unwrap();
    for d in &cr.resting.as_ref().unwrap().predicted {
        let t = d.translation_m.unwrap();
        assert!(
            (t.mean - 0.05).abs() < 1e-5 && (t.max - 0.05).abs() < 1e-5,
            "{d:?}"
        );
        assert!(d.rotation_deg.unwrap().max < 1e-3, "{d:?}");
    }
    // The drift per shape: two resting objects of shapes 5 and 3, listed by shape id, each
    // with its own count; the ground truth has no breakdown.
    let two = resting_pair_of_shapes_5_and_3();
    let r = evaluate_scenes(&creeping, &[two], &EvalOptions::default()).unwrap();
    let r = r.resting.unwrap();
    assert!(r.truth.by_shape.is_empty());
    for d in &r.predicted {
        let ids: Vec<(i32, u64)> = d
            .by_shape
            .iter()
            .map(|x| (x.shape_id, x.translation_m.count))
            .collect();
        assert_eq!(ids, vec![(3, 1), (5, 1)], "{d:?}");
        assert!((d.by_shape[0].translation_m.mean - 0.05).abs() < 1e-5);
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
