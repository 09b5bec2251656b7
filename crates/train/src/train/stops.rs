//! Windows at the end of an object's motion (`data.stop_share`).
//!
//! The resting drift of a rollout comes mostly from objects that the model keeps moving after
//! rapier's have stopped: a roll, a slide or a tumble that should end (`docs/experiments.md`,
//! on the resting drift). The moment of stopping is a few frames of each object's
//! record, and a gentle one: the deceleration that ends changes the acceleration by about
//! `friction * g * dt^2`, far less than an impact does, so neither uniform nor
//! [`super::events`]-weighted draws favour it.
//!
//! An object's *stop frame* `s` is the first frame from which it stays at rest to the end of
//! its record, at rest meaning that every later frame interval moves it by at most
//! [`REST_TRANSLATION_PER_FRAME_M`] and turns it by at most [`REST_ROTATION_PER_FRAME_RAD`]
//! (the tolerances the model's rest weight uses). Objects that never move, never stop, or stop
//! too late to stay at rest for [`STOP_HOLD_FRAMES`] are left out; so are kinematic objects.
//! The windows drawn are those whose last observed frame `t` lies in `s - STOP_LEAD_FRAMES ..=
//! s + k - 1`: the last frames of the motion and the first steps whose target is at rest.

use dynaserve_model::config::{REST_ROTATION_PER_FRAME_RAD, REST_TRANSLATION_PER_FRAME_M};
use dynaserve_sim::{ObjectRecord, SceneRecord};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Frames before an object's stop frame that a stopping window may start at (a third of a
/// second at 24 frames per second).
pub const STOP_LEAD_FRAMES: usize = 8;

/// Frames an object must stay at rest after its stop frame for the stop to count: a stop at
/// the very end of a record may be a pause, not an end.
pub const STOP_HOLD_FRAMES: usize = 4;

/// The frame from which `object` stays at rest to the end of its record, or `None` if it never
/// moves, never comes to rest, or comes to rest fewer than [`STOP_HOLD_FRAMES`] frames before
/// the end.
pub fn stop_frame(object: &ObjectRecord) -> Option<usize> {
    let frames = object.positions.len().min(object.rotations.len());
    let rotation = |f: usize| {
        let [x, y, z, w] = object.rotations[f];
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
    };
    let moves = |f: usize| {
        let d = Vector3::from(object.positions[f + 1]) - Vector3::from(object.positions[f]);
        d.norm() > REST_TRANSLATION_PER_FRAME_M
            || rotation(f).angle_to(&rotation(f + 1)) > REST_ROTATION_PER_FRAME_RAD
    };
    // The last interval in which the object moves; it is at rest from the frame after it.
    let last_move = (0..frames.checked_sub(1)?).rev().find(|&f| moves(f))?;
    let stop = last_move + 1;
    (stop + STOP_HOLD_FRAMES < frames).then_some(stop)
}

/// Candidate window frames `t` (each `k..=frames - 1 - k`) at the stops of `scene`'s dynamic
/// objects at step `k` frames, one entry per object and frame, so a frame where two objects
/// stop counts twice. Empty if no object stops or the scene is too short for step `k`.
pub fn stop_windows(scene: &SceneRecord, k: usize) -> Vec<usize> {
    let Some(frames) = super::events::window_frames(scene, k) else {
        return Vec::new();
    };
    let (lo, hi) = (k, frames - 1 - k);
    scene
        .objects
        .iter()
        .filter(|o| !o.kinematic && o.positions.len() == frames)
        .filter_map(stop_frame)
        .flat_map(|s| {
            let first = s.saturating_sub(STOP_LEAD_FRAMES).max(lo);
            let last = (s + k - 1).min(hi);
            first..=last
        })
        .collect()
}

