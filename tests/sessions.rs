//! End-to-end tests of sessions (`dynaserve.v1.Sessions`, `/v1/sessions`) against a real
//! server on 127.0.0.1 with the real RigidFormer checkpoint: steps through a session equal a
//! rollout, Fork and SetState, Predict from a session (fewer bytes, same answers), kinematic
//! objects, caps, TTL reaping and Interact; and, on a randomly initialised relative-mass
//! model, that a kinematic object's mass changes nothing.

mod common;

use std::time::{Duration, Instant};

use common::*;
use dynaserve_api::json;
use dynaserve_api::v1;
use dynaserve_client::Client;
use dynaserve_model::Pose;
use futures::StreamExt;
use prost::Message;
use tonic::Code;

fn poses_of(frames: &[v1::StepFrame]) -> Vec<json::StepFrame> {
    frames.iter().map(json::StepFrame::from_proto).collect()
}

fn create(model: &str, scene: &json::Scene, kinematic: Vec<u32>) -> v1::CreateSessionRequest {
    v1::CreateSessionRequest {
        model: model.to_string(),
        scene: Some(scene.to_proto()),
        dt_steps: 1,
        kinematic,
        shared: false,
    }
}

async fn step(c: &mut Client, id: &str, steps: u32) -> Vec<v1::StepFrame> {
    c.step_collect(v1::StepRequest {
        session_id: id.to_string(),
        steps,
        ..Default::default()
    })
    .await
    .unwrap()
}

