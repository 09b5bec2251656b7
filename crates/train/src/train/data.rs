//! Streaming training data: a worker thread reads dataset shards, draws one-step windows with
//! augmentation, prepares the scenes for the model and hands whole batches to the trainer
//! through a bounded channel.
//!
//! The sample stream is a pure function of `(run seed, global sample index)`: epoch `e` visits
//! the shards in a seeded random order and the scenes of each shard in a seeded random order,
//! and sample `g` draws its window and augmentation from a generator seeded with `(seed, g)`.
//! With [`DataConfig::mix`] set, sample `g` first draws its directory from the shares (a
//! generator seeded with `(seed, g)`) and then takes that directory's next scene in the
//! directory's own epoch order, so batches mix the directories.
//! Resuming at iteration `s` therefore restarts the stream at sample `s * batch_size` and
//! reproduces exactly the batches an uninterrupted run would have seen.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use dynaserve_model::{Body, FeatureFrame, ScenePoints, body_normals, object_params};
use dynaserve_model::{
    FeatureNormalization, ModelConfig, ObjectInput, Pose, PreparedScene, SceneState, WorldModel,
};
use dynaserve_sim::{DatasetReader, SceneRecord};
use nalgebra::{UnitQuaternion, Vector3};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::TrainError;
use super::config::DataConfig;

/// One raw training window (before model preparation).
#[derive(Clone, Debug)]
pub struct Window {
    /// Objects with their (sub-sampled) body-frame clouds and parameters.
    pub objects: Vec<ObjectInput>,
    /// Observed poses at `t - dt_steps` and `t` (possibly noised), and at `t - 2 dt_steps`
    /// with [`DataConfig::history`].
    pub state: SceneState,
    /// Ground-truth poses at `t + dt_steps`.
    pub target: Vec<Pose>,
    /// Step size in frames.
    pub dt_steps: u32,
    /// Kinematic objects `[objects]` (in `objects` order): inputs only, not learned.
    pub kinematic: Vec<bool>,
    /// For a pushforward sample (`DataConfig::pushforward`), the recorded (not noised) poses
    /// at `t - (n + 1) dt_steps, ..., t - dt_steps` (`n` = `pushforward_steps`), each
    /// `[objects]`: the trainer replaces the observed poses by the model's steps from them.
    pub pushforward: Option<Vec<Vec<Pose>>>,
}

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
    /// ([`Window::pushforward`]).
    pub pushforward: Option<Vec<Vec<Pose>>>,
}

/// A batch of samples for iteration `step`.
pub struct Batch {
    /// Iteration (0-based) this batch belongs to.
    pub step: u64,
    /// The samples.
    pub samples: Vec<Sample>,
}

/// SplitMix64 finaliser: decorrelates seeds built from small integers.
pub fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

fn rng_for(seed: u64, stream: u64, index: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(mix(mix(seed ^ mix(stream)) ^ index))
}

/// Random unit quaternion of angle `~ N(0, sigma)` about a random axis.
fn small_rotation(rng: &mut impl Rng, sigma: f32) -> UnitQuaternion<f32> {
    let axis = Vector3::new(
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
    );
    let n: f32 = axis.norm();
    if n < 1e-6 || sigma == 0.0 {
        return UnitQuaternion::identity();
    }
    let angle: f32 = StandardNormal.sample(rng);
    UnitQuaternion::from_scaled_axis(axis / n * (angle * sigma))
}

/// The reflection x -> -x of a point or position `[3]`, metres.
pub fn mirror_point(p: [f32; 3]) -> [f32; 3] {
    [-p[0], p[1], p[2]]
}

/// The orientation `M R M` (M = diag(-1, 1, 1)) of a body whose reference cloud and position
/// are reflected by [`mirror_point`]: with it, the reflected body's world points are the
/// reflections of the original's. A proper rotation (the quaternion's y and z parts negated),
/// so the reflected scene is again a rigid scene.
pub fn mirror_rotation(q: UnitQuaternion<f32>) -> UnitQuaternion<f32> {
    let q = q.into_inner();
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q.w, q.i, -q.j, -q.k))
}

fn quat(q: [f32; 4]) -> UnitQuaternion<f32> {
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[3], q[0], q[1], q[2]))
}

