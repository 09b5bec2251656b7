//! The same load run through `dynaserve_model` directly, with no server: scenes are validated
//! and built exactly as the server builds them (`dynaserve_server::families::built_scene`,
//! under the server's default caps), prepared, and stepped in lockstep, every round split into
//! forward passes by the one batching rule (`dynaserve_model::PassBudget`: scene cap and
//! object budget, FIFO), as the server's scheduler forms passes when every stream is waiting.
//! Comparing this with a server run of the same scenes gives the server's overhead.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use dynaserve_api::json;
use dynaserve_api::limits::{Caps, Limits};
use dynaserve_api::spec::Scene;
use dynaserve_model::rigidformer::DEFAULT_MAX_PASS_OBJECTS;
use dynaserve_model::{PassBudget, PreparedScene, SceneState, StepItem, WorldModel};
use dynaserve_server::engine::admission::check_steps;
use dynaserve_server::families::built_scene::build_scene;

use crate::recorder::{Recorder, RequestClock, ServerTiming};
use crate::transport::CallError;

/// A model loaded in this process with the server's batching limits.
pub struct InProcess {
    model: Arc<dyn WorldModel>,
    limits: Limits,
    budget: PassBudget,
}

struct Slot {
    scene_index: usize,
    scene: Arc<PreparedScene>,
    state: SceneState,
    objects: usize,
    done: u32,
    clock: RequestClock,
    active: bool,
}

fn model_error(e: impl std::fmt::Display) -> CallError {
    CallError::new("inprocess model", e.to_string())
}

impl InProcess {
    /// Loads a checkpoint directory on the CPU, with the server's default request limits and
    /// the given batching limits.
    pub fn load(
        dir: &Path,
        max_batch_scenes: usize,
        max_batch_objects: usize,
    ) -> anyhow::Result<InProcess> {
        let model = dynaserve_model::load_model(dir, &dynaserve_model::Device::Cpu)
            .map_err(|e| anyhow::anyhow!("loading model {}: {e}", dir.display()))?;
        Ok(InProcess::new(model, max_batch_scenes, max_batch_objects))
    }

    /// Wraps an already loaded model.
    pub fn new(
        model: Arc<dyn WorldModel>,
        max_batch_scenes: usize,
        max_batch_objects: usize,
    ) -> InProcess {
        let limits = Limits::new(&Caps::DEFAULT, model.config());
        InProcess {
            model,
            limits,
            // The server's rule: whole forwards of the RigidFormer's pass size.
            budget: PassBudget {
                max_scenes: max_batch_scenes,
                max_objects: max_batch_objects,
            }
            .in_whole_forwards(Some(DEFAULT_MAX_PASS_OBJECTS)),
        }
    }

    /// The model's name.
    pub fn name(&self) -> &str {
        self.model.name()
    }

    fn prepare(
        &self,
        scene: &json::Scene,
        dt_steps: u32,
    ) -> Result<(Arc<PreparedScene>, SceneState), CallError> {
        let dt = dt_steps as f32 * self.model.config().dt_frame;
        let built = Scene::from_json(scene, "scene")
            .and_then(|s| build_scene(&s, "scene", &self.limits, dt))
            .map_err(|e| CallError::new("inprocess invalid", e.to_string()))?;
        let prepared = self.model.prepare(built.objects).map_err(model_error)?;
        Ok((Arc::new(prepared), built.state))
    }

    fn open(
        &self,
        scene_index: usize,
        scene: &json::Scene,
        dt_steps: u32,
    ) -> Result<Slot, CallError> {
        let clock = RequestClock::start();
        let (prepared, state) = self.prepare(scene, dt_steps)?;
        Ok(Slot {
            scene_index,
            objects: prepared.len(),
            scene: prepared,
            state,
            done: 0,
            clock,
            active: true,
        })
    }

    /// One forward pass per batch of `slots` (in order); returns per slot its new poses, the
    /// time the pass finished, its duration and its size.
    fn step_round(
        &self,
        slots: &mut [&mut Slot],
        dt_steps: u32,
    ) -> Result<Vec<(Instant, ServerTiming)>, CallError> {
        let objects: Vec<usize> = slots.iter().map(|s| s.objects).collect();
        let mut out = Vec::with_capacity(slots.len());
        let round_start = Instant::now();
        for range in self.budget.plan(&objects) {
            let queued = round_start.elapsed();
            let t = Instant::now();
            let items: Vec<StepItem<'_>> = slots[range.clone()]
                .iter()
                .map(|s| StepItem {
                    scene: &s.scene,
                    state: &s.state,
                    dt_steps,
                })
                .collect();
            let poses = self.model.step(&items).map_err(model_error)?;
            drop(items);
            let done = Instant::now();
            if poses.len() != range.len() {
                return Err(model_error("the model returned a wrong number of scenes"));
            }
            let timing = ServerTiming {
                queue_ms: queued.as_secs_f64() * 1e3,
                forward_ms: (done - t).as_secs_f64() * 1e3,
                batch_scenes: range.len() as u32,
            };
            for (slot, p) in slots[range].iter_mut().zip(poses) {
                slot.state.advance(p);
                out.push((done, timing));
            }
        }
        Ok(out)
    }

