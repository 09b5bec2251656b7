//! How a soak recognises its frames: each stream's identity (pose count and ground region),
//! the scene that carries it, the per-rollout order and ownership checks, and the shared tally.

use dynaserve_api::json;

use crate::report::SoakCounts;
use crate::scenes::SceneSource;

/// Distance between the centres of neighbouring streams' regions, metres. Generated scenes
/// span a few metres and move at most a few metres per rollout, so half of it is a wide margin.
pub const REGION_SPACING_M: f32 = 50.0;

/// Violations described in the report, at most.
const EXAMPLES: usize = 10;

/// What makes a stream's frames recognisable as its own.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StreamIdentity {
    /// Poses per frame.
    pub objects: usize,
    /// Centre of the stream's region `[x, y]`, metres.
    pub centre: [f32; 2],
    /// Half the side of the region, metres.
    pub half_width: f32,
}

impl StreamIdentity {
    /// Identity of stream `i` of `streams`, whose scene has `objects` objects.
    pub fn of(i: usize, streams: usize, objects: usize) -> StreamIdentity {
        let cols = (streams.max(1) as f64).sqrt().ceil() as usize;
        let (col, row) = (i % cols, i / cols);
        StreamIdentity {
            objects,
            centre: [col as f32 * REGION_SPACING_M, row as f32 * REGION_SPACING_M],
            half_width: REGION_SPACING_M / 2.0,
        }
    }

    /// True when `poses` are this stream's: as many as its objects, every one finite and
    /// inside its region.
    pub fn owns(&self, poses: &[json::Pose]) -> bool {
        poses.len() == self.objects
            && poses.iter().all(|p| {
                let t = p.translation;
                t.iter().all(|v| v.is_finite())
                    && (t[0] - self.centre[0]).abs() < self.half_width
                    && (t[1] - self.centre[1]).abs() < self.half_width
            })
    }
}

/// Scene of stream `i` of `streams`: scene `i` of `source` cut to `1 + i % objects` objects
/// and moved to the stream's region; returns the scene and its identity.
pub fn soak_scene(source: &SceneSource, i: usize, streams: usize) -> (json::Scene, StreamIdentity) {
    let mut scene = source.scene(i);
    let keep = 1 + i % scene.objects.len().max(1);
    scene.objects.truncate(keep);
    let id = StreamIdentity::of(i, streams, scene.objects.len());
    for o in &mut scene.objects {
        for pose in std::iter::once(&mut o.pose).chain(o.previous_pose.as_mut()) {
            pose.translation[0] += id.centre[0];
            pose.translation[1] += id.centre[1];
        }
    }
    (scene, id)
}

/// Checks of one rollout's frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RolloutCheck {
    /// The step the next frame must carry.
    pub next: u32,
    /// Frames received.
    pub received: u32,
    /// Steps skipped.
    pub lost: u64,
    /// Frames not of this stream.
    pub misrouted: u64,
    /// Frames whose step was not above the previous one.
    pub out_of_order: u64,
}

impl RolloutCheck {
    /// Before the first frame.
    pub fn new() -> RolloutCheck {
        RolloutCheck {
            next: 1,
            ..RolloutCheck::default()
        }
    }

    /// Checks one frame; returns a description of what was wrong with it, if anything.
    pub fn frame(&mut self, id: &StreamIdentity, f: &json::StepFrame) -> Option<String> {
        self.received += 1;
        let mut wrong = Vec::new();
        if !id.owns(&f.poses) {
            self.misrouted += 1;
            wrong.push(format!(
                "step {} has {} poses (first at {:?}), not {} in the region around {:?}",
                f.step,
                f.poses.len(),
                f.poses.first().map(|p| p.translation),
                id.objects,
                id.centre
            ));
        }
        if f.step == self.next {
            self.next += 1;
        } else if f.step > self.next {
            self.lost += u64::from(f.step - self.next);
            wrong.push(format!("step {} came when {} was due", f.step, self.next));
            self.next = f.step + 1;
        } else {
            self.out_of_order += 1;
            wrong.push(format!("step {} came after step {}", f.step, self.next - 1));
        }
        (!wrong.is_empty()).then(|| wrong.join("; "))
    }

    /// A kept rollout of `steps` steps has ended: the steps it never brought are lost.
    pub fn finish(&mut self, steps: u32) {
        self.lost += u64::from(steps.saturating_sub(self.next - 1));
    }
}

