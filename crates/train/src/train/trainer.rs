//! The training loop: one-step supervision through [`RigidFormer::train_forward`], AdamW with
//! warm-up + cosine schedule and global clipping, periodic and on-signal checkpoints, exact
//! resume, a CSV log and a PNG loss curve.
//!
//! Run directory layout (`run.out_dir`):
//! - `checkpoint/`: `config.json`, `model.safetensors` (f32), `optimizer.safetensors` (AdamW
//!   moments, weight average, update count), `state.json` (iteration, wall time, the training
//!   configuration); replaced atomically (written to `checkpoint.tmp`, then renamed);
//! - `log.csv`: one row per `run.log_every` iterations (means over the window);
//! - `loss.png`: the loss curve, redrawn at every checkpoint;
//! - `train-config.json`: the configuration of the run.
//! - with `[heldout]` on, `heldout.csv`, `heldout/` and `heldout.png`: the physics suite
//!   scored along the run ([`super::heldout`]).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use candle_core::backprop::GradStore;
use dynaserve_model::config::RIGIDFORMER;
use dynaserve_model::{
    Drive, FeatureNormalization, InputGroup, ModelUnit, RigidFormer, TrainItem, WorldModel,
    frame_targets, load_rigidformer,
};
use indicatif::{ProgressBar, ProgressStyle};

use super::TrainError;
use super::config::TrainConfig;
use super::data::{Loader, Sources, fit_normalization};
use super::heldout::HeldoutWatch;
use super::optim::{AdamW, learning_rate};
use super::plot::{Series, line_chart};
use super::run_dir::{
    OPTIMIZER_FILE, STATE_FILE, checkpoint_dir, io, replace_checkpoint, replace_dir, resumable,
    truncate_log, write_state,
};
pub use super::run_dir::{RunState, read_state};

/// Header of `log.csv`. `rotation` is the unweighted rotation term, empty when it is off (and
/// in rows written before the column existed).
pub const CSV_HEADER: &str = "step,lr,loss,pos_pre,acc_pre,pos_post,acc_post,grad_norm,clipped_fraction,it_per_s,elapsed_s,rotation";

/// How to run [`train`].
#[derive(Clone, Debug)]
pub struct TrainOptions {
    /// Continue from `run.out_dir/checkpoint` instead of starting fresh.
    pub resume: bool,
    /// Set by a signal handler (or a test) to stop with a checkpoint after the current
    /// iteration.
    pub stop: Arc<AtomicBool>,
    /// Stop (with a checkpoint) after this many iterations in this call.
    pub stop_after: Option<u64>,
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            resume: false,
            stop: Arc::new(AtomicBool::new(false)),
            stop_after: None,
        }
    }
}

/// What a [`train`] call did.
#[derive(Clone, Debug)]
pub struct TrainSummary {
    /// Iterations completed in total (including earlier sessions).
    pub step: u64,
    /// Iterations per second in this call (excluding set-up and held-out scores).
    pub iterations_per_second: f64,
    /// Share of this call's training time (excluding set-up and held-out scores) the compute
    /// loop spent waiting for the loader's next batch: near 0 when the data keeps up, large
    /// when `run.loader_threads` should grow.
    pub data_wait_fraction: f64,
    /// Wall time this call spent scoring the held-out suite (`[heldout]`), seconds.
    pub heldout_seconds: f64,
    /// Mean loss of the first logged window of this call.
    pub first_loss: f64,
    /// Mean loss of the last logged window of this call.
    pub last_loss: f64,
    /// The checkpoint directory written last.
    pub checkpoint: PathBuf,
    /// Wall time of all sessions of the run, seconds.
    pub elapsed_seconds: f64,
}

/// Writes a checkpoint atomically: into `checkpoint.tmp`, then swapped in by renames.
fn save_checkpoint(
    out: &Path,
    model: &RigidFormer,
    opt: &AdamW,
    state: &RunState,
) -> Result<PathBuf, TrainError> {
    replace_checkpoint(out, |tmp| write_checkpoint_files(tmp, model, opt, state))
}

/// Writes a checkpoint's files (weights and configuration, optimiser, state) into `dir`.
fn write_checkpoint_files(
    dir: &Path,
    model: &RigidFormer,
    opt: &AdamW,
    state: &RunState,
) -> Result<(), TrainError> {
    model.save(dir)?;
    opt.save(&dir.join(OPTIMIZER_FILE))?;
    write_state(dir, state)
}

