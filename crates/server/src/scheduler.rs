//! Continuous batching: one scheduler thread per resident model.
//!
//! Rollout sessions and Predict variants submit one *step request* at a time (a prepared scene,
//! its two latest poses and a oneshot reply channel) over an mpsc channel. The scheduler thread
//! keeps two FIFO queues (interactive ahead of bulk), and between forward passes it:
//!
//! 1. drains the channel;
//! 2. drops requests whose caller has gone (reply receiver dropped: client disconnected,
//!    cancelled or timed out) and answers those whose deadline has passed with
//!    [`StepError::DeadlineExceeded`], so neither takes a batch slot;
//! 3. waits, at most `max_queue_delay` after the oldest queued request arrived, for the streams
//!    of the previous batch that said they would come back (`more_steps`), unless the queue
//!    already fills a batch; a stream that pauses (slow reader) or ends sends
//!    [`Scheduler::idle`] so nobody waits for it;
//! 4. takes requests in priority then FIFO order under the scene cap and the object budget (a
//!    single scene larger than the budget runs alone), and runs one `WorldModel::step` over all
//!    of them on this thread, never on the async runtime;
//! 5. sends each request its poses with its queue wait, forward time and batch size.
//!
//! A scene's result does not depend on its batch-mates: the model computes every scene of a
//! batch independently (tested end to end).

use std::collections::{HashSet, VecDeque};
use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::sync::mpsc::{self, RecvTimeoutError, TryRecvError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use dynaserve_model::{Pose, PreparedScene, SceneState, StepItem, WorldModel};
use tokio::sync::oneshot;

use crate::metrics::Metrics;

/// Scheduling class of a step request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Priority {
    /// Streamed rollouts: always batched ahead of bulk work.
    Interactive,
    /// Planner (Predict) variants.
    Bulk,
}

impl Priority {
    /// Label value of the `priority` metric label.
    pub fn as_str(self) -> &'static str {
        match self {
            Priority::Interactive => "interactive",
            Priority::Bulk => "bulk",
        }
    }

    fn index(self) -> usize {
        match self {
            Priority::Interactive => 0,
            Priority::Bulk => 1,
        }
    }
}

/// Batching limits of one scheduler.
#[derive(Clone, Copy, Debug)]
pub struct SchedulerConfig {
    /// Most scenes per forward pass (1 disables batching).
    pub max_batch_scenes: usize,
    /// Most objects per forward pass (a larger single scene still runs alone).
    pub max_batch_objects: usize,
    /// Longest wait for expected batch-mates, measured from the oldest queued request's arrival.
    pub max_queue_delay: Duration,
}

/// One scene to advance by one step.
pub struct StepRequest {
    /// The prepared scene (shared by every step of a rollout).
    pub scene: Arc<PreparedScene>,
    /// Its two latest poses, `dt_steps` frames apart.
    pub state: SceneState,
    /// Step size in frames.
    pub dt_steps: u32,
    /// Scheduling class.
    pub priority: Priority,
    /// Instant after which the result is no longer wanted.
    pub deadline: Option<Instant>,
    /// Identifies the rollout (or Predict variant) across its steps.
    pub stream_id: u64,
    /// True when the stream will submit another step right after this one.
    pub more_steps: bool,
    /// Request id for logs.
    pub request_id: Arc<str>,
    /// Where the result goes.
    pub reply: oneshot::Sender<Result<StepOutput, StepError>>,
}

/// Result of one step request.
#[derive(Clone, Debug)]
pub struct StepOutput {
    /// New pose of every object.
    pub poses: Vec<Pose>,
    /// Time spent queued.
    pub queue_wait: Duration,
    /// Duration of the forward pass that computed it.
    pub forward: Duration,
    /// Scenes in that forward pass.
    pub batch_scenes: u32,
    /// Sequence number of that forward pass (for logs).
    pub batch_id: u64,
}

