//! What the server checks after decoding (steps and step size, variant count, scenes through
//! `build_scene`, session states and actions), against the shipped model's limits and a
//! three-object session whose object 0 is kinematic.

use std::path::Path;
use std::sync::OnceLock;

use dynaserve_api::FieldError;
use dynaserve_api::limits::{Caps, Limits};
use dynaserve_api::spec::session::{CreateSessionSpec, SessionPredictSpec, SetStateSpec, StepSpec};
use dynaserve_api::spec::{Pose, PredictSpec, RolloutSpec};
use dynaserve_model::SceneState;
use dynaserve_server::engine::admission::check_steps;
use dynaserve_server::engine::sessions::input::{apply_states, check_actions, kinematic_mask};
use dynaserve_server::families::built_scene::build_scene;

/// Limits and frame duration of the shipped model.
pub(crate) struct Model {
    limits: Limits,
    dt_frame: f32,
}

fn model() -> &'static Model {
    static M: OnceLock<Model> = OnceLock::new();
    M.get_or_init(|| {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rigidformer-small");
        let config = dynaserve_model::read_config(&dir).expect("the shipped model's config.json");
        Model {
            limits: Limits::new(&Caps::DEFAULT, &config),
            dt_frame: config.dt_frame,
        }
    })
}

/// Objects of the session that session requests are checked against; object 0 is kinematic.
const SESSION_OBJECTS: usize = 3;
pub(crate) const SESSION_KINEMATIC: [bool; SESSION_OBJECTS] = [true, false, false];

pub(crate) fn session_state() -> SceneState {
    let at = |x: f32| Pose {
        translation: [x, 0.0, 0.5],
        rotation: [0.0, 0.0, 0.0, 1.0],
    };
    SceneState {
        previous: (0..SESSION_OBJECTS).map(|i| at(i as f32)).collect(),
        current: (0..SESSION_OBJECTS).map(|i| at(i as f32)).collect(),
        earlier: None,
        carry: Default::default(),
    }
}

pub(crate) fn dt_seconds(dt_steps: u32) -> f32 {
    dt_steps as f32 * model().dt_frame
}

fn variant_count(n: usize) -> Result<(), FieldError> {
    let max = model().limits.caps.max_variants;
    if n == 0 || n > max {
        return Err(FieldError::new(
            "variants",
            format!("{n} variants given; 1..={max} accepted"),
        ));
    }
    Ok(())
}

pub(crate) fn check_rollout(r: RolloutSpec) -> Result<(), FieldError> {
    let dt = check_steps(r.steps, r.dt_steps, &model().limits)?;
    build_scene(&r.scene, "scene", &model().limits, dt_seconds(dt)).map(drop)
}

pub(crate) fn check_predict(r: PredictSpec) -> Result<(), FieldError> {
    let dt = check_steps(r.steps, r.dt_steps, &model().limits)?;
    variant_count(r.variants.len())?;
    for (i, s) in r.variants.iter().enumerate() {
        build_scene(
            s,
            &format!("variants[{i}]"),
            &model().limits,
            dt_seconds(dt),
        )?;
    }
    Ok(())
}

pub(crate) fn check_create(r: CreateSessionSpec) -> Result<(), FieldError> {
    let dt = check_steps(1, r.dt_steps, &model().limits)?;
    kinematic_mask(&r.kinematic, r.scene.objects.len())?;
    build_scene(&r.scene, "scene", &model().limits, dt_seconds(dt)).map(drop)
}

pub(crate) fn check_step(r: StepSpec) -> Result<(), FieldError> {
    check_steps(r.steps, 1, &model().limits)?;
    check_actions(&r.actions, r.steps, &SESSION_KINEMATIC, "actions").map(drop)
}

pub(crate) fn check_set_state(r: SetStateSpec) -> Result<(), FieldError> {
    apply_states(&mut session_state(), &r.objects, dt_seconds(1), "objects")
}

pub(crate) fn check_session_predict(r: SessionPredictSpec) -> Result<(), FieldError> {
    check_steps(r.steps, 1, &model().limits)?;
    variant_count(r.variants.len())?;
    for (i, v) in r.variants.iter().enumerate() {
        apply_states(
            &mut session_state(),
            &v.state,
            dt_seconds(1),
            &format!("variants[{i}].state"),
        )?;
        check_actions(
            &v.actions,
            r.steps,
            &SESSION_KINEMATIC,
            &format!("variants[{i}].actions"),
        )?;
    }
    Ok(())
}