    /// `scenes.len()` concurrent rollouts of `steps` steps each, stepped in lockstep. With a
    /// `deadline`, a finished rollout starts again on the same scene until the deadline, and
    /// rollouts running at the deadline are cut. `stop` ends the run early.
    pub fn run_streams(
        &self,
        scenes: &[json::Scene],
        steps: u32,
        dt_steps: u32,
        deadline: Option<Instant>,
        stop: &AtomicBool,
        rec: &Mutex<Recorder>,
    ) {
        let lock = || rec.lock().unwrap_or_else(|p| p.into_inner());
        if let Err(e) = check_steps(steps, dt_steps, &self.limits) {
            let e = CallError::new("inprocess invalid", e.to_string());
            let mut r = lock();
            for _ in scenes {
                r.started();
                r.failed(&e);
            }
            return;
        }
        let mut slots: Vec<Slot> = Vec::with_capacity(scenes.len());
        for (i, s) in scenes.iter().enumerate() {
            lock().started();
            match self.open(i, s, dt_steps) {
                Ok(slot) => slots.push(slot),
                Err(e) => lock().failed(&e),
            }
        }
        loop {
            if stop.load(Ordering::SeqCst) || deadline.is_some_and(|d| Instant::now() >= d) {
                return;
            }
            let mut active: Vec<&mut Slot> = slots.iter_mut().filter(|s| s.active).collect();
            if active.is_empty() {
                return;
            }
            let results = match self.step_round(&mut active, dt_steps) {
                Ok(r) => r,
                Err(e) => {
                    let mut r = lock();
                    for s in active.iter_mut() {
                        r.failed(&e);
                        s.active = false;
                    }
                    continue;
                }
            };
            let mut restart = Vec::new();
            {
                let mut r = lock();
                for (s, (at, timing)) in active.iter_mut().zip(results) {
                    s.done += 1;
                    r.frame(&mut s.clock, at, s.objects, Some(timing));
                    if s.done >= steps {
                        r.rollout_ok(&s.clock, at);
                        s.active = false;
                        if deadline.is_some() {
                            restart.push(s.scene_index);
                        }
                    }
                }
            }
            for i in restart {
                if deadline.is_some_and(|d| Instant::now() >= d) || stop.load(Ordering::SeqCst) {
                    break;
                }
                lock().started();
                match self.open(i, &scenes[i], dt_steps) {
                    Ok(slot) => {
                        if let Some(old) = slots.iter_mut().find(|s| s.scene_index == i) {
                            *old = slot;
                        }
                    }
                    Err(e) => lock().failed(&e),
                }
            }
        }
    }

    /// `calls` planner calls one after another, each rolling `variants` forward `steps` steps
    /// in lockstep under the batching limits; `every` as in `PredictRequest` (0: final only).
    #[allow(clippy::too_many_arguments)]
    pub fn run_predict(
        &self,
        variants: &[json::Scene],
        steps: u32,
        dt_steps: u32,
        every: u32,
        calls: usize,
        stop: &AtomicBool,
        rec: &Mutex<Recorder>,
    ) {
        let lock = || rec.lock().unwrap_or_else(|p| p.into_inner());
        for _ in 0..calls {
            if stop.load(Ordering::SeqCst) {
                return;
            }
            lock().started();
            let clock = RequestClock::start();
            let result = (|| -> Result<(u64, u64, f64, f64), CallError> {
                check_steps(steps, dt_steps, &self.limits)
                    .map_err(|e| CallError::new("inprocess invalid", e.to_string()))?;
                let mut slots = variants
                    .iter()
                    .enumerate()
                    .map(|(i, s)| self.open(i, s, dt_steps))
                    .collect::<Result<Vec<_>, _>>()?;
                let prepared_at = Instant::now();
                let mut forward = 0.0;
                for _ in 0..steps {
                    if stop.load(Ordering::SeqCst) {
                        return Err(CallError::new("interrupted", "stopped"));
                    }
                    let mut all: Vec<&mut Slot> = slots.iter_mut().collect();
                    let t = self.step_round(&mut all, dt_steps)?;
                    // Sum of the distinct passes of this round.
                    let mut last = None;
                    for (at, timing) in t {
                        if last != Some(at) {
                            forward += timing.forward_ms;
                            last = Some(at);
                        }
                    }
                }
                let objects: u64 = slots.iter().map(|s| s.objects as u64).sum();
                let frames_per = match steps.checked_div(every) {
                    None => 1,
                    Some(q) => u64::from(q) + u64::from(!steps.is_multiple_of(every)),
                };
                let queue = (prepared_at - clock.start).as_secs_f64() * 1e3;
                Ok((frames_per * slots.len() as u64, objects, queue, forward))
            })();
            let at = Instant::now();
            match result {
                Ok((frames, objects, queue_ms, forward_ms)) => lock().predict_ok(
                    &clock,
                    at,
                    frames,
                    variants.len() as u64 * u64::from(steps),
                    objects * u64::from(steps),
                    ServerTiming {
                        queue_ms,
                        forward_ms,
                        batch_scenes: 0,
                    },
                ),
                Err(e) if e.code == "interrupted" => return,
                Err(e) => lock().failed(&e),
            }
        }
    }
}
