//! Training configuration (`dynaserve train --config FILE`), read from TOML or JSON.
//!
//! Every knob has a default; a file only names what it changes. Unknown keys are rejected so a
//! misspelt knob is an error, not a silent default. `docs/training.md` lists the same knobs.
//! Each section has its own file (`data`, `model`, `optim`, `run`, `heldout`); this one holds
//! the whole ([`TrainConfig`]), its files' `base` chains and its validation.

mod data;
mod heldout;
mod model;
mod optim;
mod run;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub(crate) use data::valid_step_sizes;
pub use data::{DataConfig, MAX_PUSHFORWARD_STEPS};
pub use heldout::HeldoutConfig;
pub use model::ModelSection;
pub use optim::OptimConfig;
pub use run::RunConfig;

use super::TrainError;

/// The whole training configuration: data, model, optimiser and run settings.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Where samples come from and how they are augmented.
    pub data: DataConfig,
    /// Which network to train.
    pub model: ModelSection,
    /// AdamW, schedule, clipping, batch size and length.
    pub optim: OptimConfig,
    /// Output directory, checkpoint cadence, logging, threads.
    pub run: RunConfig,
    /// The physics suite scored along the run (off by default).
    pub heldout: HeldoutConfig,
}

/// The TOML table of `path` laid over the table of the file its `base` key names, recursively;
/// `chain` holds the files being read, so that a cycle is an error instead of a hang.
fn toml_with_bases(path: &Path, chain: &mut Vec<PathBuf>) -> Result<toml::Table, TrainError> {
    let err = |m: String| TrainError::Config(format!("{}: {m}", path.display()));
    let text = std::fs::read_to_string(path).map_err(|e| TrainError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    let mut table: toml::Table = toml::from_str(&text).map_err(|e| err(e.to_string()))?;
    let Some(base) = table.remove("base") else {
        return Ok(table);
    };
    let base = base
        .as_str()
        .ok_or_else(|| err("`base` must be a file name".into()))?;
    let base_path = path.parent().unwrap_or(Path::new(".")).join(base);
    let key = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
    if chain.contains(&key) {
        return Err(err(format!("`base` chain returns to {}", path.display())));
    }
    chain.push(key);
    let mut merged = toml_with_bases(&base_path, chain)?;
    chain.pop();
    overlay(&mut merged, table);
    Ok(merged)
}

/// Lays `top` over `under`: tables merge key by key, every other value replaces.
fn overlay(under: &mut toml::Table, top: toml::Table) {
    for (k, v) in top {
        match (under.get_mut(&k), v) {
            (Some(toml::Value::Table(u)), toml::Value::Table(t)) => overlay(u, t),
            (_, v) => {
                under.insert(k, v);
            }
        }
    }
}

impl TrainConfig {
    /// Reads a TOML (`.toml`) or JSON (any other extension) configuration and validates it.
    /// A TOML file may name another in a top-level `base = "file.toml"` (relative to its own
    /// directory): it is that file with this one's keys laid over it (tables merged key by
    /// key, any other value, arrays included, replaced).
    pub fn from_file(path: &Path) -> Result<TrainConfig, TrainError> {
        let cfg: TrainConfig = if path.extension().is_some_and(|e| e == "toml") {
            toml_with_bases(path, &mut Vec::new())?
                .try_into()
                .map_err(|e| TrainError::Config(format!("{}: {e}", path.display())))?
        } else {
            let text = std::fs::read_to_string(path).map_err(|e| TrainError::Io {
                path: path.to_path_buf(),
                source: e,
            })?;
            serde_json::from_str(&text)
                .map_err(|e| TrainError::Config(format!("{}: {e}", path.display())))?
        };
        cfg.validate()?;
        Ok(cfg)
    }

    /// Checks ranges; every violation is named.
    pub fn validate(&self) -> Result<(), TrainError> {
        let bad = |m: &str| Err(TrainError::Config(m.to_string()));
        self.heldout.validate()?;
        if self.run.loader_threads == 0 {
            return bad("run.loader_threads must be at least 1");
        }
        let d = &self.data;
        if !valid_step_sizes(&d.step_sizes) {
            return bad("data.step_sizes must be non-empty, each in 1..=16");
        }
        if d.points_min == 0 || d.points_max < d.points_min {
            return bad("data.points_min must be >= 1 and <= data.points_max");
        }
        if !(0.0..=1.0).contains(&d.point_drop_prob) || !(0.0..0.95).contains(&d.point_drop_max) {
            return bad("data.point_drop_prob must be in [0, 1] and point_drop_max in [0, 0.95)");
        }
        if !(d.noise_position >= 0.0 && d.noise_rotation >= 0.0) {
            return bad("data.noise_position and noise_rotation must be >= 0");
        }
        if !(0.0..=1.0).contains(&d.pushforward) {
            return bad("data.pushforward must be a probability in [0, 1]");
        }
        if !(1..=MAX_PUSHFORWARD_STEPS).contains(&d.pushforward_steps) {
            return bad(&format!(
                "data.pushforward_steps must be 1 to {MAX_PUSHFORWARD_STEPS}"
            ));
        }
        if !(0.0..=1.0).contains(&d.event_share) {
            return bad("data.event_share must be a fraction in [0, 1]");
        }
        if !(0.0..=1.0).contains(&d.stop_share) {
            return bad("data.stop_share must be a fraction in [0, 1]");
        }
        if !(0.0..=1.0).contains(&d.history_drop) {
            return bad("data.history_drop must be a probability in [0, 1]");
        }
        if self.model.history == Some(true) && !d.history {
            return bad(
                "model.history = true needs data.history = true (else its inputs are always zero)",
            );
        }
        DataConfig::check_mix(&d.mix, 1 + d.extra.len())?;
        if d.prefetch == 0 {
            return bad("data.prefetch must be >= 1");
        }
        if let Some(beta) = self.model.loss_beta
            && !(beta > 0.0 && beta.is_finite())
        {
            return bad("model.loss_beta must be finite and > 0");
        }
        if let Some(w) = self.model.rest_weight
            && !(w > 0.0 && w.is_finite())
        {
            return bad("model.rest_weight must be finite and > 0");
        }
        if let Some(w) = self.model.object_contact_weight
            && !(w > 0.0 && w.is_finite())
        {
            return bad("model.object_contact_weight must be finite and > 0");
        }
        if let Some(w) = self.model.rotation_weight
            && !(w >= 0.0 && w.is_finite())
        {
            return bad("model.rotation_weight must be finite and >= 0");
        }
        if self
            .model
            .insert_blocks_after
            .as_ref()
            .is_some_and(|v| !v.is_empty())
            && self.model.init.is_none()
        {
            return bad("model.insert_blocks_after deepens the model.init model: set model.init");
        }
        if self.model.widen_encoder.is_some() && self.model.init.is_none() {
            return bad("model.widen_encoder widens the model.init model: set model.init");
        }
        let o = &self.optim;
        if o.batch_size == 0 || o.iterations == 0 {
            return bad("optim.batch_size and optim.iterations must be >= 1");
        }
        if !(o.lr > 0.0 && o.lr.is_finite()) {
            return bad("optim.lr must be finite and > 0");
        }
        if !(0.0..=1.0).contains(&o.warmup_start) || !(0.0..=1.0).contains(&o.min_lr_ratio) {
            return bad("optim.warmup_start and optim.min_lr_ratio must be in [0, 1]");
        }
        if !(0.0..1.0).contains(&o.beta1) || !(0.0..1.0).contains(&o.beta2) || o.eps <= 0.0 {
            return bad("optim.beta1/beta2 must be in [0, 1) and eps > 0");
        }
        if o.weight_decay < 0.0 || o.grad_clip < 0.0 || !(0.0..1.0).contains(&o.ema_decay) {
            return bad("optim.weight_decay, grad_clip >= 0 and ema_decay in [0, 1)");
        }
        if o.lr_scale.values().any(|f| !(f.is_finite() && *f > 0.0)) {
            return bad("optim.lr_scale factors must be finite and > 0");
        }
        if !(o.sam_rho.is_finite() && o.sam_rho >= 0.0) {
            return bad("optim.sam_rho must be finite and >= 0");
        }
        let r = &self.run;
        if r.checkpoint_minutes.is_nan()
            || r.checkpoint_minutes <= 0.0
            || r.log_every == 0
            || r.threads == 0
        {
            return bad("run.checkpoint_minutes > 0, run.log_every >= 1 and run.threads >= 1");
        }
        if let Some(k) = r
            .keep_checkpoints
            .iter()
            .find(|&&k| k == 0 || k > o.iterations)
        {
            return bad(&format!(
                "run.keep_checkpoints names iteration {k}: each must be in 1..={} (optim.iterations)",
                o.iterations
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use dynaserve_model::ModelUnit;

    use super::*;

    /// A `base` file's keys stay where the derived file is silent; a derived table key or
    /// array replaces the base's; a chain that returns to a file is an error.
    #[test]
    fn base_files_are_overlaid_and_cycles_refused() {
        let dir =
            std::env::temp_dir().join(format!("dynaserve-config-base-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let write = |name: &str, text: &str| std::fs::write(dir.join(name), text).unwrap();
        write(
            "base.toml",
            "[data]\nstep_sizes = [1, 2, 4]\nmirror = true\n[optim]\nbatch_size = 24\niterations = 8000\n",
        );
        write(
            "child.toml",
            "base = \"base.toml\"\n[data]\nstep_sizes = [2]\n[optim]\nbatch_size = 48\n",
        );
        let c = TrainConfig::from_file(&dir.join("child.toml")).unwrap();
        assert_eq!(c.data.step_sizes, vec![2]);
        assert!(c.data.mirror);
        assert_eq!((c.optim.batch_size, c.optim.iterations), (48, 8000));
        write("a.toml", "base = \"b.toml\"\n");
        write("b.toml", "base = \"a.toml\"\n");
        let e = TrainConfig::from_file(&dir.join("a.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("chain returns"), "{e}");
        write("bad.toml", "base = 3\n");
        let e = TrainConfig::from_file(&dir.join("bad.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("`base` must be a file name"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// r68 and r69 are r66, and r70 is r68, with the changes their headers name and nothing else.
    #[test]
    fn derived_run_configs_differ_from_their_base_as_stated() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
        let load = |n: &str| TrainConfig::from_file(&dir.join(n)).unwrap();
        let r66 = load("rigidformer-small-r66.toml");
        let mut want = r66.clone();
        want.data.mirror = true;
        want.run.out_dir = PathBuf::from("runs/rigidformer-small-r68");
        want.run.threads = 2;
        want.run.seed = 68;
        assert_eq!(load("rigidformer-small-r68.toml"), want);
        let mut want = load("rigidformer-small-r68.toml");
        want.optim.iterations = 20000;
        want.optim.ema_decay = 0.9995;
        want.run.out_dir = PathBuf::from("runs/rigidformer-small-r70");
        want.run.seed = 70;
        assert_eq!(load("rigidformer-small-r70.toml"), want);
        let mut want = r66;
        want.optim.batch_size = 48;
        want.optim.iterations = 4000;
        want.optim.warmup = 150;
        want.run.out_dir = PathBuf::from("runs/rigidformer-small-r69");
        want.run.threads = 2;
        want.run.seed = 69;
        assert_eq!(load("rigidformer-small-r69.toml"), want);
    }

    /// The committed RigidFormer configurations (the experiments' included), by file name
    /// relative to `configs/`, sorted.
    fn committed_config_files() -> Vec<(String, PathBuf)> {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
        let mut files = Vec::new();
        for (sub, prefix) in [("", "rigidformer"), ("experiments/", "")] {
            for entry in std::fs::read_dir(dir.join(sub)).unwrap() {
                let p = entry.unwrap().path();
                let name = p.file_name().unwrap().to_string_lossy().into_owned();
                if name.starts_with(prefix) && name.ends_with(".toml") {
                    files.push((format!("{sub}{name}"), p));
                }
            }
        }
        files.sort();
        files
    }

    /// The leaves of `value` (a serialised configuration) that differ from `default`'s at the
    /// same path, by dotted path.
    fn changed_leaves(
        path: &str,
        value: &serde_json::Value,
        default: Option<&serde_json::Value>,
        out: &mut std::collections::BTreeMap<String, serde_json::Value>,
    ) {
        if let (serde_json::Value::Object(map), Some(serde_json::Value::Object(base))) =
            (value, default)
        {
            for (k, v) in map {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                changed_leaves(&p, v, base.get(k), out);
            }
        } else if default != Some(value) {
            out.insert(path.to_string(), value.clone());
        }
    }

    /// `value` as JSON, with every number that is exactly an `f32` (the configuration's
    /// single-precision fields, widened by serde) written as that `f32`'s shortest form, so
    /// that the record reads `0.001`, not `0.0010000000474974513`, and stays exact.
    fn record_value(value: &serde_json::Value) -> String {
        use serde_json::Value;
        match value {
            Value::Number(n) if !n.is_i64() && !n.is_u64() => match n.as_f64() {
                Some(x) if f64::from(x as f32) == x => format!("{:?}", x as f32),
                _ => value.to_string(),
            },
            Value::Array(items) => {
                let items: Vec<String> = items.iter().map(record_value).collect();
                format!("[{}]", items.join(","))
            }
            Value::Object(map) => {
                let items: Vec<String> = map
                    .iter()
                    .map(|(k, v)| format!("{}:{}", Value::String(k.clone()), record_value(v)))
                    .collect();
                format!("{{{}}}", items.join(","))
            }
            _ => value.to_string(),
        }
    }

    /// Every committed configuration resolves (bases laid under it) to the settings recorded
    /// in `configs/resolved.txt`, one line per key that differs from the defaults
    /// (`file: key = value`, the value as JSON). A file edited in place changes every run
    /// built on it through `base`; this test names each such run, so that a record is not
    /// rewritten unnoticed. After a deliberate change (a new run, a new default), rewrite the
    /// record with `DYNASERVE_WRITE_RESOLVED=1` and review its diff.
    #[test]
    fn committed_configs_resolve_as_recorded() {
        use std::collections::BTreeSet;
        let default = serde_json::to_value(TrainConfig::default()).unwrap();
        let mut lines = Vec::new();
        for (name, path) in committed_config_files() {
            let c = TrainConfig::from_file(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
            let mut leaves = std::collections::BTreeMap::new();
            changed_leaves(
                "",
                &serde_json::to_value(c).unwrap(),
                Some(&default),
                &mut leaves,
            );
            for (key, value) in leaves {
                lines.push(format!("{name}: {key} = {}", record_value(&value)));
            }
        }
        let record = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/resolved.txt");
        if std::env::var_os("DYNASERVE_WRITE_RESOLVED").is_some() {
            std::fs::write(&record, lines.join("\n") + "\n").unwrap();
            return;
        }
        let text = std::fs::read_to_string(&record).unwrap();
        let recorded: BTreeSet<&str> = text.lines().collect();
        let now: BTreeSet<&str> = lines.iter().map(String::as_str).collect();
        let mut changes: Vec<String> = recorded
            .difference(&now)
            .map(|l| format!("- {l}"))
            .chain(now.difference(&recorded).map(|l| format!("+ {l}")))
            .collect();
        changes.sort_by(|a, b| a[2..].cmp(&b[2..]));
        assert!(
            changes.is_empty(),
            "committed configurations no longer resolve as configs/resolved.txt records \
             (recorded -, now +; DYNASERVE_WRITE_RESOLVED=1 rewrites it):\n{}",
            changes.join("\n")
        );
    }

    /// Every committed RigidFormer training configuration, the experiments' included, parses
    /// and validates (a typo in one surfaces here, not an hour into a run); the relative-mass
    /// run switches it on.
    #[test]
    fn committed_configs_parse_and_validate() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
        let files = committed_config_files();
        for (name, p) in &files {
            TrainConfig::from_file(p).unwrap_or_else(|e| panic!("{name}: {e}"));
        }
        let experiments = files
            .iter()
            .filter(|(n, _)| n.starts_with("experiments/"))
            .count();
        let runs = files.len() - experiments;
        assert!(
            runs >= 30,
            "only {runs} configurations in {}",
            dir.display()
        );
        // The diagnoses' and experiments' configurations too, so that the card's commands run.
        assert!(
            experiments >= 20,
            "only {experiments} configurations in {}/experiments",
            dir.display()
        );
        let r24 = TrainConfig::from_file(&dir.join("rigidformer-small-r24.toml")).unwrap();
        assert_eq!(r24.model.relative_mass, Some(true));
        let r43 = TrainConfig::from_file(&dir.join("rigidformer-small-r43.toml")).unwrap();
        assert_eq!(r43.model.kinematic_lead, Some(true));
        let r48 = TrainConfig::from_file(&dir.join("rigidformer-small-r48.toml")).unwrap();
        assert_eq!(r48.data.stop_share, 0.3);
        let refused = |text: &str, field: &str| {
            let c: TrainConfig = toml::from_str(text).unwrap();
            let e = c.validate().unwrap_err().to_string();
            assert!(
                e.contains(field),
                "{text:?} refused for another reason: {e}"
            );
        };
        refused("[data]\nstop_share = 1.5\n", "stop_share");
        let r50 = TrainConfig::from_file(&dir.join("rigidformer-small-r50.toml")).unwrap();
        assert_eq!(r50.data.pushforward_steps, 6);
        refused(
            &format!(
                "[data]\npushforward_steps = {}\n",
                MAX_PUSHFORWARD_STEPS + 1
            ),
            "pushforward_steps",
        );
        let r54 = TrainConfig::from_file(&dir.join("rigidformer-small-r54.toml")).unwrap();
        assert_eq!(r54.model.contact_summary, Some(true));
        assert_eq!(r54.optim.lr_scale.get("contact_summary."), Some(&10.0));
        assert!(r54.model.model_config().unwrap().dynamics.contact_summary);
        refused("[optim.lr_scale]\n\"a.\" = 0.0\n", "lr_scale");
        refused("[optim.lr_scale]\n\"a.\" = nan\n", "lr_scale");
        let lead = r43.model.model_config().unwrap();
        assert!(lead.dynamics.kinematic_lead);
        assert!(
            !ModelSection::default()
                .model_config()
                .unwrap()
                .dynamics
                .kinematic_lead
        );
    }

    #[test]
    fn loss_beta_switches_the_named_config_and_is_checked() {
        let c: TrainConfig = toml::from_str("[model]\nloss_beta = 0.1\n").unwrap();
        assert_eq!(c.model.model_config().unwrap().loss.beta, 0.1);
        c.validate().unwrap();
        let zero: TrainConfig = toml::from_str("[model]\nloss_beta = 0.0\n").unwrap();
        assert!(zero.validate().is_err());
    }

    #[test]
    fn rest_weight_switches_the_named_config_and_is_checked() {
        assert_eq!(
            ModelSection::default()
                .model_config()
                .unwrap()
                .loss
                .rest_weight,
            1.0
        );
        let c: TrainConfig = toml::from_str("[model]\nrest_weight = 4.0\n").unwrap();
        assert_eq!(c.model.model_config().unwrap().loss.rest_weight, 4.0);
        c.validate().unwrap();
        let neg: TrainConfig = toml::from_str("[model]\nrest_weight = -1.0\n").unwrap();
        assert!(neg.validate().is_err());
    }

    #[test]
    fn contact_and_rotation_weights_switch_the_named_config_and_are_checked() {
        let loss = |c: &ModelSection| c.model_config().unwrap().loss;
        assert_eq!(loss(&ModelSection::default()).object_contact_weight, 1.0);
        assert_eq!(loss(&ModelSection::default()).rotation_weight, 0.0);
        let c: TrainConfig =
            toml::from_str("[model]\nobject_contact_weight = 3.0\nrotation_weight = 0.5\n")
                .unwrap();
        assert_eq!(loss(&c.model).object_contact_weight, 3.0);
        assert_eq!(loss(&c.model).rotation_weight, 0.5);
        c.validate().unwrap();
        for bad in ["object_contact_weight = nan", "rotation_weight = -0.5"] {
            let c: TrainConfig = toml::from_str(&format!("[model]\n{bad}\n")).unwrap();
            assert!(c.validate().is_err(), "{bad}");
        }
    }

    /// Each unit's `[model]` switch turns it on in the named configuration; unset, it is off.
    #[test]
    fn unit_switches_change_the_named_config() {
        for unit in ModelUnit::ALL {
            let has = |c: &ModelSection| unit.enabled(&c.model_config().unwrap().dynamics);
            assert!(!has(&ModelSection::default()), "{}", unit.key());
            let text = format!("[model]\n{} = true\n", unit.key());
            let c: TrainConfig = toml::from_str(&text).unwrap();
            assert!(has(&c.model), "{}", unit.key());
            assert_eq!(c.model.unit_switch(unit), Some(true));
        }
    }

    /// The error of `[model] line` without `init`, and the validated config with one.
    fn without_and_with_init(line: &str) -> (String, TrainConfig) {
        let c: TrainConfig = toml::from_str(&format!("[model]\n{line}\n")).unwrap();
        let err = c.validate().unwrap_err().to_string();
        let c: TrainConfig =
            toml::from_str(&format!("[model]\ninit = \"runs/x\"\n{line}\n")).unwrap();
        c.validate().unwrap();
        (err, c)
    }

    #[test]
    fn a_widened_encoder_and_inserted_blocks_need_an_init_model() {
        let (err, c) = without_and_with_init("widen_encoder = [64, 96]");
        assert!(err.contains("model.widen_encoder"), "{err}");
        assert_eq!(c.model.widen_encoder, Some([64, 96]));
        let (err, c) = without_and_with_init("insert_blocks_after = [1, 3]");
        assert!(err.contains("set model.init"), "{err}");
        assert_eq!(c.model.insert_blocks_after, Some(vec![1, 3]));
    }

    #[test]
    fn rigid_extrapolation_switches_the_named_config() {
        let preset = ModelSection::default().model_config().unwrap();
        assert!(preset.dynamics.rigid_extrapolation);
        let c: TrainConfig = toml::from_str("[model]\nrigid_extrapolation = false\n").unwrap();
        let off = c.model.model_config().unwrap();
        assert!(!off.dynamics.rigid_extrapolation);
        assert_eq!(
            off.dynamics.contact_velocity,
            preset.dynamics.contact_velocity
        );
    }

    #[test]
    fn surface_normals_resize_the_named_configs_normalisation() {
        let c: TrainConfig = toml::from_str("[model]\nsurface_normals = true\n").unwrap();
        let on = c.model.model_config().unwrap();
        assert!(on.dynamics.surface_normals && on.dynamics.contact_velocity);
        assert_eq!(on.normalization.len(), 22);
        on.validate().unwrap();
        let c: TrainConfig =
            toml::from_str("[model]\nsurface_normals = true\ncontact_velocity = false\n").unwrap();
        let without_cv = c.model.model_config().unwrap();
        assert_eq!(without_cv.normalization.len(), 19);
        without_cv.validate().unwrap();
        // The approach inputs come last: 3 more, with their own default constants.
        let c: TrainConfig =
            toml::from_str("[model]\nsurface_normals = true\napproach = true\n").unwrap();
        let approach = c.model.model_config().unwrap();
        assert!(approach.dynamics.approach);
        assert_eq!(approach.normalization.len(), 25);
        assert_eq!(approach.normalization.mean[22..], [0.0, 1.0, 0.0]);
        approach.validate().unwrap();
    }

    #[test]
    fn toml_overrides_defaults_and_rejects_unknown_keys() {
        let c: TrainConfig =
            toml::from_str("[optim]\nbatch_size = 4\n[data]\npoints_min = 64\n").unwrap();
        assert_eq!(c.optim.batch_size, 4);
        assert_eq!(c.data.points_min, 64);
        assert_eq!(c.optim.lr, OptimConfig::default().lr);
        c.validate().unwrap();
        assert!(toml::from_str::<TrainConfig>("[optim]\nbatchsize = 4\n").is_err());
        let mut c = TrainConfig::default();
        c.data.points_max = 1;
        assert!(c.validate().unwrap_err().to_string().contains("points_min"));
    }

    #[test]
    fn mix_needs_one_share_per_directory() {
        let ok: TrainConfig =
            toml::from_str("[data]\nextra = [\"a\", \"b\"]\nmix = [0.5, 0.25, 0.0]\n").unwrap();
        ok.validate().unwrap();
        for bad in [
            "mix = [0.5, 0.5]",
            "mix = [0.5, -0.25, 1.0]",
            "mix = [0.0, 0.0, 0.0]",
            "mix = [0.5, nan, 1.0]",
        ] {
            let c: TrainConfig =
                toml::from_str(&format!("[data]\nextra = [\"a\", \"b\"]\n{bad}\n")).unwrap();
            let err = c.validate().unwrap_err().to_string();
            assert!(err.contains("data.mix"), "{bad}: {err}");
        }
    }
}