/// Draws one window from `scene` with the augmentation of `c` (input noise and pushforward
/// poses only if `noise`, i.e. for training batches). `scene_key` identifies the scene in its
/// dataset: with [`DataConfig::points_per_scene`] it seeds each object's point subset, so every
/// window of one scene shows the same clouds.
pub fn sample_window(
    scene: &SceneRecord,
    c: &DataConfig,
    rng: &mut ChaCha8Rng,
    noise: bool,
    scene_key: u64,
) -> Result<Window, TrainError> {
    let frames = scene
        .objects
        .first()
        .map(|o| o.positions.len())
        .unwrap_or(0);
    if scene.objects.is_empty() || frames < 3 {
        return Err(TrainError::Data(format!(
            "a scene with {} objects and {frames} frames cannot give a training window",
            scene.objects.len()
        )));
    }
    let valid: Vec<u32> = c
        .step_sizes
        .iter()
        .copied()
        .filter(|&k| 2 * (k as usize) < frames)
        .collect();
    let k = if valid.is_empty() {
        ((frames - 1) / 2) as u32
    } else {
        valid[rng.random_range(0..valid.len())]
    };
    let ku = k as usize;
    // The event draw happens only when enabled, so configurations without it keep their
    // sample streams.
    let weighted = noise && c.event_share > 0.0 && rng.random::<f32>() < c.event_share;
    // Likewise the stop draw, among the samples the event draw leaves.
    let stopping = noise && !weighted && c.stop_share > 0.0 && rng.random::<f32>() < c.stop_share;
    let drawn = if weighted {
        super::events::draw_frame(scene, ku, rng)
    } else if stopping {
        super::stops::draw_frame(scene, ku, rng)
    } else {
        None
    };
    let t = match drawn {
        Some(t) => t,
        None => rng.random_range(ku..=frames - 1 - ku),
    };
    let mut order: Vec<usize> = (0..scene.objects.len()).collect();
    if c.shuffle_objects {
        order.shuffle(rng);
    }
    let rz = if c.rotate_z {
        UnitQuaternion::from_axis_angle(
            &Vector3::z_axis(),
            rng.random_range(0.0..std::f32::consts::TAU),
        )
    } else {
        UnitQuaternion::identity()
    };
    // Drawn only with the option, so configurations without it keep their sample streams.
    let mirrored = c.mirror && rng.random::<bool>();
    let pose_at = |o: &dynaserve_sim::ObjectRecord, f: usize| -> Pose {
        let (p, q) = if mirrored {
            (
                mirror_point(o.positions[f]),
                mirror_rotation(quat(o.rotations[f])),
            )
        } else {
            (o.positions[f], quat(o.rotations[f]))
        };
        Pose::from_parts(rz * Vector3::from(p), rz * q)
    };
    let mut objects = Vec::with_capacity(order.len());
    let mut previous = Vec::with_capacity(order.len());
    let mut current = Vec::with_capacity(order.len());
    let mut earlier = Vec::with_capacity(order.len());
    // Drawn only with the option, so configurations without it keep their sample streams.
    let with_history = c.history
        && t >= 2 * ku
        && !(noise && c.history_drop > 0.0 && rng.random::<f32>() < c.history_drop);
    let mut target = Vec::with_capacity(order.len());
    let kinematic = order.iter().map(|&j| scene.objects[j].kinematic).collect();
    for &j in &order {
        let o = &scene.objects[j];
        if o.positions.len() != frames || o.rotations.len() != frames {
            return Err(TrainError::Data(format!(
                "object {j} has {} positions and {} rotations, expected {frames}",
                o.positions.len(),
                o.rotations.len()
            )));
        }
        let p = o.reference_points.len();
        if p == 0 {
            return Err(TrainError::Data(format!(
                "object {j} has no reference points"
            )));
        }
        // The subset's own generator when it is fixed per scene; the window's otherwise (so
        // configurations without the option keep their sample streams).
        let mut scene_rng = c
            .points_per_scene
            .then(|| rng_for(mix(scene_key), 5, j as u64));
        let prng: &mut ChaCha8Rng = scene_rng.as_mut().unwrap_or(rng);
        let n = prng.random_range(c.points_min..=c.points_max).min(p);
        // Partial Fisher-Yates: a uniform subset of n points.
        let mut idx: Vec<usize> = (0..p).collect();
        for i in 0..n {
            let r = prng.random_range(i..p);
            idx.swap(i, r);
        }
        idx.truncate(n);
        let mut reference: Vec<[f32; 3]> = idx
            .iter()
            .map(|&i| {
                let p = o.reference_points[i];
                if mirrored { mirror_point(p) } else { p }
            })
            .collect();
        if c.point_drop_prob > 0.0 && rng.random::<f32>() < c.point_drop_prob && n > 1 {
            // Remove the points farthest along a random direction (a contiguous patch).
            let u = small_rotation(rng, 10.0) * Vector3::z();
            let frac = rng.random_range(0.0..=c.point_drop_max);
            let drop = ((frac * n as f32) as usize).min(n - 1);
            reference.sort_by(|a, b| {
                let (da, db) = (Vector3::from(*a).dot(&u), Vector3::from(*b).dot(&u));
                da.total_cmp(&db)
            });
            reference.truncate(n - drop);
        }
        objects.push(ObjectInput {
            reference,
            mass: o.mass,
            friction: o.friction,
            restitution: o.restitution,
            kinematic: o.kinematic,
        });
        let mut prev = pose_at(o, t - ku);
        let mut cur = pose_at(o, t);
        let mut before = with_history.then(|| pose_at(o, t - 2 * ku));
        if noise && (c.noise_position > 0.0 || c.noise_rotation > 0.0) {
            for pose in [Some(&mut prev), Some(&mut cur), before.as_mut()]
                .into_iter()
                .flatten()
            {
                let mut p = Vector3::from(pose.translation);
                for d in 0..3 {
                    let e: f32 = StandardNormal.sample(rng);
                    p[d] += e * c.noise_position;
                }
                let q = small_rotation(rng, c.noise_rotation) * pose.unit_quaternion();
                *pose = Pose::from_parts(p, q);
            }
        }
        previous.push(prev);
        current.push(cur);
        earlier.extend(before);
        target.push(pose_at(o, t + ku));
    }
    // Drawn last and only when enabled, so configurations without it keep their streams.
    let n = c.pushforward_steps.max(1) as usize;
    let pushforward =
        (noise && c.pushforward > 0.0 && t >= (n + 1) * ku && rng.random::<f32>() < c.pushforward)
            .then(|| {
                (1..=n + 1)
                    .rev()
                    .map(|back| {
                        order
                            .iter()
                            .map(|&j| pose_at(&scene.objects[j], t - back * ku))
                            .collect()
                    })
                    .collect()
            });
    Ok(Window {
        objects,
        state: SceneState {
            previous,
            current,
            earlier: with_history.then_some(earlier),
        },
        target,
        dt_steps: k,
        kinematic,
        pushforward,
    })
}