fn pose_of(p: &v1::Pose) -> Pose {
    let t = p.translation.unwrap();
    let q = p.rotation.unwrap();
    Pose {
        translation: [t.x, t.y, t.z],
        rotation: [q.x, q.y, q.z, q.w],
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn session_steps_fork_and_set_state_equal_the_rollout() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let model = load(&m.dir);
    let scene = scene(11, 3, 48);
    let expected = in_process(&*model, &rollout_request(&m.name, scene.clone(), 10));
    let mut c = client(&server).await;
    let info = c
        .create_session(create(&m.name, &scene, vec![]))
        .await
        .unwrap()
        .info;
    assert_eq!((info.session_id.len(), info.objects), (32, 3));
    let id = info.session_id.clone();
    let start = c.get_state(&id).await.unwrap();
    // Two calls of 4 and 6 steps continue one trajectory: the rollout's.
    let mut frames = step(&mut c, &id, 4).await;
    frames.extend(step(&mut c, &id, 6).await);
    let diff = max_diff(&poses_of(&frames), &expected);
    assert!(diff <= 1e-5, "session differs from the rollout by {diff}");

    // A fork continues exactly like its original.
    let fork = c.fork(&id).await.unwrap();
    assert_ne!(fork.session_id, id);
    let a = step(&mut c, &id, 3).await;
    let b = step(&mut c, &fork.session_id, 3).await;
    let poses = |f: &[v1::StepFrame]| f.iter().map(|f| f.poses.clone()).collect::<Vec<_>>();
    assert_eq!(poses(&a), poses(&b));
    assert_eq!((a[0].step, b[0].step), (11, 11));

    // SetState back to the initial state: the next steps are the rollout's first ones again.
    let objects = (0..3)
        .map(|j| v1::ObjectState {
            object: j as u32,
            pose: Some(start.poses[j]),
            motion: Some(v1::object_state::Motion::PreviousPose(
                start.previous_poses[j],
            )),
        })
        .collect();
    let set = c
        .set_state(v1::SetStateRequest {
            session_id: id.clone(),
            objects,
        })
        .await
        .unwrap();
    assert_eq!(set.poses, start.poses);
    let again = step(&mut c, &id, 4).await;
    let mut renumbered = poses_of(&again);
    for (i, f) in renumbered.iter_mut().enumerate() {
        f.step = i as u32 + 1;
    }
    let diff = max_diff(&renumbered, &expected[..4]);
    assert!(diff <= 1e-5, "after SetState: {diff}");
    // The fork did not move with it.
    let fs = c.get_state(&fork.session_id).await.unwrap();
    assert_eq!(fs.step, 13);
    assert_eq!(fs.poses, b[2].poses);

    // Bad input names the field; an unknown or deleted id is NOT_FOUND.
    let bad = grpc_error(
        c.set_state(v1::SetStateRequest {
            session_id: id.clone(),
            objects: vec![v1::ObjectState {
                object: 7,
                pose: Some(start.poses[0]),
                motion: None,
            }],
        })
        .await,
    );
    assert_eq!(bad.code(), Code::InvalidArgument);
    assert!(
        bad.message().starts_with("objects[0].object"),
        "{}",
        bad.message()
    );
    c.delete_session(&id).await.unwrap();
    let gone = grpc_error(c.get_state(&id).await);
    assert_eq!(gone.code(), Code::NotFound);
    let text = metrics(&server).await;
    let forks = sample(
        &text,
        &format!("dynaserve_session_forks_total{{model=\"{}\"}}", m.name),
    );
    assert_eq!(forks, Some(1.0));
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn predict_from_a_session_sends_20x_fewer_bytes_and_answers_identically() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let scene = scene(21, 3, 128);
    let n = 64;
    let steps = 6;
    // Variant i: object 0 gets its own velocity; everything else is the session's.
    let velocity = |i: usize| [0.05 * i as f32 - 1.0, 0.3, 0.0];
    let full = json::PredictRequest {
        model: m.name.clone(),
        variants: (0..n)
            .map(|i| {
                let mut s = scene.clone();
                s.objects[0].previous_pose = None;
                s.objects[0].velocity = Some(json::Velocity {
                    linear: velocity(i),
                    angular: [0.0; 3],
                });
                s
            })
            .collect(),
        steps,
        dt_steps: 1,
        every: 2,
        timeout_ms: 0,
    };
    let full_bytes = full.to_proto().encoded_len();
    let mut c = client(&server).await;
    let id = c
        .create_session(create(&m.name, &scene, vec![]))
        .await
        .unwrap()
        .info
        .session_id;
    let from_session = v1::SessionPredictRequest {
        session_id: id,
        variants: (0..n)
            .map(|i| v1::SessionVariant {
                state: vec![v1::ObjectState {
                    object: 0,
                    pose: Some(
                        json::Pose {
                            translation: scene.objects[0].pose.translation,
                            rotation: scene.objects[0].pose.rotation,
                        }
                        .to_proto(),
                    ),
                    motion: Some(v1::object_state::Motion::Velocity(v1::Velocity {
                        linear: Some(v1::Vec3 {
                            x: velocity(i)[0],
                            y: velocity(i)[1],
                            z: velocity(i)[2],
                        }),
                        angular: Some(v1::Vec3::default()),
                    })),
                }],
                actions: vec![],
            })
            .collect(),
        steps,
        every: 2,
        timeout_ms: 0,
    };
    let ratio = full_bytes as f64 / from_session.encoded_len() as f64;
    println!(
        "request bytes: full scenes {full_bytes} B, session {} B, ratio {ratio:.1}",
        from_session.encoded_len()
    );
    assert!(ratio >= 20.0, "only {ratio:.1}x fewer bytes");
    let a = c.predict(&full).await.unwrap();
    let b = c.predict_session(from_session).await.unwrap();
    assert_eq!(a.trajectories.len(), n);
    assert_eq!(b.trajectories.len(), n);
    let mut worst = 0.0f32;
    for (ta, tb) in a.trajectories.iter().zip(&b.trajectories) {
        assert_eq!(ta.frames.len(), tb.frames.len());
        // The same steps are kept (every 2nd and the last), numbered alike: the renumbering
        // below only fits `max_diff`'s 1, 2, 3... convention.
        let kept_a: Vec<u32> = ta.frames.iter().map(|f| f.step).collect();
        let kept_b: Vec<u32> = tb.frames.iter().map(|f| f.step).collect();
        assert_eq!(kept_a, kept_b);
        let expected: Vec<Vec<Pose>> = ta
            .frames
            .iter()
            .map(|f| {
                f.poses
                    .iter()
                    .map(|p| Pose {
                        translation: p.translation,
                        rotation: p.rotation,
                    })
                    .collect()
            })
            .collect();
        let mut got = poses_of(&tb.frames);
        for (i, f) in got.iter_mut().enumerate() {
            f.step = i as u32 + 1;
        }
        worst = worst.max(max_diff(&got, &expected));
    }
    assert!(worst <= 1e-5, "session Predict differs by {worst}");
    // The variants did differ from each other.
    let x = |t: &v1::Trajectory| t.frames[0].poses[0].translation.unwrap().x;
    assert!((x(&b.trajectories[0]) - x(&b.trajectories[n - 1])).abs() > 0.05);
    server.shutdown();
    server.wait().await.unwrap();
}

/// A box resting on the floor and a kinematic pusher box beside it.
fn push_scene() -> json::Scene {
    let mut s = scene(31, 2, 96);
    for (o, x) in s.objects.iter_mut().zip([0.0f32, -0.45]) {
        o.pose = json::Pose {
            translation: [x, 0.0, 0.2],
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        o.previous_pose = None;
        o.velocity = None;
    }
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kinematic_objects_follow_given_poses_over_http() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let scene = push_scene();
    let info = create_session_http(server.http_addr, &m.name, scene.clone(), vec![1]).await;
    assert_eq!(info.kinematic, vec![1]);
    let path = format!("/v1/sessions/{}", info.session_id);
    // A bodiless POST (as `curl -X POST` sends it: no content type, no body) needs no
    // content type (a body of another type is still refused: tests/hardening.rs).
    let forked = http(server.http_addr, "POST", &format!("{path}/fork"), &[], None).await;
    assert_eq!(forked.status, 201, "{}", forked.text());
    let forked: json::SessionInfo = forked.json();
    assert_ne!(forked.session_id, info.session_id);
    let steps = 12u32;
    let target = |k: u32| json::Pose {
        translation: [-0.45 + 0.03 * k as f32, 0.0, 0.2],
        rotation: [0.0, 0.0, 0.0, 1.0],
    };
    let actions: Vec<json::Action> = (1..=steps)
        .map(|k| json::Action {
            kinematic: vec![json::ObjectPose {
                object: 1,
                pose: target(k),
            }],
        })
        .collect();
    let r = post_json(
        server.http_addr,
        &format!("{path}/step"),
        &json::StepRequest {
            steps,
            actions: actions.clone(),
            timeout_ms: 0,
        },
    )
    .await;
    assert_eq!(r.status, 200, "{}", r.text());
    let out: json::StepResponse = r.json();
    for (k, f) in out.frames.iter().enumerate() {
        assert_eq!(
            f.poses[1],
            target(k as u32 + 1),
            "the pusher follows its path"
        );
    }
    let moved = out.frames.last().unwrap().poses[0].translation[0];
    println!("pushed box moved {moved:.4} m in x while the pusher advanced 0.36 m");

    // Without actions the pusher holds its pose.
    let r = post_json(
        server.http_addr,
        &format!("{path}/step"),
        &json::StepRequest {
            steps: 2,
            actions: vec![],
            timeout_ms: 0,
        },
    )
    .await;
    let held: json::StepResponse = r.json();
    assert_eq!(held.frames[1].poses[1], target(steps));
    assert_eq!(held.frames[1].step, steps + 2);

    // Poses for a non-kinematic object, or too few actions, name the field.
    let wrong = json::StepRequest {
        steps: 1,
        actions: vec![json::Action {
            kinematic: vec![json::ObjectPose {
                object: 0,
                pose: target(0),
            }],
        }],
        timeout_ms: 0,
    };
    let r = post_json(server.http_addr, &format!("{path}/step"), &wrong).await;
    assert_eq!(r.status, 422);
    let e: json::ErrorResponse = r.json();
    assert_eq!(
        e.error.field.as_deref(),
        Some("actions[0].kinematic[0].object")
    );
    let short = json::StepRequest {
        steps: 3,
        actions: actions[..2].to_vec(),
        timeout_ms: 0,
    };
    let r = post_json(server.http_addr, &format!("{path}/step"), &short).await;
    assert_eq!(
        r.json::<json::ErrorResponse>().error.field.as_deref(),
        Some("actions")
    );

    // GET, DELETE, then 404.
    let st: json::SessionState = http(server.http_addr, "GET", &path, &[], None).await.json();
    assert_eq!(st.step, steps + 2);
    assert_eq!(st.poses[1], target(steps));
    assert_eq!(
        http(server.http_addr, "DELETE", &path, &[], None)
            .await
            .status,
        204
    );
    let r = http(server.http_addr, "GET", &path, &[], None).await;
    assert_eq!(r.status, 404);
    assert_eq!(
        r.json::<json::ErrorResponse>().error.field.as_deref(),
        Some("session_id")
    );
    // The session routes are in the OpenAPI document.
    let doc = http(server.http_addr, "GET", "/openapi.json", &[], None)
        .await
        .text();
    assert!(doc.contains("/v1/sessions/{id}/predict"));
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn caps_ttl_reaping_and_interact() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.sessions.max_sessions = 2;
        c.sessions.session_ttl_s = 0.5;
    })
    .await;
    let model = load(&m.dir);
    let scene = scene(41, 2, 48);
    let mut c = client(&server).await;
    let a = c
        .create_session(create(&m.name, &scene, vec![]))
        .await
        .unwrap()
        .info;
    c.create_session(create(&m.name, &scene, vec![]))
        .await
        .unwrap();
    let full = grpc_error(c.create_session(create(&m.name, &scene, vec![])).await);
    assert_eq!(full.code(), Code::ResourceExhausted);
    let fork = grpc_error(c.fork(&a.session_id).await);
    assert_eq!(fork.code(), Code::ResourceExhausted);

    // Left alone, both expire.
    let series = format!("dynaserve_sessions_reaped_total{{model=\"{}\"}}", m.name);
    let give_up = Instant::now() + Duration::from_secs(30);
    while sample(&metrics(&server).await, &series) != Some(2.0) {
        assert!(Instant::now() < give_up, "sessions were not reaped");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let gone = grpc_error(c.get_state(&a.session_id).await);
    assert_eq!(gone.code(), Code::NotFound);

    // Interact: a stream that creates its session, then one frame per message; equal to the
    // rollout.
    let expected = in_process(&*model, &rollout_request(&m.name, scene.clone(), 5));
    let mut interaction = c
        .interact(v1::InteractRequest {
            create: Some(create(&m.name, &scene, vec![])),
            ..Default::default()
        })
        .await
        .unwrap();
    assert_eq!(interaction.session_id.len(), 32);
    let mut frames = Vec::new();
    for _ in 0..5 {
        // The next step is asked for only after the previous frame arrived: a closed loop.
        let step = interaction.step(v1::InteractRequest::default()).await;
        frames.push(step.unwrap());
    }
    let diff = max_diff(&poses_of(&frames), &expected);
    assert!(diff <= 1e-5, "Interact differs from the rollout by {diff}");
    let mut rest = interaction.finish();
    assert!(
        rest.next().await.is_none(),
        "the stream ends with its input"
    );
    // Its own session is gone with it.
    let open = format!("dynaserve_sessions_open{{model=\"{}\"}}", m.name);
    let give_up = Instant::now() + Duration::from_secs(10);
    while sample(&metrics(&server).await, &open) != Some(0.0) {
        assert!(
            Instant::now() < give_up,
            "the stream's session was not deleted"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    server.shutdown();
    server.wait().await.unwrap();
}

/// The box's pose after 4 steps of a session on `push_scene` with the box at 1 kg, the
/// pusher at `pusher_mass` kg and `kinematic` the kinematic objects.
async fn box_after(c: &mut Client, model: &str, pusher_mass: f32, kinematic: Vec<u32>) -> Pose {
    let mut scene = push_scene();
    scene.objects[0].mass = 1.0;
    scene.objects[1].mass = pusher_mass;
    let created = c.create_session(create(model, &scene, kinematic)).await;
    let id = created.unwrap().info.session_id;
    let frames = step(c, &id, 4).await;
    pose_of(&frames.last().unwrap().poses[0])
}

/// With `dynamics.relative_mass`, a session's kinematic objects reach the model flagged: the
/// pusher's mass (which moves nothing in rigid-body physics) changes no forecast, while the
/// same object left dynamic changes the box's.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_kinematic_objects_mass_changes_nothing_under_relative_mass() {
    let m = random_model_with("relative", 41, |c| c.dynamics.relative_mass = true);
    let server = start(&m.dir, |_| {}).await;
    let mut c = client(&server).await;
    let diff = |a: &Pose, b: &Pose| {
        (0..3)
            .map(|d| (a.translation[d] - b.translation[d]).abs())
            .fold(0.0f32, f32::max)
    };
    let light = box_after(&mut c, &m.name, 1.0, vec![1]).await;
    let heavy = box_after(&mut c, &m.name, 20.0, vec![1]).await;
    assert!(diff(&light, &heavy) < 1e-6, "{light:?} against {heavy:?}");
    let dynamic_light = box_after(&mut c, &m.name, 1.0, vec![]).await;
    let dynamic_heavy = box_after(&mut c, &m.name, 20.0, vec![]).await;
    assert!(
        diff(&dynamic_light, &dynamic_heavy) > 1e-6,
        "a dynamic object's mass had no effect"
    );
    server.shutdown();
    server.wait().await.unwrap();
}

/// The box's pose after one HTTP session step of `push_scene` on `model` (served from
/// `dir`), the pusher starting at x = -0.45 m with its previous pose at `pusher_before` and
/// driven to `pusher_to`.
async fn box_after_one_push(
    dir: &std::path::Path,
    model: &str,
    pusher_before: f32,
    pusher_to: f32,
) -> Pose {
    let server = start(dir, |_| {}).await;
    let mut scene = push_scene();
    let at = |x: f32| json::Pose {
        translation: [x, 0.0, 0.2],
        rotation: [0.0, 0.0, 0.0, 1.0],
    };
    scene.objects[1].previous_pose = Some(at(pusher_before));
    let info = create_session_http(server.http_addr, model, scene, vec![1]).await;
    let r = post_json(
        server.http_addr,
        &format!("/v1/sessions/{}/step", info.session_id),
        &json::StepRequest {
            steps: 1,
            actions: vec![json::Action {
                kinematic: vec![json::ObjectPose {
                    object: 1,
                    pose: at(pusher_to),
                }],
            }],
            timeout_ms: 0,
        },
    )
    .await;
    assert_eq!(r.status, 200, "{}", r.text());
    let out: json::StepResponse = r.json();
    assert_eq!(
        out.frames[0].poses[1],
        at(pusher_to),
        "the pusher follows its path"
    );
    server.shutdown();
    server.wait().await.unwrap();
    let p = out.frames[0].poses[0];
    Pose {
        translation: p.translation,
        rotation: p.rotation,
    }
}

/// With `dynamics.kinematic_lead` a session step reads the pusher's coming pose: a pusher at
/// rest driven 5 cm moves the box exactly as, without the lead, a pusher already moving 5 cm
/// per step does; without the lead the pusher at rest is seen at rest (another answer).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_led_session_step_reads_the_pushers_coming_pose() {
    let led = random_model_with("led", 43, |c| c.dynamics.kinematic_lead = true);
    let plain = random_model_with("plain", 43, |c| c.dynamics.kinematic_lead = false);
    let diff = |a: &Pose, b: &Pose| {
        (0..3)
            .map(|d| (a.translation[d] - b.translation[d]).abs())
            .chain((0..4).map(|d| (a.rotation[d] - b.rotation[d]).abs()))
            .fold(0.0f32, f32::max)
    };
    let starting = box_after_one_push(&led.dir, &led.name, -0.45, -0.40).await;
    let moving = box_after_one_push(&plain.dir, &plain.name, -0.50, -0.40).await;
    let seen_at_rest = box_after_one_push(&plain.dir, &plain.name, -0.45, -0.40).await;
    assert!(
        diff(&starting, &moving) < 1e-6,
        "{starting:?} against {moving:?}"
    );
    assert!(
        diff(&starting, &seen_at_rest) > 1e-6,
        "the lead changed nothing: {starting:?}"
    );
}

/// A session deleted while an Interact stream drives it (over HTTP, or over gRPC from another
/// client) is not stepped again as a detached copy: the stream's next action ends it with
/// NOT_FOUND naming the session, and no further frame comes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn interact_on_a_session_deleted_mid_stream_ends_with_not_found() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let scene = scene(43, 2, 32);
    for over_http in [true, false] {
        let mut c = client(&server).await;
        let id = c
            .create_session(create(&m.name, &scene, vec![]))
            .await
            .unwrap()
            .info
            .session_id;
        let mut interaction = c
            .interact(v1::InteractRequest {
                session_id: id.clone(),
                ..Default::default()
            })
            .await
            .unwrap();
        let first = interaction.step(v1::InteractRequest::default()).await;
        assert_eq!(first.unwrap().step, 1);

        if over_http {
            let resp = http(
                server.http_addr,
                "DELETE",
                &format!("/v1/sessions/{id}"),
                &[],
                None,
            )
            .await;
            assert_eq!(resp.status, 204, "{}", resp.text());
        } else {
            // Another client, on its own connection.
            let mut other = client(&server).await;
            other.delete_session(&id).await.unwrap();
        }

        interaction
            .actions
            .send(v1::InteractRequest::default())
            .await
            .unwrap();
        let end = interaction.frames.next().await.unwrap();
        let status = match end {
            Err(dynaserve_client::ClientError::Status(s)) => s,
            other => panic!("a deleted session must not be stepped: {other:?}"),
        };
        assert_eq!(status.code(), Code::NotFound, "{}", status.message());
        assert!(status.message().contains(&id), "{}", status.message());
        assert!(
            interaction.frames.next().await.is_none(),
            "no frame follows the error"
        );
        let gone = grpc_error(c.get_state(&id).await);
        assert_eq!(gone.code(), Code::NotFound);
    }
    server.shutdown();
    server.wait().await.unwrap();
}
