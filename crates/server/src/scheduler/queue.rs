//! The scheduler's queue as plain state, with no thread, clock or channel: the worker loop
//! (`super::worker`) feeds it and asks it what to run, and tests drive it with explicit
//! instants.
//!
//! - Two FIFO levels, [`Priority::Interactive`] ahead of [`Priority::Bulk`].
//! - [`Queue::prune`] removes work whose deadline has passed or whose caller has gone.
//! - *Expected streams*: the streams of the last pass that said they would submit another step
//!   right away. While some are expected and the queue does not fill a pass, the next pass
//!   waits for them, at most `max_delay` after the oldest queued item arrived
//!   ([`Queue::wait_until`]); [`Queue::idle`] stops waiting for a stream that paused or ended.
//! - [`Queue::next_batch`] takes the first pass in priority then FIFO order under the pass
//!   budget: the batching rule of `dynaserve_model::PassBudget`.

use std::collections::{HashSet, VecDeque};
use std::time::{Duration, Instant};

use dynaserve_model::PassBudget;

use super::Priority;

/// Scheduling facts of one queued item.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ticket {
    /// Scheduling class.
    pub priority: Priority,
    /// Instant after which the result is no longer wanted.
    pub deadline: Option<Instant>,
    /// The stream (rollout, Predict variant) the item belongs to.
    pub stream_id: u64,
    /// True when the stream will submit another item right after this one.
    pub more_steps: bool,
    /// Cost against the pass budget's object count (objects of a rigid scene).
    pub cost: usize,
    /// Arrival in the queue.
    pub enqueued: Instant,
}

/// An item with its ticket.
#[derive(Debug)]
pub struct Queued<T> {
    /// Scheduling facts.
    pub ticket: Ticket,
    /// The work itself (opaque to the queue).
    pub payload: T,
}

/// Why [`Queue::prune`] removed an item.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dropped {
    /// Its deadline passed while queued.
    Expired,
    /// Nobody waits for its result any more.
    Cancelled,
}

impl Dropped {
    /// Label value of the `reason` metric label.
    pub fn as_str(self) -> &'static str {
        match self {
            Dropped::Expired => "deadline_exceeded",
            Dropped::Cancelled => "cancelled",
        }
    }
}

/// Queue state of one scheduler.
#[derive(Debug)]
pub struct Queue<T> {
    /// Index 0: interactive, 1: bulk; FIFO each.
    levels: [VecDeque<Queued<T>>; 2],
    /// Total cost queued.
    cost: usize,
    /// Streams of the last pass that announced another item and have not submitted it yet.
    expected: HashSet<u64>,
    budget: PassBudget,
    max_delay: Duration,
}

fn level(p: Priority) -> usize {
    match p {
        Priority::Interactive => 0,
        Priority::Bulk => 1,
    }
}

impl<T> Queue<T> {
    /// An empty queue forming passes under `budget`, waiting at most `max_delay` for expected
    /// streams.
    pub fn new(budget: PassBudget, max_delay: Duration) -> Queue<T> {
        Queue {
            levels: [VecDeque::new(), VecDeque::new()],
            cost: 0,
            expected: HashSet::new(),
            budget,
            max_delay,
        }
    }

    /// Appends an item; its stream is no longer expected.
    pub fn push(&mut self, item: Queued<T>) {
        self.expected.remove(&item.ticket.stream_id);
        self.cost += item.ticket.cost;
        self.levels[level(item.ticket.priority)].push_back(item);
    }

    /// Stops waiting for `stream_id` (it paused or ended).
    pub fn idle(&mut self, stream_id: u64) {
        self.expected.remove(&stream_id);
    }

