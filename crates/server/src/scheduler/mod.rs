//! Continuous batching: one scheduler thread per resident model.
//!
//! Callers (rollout sessions, Predict variants, warm-up) submit one [`Job`] at a time: a unit
//! of work of the model's [`Family`] (for stepping models a
//! [`SceneStep`](crate::families::SceneStep): a prepared scene and its state; for PhysiFormer
//! one denoising evaluation) with its priority, deadline, stream and a oneshot reply channel.
//! Between forward passes the worker (`worker`) drains its channel into the [`Queue`]
//! ([`queue`], plain state tested without threads or sleeps), which
//!
//! 1. drops jobs whose caller has gone and answers those whose deadline has passed with
//!    [`StepError::DeadlineExceeded`], so neither takes a place in a pass;
//! 2. waits, at most `max_queue_delay` after the oldest queued job arrived, for the streams of
//!    the previous pass that said they would come back (`more_steps`), unless the queue already
//!    fills a pass; a stream that pauses (slow reader) or ends sends [`Scheduler::idle`];
//! 3. takes the next pass by class ([`Priority`]): interactive jobs first, bulk jobs joining
//!    with their share of the work, callers within a class in fair order, under the scene cap
//!    and the object budget (the one batching rule, `dynaserve_model::PassBudget`; see
//!    [`queue`]), in whole forwards of a model that splits a pass into forwards
//!    ([`Family::forward_objects`]);
//! 4. waits for the device at the [`PassGate`] every scheduler of the engine shares ([`gate`]:
//!    a bulk pass never runs beside an interactive one, and gets its share of device time
//!    while both wait), runs one pass of the family over the jobs on the scheduler thread,
//!    never on the async runtime, and sends each job its output with its queue wait, forward
//!    time and pass size.
//!
//! A scene's result does not depend on its pass-mates: the model computes every scene of a
//! pass independently (tested end to end).
//!
mod family;
pub mod gate;
pub mod queue;
mod worker;

use std::sync::Arc;
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use tokio::sync::oneshot;

pub use family::{Family, Gradients, Steps};
pub use gate::PassGate;
pub use queue::{Dropped, Queue, Queued, Ticket};

use crate::metrics::Metrics;

/// Request id of warm-up jobs; their passes are not counted in the serving metrics.
pub const WARMUP_REQUEST_ID: &str = "warm-up";

/// Scheduling class of a job, set by the engine from the request's cost
/// ([`crate::config::SchedulingConfig`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Priority {
    /// Streams (Rollout, a session's Step and Interact), Predict and Generate calls below the
    /// bulk cost, warm-up: batched ahead of bulk work.
    Interactive,
    /// Predict and Generate calls above the bulk cost: their share of the passes.
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
}

/// Batching limits and classes of one scheduler.
#[derive(Clone, Debug)]
pub struct SchedulerConfig {
    /// Most jobs (scenes) per forward pass (1 disables batching).
    pub max_batch_scenes: usize,
    /// Most objects per forward pass (a larger single scene still runs alone).
    pub max_batch_objects: usize,
    /// Longest wait for expected pass-mates, measured from the oldest queued job's arrival.
    pub max_queue_delay: Duration,
    /// Share of a pass's work bulk jobs get while interactive jobs wait too, in (0, 1).
    pub bulk_share: f64,
    /// The device gate shared with the engine's other schedulers; `None`: passes start
    /// without asking anyone.
    pub gate: Option<Arc<PassGate>>,
}

/// One unit of work with what the scheduler needs to place it.
pub struct Job<F: Family> {
    /// The work.
    pub item: F::Item,
    /// Scheduling class.
    pub priority: Priority,
    /// Instant after which the result is no longer wanted.
    pub deadline: Option<Instant>,
    /// Identifies the stream (rollout, Predict variant) across its jobs.
    pub stream_id: u64,
    /// Who asked ([`crate::engine::RequestCtx::caller`]): callers share their class fairly.
    pub caller: u64,
    /// True when the stream will submit another job right after this one.
    pub more_steps: bool,
    /// Request id for logs.
    pub request_id: Arc<str>,
    /// Where the result goes.
    pub reply: Reply<F::Output>,
}

/// The reply channel of a job.
pub type Reply<O> = oneshot::Sender<Result<Done<O>, StepError>>;

/// A finished job.
#[derive(Clone, Debug)]
pub struct Done<O> {
    /// What the pass produced for it (rigid models: the new pose of every object).
    pub output: O,
    /// Time spent queued.
    pub queue_wait: Duration,
    /// Duration of the forward pass that computed it.
    pub forward: Duration,
    /// Jobs in that pass.
    pub batch_scenes: u32,
    /// Sequence number of that pass (for logs).
    pub batch_id: u64,
}

/// Why a job produced no output.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum StepError {
    /// Its deadline passed while it was queued.
    #[error("deadline exceeded while queued")]
    DeadlineExceeded,
    /// The model failed on the pass (or on this job).
    #[error("model step failed: {0}")]
    Model(String),
    /// The scheduler has stopped.
    #[error("scheduler stopped")]
    Stopped,
}

enum Command<F: Family> {
    Job(Box<Queued<Job<F>>>),
    Idle(u64),
    Stop,
}

/// Handle to a running scheduler thread.
pub struct Scheduler<F: Family> {
    tx: mpsc::Sender<Command<F>>,
    thread: std::sync::Mutex<Option<JoinHandle<()>>>,
    family: Arc<F>,
}

impl<F: Family> Scheduler<F> {
    /// Starts the scheduler thread of `family`.
    pub fn start(
        family: Arc<F>,
        config: SchedulerConfig,
        metrics: Metrics,
    ) -> std::io::Result<Scheduler<F>> {
        let (tx, rx) = mpsc::channel();
        let name = family.name().to_string();
        let worker = worker::Worker::new(family.clone(), config, rx, metrics);
        let thread = std::thread::Builder::new()
            .name(format!("sched-{name}"))
            .spawn(move || worker.run())?;
        Ok(Scheduler {
            tx,
            thread: std::sync::Mutex::new(Some(thread)),
            family,
        })
    }

    /// The family this scheduler runs.
    pub fn family(&self) -> &Arc<F> {
        &self.family
    }

    /// Queues a job. If the scheduler has stopped, the job's reply channel receives
    /// [`StepError::Stopped`].
    pub fn submit(&self, job: Job<F>) {
        let ticket = Ticket {
            priority: job.priority,
            deadline: job.deadline,
            stream_id: job.stream_id,
            caller: job.caller,
            more_steps: job.more_steps,
            cost: self.family.cost(&job.item),
            enqueued: Instant::now(),
        };
        let queued = Box::new(Queued {
            ticket,
            payload: job,
        });
        if let Err(mpsc::SendError(Command::Job(q))) = self.tx.send(Command::Job(queued)) {
            let _ = q.payload.reply.send(Err(StepError::Stopped));
        }
    }

    /// Tells the scheduler not to wait for `stream_id`'s next job (it paused or ended).
    pub fn idle(&self, stream_id: u64) {
        let _ = self.tx.send(Command::Idle(stream_id));
    }

    /// Stops the thread after its current pass; queued jobs get [`StepError::Stopped`].
    /// Blocks until the thread has exited.
    pub fn shutdown(&self) {
        let _ = self.tx.send(Command::Stop);
        let handle = self.thread.lock().ok().and_then(|mut t| t.take());
        if let Some(h) = handle {
            let _ = h.join();
        }
    }
}

impl<F: Family> Drop for Scheduler<F> {
    fn drop(&mut self) {
        let _ = self.tx.send(Command::Stop);
    }
}
