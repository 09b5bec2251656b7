//! Collects what the load produced (frames, request outcomes, errors) into a [`Report`].

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use crate::report::{Report, RequestCounts, Throughput};
use crate::stats::Summary;
use crate::transport::CallError;

/// Error messages kept per level, for the report.
const EXAMPLES: usize = 5;

/// Shared accumulator of one load level (behind a mutex; every call is short).
#[derive(Debug)]
pub struct Recorder {
    /// Samples before this instant are warm-up and not counted.
    pub measure_from: Instant,
    step_ms: Vec<f64>,
    first_ms: Vec<f64>,
    request_ms: Vec<f64>,
    batch_scenes: Vec<f64>,
    queue_ms: Vec<f64>,
    forward_ms: Vec<f64>,
    frames: u64,
    scene_steps: u64,
    object_steps: u64,
    counts: RequestCounts,
    errors: BTreeMap<String, u64>,
    examples: Vec<String>,
    last_event: Option<Instant>,
}

/// Per-request state for frame timing.
#[derive(Clone, Copy, Debug)]
pub struct RequestClock {
    /// When the request was sent.
    pub start: Instant,
    /// When its previous frame arrived.
    pub last: Option<Instant>,
}

impl RequestClock {
    /// A request sent now.
    pub fn start() -> RequestClock {
        RequestClock {
            start: Instant::now(),
            last: None,
        }
    }
}

/// Server-reported timing of one frame or call.
#[derive(Clone, Copy, Debug, Default)]
pub struct ServerTiming {
    /// Queue wait, ms.
    pub queue_ms: f64,
    /// Forward time, ms.
    pub forward_ms: f64,
    /// Scenes in the batch (0 when unknown).
    pub batch_scenes: u32,
}

impl Recorder {
    /// An empty recorder whose measured window starts at `measure_from`.
    pub fn new(measure_from: Instant) -> Recorder {
        Recorder {
            measure_from,
            step_ms: Vec::new(),
            first_ms: Vec::new(),
            request_ms: Vec::new(),
            batch_scenes: Vec::new(),
            queue_ms: Vec::new(),
            forward_ms: Vec::new(),
            frames: 0,
            scene_steps: 0,
            object_steps: 0,
            counts: RequestCounts::default(),
            errors: BTreeMap::new(),
            examples: Vec::new(),
            last_event: None,
        }
    }

    /// A request was sent.
    pub fn started(&mut self) {
        self.counts.started += 1;
    }

    /// A Poisson arrival was not sent (in-flight limit).
    pub fn skipped(&mut self) {
        self.counts.skipped += 1;
    }

    /// One frame of a stream arrived at `at` with `objects` poses.
    pub fn frame(
        &mut self,
        clock: &mut RequestClock,
        at: Instant,
        objects: usize,
        timing: Option<ServerTiming>,
    ) {
        if at >= self.measure_from {
            self.frames += 1;
            self.scene_steps += 1;
            self.object_steps += objects as u64;
            match clock.last {
                Some(last) => self.step_ms.push(ms(at - last)),
                None if clock.start >= self.measure_from => {
                    self.first_ms.push(ms(at - clock.start))
                }
                None => {}
            }
            if let Some(t) = timing {
                self.queue_ms.push(t.queue_ms);
                self.forward_ms.push(t.forward_ms);
                if t.batch_scenes > 0 {
                    self.batch_scenes.push(f64::from(t.batch_scenes));
                }
            }
            self.last_event = Some(at);
        }
        clock.last = Some(at);
    }

    /// A rollout completed at `at`.
    pub fn rollout_ok(&mut self, clock: &RequestClock, at: Instant) {
        self.counts.ok += 1;
        if clock.start >= self.measure_from {
            self.request_ms.push(ms(at - clock.start));
        }
    }

    /// A Predict call completed at `at`, returning `frames` frames and computing
    /// `scene_steps` scene-steps and `object_steps` object-steps.
    pub fn predict_ok(
        &mut self,
        clock: &RequestClock,
        at: Instant,
        frames: u64,
        scene_steps: u64,
        object_steps: u64,
        timing: ServerTiming,
    ) {
        self.counts.ok += 1;
        if at >= self.measure_from {
            self.frames += frames;
            self.scene_steps += scene_steps;
            self.object_steps += object_steps;
            self.last_event = Some(at);
        }
        if clock.start >= self.measure_from {
            self.request_ms.push(ms(at - clock.start));
            self.queue_ms.push(timing.queue_ms);
            self.forward_ms.push(timing.forward_ms);
        }
    }