/// When `state.step` is listed in `run.keep_checkpoints`, writes a copy of the checkpoint as
/// `out/checkpoint-NNNNN` (the iteration, five digits or more; atomically, as the checkpoint
/// itself, with `elapsed_seconds` as the run's wall time so far) and says so when `plain`.
fn keep_if_listed(
    cfg: &TrainConfig,
    out: &Path,
    model: &RigidFormer,
    opt: &AdamW,
    state: &mut RunState,
    elapsed_seconds: f64,
    plain: bool,
) -> Result<(), TrainError> {
    if !cfg.run.keep_checkpoints.contains(&state.step) {
        return Ok(());
    }
    state.elapsed_seconds = elapsed_seconds;
    let state = &*state;
    let dir = out.join(format!("checkpoint-{:05}", state.step));
    replace_dir(&dir, |tmp| write_checkpoint_files(tmp, model, opt, state))?;
    if plain {
        println!(
            "checkpoint kept at iteration {} -> {}",
            state.step,
            dir.display()
        );
    }
    Ok(())
}

/// Rows of `log.csv` as `(step, loss, pos_post)`.
fn read_log(path: &Path) -> Vec<(f64, f64, f64)> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Vec::new();
    };
    text.lines()
        .skip(1)
        .filter_map(|l| {
            let v: Vec<f64> = l.split(',').filter_map(|x| x.parse().ok()).collect();
            (v.len() >= 6).then(|| (v[0], v[2], v[5]))
        })
        .collect()
}

/// Redraws the loss curve from `log.csv`.
pub fn plot_loss(out: &Path) -> Result<(), TrainError> {
    let rows = read_log(&out.join("log.csv"));
    if rows.is_empty() {
        return Ok(());
    }
    line_chart(
        &out.join("loss.png"),
        "RigidFormer one-step training loss",
        "iteration",
        "loss (Smooth L1, sum of 4 terms)",
        &[
            Series {
                name: "loss".into(),
                points: rows.iter().map(|r| (r.0, r.1)).collect(),
            },
            Series {
                name: "pos_post term".into(),
                points: rows.iter().map(|r| (r.0, r.2)).collect(),
            },
        ],
        true,
    )
}

/// Applies `model.contact_velocity`, `model.surface_normals`, `model.history` and
/// `model.approach` to a model loaded from
/// `model.init`: widens a model without those inputs when asked (zero weight columns, so it
/// starts as the same function; the new normalisation constants fitted from the training data
/// like a fresh run's, the old ones kept). Removing inputs is an error.
fn init_inputs(
    mut m: RigidFormer,
    cfg: &TrainConfig,
    reader: &Sources,
) -> Result<RigidFormer, TrainError> {
    for group in InputGroup::ALL {
        let (option, wanted) = (group.key(), cfg.model.input_switch(group));
        let has = group.enabled(&m.config().dynamics);
        match wanted {
            Some(true) if !has => {
                let mut wide = m.config().clone();
                group.set(&mut wide.dynamics, true);
                wide.normalization = FeatureNormalization::defaults_for(&wide.dynamics);
                let fitted = fit_normalization(reader, &cfg.data, &wide, cfg.run.seed)?;
                let at = group.offset(&wide.dynamics);
                let extra = FeatureNormalization {
                    mean: fitted.mean[at..at + group.count()].to_vec(),
                    std: fitted.std[at..at + group.count()].to_vec(),
                };
                eprintln!(
                    "widened for model.{option}: fitted mean {:?} std {:?}",
                    extra.mean, extra.std
                );
                m = m.widened_with_inputs(group, &extra, true)?;
            }
            Some(false) if has => {
                return Err(TrainError::Config(format!(
                    "model.{option} = false, but the model.init model takes those inputs (inputs cannot be removed)"
                )));
            }
            _ => {}
        }
    }
    Ok(m)
}

