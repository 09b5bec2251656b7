//! The device as one resource shared by every scheduler of an engine. Each model has its own
//! scheduler thread, so without coordination a PhysiFormer pass full of bulk samples would run
//! at the same time as a RigidFormer pass of interactive streams and take the cores from it.
//! Every pass goes through the [`PassGate`]:
//!
//! - a pass holding an interactive step is interactive, any other pass is bulk;
//! - interactive passes may run together (different models) but never beside a bulk pass, and
//!   a bulk pass runs alone;
//! - while both classes want the device, the one furthest below its share of device time goes
//!   next (weighted fair queueing on measured pass time: each class's time is divided by its
//!   weight, `1 - bulk_share` and `bulk_share`), so bulk gets its share and never more while
//!   interactive work waits;
//! - for a short `hold` after an interactive pass whose streams announced another step, the
//!   device is kept for them (they come back within the scheduler's queue delay) unless bulk
//!   is below its share;
//! - a class that comes back after being idle starts level with the other (it banks no
//!   credit from its idle time);
//! - within the bulk class the schedulers (models) share fairly: of the schedulers with bulk
//!   work waiting, the one whose bulk work has had the least device time goes next, and an
//!   interactive pass may take bulk steps along ([`GatePass::bulk_allowed`]) only while no
//!   other scheduler's waiting bulk work has had less.
//!
//! The decisions are [`GateState`], plain state driven with explicit instants in tests.

use std::sync::{Condvar, Mutex};
use std::time::{Duration, Instant};

use super::Priority;

fn idx(p: Priority) -> usize {
    match p {
        Priority::Interactive => 0,
        Priority::Bulk => 1,
    }
}

/// Bulk bookkeeping of one scheduler.
#[derive(Clone, Debug, Default)]
struct Client {
    /// Device seconds its bulk steps took.
    bulk_used: f64,
    /// Its bulk passes waiting to start.
    waiting_bulk: usize,
    /// It had bulk work queued when it last asked for the device.
    has_bulk: bool,
}

/// The gate's bookkeeping, with no lock or clock of its own.
#[derive(Debug)]
pub struct GateState {
    /// Per scheduler ([`GateState::register`]).
    clients: Vec<Client>,
    /// Weight of each class (interactive, bulk).
    weight: [f64; 2],
    hold: Duration,
    /// Passes running, per class.
    running: [usize; 2],
    /// Passes waiting to start, per class.
    waiting: [usize; 2],
    /// Device seconds used, divided by the class weight.
    used: [f64; 2],
    /// End of the class's last pass.
    last_end: [Option<Instant>; 2],
    /// Until when the device is kept for interactive streams that announced another step.
    held_until: Option<Instant>,
}

impl GateState {
    /// A gate giving bulk work `bulk_share` of the device while both classes wait, keeping it
    /// `hold` for interactive streams expected back.
    pub fn new(bulk_share: f64, hold: Duration) -> GateState {
        let s = bulk_share.clamp(0.01, 0.99);
        GateState {
            clients: Vec::new(),
            weight: [1.0 - s, s],
            hold,
            running: [0; 2],
            waiting: [0; 2],
            used: [0.0; 2],
            last_end: [None; 2],
            held_until: None,
        }
    }

    fn bulk_turn(&self) -> bool {
        self.used[1] < self.used[0]
    }

    fn active(&self, c: usize, now: Instant) -> bool {
        self.running[c] > 0
            || self.waiting[c] > 0
            || self.last_end[c].is_some_and(|t| now.saturating_duration_since(t) <= self.hold)
    }

    /// A new scheduler's id.
    pub fn register(&mut self) -> usize {
        self.clients.push(Client::default());
        self.clients.len() - 1
    }

    fn bulk_active(&self, client: usize) -> bool {
        let c = &self.clients[client];
        c.waiting_bulk > 0 || c.has_bulk
    }

    /// True when no other scheduler with bulk work waiting has had less bulk device time.
    fn least_bulk(&self, client: usize) -> bool {
        let mine = self.clients[client].bulk_used;
        self.clients
            .iter()
            .enumerate()
            .all(|(i, c)| i == client || c.waiting_bulk == 0 || c.bulk_used >= mine)
    }

