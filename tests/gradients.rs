//! End-to-end tests of session Gradient calls on a real server on 127.0.0.1, over gRPC (the
//! client crate's `Client::gradient`) and HTTP (`POST /v1/sessions/{id}/gradient`), on a box
//! resting on the floor and a kinematic pusher moving into it:
//!
//! - every candidate's cost equals `dynaserve_model::path_cost` of the rollout a session
//!   Predict of the same path gives, and the answer's frames are that rollout; gradients are
//!   finite, not all zero for a path in contact, and the same over both transports;
//! - bad candidates, costs and limits are refused with INVALID_ARGUMENT / 422 naming the field;
//! - an ensemble and the rapier simulator answer FAILED_PRECONDITION / 400;
//! - a deadline that cannot be met answers DEADLINE_EXCEEDED, also for a call still queued;
//! - concurrent calls are served, those queued together in one gradient pass.
//!
//! The gradients themselves are checked against finite differences in
//! `crates/model/tests/gradients.rs`.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use common::*;
use dynaserve_api::{json, v1};
use dynaserve_model::{PathCost, Pose, SceneState, path_cost};
use dynaserve_server::{Models, ServeConfig};

/// The shipped RigidFormer (backpropagation through its rollout).
const MODEL: &str = "rigidformer-small";
const ENSEMBLE: &str = "rigidformer-small-ensemble";
const SIM: &str = "rapier";
const SIM_DIR: &str = "models/simulators/rapier";
/// Steps of a candidate: the pusher reaches the box after three.
const STEPS: u32 = 6;
/// The server's `--max-gradient-work` in these tests.
const MAX_WORK: u64 = 256;

/// A server with the shipped RigidFormer, the shipped ensemble and the rapier simulator,
/// `--max-gradient-work` [`MAX_WORK`].
async fn start_all() -> dynaserve_server::RunningServer {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let network = load(&root.join(SHIPPED));
    let ensemble = load(&root.join(SHIPPED_ENSEMBLE));
    let mut models = Models::from(vec![network, ensemble]);
    let sim = dynaserve_server::load_all(&[root.join(SIM_DIR)]).unwrap();
    models.stepping.extend(sim.stepping);
    let mut config = ServeConfig::local(Vec::new());
    config.max_gradient_work = MAX_WORK;
    let server = dynaserve_server::start(config, models).await.unwrap();
    server.wait_ready(Duration::from_secs(120)).await.unwrap();
    server
}

/// Surface points of a cube of half-size `half` metres: a 4 x 4 grid on each face.
fn cube_points(half: f32) -> Vec<[f32; 3]> {
    let grid: Vec<f32> = (0..4)
        .map(|i| half * (-1.0 + 2.0 * i as f32 / 3.0))
        .collect();
    let mut out = Vec::new();
    for axis in 0..3 {
        for side in [-half, half] {
            for &u in &grid {
                for &v in &grid {
                    let mut p = [0.0; 3];
                    p[axis] = side;
                    p[(axis + 1) % 3] = u;
                    p[(axis + 2) % 3] = v;
                    out.push(p);
                }
            }
        }
    }
    out
}

fn at(x: f32, z: f32) -> json::Pose {
    json::Pose {
        translation: [x, 0.0, z],
        rotation: [0.0, 0.0, 0.0, 1.0],
    }
}

/// A 20 cm box resting on the floor (object 0) and a 10 cm pusher 30 cm behind it (object 1,
/// kinematic).
fn push_scene() -> json::Scene {
    let object = |half: f32, x: f32| json::ObjectSpec {
        points: Some(cube_points(half)),
        mesh: None,
        pose: at(x, half),
        previous_pose: None,
        velocity: None,
        mass: 1.0,
        friction: 0.5,
        restitution: 0.2,
    };
    json::Scene {
        objects: vec![object(0.1, 0.0), object(0.05, -0.3)],
    }
}