/// Why a step request produced no poses.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum StepError {
    /// Its deadline passed while it was queued.
    #[error("deadline exceeded while queued")]
    DeadlineExceeded,
    /// The model failed on the batch.
    #[error("model step failed: {0}")]
    Model(String),
    /// The scheduler has stopped.
    #[error("scheduler stopped")]
    Stopped,
}

enum Command {
    Step(Box<Queued>),
    Idle(u64),
    Stop,
}

struct Queued {
    req: StepRequest,
    enqueued: Instant,
    objects: usize,
}

/// Handle to a running scheduler thread.
pub struct Scheduler {
    tx: mpsc::Sender<Command>,
    thread: std::sync::Mutex<Option<JoinHandle<()>>>,
    model: Arc<dyn WorldModel>,
}

impl Scheduler {
    /// Starts the scheduler thread of `model`.
    pub fn start(
        model: Arc<dyn WorldModel>,
        config: SchedulerConfig,
        metrics: Metrics,
    ) -> std::io::Result<Scheduler> {
        let (tx, rx) = mpsc::channel();
        let name = model.name().to_string();
        let worker = Worker {
            model: model.clone(),
            config: SchedulerConfig {
                max_batch_scenes: config.max_batch_scenes.max(1),
                max_batch_objects: config.max_batch_objects.max(1),
                ..config
            },
            rx,
            queues: [VecDeque::new(), VecDeque::new()],
            queued_objects: 0,
            expected: HashSet::new(),
            metrics,
            name: name.clone(),
            batches: 0,
            recent: VecDeque::new(),
        };
        let thread = std::thread::Builder::new()
            .name(format!("sched-{name}"))
            .spawn(move || worker.run())?;
        Ok(Scheduler {
            tx,
            thread: std::sync::Mutex::new(Some(thread)),
            model,
        })
    }

    /// The model this scheduler runs.
    pub fn model(&self) -> &Arc<dyn WorldModel> {
        &self.model
    }

    /// Queues a step request. On failure (scheduler stopped) the request's reply channel
    /// receives [`StepError::Stopped`].
    pub fn submit(&self, req: StepRequest) {
        let objects = req.scene.len();
        let queued = Box::new(Queued {
            req,
            enqueued: Instant::now(),
            objects,
        });
        if let Err(mpsc::SendError(Command::Step(q))) = self.tx.send(Command::Step(queued)) {
            let _ = q.req.reply.send(Err(StepError::Stopped));
        }
    }

    /// Tells the scheduler not to wait for `stream_id`'s next step (it paused or ended).
    pub fn idle(&self, stream_id: u64) {
        let _ = self.tx.send(Command::Idle(stream_id));
    }

    /// Stops the thread after its current batch; queued requests get [`StepError::Stopped`].
    /// Blocks until the thread has exited.
    pub fn shutdown(&self) {
        let _ = self.tx.send(Command::Stop);
        let handle = self.thread.lock().ok().and_then(|mut t| t.take());
        if let Some(h) = handle {
            let _ = h.join();
        }
    }
}

impl Drop for Scheduler {
    fn drop(&mut self) {
        let _ = self.tx.send(Command::Stop);
    }
}

struct Worker {
    model: Arc<dyn WorldModel>,
    config: SchedulerConfig,
    rx: mpsc::Receiver<Command>,
    /// Index 0: interactive, 1: bulk; FIFO each.
    queues: [VecDeque<Box<Queued>>; 2],
    queued_objects: usize,
    /// Streams of the last batch that announced another step and have not submitted it yet.
    expected: HashSet<u64>,
    metrics: Metrics,
    name: String,
    batches: u64,
    /// (finish time, scenes) of the batches of the last second, for the FPS gauge.
    recent: VecDeque<(Instant, u64)>,
}