    /// Registers a pass of `class` from scheduler `client` that wants the device at `now`;
    /// `has_bulk`: the scheduler has bulk work queued. A class, or a scheduler's bulk work,
    /// coming back from idle starts level with the others.
    pub fn arrive(&mut self, client: usize, class: Priority, has_bulk: bool, now: Instant) {
        let c = idx(class);
        if !self.active(c, now) {
            self.used[c] = self.used[c].max(self.used[1 - c]);
        }
        let has_bulk = has_bulk || class == Priority::Bulk;
        if has_bulk && !self.bulk_active(client) {
            let level = (0..self.clients.len())
                .filter(|&i| i != client && self.bulk_active(i))
                .map(|i| self.clients[i].bulk_used)
                .min_by(f64::total_cmp);
            if let Some(l) = level {
                let mine = &mut self.clients[client].bulk_used;
                *mine = mine.max(l);
            }
        }
        self.clients[client].has_bulk = has_bulk;
        if class == Priority::Bulk {
            self.clients[client].waiting_bulk += 1;
        }
        self.waiting[c] += 1;
    }

    /// True when an interactive pass of scheduler `client` starting now may take bulk steps
    /// along: no other scheduler's waiting bulk work has had less device time.
    pub fn bulk_allowed(&self, client: usize) -> bool {
        self.least_bulk(client)
    }

    /// True when a waiting pass of `class` from scheduler `client` may start at `now`.
    pub fn may_start(&self, client: usize, class: Priority, now: Instant) -> bool {
        match class {
            Priority::Interactive => {
                self.running[1] == 0 && !(self.waiting[1] > 0 && self.bulk_turn())
            }
            Priority::Bulk => {
                let held = self.held_until.is_some_and(|t| now < t);
                self.running == [0, 0]
                    && (self.bulk_turn() || (self.waiting[0] == 0 && !held))
                    && self.least_bulk(client)
            }
        }
    }

    /// When a bulk pass that may not start now could start without any other event: the end
    /// of the hold.
    pub fn hold_ends(&self) -> Option<Instant> {
        self.held_until
    }

    /// A waiting pass of `class` from scheduler `client` starts.
    pub fn start(&mut self, client: usize, class: Priority) {
        let c = idx(class);
        if class == Priority::Bulk {
            let w = &mut self.clients[client].waiting_bulk;
            *w = w.saturating_sub(1);
        }
        self.waiting[c] = self.waiting[c].saturating_sub(1);
        self.running[c] += 1;
    }

    /// A pass of `class` from scheduler `client` that started ends at `now` after `seconds`
    /// on the device, of which the fraction `bulk_part` went to bulk steps (the rest to
    /// interactive ones). `streams_back`: interactive streams of the pass announced another
    /// step.
    pub fn finish(
        &mut self,
        client: usize,
        class: Priority,
        seconds: f64,
        bulk_part: f64,
        streams_back: bool,
        now: Instant,
    ) {
        let c = idx(class);
        self.running[c] = self.running[c].saturating_sub(1);
        let b = bulk_part.clamp(0.0, 1.0);
        self.used[0] += seconds * (1.0 - b) / self.weight[0];
        self.used[1] += seconds * b / self.weight[1];
        self.clients[client].bulk_used += seconds * b;
        self.last_end[c] = Some(now);
        if class == Priority::Interactive {
            self.held_until = streams_back.then(|| now + self.hold);
        }
    }
}

/// The device gate shared by an engine's schedulers (see the module documentation).
#[derive(Debug)]
pub struct PassGate {
    state: Mutex<GateState>,
    cv: Condvar,
}

/// A pass holding the device; give it back with [`GatePass::finish`] (dropping it finishes
/// it as a pass of no time).
#[derive(Debug)]
pub struct GatePass<'a> {
    gate: &'a PassGate,
    client: usize,
    class: Priority,
    bulk_allowed: bool,
    done: bool,
}