/// The training directories as one sequence of shards: the first directory's shards, then
/// each further directory's.
pub struct Sources {
    readers: Vec<DatasetReader>,
    /// `(reader, local shard)` of every global shard.
    shards: Vec<(usize, usize)>,
}

impl Sources {
    /// Opens the directories; all must share the first one's frame interval and gravity.
    pub fn open(dirs: &[std::path::PathBuf]) -> Result<Sources, TrainError> {
        let mut readers: Vec<DatasetReader> = Vec::with_capacity(dirs.len());
        for d in dirs {
            let r = DatasetReader::open(d)?;
            if let Some(first) = readers.first() {
                let (a, b) = (first.manifest(), r.manifest());
                if a.dt_frame != b.dt_frame || a.gravity != b.gravity {
                    return Err(TrainError::Data(format!(
                        "{} has dt_frame {} and gravity {:?}, but {} has {} and {:?}",
                        d.display(),
                        b.dt_frame,
                        b.gravity,
                        first.dir().display(),
                        a.dt_frame,
                        a.gravity
                    )));
                }
            }
            readers.push(r);
        }
        let shards = readers
            .iter()
            .enumerate()
            .flat_map(|(i, r)| (0..r.manifest().shards.len()).map(move |s| (i, s)))
            .collect();
        Ok(Sources { readers, shards })
    }

    /// The first directory's reader (its manifest fixes the frame interval and gravity).
    pub fn primary(&self) -> &DatasetReader {
        &self.readers[0]
    }

    /// Every reader, in order.
    pub fn readers(&self) -> &[DatasetReader] {
        &self.readers
    }

    /// The directory (0 = `train`, then each extra) that global shard `shard` belongs to.
    pub fn directory_of(&self, shard: usize) -> usize {
        self.shards[shard].0
    }

    /// Scenes per global shard.
    fn shard_sizes(&self) -> Vec<usize> {
        self.shards
            .iter()
            .map(|&(r, s)| self.readers[r].manifest().shards[s].scenes)
            .collect()
    }

    fn read_shard(&self, global: usize) -> Result<Vec<SceneRecord>, TrainError> {
        let (r, s) = self.shards[global];
        Ok(self.readers[r].read_shard(s)?)
    }
}