/// The pusher's path: `speed` metres per step along +x for `steps` steps (in contact with the
/// box from the fourth step at 5 cm a step).
fn path(speed: f32, steps: u32) -> Vec<json::Action> {
    (1..=steps)
        .map(|k| json::Action {
            kinematic: vec![json::ObjectPose {
                object: 1,
                pose: at(-0.3 + speed * k as f32, 0.05),
            }],
        })
        .collect()
}

/// The box pushed to x = 0.3 m, upright, and a smooth path.
fn cost() -> json::GradientCost {
    json::GradientCost {
        targets: vec![json::CostTarget {
            object: 0,
            step: 0,
            position: [0.3, 0.0, 0.1],
            position_weight: 1.0,
            rotation: Some([0.0, 0.0, 0.0, 1.0]),
            rotation_weight: 0.5,
        }],
        smoothness: 0.1,
    }
}

/// The model's form of [`cost`] for rollouts of `steps` steps.
fn model_cost(steps: u32) -> PathCost {
    PathCost {
        targets: vec![dynaserve_model::CostTarget {
            object: 0,
            step: steps as usize,
            position: [0.3, 0.0, 0.1],
            position_weight: 1.0,
            rotation: Some([0.0, 0.0, 0.0, 1.0]),
            rotation_weight: 0.5,
        }],
        smoothness: 0.1,
    }
}

fn request(candidates: &[Vec<json::Action>], steps: u32) -> json::SessionGradientRequest {
    json::SessionGradientRequest {
        candidates: candidates
            .iter()
            .map(|a| json::GradientCandidate { actions: a.clone() })
            .collect(),
        steps,
        cost: cost(),
        every: 1,
        timeout_ms: 0,
    }
}

fn action_v1(a: &json::Action) -> v1::Action {
    v1::Action {
        kinematic: a
            .kinematic
            .iter()
            .map(|k| v1::ObjectPose {
                object: k.object,
                pose: Some(k.pose.to_proto()),
            })
            .collect(),
    }
}

/// The gRPC form of a JSON request on session `id`.
fn request_v1(id: &str, r: &json::SessionGradientRequest) -> v1::SessionGradientRequest {
    let c = &r.cost;
    v1::SessionGradientRequest {
        session_id: id.into(),
        candidates: r
            .candidates
            .iter()
            .map(|c| v1::GradientCandidate {
                actions: c.actions.iter().map(action_v1).collect(),
            })
            .collect(),
        steps: r.steps,
        cost: Some(v1::GradientCost {
            targets: c
                .targets
                .iter()
                .map(|t| v1::CostTarget {
                    object: t.object,
                    step: t.step,
                    position: Some(v1::Vec3 {
                        x: t.position[0],
                        y: t.position[1],
                        z: t.position[2],
                    }),
                    position_weight: t.position_weight,
                    rotation: t.rotation.map(|[x, y, z, w]| v1::Quaternion { x, y, z, w }),
                    rotation_weight: t.rotation_weight,
                })
                .collect(),
            smoothness: c.smoothness,
        }),
        every: r.every,
        timeout_ms: r.timeout_ms,
    }
}

async fn create(c: &mut dynaserve_client::Client, model: &str) -> String {
    let created = c
        .create_session(v1::CreateSessionRequest {
            model: model.into(),
            scene: Some(push_scene().to_proto()),
            kinematic: vec![1],
            ..Default::default()
        })
        .await
        .unwrap();
    created.info.session_id
}

fn pose_of(p: &v1::Pose) -> Pose {
    let j = json::Pose::from_proto(p);
    Pose {
        translation: j.translation,
        rotation: j.rotation,
    }
}

fn vec3(v: &Option<v1::Vec3>) -> [f32; 3] {
    let v = v.unwrap_or_default();
    [v.x, v.y, v.z]
}

/// Every gradient of a gRPC answer, `[candidates][steps][kinematic]` (translation, rotation).
type Grads = Vec<Vec<Vec<([f32; 3], [f32; 3])>>>;

