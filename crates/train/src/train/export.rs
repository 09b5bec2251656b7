//! `dynaserve train export`: a run's checkpoint written as a model directory (raw weights or
//! their average, in the chosen weight type), checked by loading it.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{DType, Device, Tensor};
use dynaserve_model::checkpoint::{CONFIG_FILE, WEIGHTS_FILE};
use dynaserve_model::{ModelConfig, TrainedRanges, load_model, load_rigidformer, read_config};
use dynaserve_sim::dataset::DatasetReader;

use super::TrainError;
use super::run_dir::{OPTIMIZER_FILE, STATE_FILE, io, read_state, resumable};

/// What [`export`] writes.
#[derive(Clone, Debug)]
pub struct ExportOptions {
    /// Run directory (holds `checkpoint/`), or a checkpoint directory itself.
    pub run: PathBuf,
    /// Output model directory (`config.json`, `model.safetensors`; an existing `card.md` is
    /// kept).
    pub out: PathBuf,
    /// Export the weight average instead of the raw weights.
    pub ema: bool,
    /// Stored weight type (F32, F16 or BF16).
    pub dtype: DType,
}

/// The parameter ranges of everything the exported weights have seen: those the checkpoint
/// inherited from its `model.init` (`inherited`), joined with every object of the run's
/// training directories that have a share of the samples; masses as ratios within a scene
/// when `mass_relative` (the model's `dynamics.relative_mass`), in which case inherited
/// absolute masses are dropped. Data paths are read as the run recorded them (relative to the
/// directory training ran in); when they cannot be read, the inherited ranges are kept and a
/// warning printed.
fn trained_ranges(
    ckpt: &Path,
    inherited: Option<TrainedRanges>,
    mass_relative: bool,
) -> Result<Option<TrainedRanges>, TrainError> {
    let state = read_state(ckpt)?;
    let data = &state.config.data;
    let dirs = std::iter::once(&data.train).chain(&data.extra);
    let mut measured = Vec::new();
    for (i, dir) in dirs.enumerate() {
        if data.mix.get(i).is_some_and(|&share| share <= 0.0) {
            continue;
        }
        let params = DatasetReader::open(dir).and_then(|r| r.object_parameters());
        match params {
            Ok(p) => {
                measured.extend(TrainedRanges::of(p, mass_relative));
            }
            Err(e) => {
                eprintln!(
                    "warning: trained_ranges left without {} ({e}); run the export where training ran",
                    dir.display()
                );
            }
        }
    }
    let kinds_differ = inherited.is_some_and(|r| r.mass_relative != mass_relative);
    let ranges = TrainedRanges::seen(inherited, measured, mass_relative);
    if ranges.is_none() && kinds_differ {
        eprintln!(
            "warning: trained_ranges left out: no data to measure the masses as the model sees them"
        );
    }
    if let Some(r) = &ranges {
        let unit = if r.mass_relative {
            "times the scene's geometric mean"
        } else {
            "kg"
        };
        eprintln!(
            "trained ranges: mass {:?} {unit}, friction {:?}, restitution {:?}",
            r.mass, r.friction, r.restitution
        );
    }
    Ok(ranges)
}

/// Writes a run's checkpoint as a model directory (its `config.json` with the
/// [`TrainedRanges`] of the run's data) and checks that it loads.
pub fn export(o: &ExportOptions) -> Result<(), TrainError> {
    let ckpt = if o.run.join(STATE_FILE).exists() {
        o.run.clone()
    } else {
        resumable(&o.run)
            .ok_or_else(|| TrainError::Config(format!("{} holds no checkpoint", o.run.display())))?
    };
    if !matches!(o.dtype, DType::F32 | DType::F16 | DType::BF16) {
        return Err(TrainError::Config(format!(
            "cannot store weights as {:?}",
            o.dtype
        )));
    }
    let model = load_rigidformer(&ckpt, &Device::Cpu, false)?;
    let weights: HashMap<String, Tensor> = if o.ema {
        let map = candle_core::safetensors::load(ckpt.join(OPTIMIZER_FILE), &Device::Cpu)?;
        let names: Vec<String> = model
            .varmap()
            .data()
            .lock()
            .map_err(|_| TrainError::Config("parameter map lock poisoned".into()))?
            .keys()
            .cloned()
            .collect();
        let mut w = HashMap::new();
        for n in names {
            let t = map.get(&format!("ema.{n}")).ok_or_else(|| {
                TrainError::Config(format!(
                    "{}: no weight average for {n} (was ema_decay 0?)",
                    ckpt.display()
                ))
            })?;
            w.insert(n, t.clone());
        }
        w
    } else {
        candle_core::safetensors::load(ckpt.join(WEIGHTS_FILE), &Device::Cpu)?
    };
    let weights = weights
        .into_iter()
        .map(|(k, v)| Ok((k, v.to_dtype(o.dtype)?)))
        .collect::<Result<HashMap<_, _>, TrainError>>()?;
    let mut config = read_config(&ckpt)?;
    config.trained_ranges =
        trained_ranges(&ckpt, config.trained_ranges, config.dynamics.relative_mass)?;
    write_model(&o.out, &config, &weights)
}

/// Writes `config` and `weights` as a model directory (an existing `card.md` is kept) and
/// checks that the directory loads as a model.
pub(super) fn write_model(
    out: &Path,
    config: &ModelConfig,
    weights: &HashMap<String, Tensor>,
) -> Result<(), TrainError> {
    std::fs::create_dir_all(out).map_err(io(out))?;
    let cfg_dst = out.join(CONFIG_FILE);
    let text = serde_json::to_string_pretty(config)
        .map_err(|e| TrainError::Config(format!("config.json: {e}")))?;
    std::fs::write(&cfg_dst, text + "\n").map_err(io(&cfg_dst))?;
    dynaserve_model::save_tensors(weights, &out.join(WEIGHTS_FILE))?;
    load_model(out, &Device::Cpu)?;
    Ok(())
}