/// Where the stream's global sample `g` comes from: `(global shard, scene within the shard)`,
/// for [`DataConfig::mix`] unset (pooled) or set (mixed).
pub struct SampleOrder {
    kind: OrderKind,
}

enum OrderKind {
    Pooled(Order),
    Mixed(MixedOrder),
}

impl SampleOrder {
    /// The order of `sources` for `shares` ([`DataConfig::mix`]: one per directory, or empty
    /// for the pooled stream) and the run's `seed`. Shares that do not match the directories
    /// are an error ([`DataConfig::check_mix`]).
    pub fn new(sources: &Sources, shares: &[f32], seed: u64) -> Result<SampleOrder, TrainError> {
        let sizes = sources.shard_sizes();
        if shares.is_empty() {
            return Ok(SampleOrder {
                kind: OrderKind::Pooled(Order::new(sizes, seed)),
            });
        }
        DataConfig::check_mix(shares, sources.readers.len())?;
        let total: f64 = shares.iter().map(|&w| w as f64).sum();
        let mut acc = 0.0;
        let cdf = shares
            .iter()
            .map(|&w| {
                acc += w as f64 / total;
                acc
            })
            .collect();
        let mut first = 0;
        let directories = (0..sources.readers.len())
            .map(|d| {
                let n = sources.readers[d].manifest().shards.len();
                let own = Order::new(
                    sizes[first..first + n].to_vec(),
                    mix(seed ^ mix(1000 + d as u64)),
                );
                let entry = (own, first);
                first += n;
                entry
            })
            .collect();
        Ok(SampleOrder {
            kind: OrderKind::Mixed(MixedOrder {
                last: shares.iter().rposition(|&w| w > 0.0).unwrap_or(0),
                cdf,
                directories,
                drawn: vec![0; shares.len()],
                next: 0,
                seed,
            }),
        })
    }

    /// `(global shard, scene within the shard)` of sample `g`. Mixed orders count the samples
    /// each directory has given, so they are cheapest called with increasing `g`; any `g`
    /// gives the same answer.
    pub fn locate(&mut self, g: u64) -> (usize, usize) {
        match &mut self.kind {
            OrderKind::Pooled(o) => o.locate(g),
            OrderKind::Mixed(m) => m.locate(g),
        }
    }
}

/// The pooled order: epoch `e` visits all shards in a seeded order and each shard's scenes in
/// a seeded order.
struct Order {
    /// Scene count per shard.
    shard_sizes: Vec<usize>,
    total: usize,
    seed: u64,
    /// Cached epoch layout: `(epoch, shard order, cumulative starts)`.
    cached: Option<(u64, Vec<usize>, Vec<usize>)>,
    /// Cached scene order of the shard in use: `(epoch, shard, scene order)`.
    scenes: Option<(u64, usize, Vec<usize>)>,
}

impl Order {
    fn new(shard_sizes: Vec<usize>, seed: u64) -> Order {
        Order {
            total: shard_sizes.iter().sum(),
            shard_sizes,
            seed,
            cached: None,
            scenes: None,
        }
    }

    fn locate(&mut self, g: u64) -> (usize, usize) {
        let epoch = g / self.total as u64;
        let pos = (g % self.total as u64) as usize;
        if self.cached.as_ref().is_none_or(|c| c.0 != epoch) {
            let mut perm: Vec<usize> = (0..self.shard_sizes.len()).collect();
            perm.shuffle(&mut rng_for(self.seed, 1, epoch));
            let mut starts = Vec::with_capacity(perm.len() + 1);
            let mut acc = 0;
            for &s in &perm {
                starts.push(acc);
                acc += self.shard_sizes[s];
            }
            starts.push(acc);
            self.cached = Some((epoch, perm, starts));
        }
        let (_, perm, starts) = self.cached.as_ref().expect("layout cached above");
        let i = starts.partition_point(|&s| s <= pos) - 1;
        let shard = perm[i];
        let start = starts[i];
        if self
            .scenes
            .as_ref()
            .is_none_or(|c| (c.0, c.1) != (epoch, shard))
        {
            let mut order: Vec<usize> = (0..self.shard_sizes[shard]).collect();
            order.shuffle(&mut rng_for(self.seed, 2, epoch * 1_000_003 + shard as u64));
            self.scenes = Some((epoch, shard, order));
        }
        let (_, _, order) = self.scenes.as_ref().expect("scene order cached above");
        (shard, order[pos - start])
    }
}