/// Draws a window frame uniformly from [`stop_windows`]; `None` if the scene has none.
pub fn draw_frame(scene: &SceneRecord, k: usize, rng: &mut ChaCha8Rng) -> Option<usize> {
    let w = stop_windows(scene, k);
    (!w.is_empty()).then(|| w[rng.random_range(0..w.len())])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::test_records::object;
    use rand::SeedableRng;

    /// An object sliding along x that friction stops at frame 40 of 60, one that never moves,
    /// and a kinematic one that stops at frame 20 (to be ignored).
    fn slide_scene() -> SceneRecord {
        let frames = 60;
        let dt = 1.0 / 24.0;
        let slide: Vec<[f32; 3]> = (0..frames)
            .map(|f| {
                // v(t) = 2 - 1.2 t m/s until it stops at t = 40 dt.
                let t = (f.min(40) as f32) * dt;
                let a = 2.0 / (40.0 * dt);
                [2.0 * t - 0.5 * a * t * t, 0.0, 0.1]
            })
            .collect();
        let still = vec![[1.0, 1.0, 0.1]; frames];
        let pusher: Vec<[f32; 3]> = (0..frames)
            .map(|f| [0.0, 3.0 + 0.1 * f.min(20) as f32, 0.1])
            .collect();
        SceneRecord {
            objects: vec![
                object(slide, false),
                object(still, false),
                object(pusher, true),
            ],
            dt_frame: dt,
        }
    }

    #[test]
    fn the_stop_frame_is_where_the_motion_ends() {
        let scene = slide_scene();
        // The slide's last frame intervals move it less than the tolerance (it decelerates
        // to zero), so its stop comes a frame or two before frame 40.
        let s = stop_frame(&scene.objects[0]).unwrap();
        assert!((37..=40).contains(&s), "stop frame {s}");
        assert_eq!(
            stop_frame(&scene.objects[1]),
            None,
            "a still object never stops"
        );
        let mut moving = scene.objects[0].clone();
        for (f, p) in moving.positions.iter_mut().enumerate() {
            p[1] = 0.01 * f as f32;
        }
        assert_eq!(
            stop_frame(&moving),
            None,
            "an object moving to the end never stops"
        );
    }

    #[test]
    fn a_turning_object_is_not_at_rest() {
        let mut spinning = slide_scene().objects[1].clone();
        for (f, q) in spinning.rotations.iter_mut().enumerate().take(30) {
            let r = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.05 * f as f32);
            *q = [r.i, r.j, r.k, r.w];
        }
        for q in spinning.rotations.iter_mut().skip(30) {
            let r = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.05 * 29.0);
            *q = [r.i, r.j, r.k, r.w];
        }
        assert_eq!(stop_frame(&spinning), Some(29));
    }

    #[test]
    fn windows_cover_the_stop_of_dynamic_objects_only() {
        let scene = slide_scene();
        let s = stop_frame(&scene.objects[0]).unwrap();
        for k in [1usize, 2, 4] {
            let w = stop_windows(&scene, k);
            let want: Vec<usize> = (s - STOP_LEAD_FRAMES..=s + k - 1).collect();
            assert_eq!(w, want, "k = {k}");
        }
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..100 {
            let t = draw_frame(&scene, 2, &mut rng).unwrap();
            assert!((s - STOP_LEAD_FRAMES..=s + 1).contains(&t), "frame {t}");
        }
    }

    /// Training windows under `stop_share = 1` all end at or after the slide's stop window
    /// (its target is no earlier than frame `s - STOP_LEAD_FRAMES + k`); uniform ones do not.
    #[test]
    fn the_share_moves_training_windows_to_the_stop() {
        let scene = slide_scene();
        let s = stop_frame(&scene.objects[0]).unwrap();
        let earliest = scene.objects[0].positions[s - STOP_LEAD_FRAMES + 1][0];
        let mut c = crate::train::config::DataConfig {
            rotate_z: false,
            mirror: false,
            shuffle_objects: false,
            ..Default::default()
        };
        let targets = |c: &crate::train::config::DataConfig| -> Vec<f32> {
            (0..64u64)
                .map(|i| {
                    let mut rng = ChaCha8Rng::seed_from_u64(i);
                    let w =
                        crate::train::data::sample_window(&scene, c, &mut rng, true, i).unwrap();
                    w.target[0].translation[0]
                })
                .collect()
        };
        assert!(targets(&c).iter().any(|&x| x < earliest - 1e-6));
        c.stop_share = 1.0;
        for x in targets(&c) {
            assert!(x >= earliest - 1e-6, "target at x = {x}, before {earliest}");
        }
    }

    #[test]
    fn scenes_without_a_stop_give_no_frame() {
        let mut scene = slide_scene();
        scene.objects.remove(0);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        assert_eq!(draw_frame(&scene, 1, &mut rng), None);
        scene.objects[0].positions.truncate(2);
        assert!(stop_windows(&scene, 1).is_empty());
    }
}