fn grads_v1(r: &v1::GradientResponse) -> Grads {
    r.candidates
        .iter()
        .map(|c| {
            c.steps
                .iter()
                .map(|s| {
                    s.kinematic
                        .iter()
                        .map(|g| (vec3(&g.translation), vec3(&g.rotation)))
                        .collect()
                })
                .collect()
        })
        .collect()
}

fn grads_json(r: &json::GradientResponse) -> Grads {
    r.candidates
        .iter()
        .map(|c| {
            c.steps
                .iter()
                .map(|s| {
                    s.kinematic
                        .iter()
                        .map(|g| (g.translation, g.rotation))
                        .collect()
                })
                .collect()
        })
        .collect()
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()) + 1e-6
}

/// (a) and (b) on `model`: costs recomputed from a session Predict of the same paths, the
/// answer's frames that Predict's rollout, gradients finite and not all zero, the same over
/// gRPC and HTTP.
async fn answers_like_predict(model: &str) {
    let server = start_all().await;
    let mut c = client(&server).await;
    let id = create(&mut c, model).await;
    let candidates = [path(0.05, STEPS), path(0.04, STEPS)];
    let req = request(&candidates, STEPS);
    let over_grpc = c.gradient(request_v1(&id, &req)).await;
    let over_grpc = over_grpc.unwrap_or_else(|e| panic!("{model}: gRPC Gradient: {e}"));
    assert_eq!(over_grpc.model, model);
    assert_eq!(over_grpc.candidates.len(), candidates.len());

    // The same paths through a session Predict, every step kept.
    let state = c.get_state(&id).await.unwrap();
    let start = SceneState {
        previous: state.previous_poses.iter().map(pose_of).collect(),
        current: state.poses.iter().map(pose_of).collect(),
        earlier: None,
        carry: Default::default(),
    };
    let predicted = c
        .predict_session(v1::SessionPredictRequest {
            session_id: id.clone(),
            variants: candidates
                .iter()
                .map(|a| v1::SessionVariant {
                    state: Vec::new(),
                    actions: a.iter().map(action_v1).collect(),
                })
                .collect(),
            steps: STEPS,
            every: 1,
            timeout_ms: 0,
        })
        .await
        .unwrap();
    let kinematic = [false, true];
    for (i, (answer, trajectory)) in over_grpc
        .candidates
        .iter()
        .zip(&predicted.trajectories)
        .enumerate()
    {
        let poses: Vec<Vec<Pose>> = trajectory
            .frames
            .iter()
            .map(|f| f.poses.iter().map(pose_of).collect())
            .collect();
        let expected = path_cost(&model_cost(STEPS), &start, &kinematic, &poses);
        assert!(
            close(answer.cost, expected, 1e-3),
            "{model}: candidate {i}: cost {} from Gradient, {expected} from Predict",
            answer.cost
        );
        // The answer's frames are the rollout the cost was measured on.
        let frames: Vec<json::StepFrame> = answer
            .frames
            .iter()
            .map(json::StepFrame::from_proto)
            .collect();
        let steps: Vec<u32> = frames.iter().map(|f| f.step).collect();
        assert_eq!(steps, (1..=STEPS).collect::<Vec<_>>(), "{model}");
        let drift = max_diff(&frames, &poses);
        assert!(
            drift < 1e-3,
            "{model}: candidate {i}: frames {drift} m from Predict's"
        );
        assert_eq!(answer.steps.len(), STEPS as usize);
        assert!(answer.steps.iter().all(|s| s.kinematic.len() == 1));
    }
    let grads = grads_v1(&over_grpc);
    let values: Vec<f32> = grads
        .iter()
        .flatten()
        .flatten()
        .flat_map(|(t, r)| t.iter().chain(r).copied().collect::<Vec<_>>())
        .collect();
    assert!(values.iter().all(|v| v.is_finite()), "{model}: {grads:?}");
    // The pusher moves the box: where it is in contact, moving it changes the cost.
    let pushing: f32 = grads[0][STEPS as usize - 2..]
        .iter()
        .map(|s| s[0].0.iter().map(|v| v.abs()).sum::<f32>())
        .sum();
    assert!(
        pushing > 0.0,
        "{model}: no gradient where the pusher pushes: {grads:?}"
    );

    // The same call over HTTP answers the same.
    let resp = post_json(
        server.http_addr,
        &format!("/v1/sessions/{id}/gradient"),
        &req,
    )
    .await;
    assert_eq!(resp.status, 200, "{model}: {}", resp.text());
    assert!(resp.header("x-dynaserve-forward-ms").is_some());
    let over_http: json::GradientResponse = resp.json();
    for (a, b) in over_grpc.candidates.iter().zip(&over_http.candidates) {
        assert!(
            close(a.cost, b.cost, 1e-6),
            "{model}: {} vs {}",
            a.cost,
            b.cost
        );
    }
    for (a, b) in grads
        .iter()
        .flatten()
        .flatten()
        .zip(grads_json(&over_http).iter().flatten().flatten())
    {
        for (x, y) in a.0.iter().chain(&a.1).zip(b.0.iter().chain(&b.1)) {
            assert!(
                close(f64::from(*x), f64::from(*y), 1e-5),
                "{model}: {a:?} vs {b:?}"
            );
        }
    }
    // The session did not move.
    assert_eq!(c.get_state(&id).await.unwrap().step, 0);
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn rigidformer_gradients_answer_like_predict_on_both_transports() {
    answers_like_predict(MODEL).await;
}

/// An HTTP error's status, code and field.
fn http_error(r: &HttpResponse) -> (u16, String, Option<String>) {
    let e: json::ErrorResponse = r.json();
    (r.status, e.error.code, e.error.field)
}

/// (c) and (d): refusals name the field; models without gradients say so.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn refusals_name_the_problem_and_models_without_gradients_say_so() {
    let server = start_all().await;
    let mut c = client(&server).await;
    let listed = c.list_models().await.unwrap();
    let info = |name: &str| listed.iter().find(|m| m.name == name).unwrap().clone();
    assert!(info(MODEL).gradients);
    assert_eq!(info(MODEL).max_gradient_work, MAX_WORK);
    for name in [ENSEMBLE, SIM] {
        assert!(!info(name).gradients, "{name}");
        assert_eq!(info(name).max_gradient_work, 0, "{name}");
    }
    let id = create(&mut c, MODEL).await;
    let good = request(&[path(0.05, STEPS)], STEPS);
    let mut cases: Vec<(&str, json::SessionGradientRequest, &str)> = Vec::new();
    let mut r = good.clone();
    r.candidates[0].actions.pop();
    cases.push(("wrong number of actions", r, "candidates[0].actions"));
    let mut r = good.clone();
    r.candidates[0].actions[2].kinematic.clear();
    cases.push(("no pusher pose", r, "candidates[0].actions[2].kinematic"));
    let mut r = good.clone();
    r.candidates[0].actions[1].kinematic[0].object = 0;
    cases.push((
        "a pose for the box",
        r,
        "candidates[0].actions[1].kinematic[0].object",
    ));
    let mut r = good.clone();
    r.cost.targets[0].object = 5;
    cases.push(("unknown object", r, "cost.targets[0].object"));
    let mut r = good.clone();
    r.cost.targets[0].step = STEPS + 1;
    cases.push(("step out of range", r, "cost.targets[0].step"));
    let mut r = good.clone();
    r.cost.smoothness = -1.0;
    cases.push(("negative smoothness", r, "cost.smoothness"));
    let mut r = good.clone();
    r.steps = 0;
    r.candidates[0].actions.clear();
    cases.push(("no steps", r, "steps"));
    // 8 candidates x 40 steps = 320 scene-steps, above the 256 of MAX_WORK.
    let r = request(&vec![path(0.001, 40); 8], 40);
    cases.push(("too much work", r, "candidates"));
    for (what, r, field) in &cases {
        let s = grpc_error(c.gradient(request_v1(&id, r)).await);
        assert_eq!(s.code(), tonic::Code::InvalidArgument, "{what}: {s:?}");
        assert!(
            s.message().starts_with(&format!("{field}: ")),
            "{what}: {s:?}"
        );
        let resp = post_json(server.http_addr, &format!("/v1/sessions/{id}/gradient"), r).await;
        let (status, code, named) = http_error(&resp);
        assert_eq!((status, code.as_str()), (422, "INVALID_ARGUMENT"), "{what}");
        assert_eq!(named.as_deref(), Some(*field), "{what}");
    }
    let s = grpc_error(c.gradient(request_v1(&id, &cases.last().unwrap().1)).await);
    assert!(s.message().contains("--max-gradient-work"), "{s:?}");
    // An unknown field of the JSON body names itself.
    let mut body = serde_json::to_value(&good).unwrap();
    body["cost"]["weight"] = 1.0.into();
    let resp = post_json(
        server.http_addr,
        &format!("/v1/sessions/{id}/gradient"),
        &body,
    )
    .await;
    assert_eq!(http_error(&resp).0, 422, "{}", resp.text());

    // Models without gradients: FAILED_PRECONDITION / 400 saying why.
    for (name, why) in [(ENSEMBLE, "ensemble"), (SIM, "simulator")] {
        let sid = create(&mut c, name).await;
        let s = grpc_error(c.gradient(request_v1(&sid, &good)).await);
        assert_eq!(s.code(), tonic::Code::FailedPrecondition, "{name}: {s:?}");
        assert!(s.message().contains(why), "{name}: {s:?}");
        let resp = post_json(
            server.http_addr,
            &format!("/v1/sessions/{sid}/gradient"),
            &good,
        )
        .await;
        let (status, code, _) = http_error(&resp);
        assert_eq!(
            (status, code.as_str()),
            (400, "FAILED_PRECONDITION"),
            "{name}"
        );
    }
    // An unknown session is NOT_FOUND, as for every session call.
    let s = grpc_error(c.gradient(request_v1("00ff", &good)).await);
    assert_eq!(s.code(), tonic::Code::NotFound);
    let text = metrics(&server).await;
    let refused = sample(
        &text,
        "dynaserve_request_failures_total{method=\"session_gradient\",protocol=\"grpc\",reason=\"invalid_argument\"}",
    );
    assert_eq!(refused, Some((cases.len() + 1 + 2 + 1) as f64), "{text}");
    server.shutdown();
    server.wait().await.unwrap();
}

