//! The scheduler thread: moves commands from its channel into the [`Queue`], waits as the
//! queue says, runs one pass of the [`Family`] at a time and records queue, pass and throughput
//! metrics (not for warm-up passes). Every pass waits for the device at the engine's
//! [`super::PassGate`] first. A pass that fails as a whole (an error or a panic) is run
//! again one job at a time, so a job that cannot be computed fails alone, with its own error,
//! and its pass-mates still get their results; the thread never dies with a pass.

use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::sync::mpsc::{self, RecvTimeoutError, TryRecvError};
use std::time::{Duration, Instant};

use dynaserve_model::PassBudget;

use super::{
    Command, Done, Family, Job, PassGate, Priority, Queue, Queued, SchedulerConfig, StepError,
};
use crate::metrics::Metrics;

/// How long an idle worker sleeps before refreshing the FPS gauge.
const IDLE_TICK: Duration = Duration::from_millis(250);

pub(super) struct Worker<F: Family> {
    family: Arc<F>,
    rx: mpsc::Receiver<Command<F>>,
    queue: Queue<Job<F>>,
    /// The engine's device gate and this scheduler's id at it.
    gate: Option<(Arc<PassGate>, usize)>,
    /// A stop command arrived.
    stopping: bool,
    metrics: Metrics,
    name: String,
    batches: u64,
    /// (finish time, jobs) of the passes of the last second, for the FPS gauge.
    recent: std::collections::VecDeque<(Instant, u64)>,
}

enum Flow {
    Continue,
    Stop,
}

impl<F: Family> Worker<F> {
    pub(super) fn new(
        family: Arc<F>,
        config: SchedulerConfig,
        rx: mpsc::Receiver<Command<F>>,
        metrics: Metrics,
    ) -> Worker<F> {
        let budget = PassBudget {
            max_scenes: config.max_batch_scenes.max(1),
            max_objects: config.max_batch_objects.max(1),
        }
        .in_whole_forwards(family.forward_objects());
        let queue = Queue::new(budget, config.max_queue_delay, config.bulk_share);
        let queue = if family.separate_forwards() {
            queue.one_bulk_item_per_pass()
        } else if family.only_bulk() {
            queue.whole_budget_for_bulk()
        } else {
            queue
        };
        Worker {
            name: family.name().to_string(),
            family,
            rx,
            queue,
            gate: config.gate.map(|g| {
                let id = g.register();
                (g, id)
            }),
            stopping: false,
            metrics,
            batches: 0,
            recent: std::collections::VecDeque::new(),
        }
    }

    pub(super) fn run(mut self) {
        'main: loop {
            if self.queue.is_empty() {
                match self.rx.recv_timeout(IDLE_TICK) {
                    Ok(cmd) => {
                        if let Flow::Stop = self.handle(cmd) {
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
                        if let Flow::Stop = self.handle(cmd) {
                            break 'main;
                        }
                    }
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => break 'main,
                }
            }
            self.prune(Instant::now());
            if self.queue.is_empty() {
                continue;
            }
            if let Some(until) = self.queue.wait_until() {
                let now = Instant::now();
                if now < until {
                    match self.rx.recv_timeout(until - now) {
                        Ok(cmd) => {
                            if let Flow::Stop = self.handle(cmd) {
                                break 'main;
                            }
                            continue 'main;
                        }
                        Err(RecvTimeoutError::Timeout) => self.prune(Instant::now()),
                        Err(RecvTimeoutError::Disconnected) => break 'main,
                    }
                    if self.queue.is_empty() {
                        continue 'main;
                    }
                }
            }
            self.run_pass();
            if self.stopping {
                break 'main;
            }
        }
        for item in self.queue.drain() {
            let _ = item.payload.reply.send(Err(StepError::Stopped));
        }
        self.update_depth();
    }

    fn handle(&mut self, cmd: Command<F>) -> Flow {
        match cmd {
            Command::Job(q) => {
                self.queue.push(*q);
                self.update_depth();
                Flow::Continue
            }
            Command::Idle(id) => {
                self.queue.idle(id);
                Flow::Continue
            }
            Command::Stop => Flow::Stop,
        }
    }

    /// Moves what arrived meanwhile into the queue (a stop is kept for the main loop).
    fn take_in(&mut self) {
        while !self.stopping {
            match self.rx.try_recv() {
                Ok(cmd) => {
                    if let Flow::Stop = self.handle(cmd) {
                        self.stopping = true;
                    }
                }
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => self.stopping = true,
            }
        }
    }

