//! End-to-end tests of the `rapier` family (the simulator served as a model, beside the
//! bundled RigidFormer) on a real server on 127.0.0.1: ListModels, Rollout, Predict, sessions
//! (Step with a driven pusher, Fork, Predict from a session, SetState) and Interact, over gRPC
//! and HTTP. Every forecast must equal `dynaserve sim replay` of the same scene (the replay
//! library the command runs) within 1e-6 m.

mod common;

use std::path::PathBuf;
use std::time::Duration;

use common::*;
use dynaserve_api::json;
use dynaserve_api::v1;
use dynaserve_server::ServeConfig;
use dynaserve_sim::replay::{PathDoc, ReplayOptions, replay};

const SIM: &str = "rapier";
const SIM_DIR: &str = "models/simulators/rapier";
const TOLERANCE: f32 = 1e-6;

async fn start_both() -> dynaserve_server::RunningServer {
    let dirs = vec![PathBuf::from(SHIPPED), PathBuf::from(SIM_DIR)];
    let config = ServeConfig::local(dirs.clone());
    let models = dynaserve_server::load_all(&dirs).unwrap();
    let server = dynaserve_server::start(config, models).await.unwrap();
    server.wait_ready(Duration::from_secs(60)).await.unwrap();
    server
}

/// The corners of a cube of half-size `half` metres.
fn cube(half: f32) -> Vec<[f32; 3]> {
    dynaserve_geometry::mesh::cube()
        .vertices
        .iter()
        .map(|v| v.map(|c| 2.0 * half * c))
        .collect()
}

fn at_rest(points: Vec<[f32; 3]>, x: f32, z: f32, mass: f32) -> json::ObjectSpec {
    json::ObjectSpec {
        points: Some(points),
        mesh: None,
        pose: json::Pose {
            translation: [x, 0.0, z],
            rotation: [0.0, 0.0, 0.0, 1.0],
        },
        previous_pose: None,
        velocity: None,
        mass,
        friction: 0.5,
        restitution: 0.2,
    }
}

/// A box on the floor and a pusher (object 1) behind it.
fn push_scene() -> json::Scene {
    json::Scene {
        objects: vec![
            at_rest(cube(0.1), 0.0, 0.1, 1.0),
            at_rest(cube(0.05), -0.3, 0.05, 1.0),
        ],
    }
}

/// The pusher's pose after each of `steps` steps: 3 cm per step along +x.
fn pusher_path(steps: usize) -> Vec<json::Pose> {
    (1..=steps)
        .map(|k| json::Pose {
            translation: [-0.3 + 0.03 * k as f32, 0.0, 0.05],
            rotation: [0.0, 0.0, 0.0, 1.0],
        })
        .collect()
}

fn path_doc(path: &[json::Pose]) -> PathDoc {
    PathDoc {
        object: 1,
        poses: path
            .iter()
            .map(|p| {
                let (t, q) = (p.translation, p.rotation);
                [t[0], t[1], t[2], q[0], q[1], q[2], q[3]]
            })
            .collect(),
    }
}

fn action(p: &json::Pose) -> json::Action {
    json::Action {
        kinematic: vec![json::ObjectPose {
            object: 1,
            pose: *p,
        }],
    }
}

/// The replay's poses `[steps + 1][objects][7]` of `scene` (with `paths`), `dt_steps` frames
/// per step.
fn replayed(
    scene: &json::Scene,
    paths: &[PathDoc],
    steps: usize,
    dt_steps: u32,
) -> Vec<Vec<[f32; 7]>> {
    let opts = ReplayOptions {
        dt_steps,
        ..ReplayOptions::default()
    };
    replay(scene, paths, steps, &opts).unwrap().poses
}

