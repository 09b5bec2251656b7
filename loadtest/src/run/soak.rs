//! The soak: many streams for a long time, clients dropping their rollouts at random and
//! reconnecting, every frame checked.
//!
//! Stream `i` owns a scene no other stream has: its own object count (`1 + i % objects`) and
//! its objects moved to their own square region of the ground plane, [`REGION_SPACING_M`]
//! metres apart on a grid. A frame belongs to its stream when it carries that many poses and
//! every pose lies inside the stream's region (a frame of another stream would lie in another
//! region). The frames of a rollout must come with steps 1, 2, 3, ...; a rollout its client
//! keeps must bring every step and end cleanly. Each stream owns its connection; after a drop
//! it opens a new one.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use dynaserve_api::json;
use rand::{Rng, SeedableRng};
use serde::Serialize;
use tokio::sync::Notify;

use super::{Load, Remote, Stop, lock};
use crate::recorder::{Recorder, RequestClock, ServerTiming};
use crate::rss::{RssRecord, RssSource};
use crate::scenes::SceneSource;
use crate::transport::{CallError, Conn};

/// Distance between the centres of neighbouring streams' regions, metres. Generated scenes
/// span a few metres and move at most a few metres per rollout, so half of it is a wide margin.
pub const REGION_SPACING_M: f32 = 50.0;

/// Violations described in the report, at most.
const EXAMPLES: usize = 10;

/// How long streams may take to finish their last rollout after the soak's duration.
pub const DRAIN_LIMIT: Duration = Duration::from_secs(120);

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

/// Soak outcome counts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct SoakCounts {
    /// Rollouts the client kept that brought every frame and ended cleanly.
    pub kept_complete: u64,
    /// Rollouts the client dropped on purpose (each followed by a new connection).
    pub dropped: u64,
    /// Kept rollouts that ended with an error or too few frames (frames lost).
    pub failed: u64,
    /// Rollouts refused at admission (RESOURCE_EXHAUSTED / 429) before any frame, retried.
    pub refused: u64,
    /// Rollouts still running when the run stopped (Ctrl-C, or the drain limit after the
    /// duration: then they are counted as stalled too).
    pub cut: u64,
    /// Rollouts still running [`DRAIN_LIMIT`] after the duration ended.
    pub stalled: u64,
    /// New connections opened after a drop or a failure.
    pub reconnects: u64,
    /// Connection attempts that failed.
    pub connect_errors: u64,
    /// Frames received and checked.
    pub frames: u64,
    /// Frames a kept rollout never brought, and steps skipped before a drop.
    pub lost_frames: u64,
    /// Frames with another pose count or a pose outside the stream's region.
    pub misrouted_frames: u64,
    /// Frames whose step was not above the previous frame's.
    pub out_of_order_frames: u64,
}

/// The soak's section of a level report.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SoakReport {
    /// Concurrent streams.
    pub streams: usize,
    /// Time new rollouts were started, seconds.
    pub duration_s: f64,
    /// Time until every stream had finished its last rollout, seconds.
    pub elapsed_s: f64,
    /// Chance that a rollout is dropped by its client at a random frame.
    pub drop_probability: f64,
    /// Steps per rollout.
    pub steps: u32,
    /// Outcomes.
    pub counts: SoakCounts,
    /// Checked frames per second over `elapsed_s`.
    pub frames_per_s: f64,
    /// The server's resident memory, when it could be read.
    pub rss: Option<RssRecord>,
    /// A few violations or failures, described.
    pub examples: Vec<String>,
}

fn mib(bytes: u64) -> String {
    format!("{:.1} MiB", bytes as f64 / (1024.0 * 1024.0))
}

impl SoakReport {
    /// The soak's block of the text report.
    pub fn to_text(&self) -> String {
        let c = &self.counts;
        let mut o = format!(
            "  soak: {} streams, new rollouts for {:.0} s (all done after {:.0} s), {} steps each, \
             drop probability {}\n",
            self.streams, self.duration_s, self.elapsed_s, self.steps, self.drop_probability
        );
        o += &format!(
            "    rollouts: {} kept to the end, {} dropped by their client ({} new connections), \
             {} failed, {} refused at admission, {} cut, {} stalled, {} failed connection attempts\n",
            c.kept_complete,
            c.dropped,
            c.reconnects,
            c.failed,
            c.refused,
            c.cut,
            c.stalled,
            c.connect_errors
        );
        o += &format!(
            "    frames checked {} ({:.1} frames/s): {} lost, {} misrouted, {} out of order\n",
            c.frames, self.frames_per_s, c.lost_frames, c.misrouted_frames, c.out_of_order_frames
        );
        match &self.rss {
            Some(r) => match (r.start(), r.peak(), r.end()) {
                (Some(a), Some(p), Some(e)) => {
                    o += &format!(
                        "    server RSS ({}): start {}, peak {}, end {} ({} readings)\n",
                        r.source,
                        mib(a),
                        mib(p),
                        mib(e),
                        r.samples.len()
                    )
                }
                _ => {
                    o += &format!(
                        "    server RSS: not read ({})\n",
                        r.errors.first().map_or("no reading", String::as_str)
                    )
                }
            },
            None => o += "    server RSS: not read (no --pid, no spawned server, no /metrics)\n",
        }
        for e in &self.examples {
            o += &format!("    e.g. {e}\n");
        }
        o += if self.passed() {
            "    result: PASS, every frame came in order in its own stream, every kept rollout complete\n"
        } else {
            "    result: FAIL (see the counts above)\n"
        };
        o
    }

