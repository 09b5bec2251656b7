//! The PhysiFormer training loop: AdamW with warm-up and cosine decay, gradient clipping and
//! a weight average (EMA), `log.csv` and `loss.png`, checkpoints every few minutes (and at the
//! end or on Ctrl-C / SIGTERM) that `--resume` continues from, and the EMA weights written as
//! a model directory (`model/`) at every checkpoint. The checkpoint swap, the choice of the
//! checkpoint to resume and the log truncation on resume are the RigidFormer trainer's
//! ([`crate::train::trainer`]).

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::Context;
use dynaserve_model::physiformer::config::{PhysiConfig, TrajectoryPrior};
use dynaserve_model::{Device, PhysiFormer};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::data::load_scenes;
use crate::train::config::OptimConfig;
use crate::train::optim::{AdamW, learning_rate};
use crate::train::plot::{Series, line_chart};
use crate::train::run_dir::{
    OPTIMIZER_FILE, STATE_FILE, replace_checkpoint, resumable, truncate_log, write_state,
};

/// Header of a PhysiFormer run's `log.csv`.
const CSV_HEADER: &str = "step,lr,loss,grad_norm,seconds";

/// A PhysiFormer training configuration (TOML).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhysiTrainConfig {
    /// `"physiformer"` (what routes `dynaserve train` here).
    pub architecture: String,
    /// Network preset (`small`, `b`).
    pub preset: String,
    /// The trajectory the network's output corrects, replacing the preset's (`static` or
    /// `ballistic`; docs/physiformer.md). A new run takes it; `--resume` refuses a value
    /// other than the checkpoint's.
    #[serde(default)]
    pub prior: Option<TrajectoryPrior>,
    /// Frames over which the network's correction of the prior ramps up from zero
    /// (`correction_ramp_frames` of the model's `config.json`), replacing the preset's or the
    /// `init` model's; `--resume` refuses a value other than the checkpoint's.
    #[serde(default)]
    pub correction_ramp_frames: Option<usize>,
    /// A model directory whose weights (and configuration, with `prior` and
    /// `correction_ramp_frames` applied) a new run starts from instead of a fresh preset.
    #[serde(default)]
    pub init: Option<PathBuf>,
    /// Mesh dataset split directories trained on (scenes drawn uniformly from their union).
    pub train: Vec<PathBuf>,
    /// Optimiser and schedule (`[optim]`, as for RigidFormer).
    #[serde(default)]
    pub optim: OptimConfig,
    /// Run directory: `checkpoint/`, `model/`, `log.csv`, `loss.png`.
    pub out_dir: PathBuf,
    /// Minutes between checkpoints.
    #[serde(default = "default_minutes")]
    pub checkpoint_minutes: f64,
    /// Iterations between log rows.
    #[serde(default = "default_log_every")]
    pub log_every: u64,
    /// Seed of the weights, the scene order and the noise.
    #[serde(default)]
    pub seed: u64,
    /// Device the model trains on: `cpu` (the default), `cuda` or `cuda:N` (a build with
    /// `--features cuda`).
    #[serde(default = "default_device")]
    pub device: String,
}

fn default_device() -> String {
    "cpu".to_string()
}

fn default_minutes() -> f64 {
    4.0
}
fn default_log_every() -> u64 {
    10
}

#[derive(Serialize, Deserialize)]
struct RunState {
    step: u64,
    rng_draws: u64,
}

/// True when the TOML at `path` selects PhysiFormer (`architecture = "physiformer"`).
pub fn is_physi_config(path: &Path) -> bool {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| toml::from_str::<toml::Value>(&t).ok())
        .and_then(|v| v.get("architecture")?.as_str().map(|s| s == "physiformer"))
        .unwrap_or(false)
}

/// Trains as `path` says; `resume` continues from the run's checkpoint, `stop_after` ends
/// (with a checkpoint) after that many iterations of this invocation, `device` replaces the
/// configuration's device, `stop` ends on a signal.
pub fn run(
    path: &Path,
    resume: bool,
    stop_after: Option<u64>,
    device: Option<&str>,
    stop: Arc<AtomicBool>,
) -> anyhow::Result<()> {
    run_with_checkpoint_minutes(path, resume, stop_after, device, None, stop)
}