/// Largest translation difference (m) between served frames and replay steps `from..`; the
/// rotations must agree within the same tolerance (up to the quaternion's sign).
fn worst(frames: &[json::StepFrame], expected: &[Vec<[f32; 7]>], from: usize) -> f32 {
    assert_eq!(frames.len() + from, expected.len(), "frame count");
    let mut worst = 0.0f32;
    for (f, e) in frames.iter().zip(&expected[from..]) {
        assert_eq!(f.poses.len(), e.len());
        for (p, q) in f.poses.iter().zip(e) {
            for (a, b) in p.translation.iter().zip(q) {
                worst = worst.max((a - b).abs());
            }
            let dot: f32 = (0..4).map(|k| p.rotation[k] * q[3 + k]).sum();
            assert!(
                1.0 - dot.abs() < 1e-6,
                "rotation {:?} vs {:?}",
                p.rotation,
                &q[3..]
            );
        }
    }
    worst
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_simulator_is_listed_and_its_rollouts_and_predictions_are_the_replay() {
    let server = start_both().await;
    let mut c = client(&server).await;

    // Listed beside the learned model, over gRPC and HTTP.
    let models = c.list_models().await.unwrap();
    let sim = models
        .iter()
        .find(|m| m.name == SIM)
        .expect("rapier listed");
    assert_eq!(sim.architecture, "rapier");
    assert!((sim.dt_frame - 1.0 / 24.0).abs() < 1e-6);
    assert!(models.iter().any(|m| m.architecture == "rigidformer"));
    let listed: json::ListModelsResponse = http(server.http_addr, "GET", "/v1/models", &[], None)
        .await
        .json();
    let sim_json = listed.models.iter().find(|m| m.name == SIM).unwrap();
    assert_eq!(sim_json.config["physics_hz"], 240);

    // Rollout over gRPC: falling, colliding boxes; and with two frames per step.
    let scene = scene(7, 3, 32);
    for dt_steps in [1, 2] {
        let mut req = rollout_request(SIM, scene.clone(), 40);
        req.dt_steps = dt_steps;
        let frames = c.rollout_collect(&req).await.unwrap();
        let expected = replayed(&scene, &[], 40, dt_steps);
        let w = worst(&frames, &expected, 1);
        assert!(
            w <= TOLERANCE,
            "rollout dt_steps {dt_steps}: {w} m from the replay"
        );
        assert!((frames[9].time - 10.0 * f64::from(dt_steps) / 24.0).abs() < 1e-6);
    }

    // Rollout over HTTP of a mesh object: the hull of its vertices, as in the replay.
    let mesh = dynaserve_geometry::mesh::cube();
    let mut meshed = push_scene();
    meshed.objects[0].points = None;
    meshed.objects[0].mesh = Some(json::TriangleMesh {
        vertices: mesh.vertices.iter().map(|v| v.map(|c| c * 0.2)).collect(),
        faces: mesh.faces.clone(),
        samples: 0,
        seed: 0,
    });
    meshed.objects[0].pose.translation[2] = 0.5;
    let resp = post_json(
        server.http_addr,
        "/v1/rollout",
        &rollout_request(SIM, meshed.clone(), 20),
    )
    .await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    let body: json::RolloutResponse = resp.json();
    let w = worst(&body.frames, &replayed(&meshed, &[], 20, 1), 1);
    assert!(w <= TOLERANCE, "mesh rollout: {w} m from the replay");

    // Predict: every variant is its own replay (every 5th step).
    let variants: Vec<json::Scene> = (0..4).map(|s| common::scene(20 + s, 2, 24)).collect();
    let predicted = c
        .predict(&json::PredictRequest {
            model: SIM.into(),
            variants: variants.clone(),
            steps: 25,
            dt_steps: 1,
            every: 5,
            timeout_ms: 0,
        })
        .await
        .unwrap();
    for (v, t) in variants.iter().zip(&predicted.trajectories) {
        let all = replayed(v, &[], 25, 1);
        let expected: Vec<Vec<[f32; 7]>> = [5, 10, 15, 20, 25]
            .iter()
            .map(|&k| all[k].clone())
            .collect();
        let w = worst(&t.frames, &expected, 0);
        assert!(w <= TOLERANCE, "predict: {w} m from the replay");
    }

    // The same scheduler and metrics as the learned models.
    let text = metrics(&server).await;
    let steps = sample(&text, "dynaserve_scene_steps_total{model=\"rapier\"}").unwrap_or(0.0);
    assert!(
        steps >= 80.0 + 20.0 + 100.0,
        "{steps} scene-steps counted for the simulator"
    );
    assert!(
        text.contains("dynaserve_batch_scenes_count{model=\"rapier\"}"),
        "pass metrics for the simulator"
    );
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_and_interact_drive_the_simulator_as_a_replay_with_paths() {
    let server = start_both().await;
    let scene = push_scene();
    let steps = 24;
    let path = pusher_path(steps);
    let expected = replayed(&scene, &[path_doc(&path)], steps, 1);
    // The pusher really moves the box.
    assert!(
        expected[steps][0][0] > 0.1,
        "box at {:?}",
        expected[steps][0]
    );

    // HTTP: create, step 12 with actions, fork, step both 12 more.
    let info = create_session_http(server.http_addr, SIM, scene.clone(), vec![1]).await;
    let base = format!("/v1/sessions/{}", info.session_id);
    let step = |from: usize, n: usize| json::StepRequest {
        steps: n as u32,
        actions: path[from..from + n].iter().map(action).collect(),
        timeout_ms: 0,
    };
    let first: json::StepResponse =
        post_json(server.http_addr, &format!("{base}/step"), &step(0, 12))
            .await
            .json();
    let w = worst(&first.frames, &expected[..13], 1);
    assert!(w <= TOLERANCE, "session steps 1-12: {w} m");
    let fork = post_json(
        server.http_addr,
        &format!("{base}/fork"),
        &serde_json::json!({}),
    )
    .await;
    assert_eq!(fork.status, 201, "{}", fork.text());
    let fork: json::SessionInfo = fork.json();
    for id in [&info.session_id, &fork.session_id] {
        let rest: json::StepResponse = post_json(
            server.http_addr,
            &format!("/v1/sessions/{id}/step"),
            &step(12, 12),
        )
        .await
        .json();
        let w = worst(&rest.frames, &expected[12..], 13 - 12);
        assert!(w <= TOLERANCE, "session {id} steps 13-24: {w} m");
    }

    // Predict from a session at step 24: variants continuing the push are the replay of the
    // longer path.
    let longer = pusher_path(steps + 6);
    let expected_longer = replayed(&scene, &[path_doc(&longer)], steps + 6, 1);
    let resp = post_json(
        server.http_addr,
        &format!("{base}/predict"),
        &json::SessionPredictRequest {
            variants: vec![
                json::SessionVariant {
                    state: vec![],
                    actions: longer[steps..].iter().map(action).collect(),
                };
                2
            ],
            steps: 6,
            every: 1,
            timeout_ms: 0,
        },
    )
    .await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    let predicted: json::PredictResponse = resp.json();
    for t in &predicted.trajectories {
        let w = worst(&t.frames, &expected_longer[steps..], 1);
        assert!(w <= TOLERANCE, "session predict: {w} m");
    }

    // gRPC Interact through the client: a new session for the stream, one action per message.
    let mut c = client(&server).await;
    let mut interaction = c
        .interact(v1::InteractRequest {
            create: Some(v1::CreateSessionRequest {
                model: SIM.into(),
                scene: Some(scene.to_proto()),
                dt_steps: 1,
                kinematic: vec![1],
                shared: false,
            }),
            ..Default::default()
        })
        .await
        .unwrap();
    let mut frames = Vec::new();
    for p in &path {
        let f = interaction
            .step(v1::InteractRequest {
                action: Some(v1::Action {
                    kinematic: vec![v1::ObjectPose {
                        object: 1,
                        pose: Some(p.to_proto()),
                    }],
                }),
                ..Default::default()
            })
            .await
            .unwrap();
        frames.push(json::StepFrame::from_proto(&f));
    }
    let w = worst(&frames, &expected, 1);
    assert!(w <= TOLERANCE, "interact: {w} m");

    // SetState puts the box elsewhere: the simulator rebuilds from the new poses and the box
    // falls from where it was put.
    let set_body = serde_json::to_vec(&json::SetStateRequest {
        objects: vec![json::ObjectState {
            object: 0,
            pose: json::Pose {
                translation: [2.0, 0.0, 1.0],
                rotation: [0.0, 0.0, 0.0, 1.0],
            },
            previous_pose: None,
            velocity: None,
        }],
    })
    .unwrap();
    let set = http(
        server.http_addr,
        "PUT",
        &format!("/v1/sessions/{}/state", fork.session_id),
        &[("content-type", "application/json")],
        Some(&set_body),
    )
    .await;
    assert_eq!(set.status, 200, "{}", set.text());
    let after: json::StepResponse = post_json(
        server.http_addr,
        &format!("/v1/sessions/{}/step", fork.session_id),
        &json::StepRequest {
            steps: 6,
            actions: vec![],
            timeout_ms: 0,
        },
    )
    .await
    .json();
    let z: Vec<f32> = after
        .frames
        .iter()
        .map(|f| f.poses[0].translation[2])
        .collect();
    assert!(z.windows(2).all(|w| w[1] < w[0]), "falls: {z:?}");
    let fallen = 1.0 - z[5];
    let free_fall = 0.5 * 10.0 * (6.0f32 / 24.0).powi(2);
    assert!(
        (fallen - free_fall).abs() < 0.01,
        "fell {fallen} m, free fall {free_fall} m"
    );
    server.shutdown();
}