/// The mixed order: sample `g` draws its directory from the shares, then takes that
/// directory's next scene in the directory's own pooled order.
struct MixedOrder {
    /// Cumulative normalised shares, one per directory.
    cdf: Vec<f64>,
    /// The last directory with a positive share (where rounding at the top of `cdf` goes).
    last: usize,
    /// Each directory's own order and its first global shard.
    directories: Vec<(Order, usize)>,
    /// Samples each directory has given before sample `next`.
    drawn: Vec<u64>,
    next: u64,
    seed: u64,
}

impl MixedOrder {
    fn directory_of(&self, g: u64) -> usize {
        let u: f64 = rng_for(self.seed, 4, g).random();
        self.cdf.partition_point(|&c| c <= u).min(self.last)
    }

    fn locate(&mut self, g: u64) -> (usize, usize) {
        if g < self.next {
            self.drawn.iter_mut().for_each(|n| *n = 0);
            self.next = 0;
        }
        while self.next < g {
            let d = self.directory_of(self.next);
            self.drawn[d] += 1;
            self.next += 1;
        }
        let d = self.directory_of(g);
        let k = self.drawn[d];
        self.drawn[d] += 1;
        self.next = g + 1;
        let (order, first) = &mut self.directories[d];
        let (shard, scene) = order.locate(k);
        (*first + shard, scene)
    }
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

/// Per-feature mean and standard deviation of the raw point features of `model` (contact
/// displacement, per-step increment, offset from the reference cloud, `[ln mass, friction,
/// restitution]`, then the contact velocity, the surface normals and the history if the
/// model takes them) over `c.norm_windows` augmented windows of each of the first
/// `c.norm_scenes` scenes, computed by the model's own
/// [`ScenePoints`]. Standard deviations are floored at 0.01 so constant features do not
/// explode.
pub fn fit_normalization(
    sources: &Sources,
    c: &DataConfig,
    model: &ModelConfig,
    seed: u64,
) -> Result<FeatureNormalization, TrainError> {
    let nf = model.point_features();
    let mut sum = vec![0f64; nf];
    let mut sq = vec![0f64; nf];
    let mut raw = vec![0f32; nf];
    let mut count = 0f64;
    let scenes = sources
        .readers()
        .iter()
        .enumerate()
        .flat_map(|(r, reader)| reader.iter().take(c.norm_scenes).map(move |s| (r, s)));
    for (i, (r, rec)) in scenes.enumerate() {
        let rec = rec?;
        // The first directory keeps the indices (and so the windows) it always had.
        let i = if r == 0 { i } else { i + 1_000_000 * r };
        for w in 0..c.norm_windows {
            let mut rng = rng_for(seed, 4, (i * 1000 + w) as u64);
            let win = sample_window(&rec, c, &mut rng, false, i as u64)?;
            // The partner's mass enters as a ratio, which a scene-wide mass factor leaves as is
            // (kinematic objects aside: scene-relative mass places them at the reference).
            let params: Vec<[f32; 3]> = win
                .objects
                .iter()
                .map(|o| object_params(o.mass, o.friction, o.restitution))
                .collect();
            let bodies: Vec<Body<'_>> = win
                .objects
                .iter()
                .zip(&params)
                .map(|(o, &params)| Body {
                    reference: &o.reference,
                    params,
                })
                .collect();
            let points = ScenePoints::for_model(
                model,
                &bodies,
                || bodies.iter().map(|b| body_normals(b.reference)).collect(),
                &win.state.current,
                &win.state.previous,
                win.state.earlier.as_deref(),
                win.dt_steps,
            );
            for (j, (o, &params)) in win.objects.iter().zip(&params).enumerate() {
                let frame = FeatureFrame::new(
                    &model.dynamics,
                    win.dt_steps,
                    win.state.current[j].translation,
                );
                let first = points.offsets[j];
                for (q, x) in (first..points.offsets[j + 1]).zip(&o.reference) {
                    points.raw_features(q, *x, params, &frame, &model.dynamics, &mut raw);
                    for f in 0..nf {
                        sum[f] += raw[f] as f64;
                        sq[f] += (raw[f] as f64).powi(2);
                    }
                    count += 1.0;
                }
            }
        }
    }
    if count == 0.0 {
        return Err(TrainError::Data(
            "no points to fit the normalisation from".into(),
        ));
    }
    let mut n = FeatureNormalization::defaults_for(&model.dynamics);
    for f in 0..nf {
        let mean = sum[f] / count;
        let var = (sq[f] / count - mean * mean).max(0.0);
        n.mean[f] = mean as f32;
        n.std[f] = (var.sqrt() as f32).max(0.01);
    }
    Ok(n)
}
