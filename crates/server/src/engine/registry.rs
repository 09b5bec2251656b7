//! The resident models: for each its scheduler, request limits and description, and the
//! preparation of request scenes for it (validation, then the model's own per-scene caches).

use std::sync::Arc;

use dynaserve_api::limits::{Caps, Limits};
use dynaserve_api::spec::{ModelInfo, Scene};
use dynaserve_model::{OutOfRange, SceneState};

use crate::error::ApiError;
use crate::families::contract::{SteppedScene, SteppingModel};
use crate::metrics::Metrics;
use crate::scheduler::{Gradients, Scheduler, SchedulerConfig, Steps};

/// A resident stepping model: its schedulers, limits and description.
pub struct ModelEntry {
    /// Name used in requests.
    pub name: String,
    /// The scheduler that owns all forward passes of the model.
    pub scheduler: Scheduler<Steps>,
    /// The scheduler of its gradient passes (bulk work, at most `max_gradient_work`
    /// candidate-steps a pass), when the model computes gradients.
    pub gradients: Option<Scheduler<Gradients>>,
    /// Request limits.
    pub limits: Limits,
    /// Description returned by ListModels.
    pub info: ModelInfo,
    /// Interval of one frame, seconds.
    pub dt_frame: f64,
}

impl ModelEntry {
    /// Starts the schedulers of `model` (steps, and gradient passes when it computes them)
    /// and derives its limits under the server's `caps`.
    pub fn start(
        model: Arc<dyn SteppingModel>,
        caps: &Caps,
        scheduling: SchedulerConfig,
        metrics: &Metrics,
    ) -> std::io::Result<ModelEntry> {
        let name = model.name().to_string();
        let limits = model.limits(caps);
        let info = model.info(limits);
        let dt_frame = model.dt_frame();
        let gradients = match model.gradients_unsupported() {
            Some(_) => None,
            None => {
                let passes = SchedulerConfig {
                    max_batch_objects: usize::try_from(limits.caps.max_gradient_work)
                        .unwrap_or(usize::MAX),
                    ..scheduling.clone()
                };
                let family = Arc::new(Gradients::new(model.clone()));
                Some(Scheduler::start(family, passes, metrics.clone())?)
            }
        };
        let scheduler = Scheduler::start(Arc::new(Steps::new(model)), scheduling, metrics.clone())?;
        Ok(ModelEntry {
            info,
            name,
            scheduler,
            gradients,
            limits,
            dt_frame,
        })
    }

    /// The model.
    pub fn model(&self) -> &Arc<dyn SteppingModel> {
        self.scheduler.family().model()
    }

    /// Physical time after `step` steps of `dt_steps` frames, seconds.
    pub fn time_at(&self, step: u32, dt_steps: u32) -> f64 {
        f64::from(step) * f64::from(dt_steps) * self.dt_frame
    }
}

/// Scenes prepared for a model (request order), with every parameter of their objects that
/// lies outside the model's trained ranges (`(scene path, parameter)`; empty when the model
/// records no ranges).
pub(crate) struct PreparedScenes {
    /// Each scene's caches and initial state.
    pub scenes: Vec<(Arc<dyn SteppedScene>, SceneState)>,
    /// Parameters outside the trained ranges, with the path of their scene.
    pub outside: Vec<(String, OutOfRange)>,
}

/// Most warning lines in one answer: each is a header (HTTP) or metadata entry (gRPC) of about
/// 150 bytes, and a Predict of hundreds of variants must not outgrow a client's header limit
/// (16 KiB is common).
pub(crate) const MAX_WARNINGS: usize = 8;

impl PreparedScenes {
    /// One warning line per parameter outside the trained ranges (ASCII; see
    /// [`OutOfRange::message`]), at most [`MAX_WARNINGS`]: past that, the last line counts
    /// the ones left out.
    pub fn warnings(&self) -> Vec<String> {
        let n = self.outside.len();
        let shown = if n > MAX_WARNINGS {
            MAX_WARNINGS - 1
        } else {
            n
        };
        let mut lines: Vec<String> = self.outside[..shown]
            .iter()
            .map(|(path, o)| o.message(path))
            .collect();
        if n > shown {
            lines.push(format!(
                "{} more parameters outside the trained ranges in later scenes of this request",
                n - shown
            ));
        }
        lines
    }
}

/// Validates, builds and prepares scenes on a blocking thread (mesh sampling and the model's
/// per-scene caches are CPU work that must not run on the async runtime). `field` names the
/// scenes in errors and warnings: `scene` for one, `variants` for `variants[i]`. `kinematic`
/// flags the objects the caller moves (`[objects]`, the same for every scene; empty for
/// none).
pub(crate) async fn prepare_scenes(
    entry: &Arc<ModelEntry>,
    scenes: Vec<Scene>,
    dt_steps: u32,
    field: &'static str,
    kinematic: Arc<[bool]>,
) -> Result<PreparedScenes, ApiError> {
    let entry = entry.clone();
    let single = field == "scene";
    tokio::task::spawn_blocking(move || {
        let mut outside = Vec::new();
        let scenes = scenes
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let path = if single {
                    field.to_string()
                } else {
                    format!("{field}[{i}]")
                };
                let p = entry
                    .model()
                    .prepare(s, &path, &entry.limits, dt_steps, &kinematic)?;
                outside.extend(p.outside.into_iter().map(|o| (path.clone(), o)));
                Ok((p.scene, p.state))
            })
            .collect::<Result<Vec<_>, ApiError>>()?;
        Ok(PreparedScenes { scenes, outside })
    })
    .await
    .map_err(|e| ApiError::internal(format!("scene preparation failed: {e}")))?
}
