//! The scheduler's queue as plain state, with no thread, clock or channel: the worker loop
//! (`super::worker`) feeds it and asks it what to run, and tests drive it with explicit
//! instants.
//!
//! - Two classes, [`Priority::Interactive`] and [`Priority::Bulk`]. Within a class each caller
//!   (its bearer token, else its peer address, else the request) has its own FIFO, and the
//!   callers are served in fair order of the work (cost) each has had run: the caller with the
//!   least goes next, and a caller that comes back after its queue emptied starts level with
//!   the others.
//! - [`Queue::next_batch`] forms a pass: interactive steps first, under the pass budget (less
//!   the bulk share while bulk waits); bulk steps then join it as far as their credit allows,
//!   `bulk_share / (1 - bulk_share)` of the interactive work of each pass (deficit round robin
//!   between the classes; at least one bulk step once it has earned its cost, so bulk is never
//!   starved). Without interactive work, bulk steps form passes of at most the bulk budget
//!   (the bulk share of the pass budget, or one step for families whose steps run as separate
//!   forwards), so an interactive step that arrives waits for one short pass at most.
//! - [`Queue::prune`] removes work whose deadline has passed or whose caller has gone.
//! - *Expected streams*: the streams of the last pass that said they would submit another step
//!   right away. While some are expected and the queue does not fill a pass, the next pass
//!   waits for them, at most `max_delay` ([`Queue::wait_until`]); while interactive streams are
//!   expected, queued bulk work does not start a pass without them. [`Queue::idle`] stops
//!   waiting for a stream that paused or ended.

use std::collections::{HashMap, VecDeque};
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
    /// Who asked for it: items of one caller share that caller's turn within the class.
    pub caller: u64,
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

/// One caller's FIFO within a class.
#[derive(Debug)]
struct CallerQueue<T> {
    caller: u64,
    /// Cost of this caller's items run so far (relative to the other callers of the class).
    served: u64,
    items: VecDeque<Queued<T>>,
}

/// One class: a FIFO per caller, served least-served caller first.
#[derive(Debug)]
struct Class<T> {
    /// Callers with queued items (a caller whose FIFO empties is removed).
    callers: Vec<CallerQueue<T>>,
    len: usize,
    cost: usize,
}

impl<T> Class<T> {
    fn new() -> Class<T> {
        Class {
            callers: Vec::new(),
            len: 0,
            cost: 0,
        }
    }

    fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn push(&mut self, item: Queued<T>) {
        self.len += 1;
        self.cost += item.ticket.cost;
        let caller = item.ticket.caller;
        match self.callers.iter_mut().find(|c| c.caller == caller) {
            Some(c) => c.items.push_back(item),
            None => {
                // A caller (back) in the queue starts level with the least served one.
                let served = self.callers.iter().map(|c| c.served).min().unwrap_or(0);
                self.callers.push(CallerQueue {
                    caller,
                    served,
                    items: VecDeque::from([item]),
                });
            }
        }
    }

    /// The caller served next: least served, then oldest head.
    fn next_caller(&self) -> Option<usize> {
        self.callers
            .iter()
            .enumerate()
            .filter_map(|(i, c)| c.items.front().map(|h| (c.served, h.ticket.enqueued, i)))
            .min()
            .map(|(_, _, i)| i)
    }

    fn peek_cost(&self) -> Option<usize> {
        self.next_caller()
            .and_then(|i| self.callers[i].items.front())
            .map(|h| h.ticket.cost)
    }

    fn pop(&mut self) -> Option<Queued<T>> {
        let i = self.next_caller()?;
        let c = &mut self.callers[i];
        let item = c.items.pop_front()?;
        c.served = c.served.saturating_add(item.ticket.cost.max(1) as u64);
        if c.items.is_empty() {
            self.callers.swap_remove(i);
        }
        self.len -= 1;
        self.cost -= item.ticket.cost;
        Some(item)
    }