    /// True when no frame was lost, misrouted or out of order, no kept rollout failed or
    /// stalled and every connection attempt succeeded.
    pub fn passed(&self) -> bool {
        let c = &self.counts;
        c.lost_frames == 0
            && c.misrouted_frames == 0
            && c.out_of_order_frames == 0
            && c.failed == 0
            && c.stalled == 0
            && c.connect_errors == 0
    }
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
    fn note(&mut self, what: String) {
        if self.examples.len() < EXAMPLES {
            self.examples.push(what);
        }
    }

    fn add(&mut self, c: &RolloutCheck) {
        self.counts.frames += u64::from(c.received);
        self.counts.lost_frames += c.lost;
        self.counts.misrouted_frames += c.misrouted;
        self.counts.out_of_order_frames += c.out_of_order;
    }
}

/// What one stream of the soak does.
pub(super) struct SoakStream {
    pub(super) index: usize,
    pub(super) request: json::RolloutRequest,
    pub(super) identity: StreamIdentity,
    pub(super) drop_probability: f64,
    pub(super) seed: u64,
}

fn is_refusal(e: &CallError) -> bool {
    e.code.contains("RESOURCE_EXHAUSTED") || e.code.starts_with("http 429")
}

enum Outcome {
    Complete,
    Dropped,
    Refused(CallError),
    Failed(CallError),
    Cut,
}

/// Runs stream `s` until `end` (then finishes its rollout, up to `drain_end`), recording
/// frames in `rec` and checks in `tally`.
pub(super) async fn soak_stream(
    s: SoakStream,
    remote: Arc<Remote>,
    rec: Arc<Mutex<Recorder>>,
    tally: Arc<Mutex<SoakTally>>,
    end: Instant,
    drain_end: Instant,
    stop: Stop,
) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(s.seed ^ (s.index as u64) << 20);
    let steps = s.request.steps;
    let Some(mut conn) = connect(&remote, &s, &tally, end, &stop).await else {
        return;
    };
    let mut rollout = 0u64;
    while !stop.is_set() && Instant::now() < end {
        let drop_after = (steps >= 2 && rng.random_bool(s.drop_probability.clamp(0.0, 1.0)))
            .then(|| rng.random_range(1..steps));
        rollout += 1;
        let mut check = RolloutCheck::new();
        let outcome = tokio::select! {
            o = run_one(&mut conn, &s, &mut check, drop_after, &rec, &tally, rollout) => o,
            _ = tokio::time::sleep_until(drain_end.into()) => Outcome::Cut,
            _ = stop.wait() => Outcome::Cut,
        };
        let who = format!("stream {} rollout {rollout}", s.index);
        let mut new_connection = false;
        let mut wait = None;
        {
            let mut t = lock(&tally);
            match outcome {
                Outcome::Complete => {
                    check.finish(steps);
                    t.counts.kept_complete += 1;
                }
                Outcome::Dropped => {
                    t.counts.dropped += 1;
                    new_connection = true;
                }
                Outcome::Refused(e) => {
                    t.counts.refused += 1;
                    wait = Some(Duration::from_millis(
                        e.retry_after_ms.unwrap_or(100).clamp(10, 1000),
                    ));
                }
                Outcome::Failed(e) => {
                    check.finish(steps);
                    t.counts.failed += 1;
                    t.note(format!(
                        "{who}: failed after {} frames: {e}",
                        check.received
                    ));
                    new_connection = true;
                    wait = Some(Duration::from_millis(100));
                }
                Outcome::Cut => {
                    t.counts.cut += 1;
                    if !stop.is_set() {
                        t.counts.stalled += 1;
                        t.note(format!(
                            "{who}: still running {} s after the soak's end ({} frames)",
                            DRAIN_LIMIT.as_secs(),
                            check.received
                        ));
                    }
                }
            }
            t.add(&check);
        }
        if stop.is_set() || Instant::now() >= drain_end {
            return;
        }
        if let Some(w) = wait {
            tokio::select! {
                _ = tokio::time::sleep(w) => {}
                _ = stop.wait() => return,
            }
        }
        if new_connection && Instant::now() < end {
            // The client went away mid-rollout: it comes back on a new connection.
            let Some(c) = connect(&remote, &s, &tally, end, &stop).await else {
                return;
            };
            conn = c;
            lock(&tally).counts.reconnects += 1;
        }
    }
}