    /// A request failed.
    pub fn failed(&mut self, e: &CallError) {
        self.counts.failed += 1;
        *self.errors.entry(e.code.clone()).or_insert(0) += 1;
        if self.examples.len() < EXAMPLES {
            let msg = format!("{}: {}", e.code, e.message);
            if !self.examples.contains(&msg) {
                self.examples.push(msg);
            }
        }
    }

    /// Frames, completed requests and failures so far (for progress lines).
    pub fn progress(&self) -> (u64, u64, u64) {
        (self.frames, self.counts.ok, self.counts.failed)
    }

    /// Time of the last counted frame or response.
    pub fn last_event(&self) -> Option<Instant> {
        self.last_event
    }

    /// The report of this level over the window from `measure_from` to `end`.
    pub fn report(&self, concurrency: usize, end: Instant, interrupted: bool) -> Report {
        let window = end.saturating_duration_since(self.measure_from);
        let secs = window.max(Duration::from_micros(1)).as_secs_f64();
        let mut counts = self.counts;
        counts.cut = counts.started.saturating_sub(counts.ok + counts.failed);
        Report {
            concurrency,
            duration_s: window.as_secs_f64(),
            interrupted,
            requests: counts,
            frames: self.frames,
            scene_steps: self.scene_steps,
            object_steps: self.object_steps,
            throughput: Throughput {
                scene_steps_per_s: self.scene_steps as f64 / secs,
                object_steps_per_s: self.object_steps as f64 / secs,
                requests_per_s: self.request_ms.len() as f64 / secs,
            },
            step_latency_ms: Summary::of(&self.step_ms),
            first_frame_ms: Summary::of(&self.first_ms),
            request_latency_ms: Summary::of(&self.request_ms),
            frame_batch_scenes: Summary::of(&self.batch_scenes),
            server_queue_ms: Summary::of(&self.queue_ms),
            server_forward_ms: Summary::of(&self.forward_ms),
            errors: self.errors.clone(),
            error_examples: self.examples.clone(),
            ..Report::default()
        }
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_gaps_and_warmup() {
        let t0 = Instant::now();
        let from = t0 + Duration::from_millis(100);
        let mut r = Recorder::new(from);
        // A request sent during warm-up: its frames after the window start count, its first
        // frame and total latency do not.
        let mut early = RequestClock {
            start: t0,
            last: None,
        };
        r.started();
        r.frame(&mut early, t0 + Duration::from_millis(50), 3, None);
        r.frame(&mut early, t0 + Duration::from_millis(120), 3, None);
        r.rollout_ok(&early, t0 + Duration::from_millis(120));
        let mut late = RequestClock {
            start: t0 + Duration::from_millis(200),
            last: None,
        };
        r.started();
        r.frame(
            &mut late,
            t0 + Duration::from_millis(210),
            2,
            Some(ServerTiming {
                queue_ms: 1.0,
                forward_ms: 5.0,
                batch_scenes: 4,
            }),
        );
        r.frame(&mut late, t0 + Duration::from_millis(230), 2, None);
        r.started();
        r.failed(&CallError::new("grpc UNAVAILABLE", "x"));
        let rep = r.report(2, t0 + Duration::from_millis(300), false);
        assert_eq!(rep.frames, 3);
        assert_eq!(rep.object_steps, 7);
        assert_eq!(
            (rep.requests.ok, rep.requests.failed, rep.requests.cut),
            (1, 1, 1)
        );
        assert_eq!(rep.step_latency_ms.count, 2);
        assert!((rep.step_latency_ms.max - 70.0).abs() < 1e-6);
        assert_eq!(rep.first_frame_ms.count, 1);
        assert!((rep.first_frame_ms.p50 - 10.0).abs() < 1e-6);
        assert_eq!(rep.request_latency_ms.count, 0);
        assert!((rep.duration_s - 0.2).abs() < 1e-9);
        assert!((rep.throughput.scene_steps_per_s - 15.0).abs() < 1e-6);
        assert_eq!(rep.errors.get("grpc UNAVAILABLE"), Some(&1));
        assert_eq!(rep.frame_batch_scenes.p50, 4.0);
    }
}