    /// Moves items into `out` in fair order while they fit `budget` (the batching rule: the
    /// first item always, an item above the object budget alone); returns (items, cost).
    fn take(&mut self, budget: PassBudget, out: &mut Vec<Queued<T>>) -> (usize, usize) {
        let (max_scenes, max_objects) = (budget.max_scenes.max(1), budget.max_objects.max(1));
        let (mut n, mut cost) = (0, 0);
        while let Some(c) = self.peek_cost() {
            if n >= max_scenes || (n > 0 && cost + c > max_objects) {
                break;
            }
            if let Some(item) = self.pop() {
                out.push(item);
                n += 1;
                cost += c;
            }
        }
        (n, cost)
    }

    fn oldest(&self) -> Option<Instant> {
        self.callers
            .iter()
            .filter_map(|c| c.items.front().map(|i| i.ticket.enqueued))
            .min()
    }

    fn fills(&self, budget: PassBudget) -> bool {
        self.len >= budget.max_scenes.max(1) || self.cost >= budget.max_objects.max(1)
    }

    fn retain(&mut self, mut remove: impl FnMut(&Queued<T>) -> bool) -> Vec<Queued<T>> {
        let mut out = Vec::new();
        for c in &mut self.callers {
            if c.items.iter().all(|i| !remove(i)) {
                continue;
            }
            let mut kept = VecDeque::with_capacity(c.items.len());
            for item in c.items.drain(..) {
                if remove(&item) {
                    out.push(item);
                } else {
                    kept.push_back(item);
                }
            }
            c.items = kept;
        }
        self.callers.retain(|c| !c.items.is_empty());
        self.len -= out.len();
        self.cost -= out.iter().map(|i| i.ticket.cost).sum::<usize>();
        out
    }
}

/// Queue state of one scheduler.
#[derive(Debug)]
pub struct Queue<T> {
    /// Index 0: interactive, 1: bulk.
    classes: [Class<T>; 2],
    /// Streams of the last pass that announced another item and have not submitted it yet,
    /// with their class.
    expected: HashMap<u64, Priority>,
    /// When the last pass ended (the expected streams were announced).
    expected_since: Option<Instant>,
    budget: PassBudget,
    /// Budget of a pass without interactive items.
    bulk_budget: PassBudget,
    /// Bulk share of a pass's work while interactive work waits too.
    share: f64,
    /// Bulk credit: cost bulk items may still take in passes with interactive items.
    credit: f64,
    max_delay: Duration,
}

fn level(p: Priority) -> usize {
    match p {
        Priority::Interactive => 0,
        Priority::Bulk => 1,
    }
}

/// `budget` scaled by `f` (at least one scene and one object).
fn scaled(budget: PassBudget, f: f64) -> PassBudget {
    let part = |n: usize| ((n.max(1) as f64 * f).ceil() as usize).clamp(1, n.max(1));
    PassBudget {
        max_scenes: part(budget.max_scenes),
        max_objects: part(budget.max_objects),
    }
}

impl<T> Queue<T> {
    /// An empty queue forming passes under `budget`, giving bulk work `bulk_share` of a pass's
    /// work while interactive work waits too (and passes of that share of the budget alone),
    /// waiting at most `max_delay` for expected streams.
    pub fn new(budget: PassBudget, max_delay: Duration, bulk_share: f64) -> Queue<T> {
        let share = if bulk_share.is_finite() {
            bulk_share.clamp(0.01, 0.99)
        } else {
            0.25
        };
        Queue {
            classes: [Class::new(), Class::new()],
            expected: HashMap::new(),
            expected_since: None,
            budget,
            bulk_budget: scaled(budget, share),
            share,
            credit: 0.0,
            max_delay,
        }
    }

    /// At most one bulk item per pass without interactive items: for families whose items
    /// run as separate forwards, where a larger pass gains nothing and only holds the device
    /// longer.
    pub fn one_bulk_item_per_pass(mut self) -> Queue<T> {
        self.bulk_budget.max_scenes = 1;
        self
    }

