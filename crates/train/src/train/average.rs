//! `dynaserve train average`: several model directories of one architecture written as one,
//! each weight the mean of theirs (a "weight soup").
//!
//! Runs fine-tuned from the same release (the same `model.init`) stay in one basin of the loss,
//! and the mean of their weights is usually better than each of them on most figures: it keeps
//! what they share and averages away what each fitted to its own samples. Weights of runs that
//! did not start from a common checkpoint do not line up, and their mean is a broken model: the
//! command cannot detect that, so check the result with `dynaserve eval` before serving it.

use std::collections::HashMap;
use std::path::PathBuf;

use candle_core::{DType, Device, Tensor};
use dynaserve_model::checkpoint::WEIGHTS_FILE;
use dynaserve_model::{ModelConfig, TrainedRanges, read_config};

use super::TrainError;
use super::export::write_model;

/// What [`average`] writes.
#[derive(Clone, Debug)]
pub struct AverageOptions {
    /// Model directories (`config.json`, `model.safetensors`), at least two.
    pub models: Vec<PathBuf>,
    /// Output model directory; an existing `card.md` is kept.
    pub out: PathBuf,
    /// Stored weight type (F32, F16 or BF16).
    pub dtype: DType,
}

/// Configuration fields that only decide how a model is trained or served, not what its
/// weights mean: they may differ between the averaged models, and the first model's values
/// are written (a warning names each difference). `trained_ranges` are joined instead.
const SETTINGS: [&str; 3] = [
    "loss",
    "dynamics.kinematic_lead",
    "dynamics.free_flight_gate",
];

/// The configuration as JSON without [`SETTINGS`] and `trained_ranges`: two models whose
/// weights can be averaged have equal values here.
fn weight_meaning(config: &ModelConfig) -> Result<serde_json::Value, TrainError> {
    let mut v = to_json(config)?;
    for path in SETTINGS.iter().chain(&["trained_ranges"]) {
        let (parent, key) = match path.rsplit_once('.') {
            Some((parent, key)) => (at_mut(&mut v, parent), key),
            None => (Some(&mut v), *path),
        };
        if let Some(map) = parent.and_then(|p| p.as_object_mut()) {
            map.remove(key);
        }
    }
    Ok(v)
}

/// `config` as a JSON value.
fn to_json(config: &ModelConfig) -> Result<serde_json::Value, TrainError> {
    serde_json::to_value(config).map_err(|e| TrainError::Config(format!("config.json: {e}")))
}

/// The value at a dotted path of a JSON object, mutably.
fn at_mut<'a>(v: &'a mut serde_json::Value, path: &str) -> Option<&'a mut serde_json::Value> {
    path.split('.').try_fold(v, |v, key| v.get_mut(key))
}

/// The value at a dotted path of a JSON object (`"dynamics.kinematic_lead"`).
fn at<'a>(v: &'a serde_json::Value, path: &str) -> Option<&'a serde_json::Value> {
    path.split('.').try_fold(v, |v, key| v.get(key))
}

/// Names the top-level (or `dynamics.*`) fields in which `a` and `b` differ.
fn differing_fields(a: &serde_json::Value, b: &serde_json::Value) -> Vec<String> {
    let mut out = Vec::new();
    let (Some(a), Some(b)) = (a.as_object(), b.as_object()) else {
        return vec!["(the whole configuration)".into()];
    };
    for (key, va) in a {
        match (va.as_object(), b.get(key)) {
            (Some(inner), Some(vb)) if vb.is_object() => {
                for (k, x) in inner {
                    if vb.get(k) != Some(x) {
                        out.push(format!("{key}.{k}"));
                    }
                }
            }
            (_, vb) if vb != Some(va) => out.push(key.clone()),
            _ => {}
        }
    }
    out.extend(b.keys().filter(|k| !a.contains_key(*k)).cloned());
    out.sort();
    out
}

/// Writes the element-wise mean of the weights of `o.models` (computed in f64) as a model
/// directory with the first model's configuration, its trained ranges joined over all, and
/// checks that it loads. Refuses models whose configurations differ beyond the training and
/// serving settings, or whose weights differ in names or shapes.
pub fn average(o: &AverageOptions) -> Result<(), TrainError> {
    if o.models.len() < 2 {
        return Err(TrainError::Config(
            "averaging needs at least two model directories".into(),
        ));
    }
    if !matches!(o.dtype, DType::F32 | DType::F16 | DType::BF16) {
        return Err(TrainError::Config(format!(
            "cannot store weights as {:?}",
            o.dtype
        )));
    }
    let configs = o
        .models
        .iter()
        .map(|d| read_config(d))
        .collect::<Result<Vec<_>, _>>()?;
    let first = &configs[0];
    let meaning = weight_meaning(first)?;
    let reference =
        serde_json::to_value(first).map_err(|e| TrainError::Config(format!("config.json: {e}")))?;
    for (dir, config) in o.models.iter().zip(&configs).skip(1) {
        let diff = differing_fields(&meaning, &weight_meaning(config)?);
        if !diff.is_empty() {
            return Err(TrainError::Config(format!(
                "{} differs from {} in {}: its weights do not mean the same",
                dir.display(),
                o.models[0].display(),
                diff.join(", ")
            )));
        }
        let other = to_json(config)?;
        for field in SETTINGS {
            if at(&reference, field) != at(&other, field) {
                eprintln!(
                    "warning: {} has another {field}; the average takes {}'s",
                    dir.display(),
                    o.models[0].display()
                );
            }
        }
    }
    let sets = o
        .models
        .iter()
        .map(|d| candle_core::safetensors::load(d.join(WEIGHTS_FILE), &Device::Cpu))
        .collect::<Result<Vec<_>, _>>()?;
    let mut weights: HashMap<String, Tensor> = HashMap::new();
    for (name, t0) in &sets[0] {
        let mut sum = t0.to_dtype(DType::F64)?;
        for (dir, set) in o.models.iter().zip(&sets).skip(1) {
            let t = set.get(name).ok_or_else(|| {
                TrainError::Config(format!("{} has no weight {name}", dir.display()))
            })?;
            if t.dims() != t0.dims() {
                return Err(TrainError::Config(format!(
                    "{name} is {:?} in {} but {:?} in {}",
                    t.dims(),
                    dir.display(),
                    t0.dims(),
                    o.models[0].display()
                )));
            }
            sum = (sum + t.to_dtype(DType::F64)?)?;
        }
        let mean = (sum / sets.len() as f64)?.to_dtype(o.dtype)?;
        weights.insert(name.clone(), mean);
    }
    for (dir, set) in o.models.iter().zip(&sets).skip(1) {
        if let Some(extra) = set.keys().find(|k| !sets[0].contains_key(*k)) {
            return Err(TrainError::Config(format!(
                "{} has a weight {extra} that {} has not",
                dir.display(),
                o.models[0].display()
            )));
        }
    }
    let mut config = first.clone();
    let mass_relative = config.dynamics.relative_mass;
    config.trained_ranges = TrainedRanges::seen(
        None,
        configs.iter().filter_map(|c| c.trained_ranges),
        mass_relative,
    );
    write_model(&o.out, &config, &weights)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differing_fields_names_nested_and_missing_keys() {
        let a = serde_json::json!({"width": 128, "dynamics": {"history": false, "approach": true}});
        let b = serde_json::json!({"width": 64, "dynamics": {"history": false, "approach": false}, "extra": 1});
        assert_eq!(
            differing_fields(&a, &b),
            vec![
                "dynamics.approach".to_string(),
                "extra".into(),
                "width".into()
            ]
        );
        assert!(differing_fields(&a, &a).is_empty());
    }
}