/// A new connection for stream `s`, retried every 200 ms (each failure counted) until `end`.
async fn connect(
    remote: &Remote,
    s: &SoakStream,
    tally: &Mutex<SoakTally>,
    end: Instant,
    stop: &Stop,
) -> Option<Conn> {
    loop {
        match remote.fresh_conn().await {
            Ok(c) => return Some(c),
            Err(e) => {
                let mut t = lock(tally);
                t.counts.connect_errors += 1;
                t.note(format!("stream {}: cannot connect: {e}", s.index));
            }
        }
        if stop.is_set() || Instant::now() >= end {
            return None;
        }
        tokio::select! {
            _ = tokio::time::sleep(Duration::from_millis(200)) => {}
            _ = stop.wait() => return None,
        }
    }
}

async fn run_one(
    conn: &mut Conn,
    s: &SoakStream,
    check: &mut RolloutCheck,
    drop_after: Option<u32>,
    rec: &Mutex<Recorder>,
    tally: &Mutex<SoakTally>,
    rollout: u64,
) -> Outcome {
    let leave = Notify::new();
    lock(rec).started();
    let mut clock = RequestClock::start();
    let result = {
        let mut on_frame = |at: Instant, f: &json::StepFrame| {
            let timing = f.timing.map(|t| ServerTiming {
                queue_ms: f64::from(t.queue_ms),
                forward_ms: f64::from(t.forward_ms),
                batch_scenes: t.batch_scenes,
            });
            lock(rec).frame(&mut clock, at, f.poses.len(), timing);
            if let Some(wrong) = check.frame(&s.identity, f) {
                lock(tally).note(format!("stream {} rollout {rollout}: {wrong}", s.index));
            }
            if drop_after == Some(check.received) {
                leave.notify_one();
            }
        };
        tokio::select! {
            r = conn.rollout(&s.request, &mut on_frame) => Some(r),
            _ = leave.notified() => None,
        }
    };
    match result {
        None => Outcome::Dropped,
        Some(Ok(_)) => {
            lock(rec).rollout_ok(&clock, Instant::now());
            Outcome::Complete
        }
        Some(Err(e)) => {
            lock(rec).failed(&e);
            if check.received == 0 && is_refusal(&e) {
                Outcome::Refused(e)
            } else {
                Outcome::Failed(e)
            }
        }
    }
}

/// Parameters of a soak.
#[derive(Clone, Debug, PartialEq)]
pub struct SoakPlan {
    /// Concurrent streams.
    pub streams: usize,
    /// Time new rollouts are started; streams then finish the rollout they are in.
    pub duration: Duration,
    /// Chance that a client drops a rollout at a random frame and reconnects.
    pub drop_probability: f64,
    /// Time between two readings of the server's resident memory.
    pub rss_interval: Duration,
    /// Seed of the drop decisions.
    pub seed: u64,
}

/// Runs the soak: every stream on its own connection until the duration ends, the server's
/// memory read at the start, every `rss_interval` and at the end.
pub(super) async fn run_soak(
    load: &Arc<Load>,
    remote: &Arc<Remote>,
    plan: &SoakPlan,
    rss_source: Option<RssSource>,
    rec: &Arc<Mutex<Recorder>>,
    stop: &Stop,
) -> SoakReport {
    let start = Instant::now();
    let mut rss = rss_source.as_ref().map(RssRecord::new);
    if let (Some(r), Some(src)) = (rss.as_mut(), rss_source.as_ref()) {
        r.sample(src, start).await;
    }
    let end = start + plan.duration;
    let drain_end = end + DRAIN_LIMIT;
    let tally = Arc::new(Mutex::new(SoakTally::default()));
    let mut tasks = tokio::task::JoinSet::new();
    for i in 0..plan.streams {
        let (scene, identity) = soak_scene(&load.scenes, i, plan.streams);
        let s = SoakStream {
            index: i,
            request: load.rollout(scene),
            identity,
            drop_probability: plan.drop_probability,
            seed: plan.seed,
        };
        tasks.spawn(soak_stream(
            s,
            remote.clone(),
            rec.clone(),
            tally.clone(),
            end,
            drain_end,
            stop.clone(),
        ));
    }
    let every = plan.rss_interval.max(Duration::from_millis(100));
    let mut tick = tokio::time::interval_at((start + every).into(), every);
    loop {
        tokio::select! {
            j = tasks.join_next() => if j.is_none() { break },
            _ = tick.tick(), if rss.is_some() => {
                if let (Some(r), Some(src)) = (rss.as_mut(), rss_source.as_ref()) {
                    r.sample(src, start).await;
                }
            }
        }
    }
    if let (Some(r), Some(src)) = (rss.as_mut(), rss_source.as_ref()) {
        r.sample(src, start).await;
    }
    let t = lock(&tally);
    SoakReport {
        streams: plan.streams,
        duration_s: plan.duration.as_secs_f64(),
        elapsed_s: start.elapsed().as_secs_f64(),
        drop_probability: plan.drop_probability,
        steps: load.steps,
        counts: t.counts,
        frames_per_s: t.counts.frames as f64 / start.elapsed().as_secs_f64().max(1e-9),
        rss,
        examples: t.examples.clone(),
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
