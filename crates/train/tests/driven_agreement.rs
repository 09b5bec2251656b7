//! One driven step for serving, evaluation and training: a push scene (the pusher kinematic)
//! stepped from the same state, with the same kinematic mask and the pusher's same recorded
//! poses as targets, through driven evaluation (`driven_rollout_batch`), pushforward training
//! (`pushforward::apply`) and the calls a session step makes around its scheduled network call
//! (`Drive::input`, then `Drive::overwrite` and the state's advance), gives the same poses,
//! bit for bit, with the kinematic lead off and on.

use std::path::Path;
use std::sync::Arc;

use dynaserve_model::{
    Device, Drive, Pose, PreparedScene, RigidFormer, SceneState, StepItem, WorldModel,
    load_rigidformer,
};
use dynaserve_sim::generators::{GenerateOptions, generate_scene};
use dynaserve_sim::scenarios::Scenario;
use dynaserve_sim::{Generator, SceneRecord};
use dynaserve_train::eval::driven::driven_rollout_batch;
use dynaserve_train::eval::{ModelPredictor, Predictor, RolloutRequest, poses_at};
use dynaserve_train::train::data::Sample;
use dynaserve_train::train::pushforward;

/// The frame the steps start from: one where the pusher's speed changes enough for the lead
/// to move the pushed object (`push_eval.rs`, `LEAD_START`).
const START: usize = 34;
/// Driven steps of one step size each.
const STEPS: usize = 3;

/// The first push scene of seed 3 (split test, 128 points per object).
fn push_scene() -> SceneRecord {
    let mut opts = GenerateOptions::new(Generator::scenario(Scenario::Push), 3, "test", 1);
    opts.points = 128;
    generate_scene(&opts, 0).unwrap().record
}

/// The shipped checkpoint with the kinematic lead switched `lead`.
fn model(lead: bool) -> Arc<RigidFormer> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rigidformer-small");
    let m = load_rigidformer(&dir, &Device::Cpu, false)
        .expect("the shipped checkpoint loads")
        .with_settings(|d, _| d.kinematic_lead = lead)
        .unwrap();
    Arc::new(m)
}

fn frame(scene: &SceneRecord, t: usize) -> Vec<Pose> {
    poses_at(scene, t).unwrap()
}

/// Driven evaluation: `[STEPS][objects]`, the poses at frames `START + 1 ..= START + STEPS`.
fn evaluation(predictor: &ModelPredictor, scene: &SceneRecord) -> Vec<Vec<Pose>> {
    let request = RolloutRequest {
        scene,
        observed: SceneState::new(frame(scene, START - 1), frame(scene, START)),
        dt_steps: 1,
        steps: STEPS,
    };
    driven_rollout_batch(predictor, &[request], &[START])
        .unwrap()
        .pop()
        .unwrap()
}

/// Pushforward training: a sample at `START + STEPS` whose `STEPS + 1` recorded frames reach
/// back to `START - 1`; returns its state once the model's predictions replaced its poses.
fn training(model: &RigidFormer, prepared: PreparedScene, scene: &SceneRecord) -> SceneState {
    let kinematic: Vec<bool> = scene.objects.iter().map(|o| o.kinematic).collect();
    let at = START + STEPS;
    let mut samples = vec![Sample {
        scene: prepared,
        state: SceneState::new(frame(scene, at - 1), frame(scene, at)),
        target: frame(scene, at + 1),
        dt_steps: 1,
        kinematic,
        pushforward: Some((START - 1..at).map(|t| frame(scene, t)).collect()),
    }];
    assert_eq!(pushforward::apply(model, &mut samples).unwrap(), 1);
    samples.pop().unwrap().state
}

/// A session's `Step` with one action per step naming the pusher's recorded pose: the state
/// to submit from `Drive::input`, the network's answer (the scheduler's call, made here
/// directly), its kinematic poses overwritten by `Drive::overwrite`, the state advanced.
fn serving(model: &RigidFormer, prepared: &PreparedScene, scene: &SceneRecord) -> Vec<Vec<Pose>> {
    let kinematic: Vec<bool> = scene.objects.iter().map(|o| o.kinematic).collect();
    let lead = model.config().dynamics.kinematic_lead;
    let mut state = SceneState::new(frame(scene, START - 1), frame(scene, START));
    (1..=STEPS)
        .map(|k| {
            let recorded = frame(scene, START + k);
            let targets: Vec<(usize, Pose)> = (0..kinematic.len())
                .filter(|&j| kinematic[j])
                .map(|j| (j, recorded[j]))
                .collect();
            let drive = Drive::new(&kinematic, &targets);
            let submitted = drive.input(&state, lead);
            let mut output = model
                .step(&[StepItem {
                    scene: prepared,
                    state: &submitted,
                    dt_steps: 1,
                }])
                .unwrap()
                .pop()
                .unwrap();
            drive.overwrite(&state, &mut output);
            state.advance(output.clone());
            output
        })
        .collect()
}

#[test]
fn serving_evaluation_and_training_step_a_driven_scene_alike() {
    let scene = push_scene();
    let pusher = scene.objects.iter().position(|o| o.kinematic).unwrap();
    let pushed = scene.objects.iter().position(|o| !o.kinematic).unwrap();
    let mut by_lead = Vec::new();
    for lead in [false, true] {
        let model = model(lead);
        let predictor = ModelPredictor::from_rigidformer(model.clone());
        assert_eq!(predictor.leads_kinematic(), lead);
        let prepared = || model.prepare(predictor.inputs(&scene)).unwrap();

        let evaluated = evaluation(&predictor, &scene);
        let served = serving(&model, &prepared(), &scene);
        let trained = training(&model, prepared(), &scene);

        assert_eq!(served, evaluated, "serving and evaluation (lead {lead})");
        assert_eq!(
            trained.current,
            evaluated[STEPS - 1],
            "training (lead {lead})"
        );
        assert_eq!(
            trained.previous,
            evaluated[STEPS - 2],
            "training (lead {lead})"
        );
        for (k, poses) in evaluated.iter().enumerate() {
            assert_eq!(poses[pusher], frame(&scene, START + 1 + k)[pusher]);
        }
        by_lead.push(evaluated[STEPS - 1][pushed]);
    }
    // The lead reaches the network on every path: it moves the pushed object.
    assert_ne!(by_lead[0], by_lead[1], "the lead changed nothing");
}
