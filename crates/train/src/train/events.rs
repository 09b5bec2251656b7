//! Event-weighted choice of a training window's frame (`data.event_share`).
//!
//! Most frames of a recorded scene are easy: objects rest, fly or slide, and a constant
//! acceleration (zero, gravity, friction) extrapolates them. The frames that teach contact
//! (an impact, the first touch of a pusher, a box tipping over) are few, so uniformly drawn
//! windows rarely hold them. The *surprise* of a window at frame `t` with step `k` is how much
//! the acceleration over the window departs from the one over the window before:
//!
//! `s(t) = max over dynamic objects |a(t) - a(t - k)|`, with `a(t) = x(t+k) - 2 x(t) + x(t-k)`
//!
//! (metres, object centres). It is zero for any motion of constant acceleration, so it needs
//! neither gravity nor the frame interval, and it is large exactly around contact events.

use dynaserve_sim::SceneRecord;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Weight added to every frame's surprise, metres: windows without an event keep a small
/// chance, and a scene without any event is drawn uniformly.
pub const SURPRISE_FLOOR: f32 = 5e-4;

/// Frames of `scene`'s record (its first object's) if it holds a window at step `k` frames
/// (`k >= 1`, at least `2k + 1` frames); `None` otherwise.
pub(crate) fn window_frames(scene: &SceneRecord, k: usize) -> Option<usize> {
    let frames = scene.objects.first()?.positions.len();
    (k >= 1 && frames > 2 * k).then_some(frames)
}

/// Surprise (metres) of every candidate frame `t` in `k..=frames - 1 - k` of `scene` at step
/// `k` frames, in that order; frames with `t < 2k` (no earlier window) score 0. Kinematic
/// objects are skipped: their path is given, not predicted.
pub fn surprise(scene: &SceneRecord, k: usize) -> Vec<f32> {
    let Some(frames) = window_frames(scene, k) else {
        return Vec::new();
    };
    let accel = |p: &[[f32; 3]], t: usize| -> [f32; 3] {
        std::array::from_fn(|d| p[t + k][d] - 2.0 * p[t][d] + p[t - k][d])
    };
    (k..frames - k)
        .map(|t| {
            if t < 2 * k {
                return 0.0;
            }
            scene
                .objects
                .iter()
                .filter(|o| !o.kinematic && o.positions.len() == frames)
                .map(|o| {
                    let (a, b) = (accel(&o.positions, t), accel(&o.positions, t - k));
                    let d: [f32; 3] = std::array::from_fn(|i| a[i] - b[i]);
                    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
                })
                .fold(0.0f32, f32::max)
        })
        .collect()
}

/// Draws a window frame `t` in `k..=frames - 1 - k` with probability proportional to its
/// [`surprise`] plus [`SURPRISE_FLOOR`]. `None` if the scene is too short for step `k`.
pub fn draw_frame(scene: &SceneRecord, k: usize, rng: &mut ChaCha8Rng) -> Option<usize> {
    let w = surprise(scene, k);
    if w.is_empty() {
        return None;
    }
    let total: f64 = w.iter().map(|&s| (s + SURPRISE_FLOOR) as f64).sum();
    let mut u = rng.random::<f64>() * total;
    for (i, &s) in w.iter().enumerate() {
        u -= (s + SURPRISE_FLOOR) as f64;
        if u <= 0.0 {
            return Some(k + i);
        }
    }
    Some(k + w.len() - 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::test_records::object;
    use rand::SeedableRng;

    /// One object falling under gravity that hits the floor at frame 30 and rests; a second,
    /// kinematic object that jerks around and must be ignored.
    fn drop_scene() -> SceneRecord {
        let frames = 60;
        let dt = 1.0 / 24.0;
        let mut falling = Vec::new();
        let mut z = 3.0f32;
        let mut v = 0.0f32;
        for f in 0..frames {
            falling.push([0.0, 0.0, z]);
            if f < 30 {
                v -= 10.0 * dt;
                z += v * dt;
            }
        }
        let jerky: Vec<[f32; 3]> = (0..frames)
            .map(|f| [if f % 7 == 0 { 1.0 } else { 0.0 }, 5.0, 0.5])
            .collect();
        SceneRecord {
            objects: vec![object(falling, false), object(jerky, true)],
            dt_frame: dt,
        }
    }

    #[test]
    fn surprise_is_zero_at_constant_acceleration_and_peaks_at_the_impact() {
        let scene = drop_scene();
        let s = surprise(&scene, 1);
        assert_eq!(s.len(), 58);
        // Frames 2..=28: free fall (constant acceleration); 32..: rest.
        for t in (2..=28).chain(32..59) {
            assert!(s[t - 1] < 1e-5, "frame {t}: surprise {}", s[t - 1]);
        }
        let peak = (1..59)
            .max_by(|&a, &b| s[a - 1].total_cmp(&s[b - 1]))
            .unwrap();
        assert!((29..=31).contains(&peak), "peak at frame {peak}");
    }

    #[test]
    fn draws_concentrate_on_the_event() {
        let scene = drop_scene();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let near = (0..1000)
            .map(|_| draw_frame(&scene, 1, &mut rng).unwrap())
            .filter(|t| (27..=33).contains(t))
            .count();
        // 7 of 58 frames: about 12% if uniform.
        assert!(near > 700, "{near} of 1000 draws near the impact");
    }

    #[test]
    fn too_short_scenes_give_no_frame() {
        let mut scene = drop_scene();
        for o in &mut scene.objects {
            o.positions.truncate(4);
        }
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        assert_eq!(draw_frame(&scene, 2, &mut rng), None);
        assert!(draw_frame(&scene, 1, &mut rng).is_some());
    }
}
