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
use dynaserve_model::{ModelConfig, TrainedRanges, WorldModel, load_rigidformer};

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
/// weights mean, as JSON pointers: they may differ between the averaged models, and the first
/// model's values are written (a warning names each difference). `trained_ranges` are joined
/// instead.
const SETTINGS: [&str; 4] = [
    "/loss",
    "/dynamics/kinematic_lead",
    "/dynamics/free_flight_gate",
    "/floor_projection",
];

/// `config` as JSON, and the same without [`SETTINGS`] and `trained_ranges`: two models whose
/// weights can be averaged have equal values in the second.
fn config_json(config: &ModelConfig) -> Result<(serde_json::Value, serde_json::Value), TrainError> {
    let whole = serde_json::to_value(config)
        .map_err(|e| TrainError::Config(format!("config.json: {e}")))?;
    let mut meaning = whole.clone();
    for pointer in SETTINGS.iter().chain(&["/trained_ranges"]) {
        let (parent, key) = pointer.rsplit_once('/').unwrap_or(("", pointer));
        if let Some(map) = meaning.pointer_mut(parent).and_then(|p| p.as_object_mut()) {
            map.remove(key);
        }
    }
    Ok((whole, meaning))
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
/// checks that it loads. Every model is loaded as the server loads it (names, shapes and
/// values checked against its configuration); models whose configurations differ beyond the
/// training and serving settings are refused, so the weights line up name for name.
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
    let models = o
        .models
        .iter()
        .map(|d| load_rigidformer(d, &Device::Cpu, false))
        .collect::<Result<Vec<_>, _>>()?;
    let (reference, meaning) = config_json(models[0].config())?;
    for (dir, model) in o.models.iter().zip(&models).skip(1) {
        let (other, other_meaning) = config_json(model.config())?;
        let diff = differing_fields(&meaning, &other_meaning);
        if !diff.is_empty() {
            return Err(TrainError::Config(format!(
                "{} differs from {} in {}: its weights do not mean the same",
                dir.display(),
                o.models[0].display(),
                diff.join(", ")
            )));
        }
        for field in SETTINGS {
            if reference.pointer(field) != other.pointer(field) {
                eprintln!(
                    "warning: {} has another {}; the average takes {}'s",
                    dir.display(),
                    field[1..].replace('/', "."),
                    o.models[0].display()
                );
            }
        }
    }
    let params = models
        .iter()
        .map(|m| {
            m.varmap()
                .data()
                .lock()
                .map(|vars| vars.clone())
                .map_err(|_| TrainError::Config("parameter map lock poisoned".into()))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut weights: HashMap<String, Tensor> = HashMap::new();
    for (name, first) in &params[0] {
        let mut sum = first.as_tensor().to_dtype(DType::F64)?;
        for other in &params[1..] {
            // Equal configurations build equal parameter sets; the loader checked the shapes.
            let v = other.get(name).ok_or_else(|| {
                TrainError::Config(format!("{name} is missing from one of the models"))
            })?;
            sum = (sum + v.as_tensor().to_dtype(DType::F64)?)?;
        }
        let mean = (sum / params.len() as f64)?.to_dtype(o.dtype)?;
        weights.insert(name.clone(), mean);
    }
    let mut config = models[0].config().clone();
    config.trained_ranges = TrainedRanges::seen(
        None,
        models.iter().filter_map(|m| m.config().trained_ranges),
        config.dynamics.relative_mass,
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