/// Shared tally of a soak.
#[derive(Debug, Default)]
pub struct SoakTally {
    /// Counts so far.
    pub counts: SoakCounts,
    /// Violations described so far (the first few).
    pub examples: Vec<String>,
}

impl SoakTally {
    /// Keeps a description of a violation, while fewer than a few are kept.
    pub(super) fn note(&mut self, what: String) {
        if self.examples.len() < EXAMPLES {
            self.examples.push(what);
        }
    }

    /// Adds one rollout's frame checks to the counts.
    pub(super) fn add(&mut self, c: &RolloutCheck) {
        self.counts.frames += u64::from(c.received);
        self.counts.lost_frames += c.lost;
        self.counts.misrouted_frames += c.misrouted;
        self.counts.out_of_order_frames += c.out_of_order;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(step: u32, poses: Vec<[f32; 3]>) -> json::StepFrame {
        json::StepFrame {
            step,
            time: 0.0,
            poses: poses
                .into_iter()
                .map(|translation| json::Pose {
                    translation,
                    rotation: json::IDENTITY_ROTATION,
                })
                .collect(),
            timing: None,
            spread: Vec::new(),
        }
    }

    #[test]
    fn regions_are_disjoint_and_scenes_moved_into_them() {
        let src = SceneSource::Generated {
            objects: 4,
            points: 16,
            seed: 3,
        };
        let n = 10;
        let ids: Vec<StreamIdentity> = (0..n).map(|i| soak_scene(&src, i, n).1).collect();
        for (i, a) in ids.iter().enumerate() {
            for b in &ids[i + 1..] {
                let d = (a.centre[0] - b.centre[0])
                    .abs()
                    .max((a.centre[1] - b.centre[1]).abs());
                assert!(d >= a.half_width + b.half_width, "{a:?} {b:?}");
            }
        }
        for i in 0..n {
            let (scene, id) = soak_scene(&src, i, n);
            assert_eq!(id.objects, 1 + i % 4);
            assert_eq!(scene.objects.len(), id.objects);
            let poses: Vec<json::Pose> = scene.objects.iter().map(|o| o.pose).collect();
            assert!(id.owns(&poses), "stream {i}: {poses:?} not in {id:?}");
            for (j, other) in ids.iter().enumerate() {
                if j != i {
                    assert!(
                        !other.owns(&poses),
                        "stream {i}'s scene also fits stream {j}"
                    );
                }
            }
        }
    }

    #[test]
    fn frames_are_checked_for_stream_and_order() {
        let id = StreamIdentity::of(1, 4, 2);
        let home = [id.centre[0] + 1.0, id.centre[1], 0.3];
        let mut c = RolloutCheck::new();
        assert_eq!(c.frame(&id, &frame(1, vec![home, home])), None);
        assert_eq!(c.frame(&id, &frame(2, vec![home, home])), None);
        // Another stream's frame: wrong count, then right count in the wrong region.
        assert!(c.frame(&id, &frame(3, vec![home])).is_some());
        assert!(
            c.frame(&id, &frame(4, vec![home, [0.0, 0.0, 0.3]]))
                .unwrap()
                .contains("not 2 in the region")
        );
        assert!(
            c.frame(&id, &frame(5, vec![home, [f32::NAN, 0.0, 0.0]]))
                .is_some()
        );
        assert_eq!(c.misrouted, 3);
        // A gap loses steps 6 and 7; a repeated step is out of order.
        assert!(
            c.frame(&id, &frame(8, vec![home, home]))
                .unwrap()
                .contains("8 came when 6")
        );
        assert!(
            c.frame(&id, &frame(8, vec![home, home]))
                .unwrap()
                .contains("after step 8")
        );
        assert_eq!((c.lost, c.out_of_order, c.received), (2, 1, 7));
        // Kept to the end of a 10-step rollout, it misses 9 and 10.
        c.finish(10);
        assert_eq!(c.lost, 4);
        let mut clean = RolloutCheck::new();
        for s in 1..=3 {
            assert_eq!(clean.frame(&id, &frame(s, vec![home, home])), None);
        }
        clean.finish(3);
        assert_eq!(
            clean,
            RolloutCheck {
                next: 4,
                received: 3,
                ..RolloutCheck::default()
            }
        );
    }
}
