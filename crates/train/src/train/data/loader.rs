//! The loader: a worker thread that draws and prepares the samples of each batch and hands the
//! batches to the trainer through a bounded channel.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use dynaserve_model::{Pose, PreparedScene, SceneState, WorldModel};
use dynaserve_sim::SceneRecord;

use super::sample_order::SampleOrder;
use super::seed::rng_for;
use super::sources::Sources;
use super::window::sample_window;
use crate::train::TrainError;
use crate::train::config::DataConfig;

/// One prepared training sample.
pub struct Sample {
    /// The scene prepared by the model (anchors, grouping).
    pub scene: PreparedScene,
    /// Observed poses.
    pub state: SceneState,
    /// Ground-truth poses `dt_steps` frames after `state.current`.
    pub target: Vec<Pose>,
    /// Step size in frames.
    pub dt_steps: u32,
    /// Kinematic objects `[objects]`: inputs only, not learned.
    pub kinematic: Vec<bool>,
    /// Recorded poses at `t - (n + 1) dt_steps, ..., t - dt_steps` of a pushforward sample
    /// ([`Window::pushforward`](super::Window::pushforward)).
    pub pushforward: Option<Vec<Vec<Pose>>>,
}

/// A batch of samples for iteration `step`.
pub struct Batch {
    /// Iteration (0-based) this batch belongs to.
    pub step: u64,
    /// The samples.
    pub samples: Vec<Sample>,
}

/// The loader: a worker thread producing batches from iteration `start` on.
pub struct Loader {
    rx: Mutex<Receiver<Result<Batch, TrainError>>>,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
}

impl Loader {
    /// Starts the worker. `model` prepares scenes (anchors, grouping); `seed` fixes the stream;
    /// `threads` samples of a batch are drawn and prepared at once (the batches do not depend
    /// on it).
    pub fn start(
        reader: Sources,
        cfg: DataConfig,
        batch_size: usize,
        seed: u64,
        start: u64,
        model: Arc<dyn WorldModel>,
        threads: usize,
    ) -> Result<Loader, TrainError> {
        if let Some(empty) = reader.readers().iter().find(|r| r.is_empty()) {
            return Err(TrainError::Data(format!(
                "{} holds no scenes",
                empty.dir().display()
            )));
        }
        let order = SampleOrder::new(&reader, &cfg.mix, seed)?;
        // A pool only for more than one thread: one keeps the loader thread's own sequence.
        let pool = if threads > 1 {
            Some(
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .thread_name(|i| format!("train-loader-{i}"))
                    .build()
                    .map_err(|e| TrainError::Data(format!("cannot start the loader pool: {e}")))?,
            )
        } else {
            None
        };
        let (tx, rx) = sync_channel(cfg.prefetch);
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let handle = std::thread::Builder::new()
            .name("train-loader".into())
            .spawn(move || {
                worker(
                    reader, cfg, batch_size, seed, start, model, order, pool, tx, stop2,
                )
            })
            .map_err(|e| TrainError::Data(format!("cannot start the loader thread: {e}")))?;
        Ok(Loader {
            rx: Mutex::new(rx),
            stop,
            handle: Some(handle),
        })
    }

    /// The next batch (blocks until the worker has one).
    pub fn next(&self) -> Result<Batch, TrainError> {
        self.rx
            .lock()
            .map_err(|_| TrainError::Data("loader channel lock poisoned".into()))?
            .recv()
            .map_err(|_| TrainError::Data("the loader thread ended unexpectedly".into()))?
    }
}

impl Drop for Loader {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        // Drain so a worker blocked on a full channel can notice the stop flag.
        if let Ok(rx) = self.rx.lock() {
            while rx.try_recv().is_ok() {}
        }
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn worker(
    reader: Sources,
    cfg: DataConfig,
    batch_size: usize,
    seed: u64,
    start: u64,
    model: Arc<dyn WorldModel>,
    mut order: SampleOrder,
    pool: Option<rayon::ThreadPool>,
    tx: SyncSender<Result<Batch, TrainError>>,
    stop: Arc<AtomicBool>,
) {
    // Decoded shards by global index with the sample that last used them: two per
    // directory, so a mixed stream keeps each directory's current and next shard.
    let capacity = 2 * reader.readers().len();
    let mut cache: HashMap<usize, (Arc<Vec<SceneRecord>>, u64)> = HashMap::new();
    let mut step = start;
    while !stop.load(Ordering::Relaxed) {
        let mut make = || -> Result<Batch, TrainError> {
            // The batch's scenes, in order (shard reads and the cache stay on this thread).
            let mut scenes = Vec::with_capacity(batch_size);
            for j in 0..batch_size {
                let g = step * batch_size as u64 + j as u64;
                let (shard, local) = order.locate(g);
                if !cache.contains_key(&shard) {
                    if cache.len() >= capacity
                        && let Some(&oldest) = cache.iter().min_by_key(|e| e.1.1).map(|e| e.0)
                    {
                        cache.remove(&oldest);
                    }
                    cache.insert(shard, (Arc::new(reader.read_shard(shard)?), g));
                }
                let entry = cache.get_mut(&shard).expect("inserted above");
                entry.1 = g;
                if entry.0.get(local).is_none() {
                    return Err(TrainError::Data(format!(
                        "shard {shard} has no scene {local}"
                    )));
                }
                scenes.push((g, shard, local, entry.0.clone()));
            }
            // Each sample is a function of its index alone, so any number of threads draws
            // the same batch.
            let draw = |(g, shard, local, records): &(u64, usize, usize, Arc<Vec<SceneRecord>>)| {
                let rec = &records[*local];
                let mut rng = rng_for(seed, 3, *g);
                let w = sample_window(
                    rec,
                    &cfg,
                    &mut rng,
                    true,
                    ((*shard as u64) << 32) | *local as u64,
                )?;
                let scene = model.prepare(w.objects)?;
                Ok(Sample {
                    scene,
                    state: w.state,
                    target: w.target,
                    dt_steps: w.dt_steps,
                    kinematic: w.kinematic,
                    pushforward: w.pushforward,
                })
            };
            let samples = match &pool {
                Some(pool) => {
                    use rayon::prelude::*;
                    pool.install(|| scenes.par_iter().map(draw).collect::<Result<Vec<_>, _>>())?
                }
                None => scenes
                    .iter()
                    .map(draw)
                    .collect::<Result<Vec<_>, TrainError>>()?,
            };
            Ok(Batch { step, samples })
        };
        let mut item = make();
        let failed = item.is_err();
        // Bounded send that still notices the stop flag.
        loop {
            match tx.try_send(item) {
                Ok(()) => break,
                Err(TrySendError::Full(back)) => {
                    if stop.load(Ordering::Relaxed) {
                        return;
                    }
                    item = back;
                    std::thread::sleep(Duration::from_millis(5));
                }
                Err(TrySendError::Disconnected(_)) => return,
            }
        }
        if failed {
            return;
        }
        step += 1;
    }
}