impl PassGate {
    /// A gate giving bulk work `bulk_share` of the device while both classes wait, keeping it
    /// `hold` for interactive streams expected back (the scheduler's queue delay).
    pub fn new(bulk_share: f64, hold: Duration) -> PassGate {
        PassGate {
            state: Mutex::new(GateState::new(bulk_share, hold)),
            cv: Condvar::new(),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, GateState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A new scheduler's id for [`PassGate::acquire`].
    pub fn register(&self) -> usize {
        self.lock().register()
    }

    /// Waits until a pass of `class` from scheduler `client` may run, then holds the device
    /// for it; `has_bulk`: the scheduler has bulk work queued.
    pub fn acquire(&self, client: usize, class: Priority, has_bulk: bool) -> GatePass<'_> {
        let mut s = self.lock();
        s.arrive(client, class, has_bulk, Instant::now());
        loop {
            let now = Instant::now();
            if s.may_start(client, class, now) {
                break;
            }
            // A bulk pass held back only by the hold must look again when the hold ends.
            let wait = s
                .hold_ends()
                .filter(|t| *t > now)
                .map_or(Duration::from_millis(50), |t| t - now);
            s = match self.cv.wait_timeout(s, wait) {
                Ok((g, _)) => g,
                Err(p) => p.into_inner().0,
            };
        }
        s.start(client, class);
        GatePass {
            gate: self,
            client,
            class,
            bulk_allowed: class == Priority::Bulk || s.bulk_allowed(client),
            done: false,
        }
    }
}

impl GatePass<'_> {
    /// True when the pass may hold bulk steps: a bulk pass, or an interactive pass of a
    /// scheduler whose bulk work has had no more device time than any other's that waits.
    pub fn bulk_allowed(&self) -> bool {
        self.bulk_allowed
    }

    /// Gives the device back: the pass took `elapsed`, `bulk_part` of it for bulk steps;
    /// `streams_back`: its interactive streams announced another step.
    pub fn finish(mut self, elapsed: Duration, bulk_part: f64, streams_back: bool) {
        self.release(elapsed, bulk_part, streams_back);
    }

    fn release(&mut self, elapsed: Duration, bulk_part: f64, streams_back: bool) {
        if self.done {
            return;
        }
        self.done = true;
        let mut s = self.gate.lock();
        s.finish(
            self.client,
            self.class,
            elapsed.as_secs_f64(),
            bulk_part,
            streams_back,
            Instant::now(),
        );
        tracing::trace!(
            client = self.client,
            class = self.class.as_str(),
            ms = elapsed.as_secs_f64() * 1e3,
            bulk_part,
            used = ?s.used,
            bulk_used = ?s.clients.iter().map(|c| c.bulk_used).collect::<Vec<_>>(),
            waiting = ?s.waiting,
            "pass done"
        );
        drop(s);
        self.gate.cv.notify_all();
    }
}