    fn update_depth(&self) {
        for p in [Priority::Interactive, Priority::Bulk] {
            self.metrics
                .queue_depth
                .with_label_values(&[self.name.as_str(), p.as_str()])
                .set(self.queue.len_at(p) as i64);
        }
    }

    /// Drops jobs nobody waits for and answers expired ones.
    fn prune(&mut self, now: Instant) {
        let dropped = self.queue.prune(now, |job| job.reply.is_closed());
        if dropped.is_empty() {
            return;
        }
        for (item, reason) in dropped {
            self.metrics
                .dropped
                .with_label_values(&[self.name.as_str(), reason.as_str()])
                .inc();
            tracing::debug!(
                request_id = %item.payload.request_id,
                reason = reason.as_str(),
                "dropped queued step"
            );
            if reason == super::Dropped::Expired {
                let _ = item.payload.reply.send(Err(StepError::DeadlineExceeded));
            }
        }
        self.update_depth();
    }

    fn run_pass(&mut self) {
        // The device first: a pass holding interactive jobs is interactive.
        let class = if self.queue.len_at(Priority::Interactive) > 0 {
            Priority::Interactive
        } else {
            Priority::Bulk
        };
        let gate = self.gate.clone();
        let has_bulk = self.queue.len_at(Priority::Bulk) > 0;
        let permit = gate.as_ref().map(|(g, id)| g.acquire(*id, class, has_bulk));
        if permit.is_some() {
            // Jobs that arrived while the pass waited for the device join it.
            self.take_in();
            self.prune(Instant::now());
        }
        let bulk_allowed = permit.as_ref().is_none_or(|p| p.bulk_allowed());
        let batch: Vec<Queued<Job<F>>> = self.queue.next_batch_with(bulk_allowed);
        self.update_depth();
        if batch.is_empty() {
            return;
        }
        self.batches += 1;
        let batch_id = self.batches;
        let scenes = batch.len();
        let objects: usize = batch.iter().map(|q| q.ticket.cost).sum();
        let bulk_cost: usize = batch
            .iter()
            .filter(|q| q.ticket.priority == Priority::Bulk)
            .map(|q| q.ticket.cost)
            .sum();
        let start = Instant::now();
        let items: Vec<&F::Item> = batch.iter().map(|q| &q.payload.item).collect();
        let results = self.run_isolated(&items, batch_id);
        drop(items);
        let forward = start.elapsed();
        let finished = Instant::now();
        if let Some(p) = permit {
            let streams_back = batch
                .iter()
                .any(|q| q.ticket.more_steps && q.ticket.priority == Priority::Interactive);
            p.finish(
                forward,
                bulk_cost as f64 / objects.max(1) as f64,
                streams_back,
            );
        }
        let name = self.name.as_str();
        // Warm-up passes are not serving work: they stay out of the metrics.
        let metered = batch
            .iter()
            .any(|q| &*q.payload.request_id != super::WARMUP_REQUEST_ID);
        if tracing::enabled!(tracing::Level::DEBUG) {
            let ids: Vec<&str> = batch.iter().map(|q| &*q.payload.request_id).collect();
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
        if metered {
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
            for (p, work) in [
                (Priority::Interactive, objects - bulk_cost),
                (Priority::Bulk, bulk_cost),
            ] {
                self.metrics
                    .class_work
                    .with_label_values(&[name, p.as_str()])
                    .inc_by(work as u64);
            }
        }
        let failed = results.iter().filter(|r| r.is_err()).count();
        if metered {
            let objects_ok: usize = batch
                .iter()
                .zip(&results)
                .filter(|(_, r)| r.is_ok())
                .map(|(q, _)| q.ticket.cost)
                .sum();
            self.metrics
                .scene_steps
                .with_label_values(&[name])
                .inc_by((scenes - failed) as u64);
            self.metrics
                .object_steps
                .with_label_values(&[name])
                .inc_by(objects_ok as u64);
            self.metrics
                .scene_step_failures
                .with_label_values(&[name])
                .inc_by(failed as u64);
        }
        let mut expected = Vec::new();
        for (item, output) in batch.into_iter().zip(results) {
            let queue_wait = start.saturating_duration_since(item.ticket.enqueued);
            if metered {
                self.metrics
                    .queue_wait
                    .with_label_values(&[name, item.ticket.priority.as_str()])
                    .observe(queue_wait.as_secs_f64());
            }
            if let Err(e) = &output {
                tracing::info!(
                    model = name,
                    request_id = %item.payload.request_id,
                    error = %e,
                    "scene step failed"
                );
            }
            let reply = output
                .map(|output| Done {
                    output,
                    queue_wait,
                    forward,
                    batch_scenes: scenes as u32,
                    batch_id,
                })
                .map_err(StepError::Model);
            let delivered = item.payload.reply.send(reply).is_ok();
            if delivered && item.ticket.more_steps {
                expected.push((item.ticket.stream_id, item.ticket.priority));
            }
        }
        self.queue.expect(expected, Instant::now());
        if metered {
            self.recent.push_back((finished, scenes as u64));
        }
        self.update_fps(finished);
    }

    /// One result per item, in order. A pass that fails as a whole (an error or a panic) is
    /// run again one job at a time, so only a job that cannot be computed fails, with its own
    /// error; a one-job pass's error is that job's.
    fn run_isolated(&self, items: &[&F::Item], batch_id: u64) -> Vec<Result<F::Output, String>> {
        match run_guarded(&*self.family, items) {
            Ok(out) => out,
            Err(msg) => {
                tracing::warn!(
                    model = self.name.as_str(),
                    batch = batch_id,
                    scenes = items.len(),
                    error = %msg,
                    "pass failed"
                );
                if items.len() == 1 {
                    return vec![Err(msg)];
                }
                items
                    .iter()
                    .map(|it| {
                        run_guarded(&*self.family, &[*it]).and_then(|mut one| {
                            one.pop().unwrap_or_else(|| Err("no result".into()))
                        })
                    })
                    .collect()
            }
        }
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

/// One pass of `family` over `items`: a panic or a wrong number of results becomes the pass's
/// error.
fn run_guarded<F: Family>(
    family: &F,
    items: &[&F::Item],
) -> Result<Vec<Result<F::Output, String>>, String> {
    match std::panic::catch_unwind(AssertUnwindSafe(|| family.run(items))) {
        Ok(Ok(out)) if out.len() == items.len() => Ok(out),
        Ok(Ok(out)) => Err(format!(
            "model returned {} results for a pass of {}",
            out.len(),
            items.len()
        )),
        Ok(Err(e)) => Err(e),
        Err(_) => Err("model panicked".to_string()),
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;

    use tokio::sync::oneshot;

    use super::super::{Scheduler, StepError};
    use super::*;

    /// A stand-in family: an item is its tag, the output the tag plus one. The first pass
    /// reports that it started and is held until the test releases it, so a queue builds up
    /// behind it without any sleeping; every pass's tags are recorded.
    struct Tags {
        passes: Mutex<Vec<Vec<u32>>>,
        started: Mutex<Option<mpsc::Sender<()>>>,
        hold: Mutex<Option<mpsc::Receiver<()>>>,
    }

    impl Family for Tags {
        type Item = u32;
        type Output = u32;
        fn name(&self) -> &str {
            "test"
        }
        fn cost(&self, _: &u32) -> usize {
            1
        }
        fn run(&self, items: &[&u32]) -> Result<Vec<Result<u32, String>>, String> {
            if let Some(tx) = self.started.lock().unwrap().take() {
                let _ = tx.send(());
            }
            if let Some(rx) = self.hold.lock().unwrap().take() {
                let _ = rx.recv();
            }
            if items.iter().any(|&&t| t == 666) {
                panic!("bad item");
            }
            self.passes
                .lock()
                .unwrap()
                .push(items.iter().map(|&&t| t).collect());
            Ok(items
                .iter()
                .map(|&&t| {
                    if t == 13 {
                        Err("unlucky".into())
                    } else {
                        Ok(t + 1)
                    }
                })
                .collect())
        }
    }

    type Rx = oneshot::Receiver<Result<Done<u32>, StepError>>;

    fn submit(s: &Scheduler<Tags>, tag: u32) -> Rx {
        let (reply, rx) = oneshot::channel();
        s.submit(Job {
            item: tag,
            priority: Priority::Interactive,
            deadline: None,
            stream_id: u64::from(tag),
            caller: 0,
            more_steps: false,
            request_id: "t".into(),
            reply,
        });
        rx
    }

    /// A scheduler over [`Tags`] whose first pass (tag 100) has started and is held, so the
    /// jobs submitted next queue behind it until `release` is sent.
    struct Held {
        family: Arc<Tags>,
        metrics: Metrics,
        s: Scheduler<Tags>,
        first: Rx,
        release: mpsc::Sender<()>,
    }

    fn held() -> Held {
        let (started_tx, started) = mpsc::channel();
        let (release, hold) = mpsc::channel();
        let family = Arc::new(Tags {
            passes: Mutex::new(Vec::new()),
            started: Mutex::new(Some(started_tx)),
            hold: Mutex::new(Some(hold)),
        });
        let metrics = Metrics::new(&["test".to_string()]);
        let config = SchedulerConfig {
            max_batch_scenes: 64,
            max_batch_objects: 1000,
            max_queue_delay: Duration::from_millis(2),
            bulk_share: 0.25,
            gate: None,
        };
        let s = Scheduler::start(family.clone(), config, metrics.clone()).unwrap();
        let first = submit(&s, 100);
        started.recv().unwrap();
        Held {
            family,
            metrics,
            s,
            first,
            release,
        }
    }

    #[test]
    fn jobs_queued_behind_a_pass_share_the_next_one_and_get_their_own_results() {
        let Held {
            family,
            metrics,
            s,
            first,
            release,
        } = held();
        let rxs: Vec<Rx> = (0..10).map(|t| submit(&s, t)).collect();
        let unlucky = submit(&s, 13);
        release.send(()).unwrap();
        assert_eq!(first.blocking_recv().unwrap().unwrap().output, 101);
        for (t, rx) in rxs.into_iter().enumerate() {
            let done = rx.blocking_recv().unwrap().unwrap();
            assert_eq!((done.output, done.batch_scenes), (t as u32 + 1, 11));
        }
        // An item's own failure reaches only that item.
        assert_eq!(
            unlucky.blocking_recv().unwrap().unwrap_err(),
            StepError::Model("unlucky".into())
        );
        let mut expected: Vec<u32> = (0..10).collect();
        expected.push(13);
        assert_eq!(*family.passes.lock().unwrap(), vec![vec![100], expected]);
        let text = metrics.render();
        assert!(
            text.contains("dynaserve_scene_steps_total{model=\"test\"} 11"),
            "{text}"
        );
        // The item that failed alone is counted as a failure, not as a step, and its objects
        // are not counted as object-steps.
        assert!(
            text.contains("dynaserve_object_steps_total{model=\"test\"} 11"),
            "{text}"
        );
        assert!(
            text.contains("dynaserve_scene_step_failures_total{model=\"test\"} 1"),
            "{text}"
        );
        // A panicking pass fails its jobs, not the scheduler.
        let bad = submit(&s, 666);
        assert!(matches!(
            bad.blocking_recv().unwrap(),
            Err(StepError::Model(_))
        ));
        assert_eq!(submit(&s, 1).blocking_recv().unwrap().unwrap().output, 2);
        s.shutdown();
        assert_eq!(
            submit(&s, 2).blocking_recv().unwrap().unwrap_err(),
            StepError::Stopped
        );
    }

    #[test]
    fn a_job_that_breaks_its_pass_fails_alone_and_its_pass_mates_get_their_results() {
        let Held {
            family,
            metrics,
            s,
            first,
            release,
        } = held();
        let (a, bad, b) = (submit(&s, 7), submit(&s, 666), submit(&s, 8));
        release.send(()).unwrap();
        assert_eq!(first.blocking_recv().unwrap().unwrap().output, 101);
        assert_eq!(a.blocking_recv().unwrap().unwrap().output, 8);
        assert_eq!(b.blocking_recv().unwrap().unwrap().output, 9);
        assert_eq!(
            bad.blocking_recv().unwrap().unwrap_err(),
            StepError::Model("model panicked".into())
        );
        // The failing pass [7, 666, 8] was run again one job at a time.
        assert_eq!(
            *family.passes.lock().unwrap(),
            vec![vec![100], vec![7], vec![8]]
        );
        let text = metrics.render();
        assert!(
            text.contains("dynaserve_scene_step_failures_total{model=\"test\"} 1"),
            "{text}"
        );
        s.shutdown();
    }
}