/// (e): a call that cannot finish in time, and one whose deadline passes while it waits
/// behind another call's pass, answer DEADLINE_EXCEEDED; the queued one never runs.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn deadlines_are_kept_while_running_and_while_queued() {
    let server = start_all().await;
    let mut c = client(&server).await;
    let id = create(&mut c, MODEL).await;
    let mut req = request(&[path(0.05, STEPS), path(0.04, STEPS)], STEPS);
    req.timeout_ms = 20;
    let s = grpc_error(c.gradient(request_v1(&id, &req)).await);
    assert_eq!(s.code(), tonic::Code::DeadlineExceeded, "{s:?}");
    let resp = post_json(
        server.http_addr,
        &format!("/v1/sessions/{id}/gradient"),
        &req,
    )
    .await;
    assert_eq!(http_error(&resp).0, 504, "{}", resp.text());

    // A long call holds the gradient scheduler; a call behind it with a short deadline is
    // answered on time and dropped from the queue without running.
    let long = request(&vec![path(0.05, STEPS); 32], STEPS);
    let mut c2 = client(&server).await;
    let id2 = id.clone();
    let running = tokio::spawn(async move { c2.gradient(request_v1(&id2, &long)).await });
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut short = request(&[path(0.05, STEPS)], STEPS);
    short.timeout_ms = 150;
    let asked = Instant::now();
    let s = grpc_error(c.gradient(request_v1(&id, &short)).await);
    assert_eq!(s.code(), tonic::Code::DeadlineExceeded, "{s:?}");
    assert!(
        asked.elapsed() < Duration::from_secs(2),
        "{:?}",
        asked.elapsed()
    );
    let done = running.await.unwrap().unwrap();
    assert_eq!(done.candidates.len(), 32);
    // The scheduler drops the expired call when it next looks at its queue, right after the
    // long pass.
    let scheduler = format!("{MODEL}/gradients");
    let series = format!(
        "dynaserve_dropped_steps_total{{model=\"{scheduler}\",reason=\"deadline_exceeded\"}}"
    );
    let mut text = metrics(&server).await;
    for _ in 0..50 {
        if sample(&text, &series).is_some_and(|d| d >= 1.0) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
        text = metrics(&server).await;
    }
    let dropped = sample(&text, &series).unwrap_or(0.0);
    let ran = sample(
        &text,
        &format!("dynaserve_batch_scenes_sum{{model=\"{scheduler}\"}}"),
    );
    // Four calls: the queued one dropped, the others run (the first two until their deadline).
    assert!(dropped >= 1.0, "{text}");
    assert_eq!(ran.map(|r| r + dropped), Some(4.0), "{text}");
    server.shutdown();
    server.wait().await.unwrap();
}