impl Drop for GatePass<'_> {
    fn drop(&mut self) {
        self.release(Duration::ZERO, 0.0, false);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HOLD: Duration = Duration::from_millis(3);
    const I: Priority = Priority::Interactive;
    const B: Priority = Priority::Bulk;

    fn ms(t0: Instant, ms: u64) -> Instant {
        t0 + Duration::from_millis(ms)
    }

    #[test]
    fn a_bulk_pass_never_runs_beside_an_interactive_one() {
        let t0 = Instant::now();
        let mut g = GateState::new(0.25, HOLD);
        g.register();
        g.arrive(0, I, false, t0);
        g.arrive(0, I, false, t0);
        // Interactive passes of two models may run together.
        assert!(g.may_start(0, I, t0));
        g.start(0, I);
        assert!(g.may_start(0, I, t0));
        g.start(0, I);
        g.arrive(0, B, true, t0);
        assert!(!g.may_start(0, B, t0));
        g.finish(0, I, 0.01, 0.0, false, ms(t0, 10));
        assert!(!g.may_start(0, B, ms(t0, 10)));
        g.finish(0, I, 0.01, 0.0, false, ms(t0, 11));
        // Bulk has had nothing: its turn.
        assert!(g.may_start(0, B, ms(t0, 11)));
        g.start(0, B);
        g.arrive(0, I, false, ms(t0, 12));
        assert!(!g.may_start(0, I, ms(t0, 12)));
        g.finish(0, B, 0.005, 1.0, false, ms(t0, 16));
        assert!(g.may_start(0, I, ms(t0, 16)));
    }

    #[test]
    fn while_both_wait_bulk_gets_its_share_of_device_time() {
        let t0 = Instant::now();
        let mut g = GateState::new(0.25, HOLD);
        g.register();
        let (mut time, mut seconds) = (0u64, [0.0f64; 2]);
        g.arrive(0, I, false, t0);
        g.arrive(0, B, true, t0);
        for _ in 0..200 {
            let now = ms(t0, time);
            let (i, b) = (g.may_start(0, I, now), g.may_start(0, B, now));
            // Exactly one class may go when the device is free.
            assert!(i ^ b);
            let class = if i { I } else { B };
            g.start(0, class);
            // Bulk passes take 6 ms, interactive ones 10 ms.
            let took = if i { 10 } else { 6 };
            time += took;
            let end = ms(t0, time);
            g.finish(
                0,
                class,
                took as f64 / 1e3,
                f64::from(u8::from(!i)),
                true,
                end,
            );
            seconds[usize::from(!i)] += took as f64;
            g.arrive(0, class, true, end);
        }
        let bulk = seconds[1] / (seconds[0] + seconds[1]);
        assert!((0.24..=0.26).contains(&bulk), "bulk share {bulk}");
    }

    #[test]
    fn the_device_is_kept_for_interactive_streams_coming_back_unless_bulk_is_behind() {
        let t0 = Instant::now();
        let mut g = GateState::new(0.25, HOLD);
        g.register();
        // Bulk ran alone for 10 ms.
        g.arrive(0, B, true, t0);
        g.start(0, B);
        g.finish(0, B, 0.01, 1.0, false, ms(t0, 10));
        // Interactive comes back from idle level with bulk, runs a pass whose streams will
        // come back.
        g.arrive(0, I, false, ms(t0, 20));
        assert!(g.may_start(0, I, ms(t0, 20)));
        g.start(0, I);
        g.finish(0, I, 0.01, 0.0, true, ms(t0, 30));
        // Bulk arrives after an idle spell: level with interactive, not behind it, so it
        // waits for the hold to end.
        g.arrive(0, B, true, ms(t0, 31));
        assert!(!g.may_start(0, B, ms(t0, 31)));
        assert_eq!(g.hold_ends(), Some(ms(t0, 30) + HOLD));
        assert!(g.may_start(0, B, ms(t0, 30) + HOLD));
        // A returning stream within the hold goes first.
        g.arrive(0, I, false, ms(t0, 32));
        assert!(g.may_start(0, I, ms(t0, 32)));
        g.start(0, I);
        g.finish(0, I, 0.01, 0.0, true, ms(t0, 42));
        // Now bulk is behind its share: it goes even within the hold.
        assert!(g.may_start(0, B, ms(t0, 43)));
    }

    #[test]
    fn a_class_back_from_idle_banks_nothing() {
        let t0 = Instant::now();
        let mut g = GateState::new(0.25, HOLD);
        g.register();
        // Bulk alone for a second.
        for k in 0..100 {
            g.arrive(0, B, true, ms(t0, 10 * k));
            assert!(g.may_start(0, B, ms(t0, 10 * k)));
            g.start(0, B);
            g.finish(0, B, 0.01, 1.0, false, ms(t0, 10 * k + 10));
        }
        // Interactive arrives with bulk waiting: it does not have to wait for bulk's past
        // second to be paid back, and bulk does not lose its turn for good either.
        g.arrive(0, B, true, ms(t0, 1000));
        g.arrive(0, I, false, ms(t0, 1000));
        assert!(g.may_start(0, I, ms(t0, 1000)));
        g.start(0, I);
        g.finish(0, I, 0.01, 0.0, false, ms(t0, 1010));
        g.arrive(0, I, false, ms(t0, 1010));
        assert!(g.may_start(0, B, ms(t0, 1010)));
    }

    #[test]
    fn schedulers_share_the_bulk_class_by_device_time() {
        let t0 = Instant::now();
        let mut g = GateState::new(0.25, HOLD);
        let (rigid, physi) = (g.register(), g.register());
        // The rigid scheduler's interactive passes carry bulk steps along (a quarter of
        // each pass) while the other scheduler's bulk pass waits.
        g.arrive(physi, B, true, t0);
        g.arrive(rigid, I, true, t0);
        assert!(g.may_start(rigid, I, t0));
        g.start(rigid, I);
        assert!(g.bulk_allowed(rigid));
        g.finish(rigid, I, 0.02, 0.25, true, ms(t0, 20));
        // Its bulk steps have had 5 ms, the waiting scheduler's none: the next interactive
        // pass takes no bulk steps along, and the waiting bulk pass goes once bulk is
        // behind its share.
        g.arrive(rigid, I, true, ms(t0, 21));
        assert!(!g.bulk_allowed(rigid));
        assert!(g.may_start(rigid, I, ms(t0, 21)));
        g.start(rigid, I);
        g.finish(rigid, I, 0.02, 0.0, true, ms(t0, 41));
        assert!(g.may_start(physi, B, ms(t0, 42)));
        g.start(physi, B);
        g.finish(physi, B, 0.013, 1.0, false, ms(t0, 55));
        // Now the waiting scheduler has had more: the rigid one may carry bulk again.
        g.arrive(physi, B, true, ms(t0, 55));
        assert!(g.bulk_allowed(rigid));
        // Of two schedulers' waiting bulk passes, the one whose bulk work has had less device
        // time goes first; one bulk pass runs at a time.
        g.arrive(rigid, B, true, ms(t0, 56));
        assert!(g.may_start(rigid, B, ms(t0, 60)));
        assert!(!g.may_start(physi, B, ms(t0, 60)));
        g.start(rigid, B);
        g.finish(rigid, B, 0.01, 1.0, false, ms(t0, 70));
        g.arrive(rigid, B, true, ms(t0, 70));
        assert!(g.may_start(physi, B, ms(t0, 70)));
        assert!(!g.may_start(rigid, B, ms(t0, 70)));
    }

    #[test]
    fn a_scheduler_back_with_bulk_work_banks_nothing_from_its_idle_spell() {
        let t0 = Instant::now();
        let mut g = GateState::new(0.25, HOLD);
        let (rigid, physi) = (g.register(), g.register());
        // Only the PhysiFormer scheduler has bulk work, for 100 ms of bulk passes.
        for k in 0..10 {
            g.arrive(physi, B, true, ms(t0, 10 * k));
            g.start(physi, B);
            g.finish(physi, B, 0.01, 1.0, false, ms(t0, 10 * k + 10));
        }
        g.arrive(physi, B, true, ms(t0, 100));
        // The rigid scheduler gets bulk work: it starts level with the other, so after one
        // interactive pass carrying bulk steps it is ahead and carries none until the other
        // has had its turn (without levelling it would carry bulk for the next 100 ms).
        g.arrive(rigid, I, true, ms(t0, 100));
        assert!(g.bulk_allowed(rigid));
        g.start(rigid, I);
        g.finish(rigid, I, 0.02, 0.25, true, ms(t0, 120));
        g.arrive(rigid, I, true, ms(t0, 121));
        assert!(!g.bulk_allowed(rigid));
    }

    #[test]
    fn passes_through_the_shared_gate_take_turns_across_threads() {
        let gate = std::sync::Arc::new(PassGate::new(0.5, HOLD));
        let log = std::sync::Arc::new(Mutex::new(Vec::new()));
        let threads: Vec<_> = [I, B, I]
            .into_iter()
            .map(|class| {
                let (gate, log) = (gate.clone(), log.clone());
                std::thread::spawn(move || {
                    let me = gate.register();
                    for _ in 0..20 {
                        let pass = gate.acquire(me, class, class == B);
                        log.lock().unwrap().push((class, true));
                        std::thread::yield_now();
                        log.lock().unwrap().push((class, false));
                        pass.finish(Duration::from_micros(100), 0.0, false);
                    }
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
        // Replaying the log: a bulk pass never overlapped another pass.
        let (mut running, mut bulk) = (0i32, 0i32);
        for (class, start) in log.lock().unwrap().iter() {
            let d = if *start { 1 } else { -1 };
            running += d;
            if *class == B {
                bulk += d;
            }
            assert!(bulk == 0 || running == 1, "bulk beside another pass");
        }
    }
}