/// Applies the unit switches (`model.object_summary`, `model.contact_summary`,
/// `model.contact_wrench`, `model.contact_messages`) to a model loaded from `model.init`: adds
/// a unit when asked (zero last layer, so it starts as the same function). Removing one is an
/// error.
fn init_units(mut m: RigidFormer, cfg: &TrainConfig) -> Result<RigidFormer, TrainError> {
    for unit in ModelUnit::ALL {
        match (
            cfg.model.unit_switch(unit),
            unit.enabled(&m.config().dynamics),
        ) {
            (Some(true), false) => {
                eprintln!("{} added (last layer starting at zero)", unit.name());
                m = m.widened_with_unit(unit, cfg.model.seed, true)?;
            }
            (Some(false), true) => {
                return Err(TrainError::Config(format!(
                    "model.{} = false, but the model.init model has the {} (parts cannot be removed)",
                    unit.key(),
                    unit.name()
                )));
            }
            _ => {}
        }
    }
    Ok(m)
}

/// `Ok(None)` for a non-finite loss or gradient (the batch is skipped), other errors passed on.
fn skip_non_finite<T>(r: Result<T, TrainError>) -> Result<Option<T>, TrainError> {
    match r {
        Ok(v) => Ok(Some(v)),
        Err(TrainError::NonFinite(_)) => Ok(None),
        Err(e) => Err(e),
    }
}

