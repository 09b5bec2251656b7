//! The RigidFormer family (single checkpoints and ensembles, any [`WorldModel`]): scenes are
//! built from point clouds or sampled meshes ([`super::built_scene`]) and prepared once ([`WorldModel::prepare`]:
//! anchors, grouping); a scheduler pass is one batched [`WorldModel::step`], which the model
//! splits into forwards of at most [`DEFAULT_MAX_PASS_OBJECTS`] objects.

use std::any::Any;
use std::path::Path;
use std::sync::Arc;

use dynaserve_api::limits::{Caps, Limits};
use dynaserve_api::spec::{About, ModelInfo, ModelKind, Scene};
use dynaserve_model::config::RIGIDFORMER;
use dynaserve_model::ensemble::ENSEMBLE;
use dynaserve_model::rigidformer::DEFAULT_MAX_PASS_OBJECTS;
use dynaserve_model::{
    Drive, GradientItem, MAX_WORLD_EXTENT, ModelError, PathGradient, PreparedScene, SceneState,
    SpreadStep, StepItem, WorldModel, frame_targets,
};

use super::built_scene::{BuiltScene, build_scene};
use super::contract::{
    GradientJob, Models, Prepared, Resident, SceneStep, Stepped, SteppedScene, SteppingModel,
    pose_in_domain,
};
use super::{LoadOptions, ModelFamily};
use crate::error::ApiError;

/// Loads `rigidformer` checkpoints and `rigidformer-ensemble` directories.
pub struct RigidFormerFamily;

impl ModelFamily for RigidFormerFamily {
    fn recognises(&self, architecture: &str) -> bool {
        architecture == RIGIDFORMER || architecture == ENSEMBLE
    }

    fn load(&self, dir: &Path, opts: &LoadOptions) -> anyhow::Result<Resident> {
        let model = dynaserve_model::load_model(dir, &opts.device)?;
        Ok(Resident::Stepping(Arc::new(RigidFormerModel::new(model))))
    }
}

/// A resident [`WorldModel`] served step by step.
pub struct RigidFormerModel {
    model: Arc<dyn WorldModel>,
    /// Why the model computes no gradients, `None` when it does.
    no_gradients: Option<String>,
}

impl RigidFormerModel {
    /// Serves `model`. Whether it computes gradients is asked once, with an empty
    /// [`WorldModel::path_gradients`] call: only [`ModelError::Unsupported`] means no.
    pub fn new(model: Arc<dyn WorldModel>) -> RigidFormerModel {
        let no_gradients = match model.path_gradients(&[]) {
            Err(ModelError::Unsupported(why)) => Some(match model.member_names().first() {
                Some(first) => format!(
                    "{why} (an ensemble of {} networks: serve one of them, e.g. {first}, \
                     for gradients)",
                    model.member_names().len()
                ),
                None => why,
            }),
            _ => None,
        };
        RigidFormerModel {
            model,
            no_gradients,
        }
    }

    /// One [`WorldModel::step_with_spread`] over `items` (every state usable); each scene's
    /// output is checked to hold one pose (and spread, when there is one) per object.
    #[allow(clippy::type_complexity)]
    fn step_pass(&self, items: &[&SceneStep]) -> Result<Vec<Result<Stepped, String>>, String> {
        let scenes: Vec<&PreparedScene> = items
            .iter()
            .map(|s| prepared(s.scene.as_ref()))
            .collect::<Result<_, _>>()?;
        let led: Vec<Option<SceneState>> = items.iter().map(|s| self.input_state(s)).collect();
        let batch: Vec<StepItem<'_>> = items
            .iter()
            .zip(&scenes)
            .zip(&led)
            .map(|((s, scene), led)| StepItem {
                scene,
                state: led.as_ref().unwrap_or(&s.state),
                dt_steps: s.dt_steps,
            })
            .collect();
        let out = self
            .model
            .step_with_spread(&batch)
            .map_err(|e| e.to_string())?;
        Ok(out
            .into_iter()
            .zip(items)
            .map(|(SpreadStep { poses, spread }, item)| {
                let objects = item.scene.len();
                if poses.len() != objects {
                    return Err(format!(
                        "model returned {} poses for {objects} objects",
                        poses.len()
                    ));
                }
                if let Some(s) = spread.as_ref().filter(|s| s.len() != objects) {
                    return Err(format!(
                        "model returned {} spreads for {objects} objects",
                        s.len()
                    ));
                }
                Ok(Stepped {
                    poses,
                    carry: Default::default(),
                    spread,
                })
            })
            .collect())
    }

    /// The state the network reads for a driven step of a model trained with the kinematic
    /// objects' coming poses ([`dynaserve_model::DynamicsConfig::kinematic_lead`]); `None`
    /// when it reads the scene's own state.
    fn input_state(&self, item: &SceneStep) -> Option<SceneState> {
        let drive = item.drive.as_ref()?;
        let lead = self.model.config().dynamics.kinematic_lead;
        let targets = frame_targets(&drive.kinematic, &drive.next);
        lead.then(|| Drive::new(&drive.kinematic, &targets).input(&item.state, true))
    }
}