/// [`run`], with `checkpoint_minutes` (when given) replacing the configuration's minutes
/// between checkpoints.
pub fn run_with_checkpoint_minutes(
    path: &Path,
    resume: bool,
    stop_after: Option<u64>,
    device: Option<&str>,
    checkpoint_minutes: Option<f64>,
    stop: Arc<AtomicBool>,
) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    let mut cfg: PhysiTrainConfig = toml::from_str(&text)
        .with_context(|| format!("{} is not a valid config", path.display()))?;
    if let Some(d) = device {
        cfg.device = d.to_string();
    }
    if let Some(m) = checkpoint_minutes {
        cfg.checkpoint_minutes = m;
    }
    anyhow::ensure!(
        cfg.optim.batch_size > 0,
        "optim.batch_size must be positive"
    );
    let scenes = load_scenes(&cfg.train)?;
    let device = dynaserve_model::device_from_name(&cfg.device)?;
    let ckpt = resumable(&cfg.out_dir);
    let model = if resume {
        let ckpt = ckpt
            .as_ref()
            .with_context(|| format!("--resume: {} holds no checkpoint", cfg.out_dir.display()))?;
        let m = PhysiFormer::load(ckpt, &device, true).context("resume: no usable checkpoint")?;
        if let Some(prior) = cfg.prior {
            anyhow::ensure!(
                prior == m.config().prior,
                "--resume: the configuration asks for the {prior:?} prior but the run's checkpoint has {:?}",
                m.config().prior
            );
        }
        if let Some(n) = cfg.correction_ramp_frames {
            anyhow::ensure!(
                n == m.config().correction_ramp_frames,
                "--resume: the configuration asks for correction_ramp_frames {n} but the run's checkpoint has {}",
                m.config().correction_ramp_frames
            );
        }
        m
    } else {
        anyhow::ensure!(
            ckpt.is_none(),
            "{} already holds a checkpoint: pass --resume to continue it or choose another out_dir",
            cfg.out_dir.display()
        );
        std::fs::create_dir_all(&cfg.out_dir)?;
        let adjust = |mc: &mut PhysiConfig| {
            if let Some(prior) = cfg.prior {
                mc.prior = prior;
            }
            if let Some(n) = cfg.correction_ramp_frames {
                mc.correction_ramp_frames = n;
            }
        };
        match &cfg.init {
            Some(dir) => {
                let init = PhysiFormer::load(dir, &device, true)
                    .with_context(|| format!("init: {}", dir.display()))?;
                let mut mc = init.config().clone();
                adjust(&mut mc);
                let m = PhysiFormer::new("physiformer", mc, cfg.seed, &device)?;
                let weights: HashMap<String, _> = init
                    .varmap()
                    .data()
                    .lock()
                    .unwrap()
                    .iter()
                    .map(|(k, v)| (k.clone(), v.as_tensor().clone()))
                    .collect();
                m.set_weights(&weights)
                    .with_context(|| format!("init: {}", dir.display()))?;
                m
            }
            None => {
                let mut mc = PhysiConfig::preset(&cfg.preset)?;
                mc.frames = scenes.iter().map(|s| s.frames).max().unwrap_or(mc.frames);
                mc.official.max_frames = mc.official.max_frames.max(mc.frames);
                adjust(&mut mc);
                PhysiFormer::new("physiformer", mc, cfg.seed, &device)?
            }
        }
    };
    for (i, s) in scenes.iter().enumerate() {
        s.scene
            .validate(model.config())
            .with_context(|| format!("training scene {i}"))?;
    }
    let vars: HashMap<String, _> = model.varmap().data().lock().unwrap().clone();
    // Norm gains, biases, embeddings and learned tokens keep their size.
    let no_decay = |n: &str| {
        n.contains("norm") || n.ends_with(".bias") || n.contains("embed") || n.contains("token")
    };
    let mut opt = AdamW::new(&vars, no_decay, cfg.optim.ema_decay > 0.0)?
        .with_lr_scale(&cfg.optim.lr_scale)?;
    let mut state = RunState {
        step: 0,
        rng_draws: 0,
    };
    if let (true, Some(ckpt)) = (resume, &ckpt) {
        opt.load(&ckpt.join(OPTIMIZER_FILE))?;
        state = serde_json::from_str(&std::fs::read_to_string(ckpt.join(STATE_FILE))?)?;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5eed);
    rng.set_word_pos(state.rng_draws as u128);
    println!(
        "physiformer: {} parameters, {} training scenes, iteration {} of {}",
        model.parameter_count(),
        scenes.len(),
        state.step,
        cfg.optim.iterations
    );
    let log_path = cfg.out_dir.join("log.csv");
    if resume {
        truncate_log(&log_path, CSV_HEADER, state.step)?;
    } else {
        std::fs::write(&log_path, format!("{CSV_HEADER}\n"))?;
    }
    let mut log = std::fs::OpenOptions::new().append(true).open(&log_path)?;
    let start = Instant::now();
    let mut last_ckpt = Instant::now();
    let (mut acc, mut acc_n, mut gn) = (0.0, 0u64, 0.0);
    let mut done_here = 0u64;
    while state.step < cfg.optim.iterations {
        let batch: Vec<_> = (0..cfg.optim.batch_size)
            .map(|_| &scenes[rng.random_range(0..scenes.len())])
            .collect();
        let loss = model.train_loss(&batch, &mut rng)?.loss;
        let value = loss.to_scalar::<f32>()? as f64;
        anyhow::ensure!(
            value.is_finite(),
            "loss is {value} at iteration {}",
            state.step
        );
        let grads = loss.backward()?;
        let lr = learning_rate(&cfg.optim, state.step);
        let stats = opt.step(&grads, lr, &cfg.optim)?;
        state.step += 1;
        done_here += 1;
        acc += value;
        acc_n += 1;
        gn += stats.grad_norm;
        if state.step.is_multiple_of(cfg.log_every) || state.step == cfg.optim.iterations {
            let secs = start.elapsed().as_secs_f64();
            writeln!(
                log,
                "{},{lr:.3e},{:.6},{:.4},{secs:.1}",
                state.step,
                acc / acc_n as f64,
                gn / acc_n as f64
            )?;
            println!(
                "iter {:>6}/{} loss {:.5} grad {:.3} lr {lr:.2e} {:.2} it/s",
                state.step,
                cfg.optim.iterations,
                acc / acc_n as f64,
                gn / acc_n as f64,
                done_here as f64 / secs
            );
            (acc, acc_n, gn) = (0.0, 0, 0.0);
        }
        let stopping = stop.load(Ordering::SeqCst)
            || stop_after.is_some_and(|n| done_here >= n)
            || state.step == cfg.optim.iterations;
        if stopping || last_ckpt.elapsed().as_secs_f64() > 60.0 * cfg.checkpoint_minutes {
            state.rng_draws = rng.get_word_pos() as u64;
            save(&cfg, &model, &opt, &state, &device)?;
            last_ckpt = Instant::now();
            println!("checkpoint at iteration {}", state.step);
        }
        if stopping {
            break;
        }
    }
    Ok(())
}