impl Worker {
    fn run(mut self) {
        'main: loop {
            if self.is_empty() {
                match self.rx.recv_timeout(Duration::from_millis(250)) {
                    Ok(cmd) => {
                        if !self.handle(cmd) {
                            break 'main;
                        }
                    }
                    Err(RecvTimeoutError::Timeout) => {
                        self.update_fps(Instant::now());
                        continue;
                    }
                    Err(RecvTimeoutError::Disconnected) => break 'main,
                }
            }
            loop {
                match self.rx.try_recv() {
                    Ok(cmd) => {
                        if !self.handle(cmd) {
                            break 'main;
                        }
                    }
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => break 'main,
                }
            }
            self.prune(Instant::now());
            if self.is_empty() {
                continue;
            }
            if !self.fills_batch() && !self.expected.is_empty() {
                let until = self.oldest_enqueued() + self.config.max_queue_delay;
                let now = Instant::now();
                if now < until {
                    match self.rx.recv_timeout(until - now) {
                        Ok(cmd) => {
                            if !self.handle(cmd) {
                                break 'main;
                            }
                            continue 'main;
                        }
                        Err(RecvTimeoutError::Timeout) => self.prune(Instant::now()),
                        Err(RecvTimeoutError::Disconnected) => break 'main,
                    }
                    if self.is_empty() {
                        continue 'main;
                    }
                }
            }
            self.run_batch();
        }
        for q in self.queues.iter_mut() {
            for item in q.drain(..) {
                let _ = item.req.reply.send(Err(StepError::Stopped));
            }
        }
        self.update_depth();
    }

    fn is_empty(&self) -> bool {
        self.queues.iter().all(VecDeque::is_empty)
    }

    fn queued_scenes(&self) -> usize {
        self.queues.iter().map(VecDeque::len).sum()
    }

    fn fills_batch(&self) -> bool {
        self.queued_scenes() >= self.config.max_batch_scenes
            || self.queued_objects >= self.config.max_batch_objects
    }

    fn oldest_enqueued(&self) -> Instant {
        self.queues
            .iter()
            .filter_map(|q| q.front().map(|i| i.enqueued))
            .min()
            .unwrap_or_else(Instant::now)
    }

    /// Returns false on Stop.
    fn handle(&mut self, cmd: Command) -> bool {
        match cmd {
            Command::Step(q) => {
                self.expected.remove(&q.req.stream_id);
                self.queued_objects += q.objects;
                self.queues[q.req.priority.index()].push_back(q);
                self.update_depth();
                true
            }
            Command::Idle(id) => {
                self.expected.remove(&id);
                true
            }
            Command::Stop => false,
        }
    }

    fn update_depth(&self) {
        for p in [Priority::Interactive, Priority::Bulk] {
            self.metrics
                .queue_depth
                .with_label_values(&[self.name.as_str(), p.as_str()])
                .set(self.queues[p.index()].len() as i64);
        }
    }

    /// Drops requests nobody waits for and answers expired ones.
    fn prune(&mut self, now: Instant) {
        let mut removed_objects = 0;
        let mut changed = false;
        for q in self.queues.iter_mut() {
            let mut kept = VecDeque::with_capacity(q.len());
            for item in q.drain(..) {
                let expired = item.req.deadline.is_some_and(|d| d <= now);
                if item.req.reply.is_closed() || expired {
                    let reason = if expired {
                        "deadline_exceeded"
                    } else {
                        "cancelled"
                    };
                    self.metrics
                        .dropped
                        .with_label_values(&[self.name.as_str(), reason])
                        .inc();
                    tracing::debug!(
                        request_id = %item.req.request_id,
                        reason,
                        "dropped queued step"
                    );
                    removed_objects += item.objects;
                    changed = true;
                    if expired {
                        let _ = item.req.reply.send(Err(StepError::DeadlineExceeded));
                    }
                } else {
                    kept.push_back(item);
                }
            }
            *q = kept;
        }
        if changed {
            self.queued_objects -= removed_objects;
            self.update_depth();
        }
    }

    fn take_batch(&mut self) -> Vec<Queued> {
        let mut batch: Vec<Queued> = Vec::new();
        let mut objects = 0;
        'levels: for q in self.queues.iter_mut() {
            while let Some(front) = q.front() {
                if batch.len() >= self.config.max_batch_scenes
                    || (!batch.is_empty()
                        && objects + front.objects > self.config.max_batch_objects)
                {
                    break 'levels;
                }
                let Some(item) = q.pop_front() else { break };
                objects += item.objects;
                batch.push(*item);
            }
        }
        self.queued_objects -= objects;
        batch
    }

    fn run_batch(&mut self) {
        let batch = self.take_batch();
        self.update_depth();
        if batch.is_empty() {
            return;
        }
        self.batches += 1;
        let batch_id = self.batches;
        let scenes = batch.len();
        let objects: usize = batch.iter().map(|q| q.objects).sum();
        let start = Instant::now();
        let items: Vec<StepItem<'_>> = batch
            .iter()
            .map(|q| StepItem {
                scene: &q.req.scene,
                state: &q.req.state,
                dt_steps: q.req.dt_steps,
            })
            .collect();
        let model = self.model.clone();
        let result = std::panic::catch_unwind(AssertUnwindSafe(|| model.step(&items)));
        drop(items);
        let forward = start.elapsed();
        let finished = Instant::now();
        let result = match result {
            Ok(Ok(out)) if out.len() == scenes => Ok(out),
            Ok(Ok(out)) => Err(format!(
                "model returned {} scenes for a batch of {scenes}",
                out.len()
            )),
            Ok(Err(e)) => Err(e.to_string()),
            Err(_) => Err("model panicked".to_string()),
        };
        let name = self.name.as_str();
        if tracing::enabled!(tracing::Level::DEBUG) {
            let ids: Vec<&str> = batch.iter().map(|q| &*q.req.request_id).collect();
            tracing::debug!(
                model = name,
                batch = batch_id,
                scenes,
                objects,
                forward_ms = forward.as_secs_f64() * 1e3,
                requests = ?ids,
                "batch"
            );
        }
        self.metrics
            .batch_scenes
            .with_label_values(&[name])
            .observe(scenes as f64);
        self.metrics
            .batch_objects
            .with_label_values(&[name])
            .observe(objects as f64);
        self.metrics
            .forward_duration
            .with_label_values(&[name])
            .observe(forward.as_secs_f64());
        let mut expected = HashSet::new();
        match result {
            Ok(out) => {
                self.metrics
                    .scene_steps
                    .with_label_values(&[name])
                    .inc_by(scenes as u64);
                self.metrics
                    .object_steps
                    .with_label_values(&[name])
                    .inc_by(objects as u64);
                for (item, poses) in batch.into_iter().zip(out) {
                    let queue_wait = start.saturating_duration_since(item.enqueued);
                    self.metrics
                        .queue_wait
                        .with_label_values(&[name, item.req.priority.as_str()])
                        .observe(queue_wait.as_secs_f64());
                    let reply = if poses.len() == item.objects {
                        Ok(StepOutput {
                            poses,
                            queue_wait,
                            forward,
                            batch_scenes: scenes as u32,
                            batch_id,
                        })
                    } else {
                        Err(StepError::Model(format!(
                            "model returned {} poses for {} objects",
                            poses.len(),
                            item.objects
                        )))
                    };
                    let delivered = item.req.reply.send(reply).is_ok();
                    if delivered && item.req.more_steps {
                        expected.insert(item.req.stream_id);
                    }
                }
            }
            Err(msg) => {
                tracing::error!(model = name, batch = batch_id, error = %msg, "batch failed");
                for item in batch {
                    let _ = item.req.reply.send(Err(StepError::Model(msg.clone())));
                }
            }
        }
        self.expected = expected;
        self.recent.push_back((finished, scenes as u64));
        self.update_fps(finished);
    }

    fn update_fps(&mut self, now: Instant) {
        while self
            .recent
            .front()
            .is_some_and(|(t, _)| now.saturating_duration_since(*t) > Duration::from_secs(1))
        {
            self.recent.pop_front();
        }
        let total: u64 = self.recent.iter().map(|(_, s)| s).sum();
        self.metrics
            .fps
            .with_label_values(&[self.name.as_str()])
            .set(total as f64);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynaserve_model::{ModelConfig, ModelError, ObjectInput, RigidFormer};
    use std::sync::Mutex;

    /// Deterministic stand-in: constant-velocity extrapolation. Scenes are tagged by the x
    /// coordinate of their first object; every batch's tags are recorded. The first step can be
    /// held until the test releases it, so queues build up deterministically.
    struct TestModel {
        inner: RigidFormer,
        batches: Mutex<Vec<Vec<f32>>>,
        hold: Mutex<Option<mpsc::Receiver<()>>>,
    }

    impl WorldModel for TestModel {
        fn name(&self) -> &str {
            "test"
        }
        fn config(&self) -> &ModelConfig {
            self.inner.config()
        }
        fn prepare(&self, objects: Vec<ObjectInput>) -> Result<PreparedScene, ModelError> {
            self.inner.prepare(objects)
        }
        fn step(&self, batch: &[StepItem<'_>]) -> Result<Vec<Vec<Pose>>, ModelError> {
            if let Some(rx) = self.hold.lock().unwrap().take() {
                let _ = rx.recv();
            }
            self.batches.lock().unwrap().push(
                batch
                    .iter()
                    .map(|i| i.state.current[0].translation[0])
                    .collect(),
            );
            Ok(batch
                .iter()
                .map(|i| {
                    i.state
                        .current
                        .iter()
                        .zip(&i.state.previous)
                        .map(|(c, p)| Pose {
                            translation: std::array::from_fn(|k| {
                                2.0 * c.translation[k] - p.translation[k]
                            }),
                            rotation: c.rotation,
                        })
                        .collect()
                })
                .collect())
        }
    }

    fn setup(
        cfg: SchedulerConfig,
        held: bool,
    ) -> (Scheduler, Arc<TestModel>, Option<mpsc::Sender<()>>, Metrics) {
        let inner = RigidFormer::new(ModelConfig::tiny(), 1, &candle_core::Device::Cpu).unwrap();
        let (tx, rx) = mpsc::channel();
        let model = Arc::new(TestModel {
            inner,
            batches: Mutex::new(Vec::new()),
            hold: Mutex::new(held.then_some(rx)),
        });
        let metrics = Metrics::new(&["test".to_string()]);
        let s = Scheduler::start(model.clone(), cfg, metrics.clone()).unwrap();
        (s, model, held.then_some(tx), metrics)
    }

    fn scene(model: &TestModel, objects: usize) -> Arc<PreparedScene> {
        let obj = ObjectInput {
            reference: vec![
                [0.1, 0.0, 0.0],
                [0.0, 0.1, 0.0],
                [0.0, 0.0, 0.1],
                [-0.1, 0.0, 0.0],
            ],
            mass: 1.0,
            friction: 0.5,
            restitution: 0.5,
        };
        Arc::new(model.prepare(vec![obj; objects]).unwrap())
    }

    fn state(tag: f32, objects: usize) -> SceneState {
        let p = |x: f32| Pose {
            translation: [x, 0.0, 1.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        SceneState {
            previous: vec![p(tag - 0.5); objects],
            current: vec![p(tag); objects],
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn submit(
        s: &Scheduler,
        sc: &Arc<PreparedScene>,
        tag: f32,
        objects: usize,
        priority: Priority,
        deadline: Option<Instant>,
        stream_id: u64,
    ) -> oneshot::Receiver<Result<StepOutput, StepError>> {
        let (reply, rx) = oneshot::channel();
        s.submit(StepRequest {
            scene: sc.clone(),
            state: state(tag, objects),
            dt_steps: 1,
            priority,
            deadline,
            stream_id,
            more_steps: false,
            request_id: "t".into(),
            reply,
        });
        rx
    }

    const CFG: SchedulerConfig = SchedulerConfig {
        max_batch_scenes: 64,
        max_batch_objects: 1000,
        max_queue_delay: Duration::from_millis(2),
    };

    #[test]
    fn queued_requests_share_one_batch_and_get_their_own_results() {
        let (s, model, gate, metrics) = setup(CFG, true);
        let sc = scene(&model, 2);
        let first = submit(&s, &sc, 100.0, 2, Priority::Interactive, None, 1000);
        std::thread::sleep(Duration::from_millis(50));
        let rxs: Vec<_> = (0..10)
            .map(|i| submit(&s, &sc, i as f32, 2, Priority::Interactive, None, i))
            .collect();
        std::thread::sleep(Duration::from_millis(50));
        gate.unwrap().send(()).unwrap();
        assert!(first.blocking_recv().unwrap().is_ok());
        for (i, rx) in rxs.into_iter().enumerate() {
            let out = rx.blocking_recv().unwrap().unwrap();
            assert_eq!(out.batch_scenes, 10);
            assert_eq!(out.poses.len(), 2);
            // constant velocity: x + (x - (x - 0.5))
            assert_eq!(out.poses[1].translation[0], i as f32 + 0.5);
        }
        let batches = model.batches.lock().unwrap().clone();
        assert_eq!(batches.len(), 2);
        assert_eq!(batches[1], (0..10).map(|i| i as f32).collect::<Vec<_>>());
        let text = metrics.render();
        assert!(
            text.contains("dynaserve_scene_steps_total{model=\"test\"} 11"),
            "{text}"
        );
        s.shutdown();
    }

    #[test]
    fn interactive_goes_first_fifo_within_a_level_and_caps_hold() {
        let cfg = SchedulerConfig {
            max_batch_scenes: 3,
            max_batch_objects: 5,
            ..CFG
        };
        let (s, model, gate, _) = setup(cfg, true);
        let sc = scene(&model, 2);
        let first = submit(&s, &sc, 100.0, 2, Priority::Interactive, None, 1000);
        std::thread::sleep(Duration::from_millis(50));
        let mut rxs = Vec::new();
        for i in 0..3 {
            rxs.push(submit(
                &s,
                &sc,
                10.0 + i as f32,
                2,
                Priority::Bulk,
                None,
                10 + i,
            ));
        }
        for i in 0..3 {
            rxs.push(submit(&s, &sc, i as f32, 2, Priority::Interactive, None, i));
        }
        std::thread::sleep(Duration::from_millis(50));
        gate.unwrap().send(()).unwrap();
        assert!(first.blocking_recv().unwrap().is_ok());
        for rx in rxs {
            assert!(rx.blocking_recv().unwrap().is_ok());
        }
        let batches = model.batches.lock().unwrap().clone();
        // Object budget 5 with 2-object scenes: at most 2 scenes per batch.
        assert_eq!(
            batches[1..],
            [vec![0.0, 1.0], vec![2.0, 10.0], vec![11.0, 12.0]]
        );
        s.shutdown();
    }

    #[test]
    fn expired_and_cancelled_requests_are_dropped_before_the_next_batch() {
        let (s, model, gate, metrics) = setup(CFG, true);
        let sc = scene(&model, 1);
        let first = submit(&s, &sc, 100.0, 1, Priority::Interactive, None, 1000);
        std::thread::sleep(Duration::from_millis(30));
        let soon = Instant::now() + Duration::from_millis(20);
        let expired = submit(&s, &sc, 1.0, 1, Priority::Interactive, Some(soon), 1);
        let cancelled = submit(&s, &sc, 2.0, 1, Priority::Interactive, None, 2);
        let kept = submit(&s, &sc, 3.0, 1, Priority::Bulk, None, 3);
        drop(cancelled);
        std::thread::sleep(Duration::from_millis(60));
        gate.unwrap().send(()).unwrap();
        assert!(first.blocking_recv().unwrap().is_ok());
        assert_eq!(
            expired.blocking_recv().unwrap().unwrap_err(),
            StepError::DeadlineExceeded
        );
        assert_eq!(kept.blocking_recv().unwrap().unwrap().batch_scenes, 1);
        let batches = model.batches.lock().unwrap().clone();
        assert_eq!(batches, vec![vec![100.0], vec![3.0]]);
        let text = metrics.render();
        assert!(text.contains(
            "dynaserve_dropped_steps_total{model=\"test\",reason=\"deadline_exceeded\"} 1"
        ));
        assert!(
            text.contains("dynaserve_dropped_steps_total{model=\"test\",reason=\"cancelled\"} 1")
        );
        s.shutdown();
    }

    #[test]
    fn expected_streams_are_awaited_only_up_to_the_queue_delay() {
        let cfg = SchedulerConfig {
            max_queue_delay: Duration::from_millis(40),
            ..CFG
        };
        let (s, model, _, _) = setup(cfg, false);
        let sc = scene(&model, 1);
        // Stream 1 announces another step; a new stream 2 arrives before it comes back and
        // waits for it (up to 40 ms), so both share the next batch.
        let (reply, rx) = oneshot::channel();
        s.submit(StepRequest {
            scene: sc.clone(),
            state: state(1.0, 1),
            dt_steps: 1,
            priority: Priority::Interactive,
            deadline: None,
            stream_id: 1,
            more_steps: true,
            request_id: "a".into(),
            reply,
        });
        rx.blocking_recv().unwrap().unwrap();
        let b = submit(&s, &sc, 2.0, 1, Priority::Interactive, None, 2);
        std::thread::sleep(Duration::from_millis(5));
        let a = submit(&s, &sc, 1.5, 1, Priority::Interactive, None, 1);
        assert_eq!(b.blocking_recv().unwrap().unwrap().batch_scenes, 2);
        assert_eq!(a.blocking_recv().unwrap().unwrap().batch_scenes, 2);
        // A stream that never comes back delays a newcomer by at most the queue delay.
        let (reply, rx) = oneshot::channel();
        s.submit(StepRequest {
            scene: sc.clone(),
            state: state(1.0, 1),
            dt_steps: 1,
            priority: Priority::Interactive,
            deadline: None,
            stream_id: 7,
            more_steps: true,
            request_id: "c".into(),
            reply,
        });
        rx.blocking_recv().unwrap().unwrap();
        let t = Instant::now();
        let c = submit(&s, &sc, 3.0, 1, Priority::Interactive, None, 8);
        let out = c.blocking_recv().unwrap().unwrap();
        let waited = t.elapsed();
        assert_eq!(out.batch_scenes, 1);
        assert!(waited >= Duration::from_millis(35), "{waited:?}");
        assert!(waited < Duration::from_millis(500), "{waited:?}");
        // And `idle` releases the wait at once.
        let (reply, rx) = oneshot::channel();
        s.submit(StepRequest {
            scene: sc.clone(),
            state: state(1.0, 1),
            dt_steps: 1,
            priority: Priority::Interactive,
            deadline: None,
            stream_id: 9,
            more_steps: true,
            request_id: "d".into(),
            reply,
        });
        rx.blocking_recv().unwrap().unwrap();
        s.idle(9);
        std::thread::sleep(Duration::from_millis(5));
        let t = Instant::now();
        let d = submit(&s, &sc, 4.0, 1, Priority::Interactive, None, 10);
        d.blocking_recv().unwrap().unwrap();
        assert!(t.elapsed() < Duration::from_millis(30), "{:?}", t.elapsed());
        s.shutdown();
    }
}