/// RigidFormer models served step by step (the models of `dynaserve_server::load_models`).
impl From<Vec<Arc<dyn WorldModel>>> for Models {
    fn from(models: Vec<Arc<dyn WorldModel>>) -> Models {
        Models {
            stepping: models
                .into_iter()
                .map(|m| Arc::new(RigidFormerModel::new(m)) as Arc<dyn SteppingModel>)
                .collect(),
            sampling: Vec::new(),
        }
    }
}

/// Loads RigidFormer model directories (checkpoints or ensembles) on the CPU.
pub fn load_models(dirs: &[std::path::PathBuf]) -> anyhow::Result<Vec<Arc<dyn WorldModel>>> {
    load_models_on(dirs, &candle_core::Device::Cpu)
}

/// [`load_models`] on `device`.
pub fn load_models_on(
    dirs: &[std::path::PathBuf],
    device: &candle_core::Device,
) -> anyhow::Result<Vec<Arc<dyn WorldModel>>> {
    use anyhow::Context;
    dirs.iter()
        .map(|d| {
            dynaserve_model::load_model(d, device)
                .with_context(|| format!("loading model {}", d.display()))
        })
        .collect()
}

/// The model's own prepared scene inside `scene`.
fn prepared(scene: &dyn SteppedScene) -> Result<&PreparedScene, String> {
    scene
        .as_any()
        .downcast_ref::<PreparedScene>()
        .ok_or_else(|| "scene was prepared by another family".to_string())
}

impl SteppedScene for PreparedScene {
    fn len(&self) -> usize {
        PreparedScene::len(self)
    }

    /// Reference points (12 B each), the anchor distance table (4 B per anchor and point) and
    /// the index lists.
    fn bytes(&self) -> usize {
        (0..PreparedScene::len(self))
            .map(|j| {
                let n = self.points_of(j).unwrap_or(0);
                let k = self.anchor_indices(j).map_or(0, <[usize]>::len);
                n * 12 + k * n * 4 + (k + 2 * n) * 8 + 64
            })
            .sum()
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}

impl SteppingModel for RigidFormerModel {
    fn name(&self) -> &str {
        self.model.name()
    }

    fn dt_frame(&self) -> f64 {
        f64::from(self.model.config().dt_frame)
    }

    fn limits(&self, caps: &Caps) -> Limits {
        Limits::new(caps, self.model.config())
    }

    fn info(&self, limits: Limits) -> ModelInfo {
        let config = self.model.config();
        ModelInfo {
            name: self.model.name().to_string(),
            kind: ModelKind::Stepping {
                about: About {
                    architecture: config.architecture.clone(),
                    dt_frame: f64::from(config.dt_frame),
                    gravity: config.gravity,
                    config: serde_json::to_value(config).unwrap_or_default(),
                },
                limits,
            },
            members: self.model.member_names(),
            gradients: self.no_gradients.is_none(),
        }
    }

    fn prepare(
        &self,
        scene: &Scene,
        path: &str,
        limits: &Limits,
        dt_steps: u32,
        kinematic: &[bool],
    ) -> Result<Prepared, ApiError> {
        let dt_seconds = (f64::from(dt_steps) * self.dt_frame()) as f32;
        let BuiltScene { mut objects, state } = build_scene(scene, path, limits, dt_seconds)?;
        for (o, &k) in objects.iter_mut().zip(kinematic) {
            o.kinematic = k;
        }
        check_previous(&state, path)?;
        let outside = match &self.model.config().trained_ranges {
            Some(r) => r.check(&objects),
            None => Vec::new(),
        };
        let scene = self.model.prepare(objects).map_err(|e| match e {
            dynaserve_model::ModelError::InvalidInput(m) => ApiError::invalid(path, m),
            other => ApiError::internal(other.to_string()),
        })?;
        Ok(Prepared {
            scene: Arc::new(scene),
            state,
            outside,
        })
    }

    fn forward_objects(&self) -> Option<usize> {
        Some(DEFAULT_MAX_PASS_OBJECTS)
    }

    /// Items whose state the model would refuse (see [`state_problem`]) fail alone before
    /// the pass; the others go through one [`WorldModel::step`].
    fn step(&self, items: &[&SceneStep]) -> Result<Vec<Result<Stepped, String>>, String> {
        let problems: Vec<Option<String>> = items.iter().map(|s| state_problem(&s.state)).collect();
        let usable: Vec<&SceneStep> = items
            .iter()
            .zip(&problems)
            .filter(|(_, p)| p.is_none())
            .map(|(s, _)| *s)
            .collect();
        let mut out = if usable.is_empty() {
            Vec::new().into_iter()
        } else {
            self.step_pass(&usable)?.into_iter()
        };
        Ok(problems
            .into_iter()
            .map(|p| match p {
                Some(msg) => Err(msg),
                None => out
                    .next()
                    .unwrap_or_else(|| Err("model returned too few scenes".to_string())),
            })
            .collect())
    }