/// Sharpness-aware minimisation (`optim.sam_rho` > 0): the batch's gradient taken again at the
/// weights moved `rho` along its first gradient `grads` (normalised), the weights restored
/// before returning. `None` when either pass is not finite (the batch is then skipped as any
/// non-finite batch is).
fn sharpness_aware(
    model: &RigidFormer,
    opt: &AdamW,
    items: &[TrainItem<'_>],
    grads: GradStore,
    rho: f64,
) -> Result<Option<GradStore>, TrainError> {
    let Some(saved) = skip_non_finite(opt.perturb(&grads, rho))? else {
        return Ok(None);
    };
    drop(grads);
    let second = model
        .train_forward(items)
        .map_err(TrainError::from)
        .and_then(|outp| {
            if outp.loss.to_scalar::<f32>()?.is_finite() {
                Ok(Some(outp.loss.backward()?))
            } else {
                Ok(None)
            }
        });
    opt.restore(saved)?;
    second
}

/// Trains (or resumes) the run described by `cfg`; see the module docs for the outputs.
pub fn train(cfg: &TrainConfig, opts: &TrainOptions) -> Result<TrainSummary, TrainError> {
    cfg.validate()?;
    let out = cfg.run.out_dir.clone();
    std::fs::create_dir_all(&out).map_err(io(&out))?;
    let dirs: Vec<_> = std::iter::once(cfg.data.train.clone())
        .chain(cfg.data.extra.iter().cloned())
        .collect();
    let reader = Sources::open(&dirs)?;
    let device = dynaserve_model::device_from_name(&cfg.run.device)?;
    let (model, mut state) = if opts.resume {
        let ckpt = resumable(&out).ok_or_else(|| {
            TrainError::Config(format!("--resume: {} holds no checkpoint", out.display()))
        })?;
        let st = read_state(&ckpt)?;
        for (name, same) in [
            ("data", st.config.data == cfg.data),
            ("model", st.config.model == cfg.model),
            ("optim", st.config.optim == cfg.optim),
        ] {
            if !same {
                return Err(TrainError::Config(format!(
                    "--resume: the [{name}] section differs from the run's ({}); an exact resume needs the same settings",
                    ckpt.join(STATE_FILE).display()
                )));
            }
        }
        let m = load_rigidformer(&ckpt, &device, true)?;
        (m, st)
    } else {
        if resumable(&out).is_some() {
            return Err(TrainError::Config(format!(
                "{} already holds a checkpoint: pass --resume to continue it or choose another run.out_dir",
                out.display()
            )));
        }
        let m = if let Some(init) = &cfg.model.init {
            let m = load_rigidformer(init, &device, true)?;
            let manifest = reader.primary().manifest();
            if m.config().dt_frame != manifest.dt_frame || m.config().gravity != manifest.gravity {
                return Err(TrainError::Config(format!(
                    "model.init {}: trained at dt {} s and gravity {:?}, the data has {} s and {:?}",
                    init.display(),
                    m.config().dt_frame,
                    m.config().gravity,
                    manifest.dt_frame,
                    manifest.gravity
                )));
            }
            eprintln!("initialised from {}", init.display());
            let m = m.with_settings(|d, l| cfg.model.apply_settings(d, l))?;
            let m = init_inputs(m, cfg, &reader)?;
            let m = init_units(m, cfg)?;
            let m = match cfg.model.insert_blocks_after.as_deref() {
                Some(after) if !after.is_empty() => {
                    let deep = m.deepened(after, cfg.model.seed, true)?;
                    eprintln!(
                        "deepened to {} decoder blocks (new ones after {after:?} start as the identity), anchor taps {:?}",
                        deep.config().blocks,
                        deep.config().anchor_taps
                    );
                    deep
                }
                _ => m,
            };
            match cfg.model.widen_encoder {
                Some([point_dim, sa_dim]) => {
                    let wide = m.widened_encoder(point_dim, sa_dim, cfg.model.seed, true)?;
                    eprintln!(
                        "encoder widened to {point_dim} point and {sa_dim} set-abstraction channels (new ones start at zero), {} parameters",
                        wide.parameter_count()
                    );
                    wide
                }
                None => m,
            }
        } else {
            let mut mc = cfg.model.model_config()?;
            mc.dt_frame = reader.primary().manifest().dt_frame;
            mc.gravity = reader.primary().manifest().gravity;
            if cfg.model.fit_normalization {
                mc.normalization = fit_normalization(&reader, &cfg.data, &mc, cfg.run.seed)?;
                eprintln!(
                    "fitted feature normalisation: mean {:?} std {:?}",
                    mc.normalization.mean, mc.normalization.std
                );
            }
            RigidFormer::new(mc, cfg.model.seed, &device)?
        };
        let st = RunState {
            step: 0,
            elapsed_seconds: 0.0,
            threads: cfg.run.threads,
            config: cfg.clone(),
        };
        (m, st)
    };
    state.config.run = cfg.run.clone();
    state.threads = cfg.run.threads;
    // Named once for every start, so a resumed run writes the same card title as a fresh one
    // (a loaded checkpoint is otherwise named by its directory).
    let model = Arc::new(model.with_name(RIGIDFORMER));
    let vars = model
        .varmap()
        .data()
        .lock()
        .map_err(|_| TrainError::Config("parameter map lock poisoned".into()))?
        .clone();
    let mut opt = AdamW::new(&vars, RigidFormer::is_no_decay, cfg.optim.ema_decay > 0.0)?
        .with_lr_scale(&cfg.optim.lr_scale)?;
    if opts.resume {
        let ckpt =
            resumable(&out).ok_or_else(|| TrainError::Config("checkpoint vanished".into()))?;
        opt.load(&ckpt.join(OPTIMIZER_FILE))?;
    }
    let cfg_path = out.join("train-config.json");
    std::fs::write(
        &cfg_path,
        serde_json::to_string_pretty(cfg)
            .map_err(|e| TrainError::Config(format!("config serialisation: {e}")))?,
    )
    .map_err(io(&cfg_path))?;
    let log_path = out.join("log.csv");
    if opts.resume {
        truncate_log(&log_path, CSV_HEADER, state.step)?;
    } else {
        std::fs::write(&log_path, format!("{CSV_HEADER}\n")).map_err(io(&log_path))?;
    }
    let mut log = std::fs::OpenOptions::new()
        .append(true)
        .open(&log_path)
        .map_err(io(&log_path))?;

    let watch = HeldoutWatch::start(
        &cfg.heldout,
        &out,
        model.config().gravity,
        opts.resume.then_some(state.step),
    )?;
    let dyn_model: Arc<dyn WorldModel> = model.clone();
    let loader = Loader::start(
        reader,
        cfg.data.clone(),
        cfg.optim.batch_size,
        cfg.run.seed,
        state.step,
        dyn_model,
        cfg.run.loader_threads,
    )?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(cfg.run.threads)
        .thread_name(|i| format!("train-compute-{i}"))
        .build()
        .map_err(|e| TrainError::Config(format!("cannot build the thread pool: {e}")))?;

    let pb = if cfg.run.progress {
        ProgressBar::new(cfg.optim.iterations)
    } else {
        ProgressBar::hidden()
    };
    pb.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} {msg} (eta {eta})")
            .map_err(|e| TrainError::Config(format!("progress template: {e}")))?
            .progress_chars("=> "),
    );
    pb.set_position(state.step);
    let plain = pb.is_hidden();
    // Scores the weight average (or the raw weights) at the current iteration and returns
    // the seconds it took; a failure is reported and the run goes on.
    let score = |step: u64, opt: &AdamW| -> f64 {
        let Some(w) = &watch else { return 0.0 };
        let started = Instant::now();
        let scored = opt.ema_weights().and_then(|weights| {
            w.score(
                step,
                model.config(),
                &weights,
                cfg.optim.ema_decay > 0.0,
                model.device(),
            )
        });
        let secs = started.elapsed().as_secs_f64();
        match scored {
            Ok(s) => pb.suspend(|| println!("{} ({secs:.1} s)", s.summary())),
            Err(e) => pb.suspend(|| eprintln!("held-out score at iteration {step} failed: {e}")),
        }
        secs
    };

    let session_start = Instant::now();
    let elapsed_before = state.elapsed_seconds;
    let start_step = state.step;
    let mut last_ckpt = Instant::now();
    let mut window_start = Instant::now();
    let mut acc = [0f64; 7]; // loss, 4 terms, grad norm, clipped count
    // The rotation term's sum, present when the model reports the term (`loss.rotation_weight`).
    let mut rotation_acc: Option<f64> = None;
    let mut n_acc = 0u64;
    let mut first_loss = f64::NAN;
    let mut last_loss = f64::NAN;
    let mut bad_in_a_row = 0;
    let mut ckpt_path = checkpoint_dir(&out);
    let budget_end = opts.stop_after.map(|n| state.step + n);
    // Seconds the compute loop waited for the loader.
    let mut data_wait = 0f64;
    let mut heldout_seconds = 0f64;

    let result: Result<(), TrainError> = pool.install(|| {
        if !opts.resume {
            heldout_seconds += score(0, &opt);
            window_start = Instant::now();
        }
        while state.step < cfg.optim.iterations
            && !opts.stop.load(Ordering::SeqCst)
            && budget_end.is_none_or(|e| state.step < e)
        {
            let asked = Instant::now();
            let mut batch = loader.next()?;
            data_wait += asked.elapsed().as_secs_f64();
            if batch.step != state.step {
                return Err(TrainError::Data(format!(
                    "loader produced batch {} for iteration {}",
                    batch.step, state.step
                )));
            }
            super::pushforward::apply(&model, &mut batch.samples)?;
            // The step trained on reads what a driven step reads: the kinematic objects
            // driven to their poses in the target.
            let lead = model.config().dynamics.kinematic_lead;
            for s in batch.samples.iter_mut().filter(|s| s.kinematic.contains(&true)) {
                let targets = frame_targets(&s.kinematic, &s.target);
                s.state = Drive::new(&s.kinematic, &targets).input(&s.state, lead);
            }
            let items: Vec<TrainItem<'_>> = batch
                .samples
                .iter()
                .map(|s| TrainItem {
                    scene: &s.scene,
                    state: &s.state,
                    target: &s.target,
                    dt_steps: s.dt_steps,
                    kinematic: &s.kinematic,
                })
                .collect();
            let outp = model.train_forward(&items)?;
            let loss = outp.loss.to_scalar::<f32>()? as f64;
            let lr = learning_rate(&cfg.optim, state.step);
            let stats = if loss.is_finite() {
                let first = outp.loss.backward()?;
                let grads = if cfg.optim.sam_rho > 0.0 {
                    sharpness_aware(&model, &opt, &items, first, cfg.optim.sam_rho)?
                } else {
                    Some(first)
                };
                match grads {
                    Some(grads) => skip_non_finite(opt.step(&grads, lr, &cfg.optim))?,
                    None => None,
                }
            } else {
                None
            };
            let Some(stats) = stats else {
                bad_in_a_row += 1;
                eprintln!(
                    "iteration {}: non-finite loss or gradient, batch skipped ({bad_in_a_row} in a row)",
                    state.step
                );
                if bad_in_a_row >= 20 {
                    return Err(TrainError::NonFinite(format!(
                        "20 batches in a row gave non-finite losses or gradients (iteration {})",
                        state.step
                    )));
                }
                // The batch is consumed without an update; the stream moves on (a listed
                // iteration is still kept).
                state.step += 1;
                let elapsed = elapsed_before + session_start.elapsed().as_secs_f64();
                keep_if_listed(cfg, &out, &model, &opt, &mut state, elapsed, plain)?;
                continue;
            };
            bad_in_a_row = 0;
            state.step += 1;
            acc[0] += loss;
            for (i, t) in outp.terms.iter().enumerate() {
                acc[1 + i] += t.to_scalar::<f32>()? as f64;
            }
            acc[5] += stats.grad_norm;
            acc[6] += (stats.clip_scale < 1.0) as u8 as f64;
            if let Some(r) = &outp.rotation {
                *rotation_acc.get_or_insert(0.0) += r.to_scalar::<f32>()? as f64;
            }
            n_acc += 1;
            if state.step % cfg.run.log_every == 0 || state.step == cfg.optim.iterations {
                let n = n_acc as f64;
                let secs = window_start.elapsed().as_secs_f64();
                let its = n / secs.max(1e-9);
                let elapsed = elapsed_before + session_start.elapsed().as_secs_f64();
                let mean_loss = acc[0] / n;
                if first_loss.is_nan() {
                    first_loss = mean_loss;
                }
                last_loss = mean_loss;
                let rotation_cell = rotation_acc
                    .map(|sum| format!("{:.6}", sum / n))
                    .unwrap_or_default();
                writeln!(
                    log,
                    "{},{:.6e},{:.6},{:.6},{:.6},{:.6},{:.6},{:.4},{:.3},{:.3},{:.1},{}",
                    state.step,
                    lr,
                    mean_loss,
                    acc[1] / n,
                    acc[2] / n,
                    acc[3] / n,
                    acc[4] / n,
                    acc[5] / n,
                    acc[6] / n,
                    its,
                    elapsed,
                    rotation_cell
                )
                .map_err(io(&log_path))?;
                let msg = format!("loss {mean_loss:.4} lr {lr:.2e} {its:.2} it/s");
                if plain {
                    println!("iteration {}/{} {msg}", state.step, cfg.optim.iterations);
                }
                pb.set_message(msg);
                acc = [0.0; 7];
                rotation_acc = None;
                n_acc = 0;
                window_start = Instant::now();
            }
            pb.set_position(state.step);
            if watch
                .as_ref()
                .is_some_and(|w| w.due(state.step, cfg.optim.iterations))
            {
                let secs = score(state.step, &opt);
                heldout_seconds += secs;
                // The log's rate is the training's: the score's time leaves the window.
                window_start += std::time::Duration::from_secs_f64(secs);
            }
            if last_ckpt.elapsed().as_secs_f64() >= cfg.run.checkpoint_minutes * 60.0 {
                state.elapsed_seconds = elapsed_before + session_start.elapsed().as_secs_f64();
                ckpt_path = save_checkpoint(&out, &model, &opt, &state)?;
                log.flush().map_err(io(&log_path))?;
                if let Err(e) = plot_loss(&out) {
                    eprintln!("loss curve not drawn: {e}");
                }
                if plain {
                    println!("checkpoint at iteration {} -> {}", state.step, ckpt_path.display());
                }
                last_ckpt = Instant::now();
            }
            let elapsed = elapsed_before + session_start.elapsed().as_secs_f64();
            keep_if_listed(cfg, &out, &model, &opt, &mut state, elapsed, plain)?;
        }
        Ok(())
    });
    drop(loader);
    // Save what was reached even when the loop failed part-way (the state is consistent:
    // weights, moments and step advance together).
    state.elapsed_seconds = elapsed_before + session_start.elapsed().as_secs_f64();
    if state.step > start_step || !opts.resume {
        ckpt_path = save_checkpoint(&out, &model, &opt, &state)?;
    }
    log.flush().map_err(io(&log_path))?;
    if let Err(e) = plot_loss(&out) {
        eprintln!("loss curve not drawn: {e}");
    }
    pb.finish_and_clear();
    result?;
    let done = state.step - start_step;
    let wall = (session_start.elapsed().as_secs_f64() - heldout_seconds).max(1e-9);
    Ok(TrainSummary {
        step: state.step,
        iterations_per_second: done as f64 / wall,
        data_wait_fraction: data_wait / wall,
        heldout_seconds,
        first_loss,
        last_loss,
        checkpoint: ckpt_path,
        elapsed_seconds: state.elapsed_seconds,
    })
}