    /// Passes without interactive items may take the whole pass budget: for families whose
    /// items are all bulk, where no interactive item of this queue can wait behind them.
    pub fn whole_budget_for_bulk(mut self) -> Queue<T> {
        self.bulk_budget = self.budget;
        self
    }

    /// Appends an item; its stream is no longer expected.
    pub fn push(&mut self, item: Queued<T>) {
        self.expected.remove(&item.ticket.stream_id);
        self.classes[level(item.ticket.priority)].push(item);
    }

    /// Stops waiting for `stream_id` (it paused or ended).
    pub fn idle(&mut self, stream_id: u64) {
        self.expected.remove(&stream_id);
    }

    /// True when nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.classes.iter().all(Class::is_empty)
    }

    /// Items queued at `priority`.
    pub fn len_at(&self, priority: Priority) -> usize {
        self.classes[level(priority)].len
    }

    /// Number of streams the next pass would wait for.
    pub fn expected(&self) -> usize {
        self.expected.len()
    }

    /// Removes items whose deadline is at or before `now` and items for which `gone` is true
    /// (their caller went away), and returns them with the reason.
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
        for class in &mut self.classes {
            for item in class.retain(|i| reason(i).is_some()) {
                let r = reason(&item).unwrap_or(Dropped::Cancelled);
                dropped.push((item, r));
            }
        }
        if self.classes[1].is_empty() {
            self.credit = 0.0;
        }
        dropped
    }

    /// True when the queue holds at least one full pass: interactive items filling the pass
    /// budget, or bulk items filling the bulk budget.
    pub fn fills_pass(&self) -> bool {
        self.classes[0].fills(self.budget) || self.classes[1].fills(self.bulk_budget)
    }

    /// When the next pass should start at the latest if it is to wait for expected streams,
    /// `None` when it should start as soon as anything is queued (or nothing is). While interactive streams
    /// are expected and the queued interactive items do not fill a pass: `max_delay` after
    /// the oldest queued interactive item arrived or, with none queued, after the last pass
    /// ended. While only bulk streams are expected and the queue does not fill a pass:
    /// `max_delay` after the oldest queued item arrived.
    pub fn wait_until(&self) -> Option<Instant> {
        if self.expected.is_empty() || self.is_empty() {
            return None;
        }
        if self.expected.values().any(|p| *p == Priority::Interactive) {
            if self.classes[0].fills(self.budget) {
                return None;
            }
            let from = self.classes[0].oldest().or(self.expected_since)?;
            return Some(from + self.max_delay);
        }
        if self.fills_pass() {
            return None;
        }
        let oldest = self.classes.iter().filter_map(Class::oldest).min()?;
        Some(oldest + self.max_delay)
    }

    /// Takes the next pass (see the module documentation). Empty only when the queue is.
    pub fn next_batch(&mut self) -> Vec<Queued<T>> {
        self.next_batch_with(true)
    }

    /// [`Queue::next_batch`]; with `bulk_allowed` false (another scheduler's bulk work has
    /// its turn, `super::gate`) a pass with interactive items takes no bulk items and earns
    /// no credit.
    pub fn next_batch_with(&mut self, bulk_allowed: bool) -> Vec<Queued<T>> {
        let share = self.share;
        let budget = self.budget;
        let [inter, bulk] = &mut self.classes;
        let mut batch = Vec::new();
        if inter.is_empty() {
            self.credit = 0.0;
            bulk.take(self.bulk_budget, &mut batch);
            return batch;
        }
        if bulk.is_empty() || !bulk_allowed {
            inter.take(budget, &mut batch);
            return batch;
        }
        let (mut n, mut cost) = inter.take(scaled(budget, 1.0 - share), &mut batch);
        self.credit += cost as f64 * share / (1.0 - share);
        let mut first = true;
        while let Some(c) = bulk.peek_cost() {
            let fits = n < budget.max_scenes.max(1) && cost + c <= budget.max_objects.max(1);
            if c as f64 > self.credit || !(fits || first) {
                break;
            }
            if let Some(item) = bulk.pop() {
                batch.push(item);
                self.credit -= c as f64;
                n += 1;
                cost += c;
                first = false;
            }
        }
        if bulk.is_empty() {
            self.credit = 0.0;
        }
        batch
    }

    /// Empties the queue (the scheduler is stopping), in priority then arrival order.
    pub fn drain(&mut self) -> Vec<Queued<T>> {
        self.expected.clear();
        self.credit = 0.0;
        let mut out = Vec::new();
        for class in &mut self.classes {
            let mut items = class.retain(|_| true);
            items.sort_by_key(|i| i.ticket.enqueued);
            out.extend(items);
        }
        out
    }

    /// Records which streams of the pass that just ended at `now` will come back at once
    /// (those that announced another item and got their result), with their class; they
    /// replace the previous expectations.
    pub fn expect(&mut self, streams: impl IntoIterator<Item = (u64, Priority)>, now: Instant) {
        self.expected = streams.into_iter().collect();
        self.expected_since = Some(now);
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
            0.25,
        )
    }

    struct At(Instant);

    impl At {
        fn ms(&self, ms: u64) -> Instant {
            self.0 + Duration::from_millis(ms)
        }
        /// An item of its own caller (the stream id).
        fn item(
            &self,
            name: &'static str,
            priority: Priority,
            cost: usize,
            stream_id: u64,
            at_ms: u64,
        ) -> Queued<&'static str> {
            self.of(name, priority, cost, stream_id, stream_id, at_ms)
        }
        fn of(
            &self,
            name: &'static str,
            priority: Priority,
            cost: usize,
            stream_id: u64,
            caller: u64,
            at_ms: u64,
        ) -> Queued<&'static str> {
            Queued {
                ticket: Ticket {
                    priority,
                    deadline: None,
                    stream_id,
                    caller,
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

    fn classes(batch: &[Queued<&'static str>]) -> (usize, usize) {
        let bulk = batch
            .iter()
            .filter(|i| i.ticket.priority == Priority::Bulk)
            .count();
        (batch.len() - bulk, bulk)
    }

    #[test]
    fn interactive_goes_first_and_bulk_joins_with_its_share_of_the_work() {
        let t = At(Instant::now());
        let mut q = queue(64, 1000);
        for i in 0..100 {
            q.push(t.item("b", Priority::Bulk, 10, 100 + i, 0));
        }
        // 8 streams of 10-object scenes step 12 times while the bulk items wait.
        let mut bulk_taken = 0;
        for pass in 0..12u64 {
            for s in 0..8 {
                q.push(t.item("i", Priority::Interactive, 10, s, 1 + pass));
            }
            let batch = q.next_batch();
            let (i, b) = classes(&batch);
            // Every interactive step is in the pass, ahead of the bulk ones.
            assert_eq!(i, 8);
            assert!(
                batch[..8]
                    .iter()
                    .all(|x| x.ticket.priority == Priority::Interactive)
            );
            // A quarter of the work (bulk share 0.25): 80 interactive objects earn 26.7
            // bulk objects a pass, i.e. 2 or 3 ten-object bulk scenes.
            assert!((2..=3).contains(&b), "pass {pass}: {b} bulk items");
            bulk_taken += b;
        }
        // 12 passes earned 12 x 80 / 3 = 320 objects of bulk credit: 32 bulk scenes (31
        // where rounding leaves the last credit a hair short).
        assert!((31..=32).contains(&bulk_taken), "{bulk_taken}");
        // Without interactive work, bulk passes hold at most the bulk share of the budget.
        let batch = q.next_batch();
        assert_eq!(classes(&batch), (0, 16));
    }

    #[test]
    fn a_pass_takes_no_bulk_items_while_another_scheduler_has_the_bulk_turn() {
        let t = At(Instant::now());
        let mut q = queue(64, 1000);
        q.push(t.item("b", Priority::Bulk, 1, 9, 0));
        for s in 0..4 {
            q.push(t.item("i", Priority::Interactive, 1, s, 1));
        }
        assert_eq!(classes(&q.next_batch_with(false)), (4, 0));
        for s in 0..4 {
            q.push(t.item("i", Priority::Interactive, 1, s, 2));
        }
        // No credit was earned meanwhile: 4 interactive objects earn 4/3 now.
        assert_eq!(classes(&q.next_batch_with(true)), (4, 1));
    }

    #[test]
    fn a_bulk_item_is_never_starved_by_interactive_work_that_fills_every_pass() {
        let t = At(Instant::now());
        let mut q = queue(4, 40);
        q.push(t.item("big", Priority::Bulk, 25, 99, 0));
        for pass in 0..3u64 {
            // More interactive work than a pass holds, every time.
            for s in 0..6 {
                q.push(t.item("i", Priority::Interactive, 10, s, 1 + pass));
            }
            let batch = q.next_batch();
            let (i, b) = classes(&batch);
            // Interactive work keeps 3 of 4 scenes (0.75 of the budget) while bulk waits.
            assert_eq!(i, 3, "pass {pass}");
            // The 25-object item has earned its cost after three passes of 30 interactive
            // objects (10 credit each) and then joins, even above the object budget.
            assert_eq!(b, usize::from(pass == 2), "pass {pass}");
            q.prune(t.ms(100), |n| *n == "i");
        }
        assert!(q.is_empty());
    }

    #[test]
    fn bulk_passes_alone_are_short_and_one_item_for_separate_forwards() {
        let t = At(Instant::now());
        let mut q = queue(8, 1000);
        for (i, n) in ["a", "b", "c", "d", "e"].into_iter().enumerate() {
            q.push(t.item(n, Priority::Bulk, 1, i as u64, i as u64));
        }
        // A quarter of 8 scenes.
        assert_eq!(names(q.next_batch()), ["a", "b"]);
        let mut q = queue(8, 1000).one_bulk_item_per_pass();
        for (i, n) in ["a", "b"].into_iter().enumerate() {
            q.push(t.item(n, Priority::Bulk, 1, i as u64, i as u64));
        }
        assert!(q.fills_pass());
        assert_eq!(names(q.next_batch()), ["a"]);
        // Interactive work alone still fills the whole budget.
        for (i, n) in ["i0", "i1", "i2", "i3", "i4"].into_iter().enumerate() {
            q.push(t.item(n, Priority::Interactive, 1, 10 + i as u64, 5));
        }
        let batch = q.next_batch();
        assert_eq!(classes(&batch), (5, 1));
        // A queue of bulk items only (gradient calls) takes the whole budget: all the calls
        // that fit, by cost, a larger one alone.
        let mut q = queue(8, 100).whole_budget_for_bulk();
        for (i, (n, cost)) in [("g0", 40), ("g1", 50), ("g2", 30), ("g3", 500)]
            .into_iter()
            .enumerate()
        {
            q.push(t.item(n, Priority::Bulk, cost, i as u64, i as u64));
        }
        assert_eq!(names(q.next_batch()), ["g0", "g1"]);
        assert_eq!(names(q.next_batch()), ["g2"]);
        assert_eq!(names(q.next_batch()), ["g3"]);
    }

    #[test]
    fn callers_share_their_class_fairly_whatever_they_queued() {
        let t = At(Instant::now());
        let mut q = queue(4, 1000);
        // Caller 1 queues six variants first, caller 2 two later.
        for (i, n) in ["a0", "a1", "a2", "a3", "a4", "a5"].into_iter().enumerate() {
            q.push(t.of(n, Priority::Bulk, 1, i as u64, 1, 0));
        }
        for (i, n) in ["b0", "b1"].into_iter().enumerate() {
            q.push(t.of(n, Priority::Bulk, 1, 10 + i as u64, 2, 1));
        }
        // Whole passes of the budget, to see the order.
        q.bulk_budget = q.budget;
        assert_eq!(names(q.next_batch()), ["a0", "b0", "a1", "b1"]);
        // Caller 3 comes in after caller 1 had two items run: it starts level with
        // caller 1, it does not get the next four passes' worth to itself.
        for (i, n) in ["c0", "c1", "c2"].into_iter().enumerate() {
            q.push(t.of(n, Priority::Bulk, 1, 20 + i as u64, 3, 5));
        }
        assert_eq!(names(q.next_batch()), ["a2", "c0", "a3", "c1"]);
        assert_eq!(names(q.next_batch()), ["a4", "c2", "a5"]);
        // Costs count, not items: a caller of 3-object items gets a third of the items of a
        // caller of 1-object items.
        for (i, n) in ["x0", "x1", "x2"].into_iter().enumerate() {
            q.push(t.of(n, Priority::Interactive, 3, 30 + i as u64, 4, 10));
        }
        for (i, n) in ["y0", "y1", "y2", "y3", "y4", "y5"].into_iter().enumerate() {
            q.push(t.of(n, Priority::Interactive, 1, 40 + i as u64, 5, 11));
        }
        q.budget.max_scenes = 6;
        assert_eq!(names(q.next_batch()), ["x0", "y0", "y1", "y2", "x1", "y3"]);
    }

    #[test]
    fn the_scene_cap_holds_and_an_oversized_item_runs_alone() {
        let t = At(Instant::now());
        let mut q = queue(2, 10);
        for (i, (n, cost)) in [("a", 1), ("big", 50), ("c", 1), ("d", 1), ("e", 1)]
            .into_iter()
            .enumerate()
        {
            q.push(t.item(n, Priority::Interactive, cost, i as u64, i as u64));
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
        // Streams 1 and 7 of the last pass (ended at 4 ms) will come back: wait for them
        // from the oldest queued interactive arrival on, at most the queue delay.
        q.expect(
            [(1, Priority::Interactive), (7, Priority::Interactive)],
            t.ms(4),
        );
        assert_eq!(q.wait_until(), Some(t.ms(5) + DELAY));
        // Stream 1 comes back; 7 is still expected.
        q.push(t.item("back", Priority::Interactive, 1, 1, 6));
        assert_eq!(q.expected(), 1);
        assert_eq!(q.wait_until(), Some(t.ms(5) + DELAY));
        // Stream 7 pauses: nobody is expected, start now.
        q.idle(7);
        assert_eq!(q.wait_until(), None);
        // A full pass never waits.
        q.expect([(9, Priority::Interactive)], t.ms(7));
        q.push(t.item("third", Priority::Interactive, 1, 3, 7));
        assert!(q.fills_pass());
        assert_eq!(q.wait_until(), None);
        assert_eq!(names(q.next_batch()), ["new", "back", "third"]);
        assert_eq!(q.wait_until(), None);
    }

    #[test]
    fn queued_bulk_work_waits_for_expected_interactive_streams() {
        let t = At(Instant::now());
        let mut q = queue(64, 1000);
        // Bulk items queued long ago, more than a bulk pass of them.
        for i in 0..40 {
            q.push(t.item("b", Priority::Bulk, 1, 100 + i, 0));
        }
        assert!(q.fills_pass());
        // The interactive streams of the pass that ended at 50 ms come back: the next pass
        // waits for them (up to the delay from that end), not for the old bulk items.
        q.expect([(1, Priority::Interactive), (2, Priority::Bulk)], t.ms(50));
        assert_eq!(q.wait_until(), Some(t.ms(50) + DELAY));
        q.push(t.item("i", Priority::Interactive, 1, 1, 51));
        assert_eq!(q.wait_until(), None);
        let batch = q.next_batch();
        assert_eq!(batch[0].payload, "i");
        // Only bulk streams expected: the bulk pass is full, so it starts at once.
        q.expect([(2, Priority::Bulk)], t.ms(60));
        assert_eq!(q.wait_until(), None);
    }
}