    fn gradients_unsupported(&self) -> Option<String> {
        self.no_gradients.clone()
    }

    fn check_gradient(&self, job: &GradientJob) -> Result<(), ApiError> {
        let scene = prepared(job.scene.as_ref()).map_err(ApiError::internal)?;
        gradient_item(job, scene)
            .validate("candidates")
            .map_err(gradient_error)
    }

    /// One [`WorldModel::path_gradients`] over every job; each job's answer is checked to
    /// hold one entry per candidate.
    fn gradients(&self, jobs: &[&GradientJob]) -> Result<Vec<Vec<PathGradient>>, ApiError> {
        let scenes: Vec<&PreparedScene> = jobs
            .iter()
            .map(|j| prepared(j.scene.as_ref()))
            .collect::<Result<_, _>>()
            .map_err(ApiError::internal)?;
        let items: Vec<GradientItem<'_>> = jobs
            .iter()
            .zip(&scenes)
            .map(|(j, s)| gradient_item(j, s))
            .collect();
        let out = self.model.path_gradients(&items).map_err(gradient_error)?;
        let shapes_ok =
            out.len() == jobs.len() && out.iter().zip(jobs).all(|(o, j)| o.len() == j.paths.len());
        if !shapes_ok {
            return Err(ApiError::internal(format!(
                "model returned gradients of {} calls for a pass of {}, or a wrong candidate count",
                out.len(),
                jobs.len()
            )));
        }
        Ok(out)
    }
}

/// The model's own view of a gradient job on its prepared scene.
fn gradient_item<'a>(job: &'a GradientJob, scene: &'a PreparedScene) -> GradientItem<'a> {
    GradientItem {
        scene,
        state: &job.state,
        kinematic: &job.kinematic,
        paths: &job.paths,
        dt_steps: job.dt_steps,
        cost: &job.cost,
        deadline: job.deadline,
    }
}

/// The API error of a failed gradient call: unsupported is FAILED_PRECONDITION, a passed
/// deadline DEADLINE_EXCEEDED, invalid input INVALID_ARGUMENT naming `candidates`.
fn gradient_error(e: ModelError) -> ApiError {
    match e {
        ModelError::Unsupported(m) => ApiError::failed_precondition(m),
        ModelError::DeadlineExceeded(m) => ApiError::deadline(format!("deadline exceeded: {m}")),
        ModelError::InvalidInput(m) => {
            let m = m.strip_prefix("candidates: ").unwrap_or(&m);
            ApiError::invalid("candidates", m)
        }
        other => ApiError::internal(other.to_string()),
    }
}

/// The pose one step before the start (`translation - velocity * dt`) must lie in the model's
/// domain too, or the first step would fail; the error names the velocity that puts it there.
fn check_previous(state: &SceneState, path: &str) -> Result<(), ApiError> {
    match state.previous.iter().position(|p| !pose_in_domain(p)) {
        None => Ok(()),
        Some(j) => Err(ApiError::invalid(
            format!("{path}.objects[{j}].velocity.linear"),
            format!(
                "with this translation and velocity the object was beyond {MAX_WORLD_EXTENT} m \
                 one step earlier; the model accepts positions within {MAX_WORLD_EXTENT} m"
            ),
        )),
    }
}

/// Why a state is outside the model's domain (a pose translation not finite or beyond
/// [`MAX_WORLD_EXTENT`] metres, a rotation that is not a usable quaternion), naming the object;
/// `None` for a usable state. The message holds only this scene's data.
pub fn state_problem(state: &SceneState) -> Option<String> {
    let earlier = state.earlier.as_deref().unwrap_or_default();
    for (which, poses) in [
        ("earlier", earlier),
        ("previous", &state.previous[..]),
        ("current", &state.current[..]),
    ] {
        for (j, p) in poses.iter().enumerate() {
            if !pose_in_domain(p) {
                return Some(format!(
                    "objects[{j}]: {which} pose outside the model's domain (translation {:?} m, \
                     limit {MAX_WORLD_EXTENT} m)",
                    p.translation
                ));
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynaserve_model::Pose;

    fn at(x: f32) -> Pose {
        Pose {
            translation: [x, 0.0, 1.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        }
    }

    #[test]
    fn a_state_outside_the_domain_is_named_by_object_and_pose() {
        let fine = SceneState::new(vec![at(0.0), at(1.0)], vec![at(0.0), at(1.1)]);
        assert_eq!(state_problem(&fine), None);
        let far = 2.0 * MAX_WORLD_EXTENT;
        let mut current = fine.clone();
        current.current[1] = at(far);
        let said = state_problem(&current).unwrap();
        assert!(said.starts_with("objects[1]: current pose"), "{said}");
        let mut earlier = fine.clone();
        earlier.earlier = Some(vec![at(f32::NAN), at(1.0)]);
        let said = state_problem(&earlier).unwrap();
        assert!(said.starts_with("objects[0]: earlier pose"), "{said}");
        earlier.earlier = Some(vec![at(0.0), at(0.9)]);
        assert_eq!(state_problem(&earlier), None);
    }
}