    /// True when nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.levels.iter().all(VecDeque::is_empty)
    }

    /// Items queued at `priority`.
    pub fn len_at(&self, priority: Priority) -> usize {
        self.levels[level(priority)].len()
    }

    /// Streams the next pass would wait for.
    pub fn expected(&self) -> &HashSet<u64> {
        &self.expected
    }

    /// Removes items whose deadline is at or before `now` and items for which `gone` is true
    /// (their caller went away), and returns them with the reason, in queue order.
    pub fn prune(&mut self, now: Instant, gone: impl Fn(&T) -> bool) -> Vec<(Queued<T>, Dropped)> {
        let reason = |item: &Queued<T>| {
            if item.ticket.deadline.is_some_and(|d| d <= now) {
                Some(Dropped::Expired)
            } else if gone(&item.payload) {
                Some(Dropped::Cancelled)
            } else {
                None
            }
        };
        let mut dropped = Vec::new();
        for q in self.levels.iter_mut() {
            if q.iter().all(|i| reason(i).is_none()) {
                continue;
            }
            let mut kept = VecDeque::with_capacity(q.len());
            for item in q.drain(..) {
                match reason(&item) {
                    Some(r) => dropped.push((item, r)),
                    None => kept.push_back(item),
                }
            }
            *q = kept;
        }
        self.cost -= dropped.iter().map(|(i, _)| i.ticket.cost).sum::<usize>();
        dropped
    }

    /// True when the queue holds at least one full pass (scene cap or object budget reached).
    pub fn fills_pass(&self) -> bool {
        let queued: usize = self.levels.iter().map(VecDeque::len).sum();
        queued >= self.budget.max_scenes.max(1) || self.cost >= self.budget.max_objects.max(1)
    }

    /// When the next pass should start at the latest if it is to wait for expected streams:
    /// `Some(oldest arrival + max_delay)` while streams are expected and the queue does not
    /// fill a pass, `None` when it should start as soon as anything is queued.
    pub fn wait_until(&self) -> Option<Instant> {
        if self.expected.is_empty() || self.fills_pass() {
            return None;
        }
        let oldest = self
            .levels
            .iter()
            .filter_map(|q| q.front().map(|i| i.ticket.enqueued))
            .min()?;
        Some(oldest + self.max_delay)
    }

    /// Takes the next pass: interactive before bulk, FIFO within a level, under the pass
    /// budget (an item above the object budget runs alone). Empty only when the queue is.
    pub fn next_batch(&mut self) -> Vec<Queued<T>> {
        let costs = self.levels.iter().flatten().map(|i| i.ticket.cost);
        let (take, cost) = self.budget.first_pass(costs);
        let mut batch = Vec::with_capacity(take);
        for q in self.levels.iter_mut() {
            while batch.len() < take {
                match q.pop_front() {
                    Some(item) => batch.push(item),
                    None => break,
                }
            }
        }
        self.cost -= cost;
        batch
    }

    /// Empties the queue (the scheduler is stopping), in priority then FIFO order.
    pub fn drain(&mut self) -> Vec<Queued<T>> {
        self.cost = 0;
        self.expected.clear();
        self.levels.iter_mut().flat_map(|q| q.drain(..)).collect()
    }

    /// Records which streams of the pass just run will come back at once (those that announced
    /// another item and got their result); they replace the previous expectations.
    pub fn expect(&mut self, streams: impl IntoIterator<Item = u64>) {
        self.expected = streams.into_iter().collect();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DELAY: Duration = Duration::from_millis(2);

    fn queue(max_scenes: usize, max_objects: usize) -> Queue<&'static str> {
        Queue::new(
            PassBudget {
                max_scenes,
                max_objects,
            },
            DELAY,
        )
    }

    struct At(Instant);

    impl At {
        fn ms(&self, ms: u64) -> Instant {
            self.0 + Duration::from_millis(ms)
        }
        fn item(
            &self,
            name: &'static str,
            priority: Priority,
            cost: usize,
            stream_id: u64,
            at_ms: u64,
        ) -> Queued<&'static str> {
            Queued {
                ticket: Ticket {
                    priority,
                    deadline: None,
                    stream_id,
                    more_steps: false,
                    cost,
                    enqueued: self.ms(at_ms),
                },
                payload: name,
            }
        }
    }

    fn names(batch: Vec<Queued<&'static str>>) -> Vec<&'static str> {
        batch.into_iter().map(|i| i.payload).collect()
    }

    #[test]
    fn passes_take_interactive_first_then_fifo_under_the_budget() {
        let t = At(Instant::now());
        let mut q = queue(3, 5);
        for (i, n) in ["b0", "b1", "b2"].into_iter().enumerate() {
            q.push(t.item(n, Priority::Bulk, 2, 10 + i as u64, i as u64));
        }
        for (i, n) in ["i0", "i1", "i2"].into_iter().enumerate() {
            q.push(t.item(n, Priority::Interactive, 2, i as u64, 10 + i as u64));
        }
        // Object budget 5 with 2-object scenes: two scenes per pass.
        assert!(q.fills_pass());
        assert_eq!(names(q.next_batch()), ["i0", "i1"]);
        assert_eq!(names(q.next_batch()), ["i2", "b0"]);
        assert_eq!(names(q.next_batch()), ["b1", "b2"]);
        assert!(q.next_batch().is_empty() && q.is_empty());
    }

    #[test]
    fn the_scene_cap_holds_and_an_oversized_item_runs_alone() {
        let t = At(Instant::now());
        let mut q = queue(2, 10);
        for (i, (n, cost)) in [("a", 1), ("big", 50), ("c", 1), ("d", 1), ("e", 1)]
            .into_iter()
            .enumerate()
        {
            q.push(t.item(n, Priority::Interactive, cost, i as u64, 0));
        }
        assert_eq!(names(q.next_batch()), ["a"]);
        assert_eq!(names(q.next_batch()), ["big"]);
        assert_eq!(names(q.next_batch()), ["c", "d"]);
        assert!(!q.fills_pass());
        assert_eq!(names(q.next_batch()), ["e"]);
    }

    #[test]
    fn expired_and_abandoned_items_are_pruned_before_the_next_pass() {
        let t = At(Instant::now());
        let mut q = queue(64, 1000);
        let mut expired = t.item("expired", Priority::Interactive, 1, 1, 0);
        expired.ticket.deadline = Some(t.ms(20));
        q.push(expired);
        q.push(t.item("gone", Priority::Interactive, 1, 2, 1));
        q.push(t.item("kept", Priority::Bulk, 1, 3, 2));
        // Before the deadline only the abandoned item goes.
        let d = q.prune(t.ms(10), |p| *p == "gone");
        assert_eq!(d.len(), 1);
        assert_eq!((d[0].0.payload, d[0].1), ("gone", Dropped::Cancelled));
        // At the deadline the expired one goes too.
        let d = q.prune(t.ms(20), |_| false);
        assert_eq!((d[0].0.payload, d[0].1), ("expired", Dropped::Expired));
        assert_eq!(names(q.next_batch()), ["kept"]);
        assert!(q.prune(t.ms(30), |_| true).is_empty());
    }

    #[test]
    fn expected_streams_are_awaited_up_to_the_delay_unless_a_pass_is_full() {
        let t = At(Instant::now());
        let mut q = queue(3, 100);
        // Nothing expected: start at once.
        q.push(t.item("new", Priority::Interactive, 1, 2, 5));
        assert_eq!(q.wait_until(), None);
        // Streams 1 and 7 of the last pass will come back: wait for them from the oldest
        // arrival on, at most the queue delay.
        q.expect([1, 7]);
        assert_eq!(q.wait_until(), Some(t.ms(5) + DELAY));
        // Stream 1 comes back; 7 is still expected.
        q.push(t.item("back", Priority::Interactive, 1, 1, 6));
        assert_eq!(q.expected().len(), 1);
        assert_eq!(q.wait_until(), Some(t.ms(5) + DELAY));
        // Stream 7 pauses: nobody is expected, start now.
        q.idle(7);
        assert_eq!(q.wait_until(), None);
        // A full pass never waits.
        q.expect([9]);
        q.push(t.item("third", Priority::Bulk, 1, 3, 7));
        assert!(q.fills_pass());
        assert_eq!(q.wait_until(), None);
        assert_eq!(names(q.next_batch()), ["new", "back", "third"]);
        assert_eq!(q.wait_until(), None);
    }
}