/// (f) on `model`: a call that holds the gradient scheduler (`long` candidates of `steps`
/// steps), then two calls together behind it: all three are served, the two queued ones in one
/// pass (when the first pass ran long enough for them to queue behind it).
async fn concurrent_calls_share_a_pass(model: &str, long: usize, steps: u32) {
    let server = start_all().await;
    let mut c = client(&server).await;
    let id = create(&mut c, model).await;
    let first = request(&vec![path(0.05, steps); long], steps);
    let mut c0 = client(&server).await;
    let id0 = id.clone();
    let running = tokio::spawn(async move {
        let sent = Instant::now();
        let r = c0.gradient(request_v1(&id0, &first)).await;
        (r, sent.elapsed())
    });
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (mut c1, mut c2) = (client(&server).await, client(&server).await);
    let (a, b) = (
        request(&[path(0.05, STEPS)], STEPS),
        request(&[path(0.04, STEPS)], STEPS),
    );
    let (ra, rb) = tokio::join!(
        c1.gradient(request_v1(&id, &a)),
        c2.gradient(request_v1(&id, &b))
    );
    let (first, took) = running.await.unwrap();
    let first = first.unwrap_or_else(|e| panic!("{model}: {e}"));
    assert_eq!(first.candidates.len(), long);
    let (ra, rb) = (ra.unwrap(), rb.unwrap());
    assert_ne!(ra.candidates[0].cost, rb.candidates[0].cost, "{model}");
    let text = metrics(&server).await;
    let scheduler = format!("{model}/gradients");
    let passes = sample(
        &text,
        &format!("dynaserve_batch_scenes_count{{model=\"{scheduler}\"}}"),
    );
    let calls = sample(
        &text,
        &format!("dynaserve_batch_scenes_sum{{model=\"{scheduler}\"}}"),
    );
    assert_eq!(calls, Some(3.0), "{model}: {text}");
    println!("{model}: {passes:?} passes for 3 calls; the first call took {took:?}");
    // The first call ran alone from its arrival; when it lasted well past the 300 ms the two
    // others waited, they reached the queue during its pass and shared the next one.
    if took > Duration::from_millis(700) {
        assert_eq!(passes, Some(2.0), "{model}: {text}");
    }
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn rigidformer_concurrent_calls_share_a_pass() {
    concurrent_calls_share_a_pass(MODEL, 32, 8).await;
}