fn save(
    cfg: &PhysiTrainConfig,
    model: &PhysiFormer,
    opt: &AdamW,
    state: &RunState,
    device: &Device,
) -> anyhow::Result<()> {
    let ckpt = replace_checkpoint(&cfg.out_dir, |tmp| {
        model.save(tmp)?;
        opt.save(&tmp.join(OPTIMIZER_FILE))?;
        write_state(tmp, state)
    })?;
    // The weight average as a servable model directory.
    let out = cfg.out_dir.join("model");
    let ema = PhysiFormer::load(&ckpt, device, true)?;
    if cfg.optim.ema_decay > 0.0 {
        ema.set_weights(&opt.ema_weights()?)?;
    }
    ema.save(&out)?;
    plot_loss(&cfg.out_dir)?;
    Ok(())
}

/// Draws `loss.png` from the run's `log.csv`.
pub fn plot_loss(run: &Path) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(run.join("log.csv"))?;
    let points: Vec<(f64, f64)> = text
        .lines()
        .skip(1)
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Some((f.first()?.parse().ok()?, f.get(2)?.parse().ok()?))
        })
        .collect();
    if points.is_empty() {
        return Ok(());
    }
    line_chart(
        &run.join("loss.png"),
        "PhysiFormer training loss (v-loss)",
        "iteration",
        "loss",
        &[Series {
            name: "train".into(),
            points,
        }],
        true,
    )?;
    Ok(())
}
