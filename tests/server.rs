//! End-to-end tests of `dynaserve serve` against a real server on 127.0.0.1 with a real
//! RigidFormer loaded from disk (the shipped checkpoint when present, otherwise a randomly
//! initialised one saved to a temporary directory).
//!
//! Longer than our other files on purpose: every test here needs a running server and the same
//! helpers, and one file is one test binary (one link of the server and the model).

mod common;

use std::time::{Duration, Instant};

use common::*;
use dynaserve_api::json;
use dynaserve_api::v1;
use futures::StreamExt;
use tonic::Code;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_stream_of_100_steps_equals_the_in_process_rollout() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let model = load(&m.dir);
    let req = rollout_request(&m.name, scene(1, 3, 48), 100);
    let expected = in_process(&*model, &req);
    let mut c = client(&server).await;
    let mut rollout = c.rollout(&req).await.unwrap();
    assert_eq!(rollout.model, m.name);
    assert_eq!(rollout.request_id.len(), 16);
    let mut frames = Vec::new();
    while let Some(f) = rollout.frames.next().await {
        frames.push(f.unwrap());
    }
    let diff = max_diff(&frames, &expected);
    assert!(diff <= 1e-5, "max difference {diff}");
    let dt = model.config().dt_frame as f64;
    assert!((frames[99].time - 100.0 * dt).abs() < 1e-9);
    assert!(frames.iter().all(|f| f.timing.is_some()));
    // Something actually moved (the comparison is not between two constant trajectories).
    let moved =
        (frames[99].poses[0].translation[0] - req.scene.objects[0].pose.translation[0]).abs();
    assert!(moved > 1e-3, "object did not move ({moved})");
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_streams_each_equal_their_solo_rollout_and_are_batched() {
    let m = test_model();
    let server = start(&m.dir, |c| c.max_queue_delay_ms = 5.0).await;
    let model = load(&m.dir);
    let steps = 12;
    let requests: Vec<json::RolloutRequest> = (0..32)
        .map(|i| {
            rollout_request(
                &m.name,
                scene(100 + i, 1 + (i as usize % 4), 24 + i as usize),
                steps,
            )
        })
        .collect();
    let c = client(&server).await;
    let tasks: Vec<_> = requests
        .iter()
        .cloned()
        .map(|r| {
            let mut c = c.clone();
            tokio::spawn(async move { c.rollout_collect(&r).await.unwrap() })
        })
        .collect();
    let mut results = Vec::new();
    for t in tasks {
        results.push(t.await.unwrap());
    }
    let mut biggest = 0;
    for (req, frames) in requests.iter().zip(&results) {
        let solo = in_process(&*model, req);
        let diff = max_diff(frames, &solo);
        assert!(
            diff <= 1e-5,
            "stream differs from its solo rollout by {diff}"
        );
        biggest = biggest.max(
            frames
                .iter()
                .map(|f| f.timing.unwrap().batch_scenes)
                .max()
                .unwrap(),
        );
    }
    assert!(biggest >= 8, "largest batch had only {biggest} scenes");
    let text = metrics(&server).await;
    let label = format!("model=\"{}\"", m.name);
    let count = sample(&text, &format!("dynaserve_batch_scenes_count{{{label}}}")).unwrap();
    let ones = sample(
        &text,
        &format!("dynaserve_batch_scenes_bucket{{{label},le=\"1\"}}"),
    )
    .unwrap();
    let sum = sample(&text, &format!("dynaserve_batch_scenes_sum{{{label}}}")).unwrap();
    assert!(
        count - ones >= 1.0,
        "no batch held more than one scene: {count} {ones}"
    );
    // Every stream step (warm-up is not counted), and far fewer passes than scene-steps.
    assert_eq!(sum, 32.0 * steps as f64);
    assert!(count < sum / 4.0, "{count} passes for {sum} scene-steps");
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn http_json_and_sse_rollouts_equal_the_grpc_one() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let req = rollout_request(&m.name, scene(7, 2, 40), 20);
    let grpc = client(&server).await.rollout_collect(&req).await.unwrap();

    let resp = post_json(server.http_addr, "/v1/rollout", &req).await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    assert!(resp.header("x-request-id").is_some());
    assert!(resp.header("x-dynaserve-forward-ms").is_some());
    assert!(resp.header("server-timing").unwrap().contains("queue;dur="));
    let body: json::RolloutResponse = resp.json();
    assert_eq!(body.frames.len(), 20);

    let mut sse_req = req.clone();
    sse_req.stream = true;
    let resp = post_json(server.http_addr, "/v1/rollout", &sse_req).await;
    assert_eq!(resp.status, 200);
    assert!(
        resp.header("content-type")
            .unwrap()
            .starts_with("text/event-stream")
    );
    let events = parse_sse(&resp.text());
    let frames: Vec<json::StepFrame> = events
        .iter()
        .filter(|(e, _)| e == "frame")
        .map(|(_, d)| serde_json::from_str(d).unwrap())
        .collect();
    assert_eq!(events.last().unwrap().0, "done");
    // Accept: text/event-stream asks for the same.
    let b = serde_json::to_vec(&req).unwrap();
    let resp = http(
        server.http_addr,
        "POST",
        "/v1/rollout",
        &[("Accept", "text/event-stream")],
        Some(&b),
    )
    .await;
    let frames2 = parse_sse(&resp.text())
        .iter()
        .filter(|(e, _)| e == "frame")
        .count();
    assert_eq!(frames2, 20);

    let as_poses = |fr: &[json::StepFrame]| -> Vec<Vec<dynaserve_model::Pose>> {
        fr.iter()
            .map(|f| {
                f.poses
                    .iter()
                    .map(|p| dynaserve_model::Pose {
                        translation: p.translation,
                        rotation: p.rotation,
                    })
                    .collect()
            })
            .collect()
    };
    let reference = as_poses(&grpc);
    assert!(max_diff(&body.frames, &reference) <= 1e-5);
    assert!(max_diff(&frames, &reference) <= 1e-5);
    for (a, b) in frames.iter().zip(&grpc) {
        assert_eq!(a.time, b.time);
    }
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_disconnected_stream_frees_its_slot_before_the_next_step() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.max_active_rollouts = 1;
        c.stream_buffer = 1;
    })
    .await;
    let label = format!("model=\"{}\"", m.name);
    let active = format!("dynaserve_active_rollouts{{{label}}}");
    let steps_series = format!("dynaserve_scene_steps_total{{{label}}}");
    let mut c = client(&server).await;
    let req = rollout_request(&m.name, scene(3, 2, 32), 5000);
    let mut rollout = c.rollout(&req).await.unwrap();
    for _ in 0..3 {
        rollout.frames.next().await.unwrap().unwrap();
    }
    // A second stream is refused while the only slot is taken.
    let err = c.rollout(&req).await.err().expect("slot should be taken");
    assert!(
        matches!(err, dynaserve_client::ClientError::Status(ref s) if s.code() == Code::ResourceExhausted)
    );
    drop(rollout);
    let dropped = Instant::now();
    // The session notices the reset stream and releases its slot...
    loop {
        let text = metrics(&server).await;
        if sample(&text, &active) == Some(0.0) {
            break;
        }
        assert!(dropped.elapsed() < Duration::from_secs(2), "slot not freed");
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    // ...and no further step of the dropped stream is computed: at most the one already in
    // the running forward pass completes.
    let at_release = sample(&metrics(&server).await, &steps_series).unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    let later = sample(&metrics(&server).await, &steps_series).unwrap();
    assert!(
        later - at_release <= 1.0,
        "{} steps computed after the slot was freed",
        later - at_release
    );
    tokio::time::sleep(Duration::from_millis(200)).await;
    let settled = sample(&metrics(&server).await, &steps_series).unwrap();
    assert_eq!(later, settled, "the dropped stream is still stepping");
    assert!(later < 1000.0, "the rollout kept running: {later} steps");
    // The freed slot admits a new stream at once.
    let mut short = req.clone();
    short.steps = 3;
    assert_eq!(c.rollout_collect(&short).await.unwrap().len(), 3);
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_deadline_in_the_queue_yields_deadline_exceeded_on_time() {
    let m = test_model();
    // Scene cap 1 and eight interactive streams keep the queue full, so bulk (Predict) work
    // waits in the queue behind them until its deadline.
    let server = start(&m.dir, |c| c.max_batch_scenes = 1).await;
    let c = client(&server).await;
    let busy: Vec<_> = (0..8)
        .map(|i| {
            let mut c = c.clone();
            let req = rollout_request(&m.name, scene(40 + i, 3, 48), 10_000);
            tokio::spawn(async move {
                let mut r = c.rollout(&req).await.unwrap();
                while let Some(f) = r.frames.next().await {
                    if f.is_err() {
                        break;
                    }
                }
            })
        })
        .collect();
    tokio::time::sleep(Duration::from_millis(300)).await;
    let predict = json::PredictRequest {
        model: m.name.clone(),
        variants: vec![scene(5, 2, 32)],
        steps: 5,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    };
    // "On time" is asserted by cause, not by a wall-clock bound: the answer is the server's
    // DEADLINE_EXCEEDED (had the server waited for the queue, the client's own timer,
    // `DEADLINE_BACKSTOP` later, would have ended the call as CANCELLED), it never comes before
    // the deadline, and it comes while the work queued ahead of the call is still running, so
    // the call did not wait for its turn in a batch.
    let queue_still_full =
        |busy: &[tokio::task::JoinHandle<()>]| busy.iter().all(|b| !b.is_finished());
    for budget in [150u64, 400] {
        let mut pc = c.clone().with_timeout(Some(Duration::from_millis(budget)));
        let t = Instant::now();
        let err = pc.predict(&predict).await.expect_err("must time out");
        let took = t.elapsed();
        match err {
            dynaserve_client::ClientError::Status(s) => {
                assert_eq!(s.code(), Code::DeadlineExceeded, "{s:?}");
                assert!(s.message().starts_with("deadline exceeded"), "{s:?}");
            }
            other => panic!("unexpected {other:?}"),
        }
        assert!(took >= Duration::from_millis(budget - 5), "early: {took:?}");
        assert!(
            queue_still_full(&busy),
            "the queue ahead of the call drained"
        );
    }
    // The HTTP field does the same (504); this client has no timer of its own, so the 504
    // itself is the server's deadline.
    let mut http_req = predict.clone();
    http_req.timeout_ms = 150;
    let t = Instant::now();
    let resp = post_json(server.http_addr, "/v1/predict", &http_req).await;
    assert_eq!(resp.status, 504, "{}", resp.text());
    assert!(
        t.elapsed() >= Duration::from_millis(145),
        "early: {:?}",
        t.elapsed()
    );
    assert!(
        queue_still_full(&busy),
        "the queue ahead of the call drained"
    );
    let e: json::ErrorResponse = resp.json();
    assert_eq!(e.error.code, "DEADLINE_EXCEEDED");
    let dropped_of = |text: &str| {
        ["deadline_exceeded", "cancelled"]
            .iter()
            .map(|r| {
                sample(
                    text,
                    &format!(
                        "dynaserve_dropped_steps_total{{model=\"{}\",reason=\"{r}\"}}",
                        m.name
                    ),
                )
                .unwrap()
            })
            .sum::<f64>()
    };
    // Each expired call's queued step is removed before the next batch.
    let t = Instant::now();
    while dropped_of(&metrics(&server).await) < 3.0 && t.elapsed() < Duration::from_secs(2) {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let text = metrics(&server).await;
    let dropped = dropped_of(&text);
    assert!(
        dropped >= 3.0,
        "expired work was not dropped from the queue: {dropped}"
    );
    server.shutdown();
    for b in busy {
        b.abort();
    }
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn overload_yields_resource_exhausted_and_429_with_a_retry_hint() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.max_active_rollouts = 2;
        c.max_predict_variants = 3;
        c.stream_buffer = 1;
        c.retry_after_ms = 1500;
    })
    .await;
    let mut c = client(&server).await;
    let req = rollout_request(&m.name, scene(9, 2, 32), 10_000);
    let mut held = Vec::new();
    for _ in 0..2 {
        let mut r = c.rollout(&req).await.unwrap();
        r.frames.next().await.unwrap().unwrap();
        held.push(r);
    }
    let err = c
        .rollout(&req)
        .await
        .err()
        .expect("third stream must be refused");
    assert_eq!(err.retry_after(), Some(Duration::from_millis(1500)));
    match err {
        dynaserve_client::ClientError::Status(s) => assert_eq!(s.code(), Code::ResourceExhausted),
        other => panic!("unexpected {other:?}"),
    }
    let resp = post_json(server.http_addr, "/v1/rollout", &req).await;
    assert_eq!(resp.status, 429);
    assert_eq!(resp.header("retry-after"), Some("2"));
    let e: json::ErrorResponse = resp.json();
    assert_eq!(e.error.code, "RESOURCE_EXHAUSTED");
    assert_eq!(e.error.retry_after_ms, Some(1500));
    // More variants than the server's Predict cap can never succeed: refused as invalid (not
    // "retry later"), naming the field.
    let predict = json::PredictRequest {
        model: m.name.clone(),
        variants: vec![scene(1, 1, 16); 4],
        steps: 2,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    };
    let err = c.predict(&predict).await.err().unwrap();
    match err {
        dynaserve_client::ClientError::Status(s) => {
            assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
            assert!(s.message().contains("variants"), "{}", s.message());
        }
        other => panic!("unexpected {other:?}"),
    }
    let text = metrics(&server).await;
    assert_eq!(
        sample(
            &text,
            "dynaserve_request_failures_total{method=\"rollout\",protocol=\"grpc\",reason=\"resource_exhausted\"}"
        ),
        Some(1.0)
    );
    drop(held);
    server.shutdown();
    server.wait().await.unwrap();
}

/// Every bad input is refused with INVALID_ARGUMENT / 422 naming the field, while a good
/// stream keeps running next to them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn invalid_inputs_are_refused_naming_the_field_while_others_are_served() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.max_objects = 8;
        c.max_points_per_object = 100;
        c.max_steps = 500;
        c.max_dt_steps = 4;
        c.max_request_bytes = 64 * 1024;
    })
    .await;
    let model = load(&m.dir);
    let good = rollout_request(&m.name, scene(11, 2, 32), 150);
    let expected = in_process(&*model, &good);
    let mut c = client(&server).await;
    let mut running = c.rollout(&good).await.unwrap();
    let mut frames = vec![running.frames.next().await.unwrap().unwrap()];

    let base = rollout_request(&m.name, scene(12, 2, 32), 5);
    type Edit = Box<dyn Fn(&mut json::RolloutRequest)>;
    let o = |f: fn(&mut json::ObjectSpec)| -> Edit {
        Box::new(move |r: &mut json::RolloutRequest| f(&mut r.scene.objects[1]))
    };
    let cases: Vec<(&str, Edit, &str)> = vec![
        (
            "unknown model",
            Box::new(|r| r.model = "nope".into()),
            "model",
        ),
        ("zero steps", Box::new(|r| r.steps = 0), "steps"),
        ("too many steps", Box::new(|r| r.steps = 501), "steps"),
        ("bad step size", Box::new(|r| r.dt_steps = 5), "dt_steps"),
        (
            "no objects",
            Box::new(|r| r.scene.objects.clear()),
            "scene.objects",
        ),
        (
            "too many objects",
            Box::new(|r| r.scene.objects = vec![r.scene.objects[0].clone(); 9]),
            "scene.objects",
        ),
        (
            "empty cloud",
            o(|o| o.points = Some(vec![])),
            "scene.objects[1].points",
        ),
        (
            "oversized cloud",
            o(|o| o.points = Some(vec![[0.1, 0.0, 0.0]; 101])),
            "scene.objects[1].points",
        ),
        (
            "infinite point",
            o(|o| o.points.as_mut().unwrap()[3][2] = f32::INFINITY),
            "scene.objects[1].points[3]",
        ),
        (
            "non-unit quaternion",
            o(|o| o.pose.rotation = [0.0, 0.0, 0.5, 0.5]),
            "scene.objects[1].pose.rotation",
        ),
        (
            "zero quaternion",
            o(|o| o.pose.rotation = [0.0; 4]),
            "scene.objects[1].pose.rotation",
        ),
        (
            "infinite translation",
            o(|o| o.pose.translation[0] = f32::INFINITY),
            "scene.objects[1].pose.translation",
        ),
        ("zero mass", o(|o| o.mass = 0.0), "scene.objects[1].mass"),
        ("huge mass", o(|o| o.mass = 1e9), "scene.objects[1].mass"),
        (
            "negative friction",
            o(|o| o.friction = -0.1),
            "scene.objects[1].friction",
        ),
        (
            "restitution above 1",
            o(|o| o.restitution = 1.5),
            "scene.objects[1].restitution",
        ),
        (
            "absurd speed",
            o(|o| o.velocity.as_mut().unwrap().linear[0] = 1e7),
            "scene.objects[1].velocity.linear",
        ),
        (
            // (HTTP only: a protobuf oneof cannot carry both)
            "two motions",
            o(|o| o.previous_pose = Some(o.pose)),
            "scene.objects[1]",
        ),
        (
            "bad mesh face",
            o(|o| {
                o.points = None;
                o.mesh = Some(json::TriangleMesh {
                    vertices: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                    faces: vec![[0, 1, 7]],
                    samples: 16,
                    seed: 0,
                });
            }),
            "scene.objects[1].mesh.faces[0]",
        ),
        (
            "payload too large",
            o(|o| {
                // Vertex counts are limited only by the payload size: 8000 vertices are
                // ~96 KB as protobuf and ~300 KB as JSON, over the 64 KiB limit.
                o.points = None;
                o.mesh = Some(json::TriangleMesh {
                    vertices: (0..8000)
                        .map(|k| [1e-4 * k as f32, 0.123_456_7, -0.234_567_8])
                        .collect(),
                    faces: vec![[0, 1, 2]],
                    samples: 16,
                    seed: 0,
                });
            }),
            "request",
        ),
    ];
    for (what, edit, field) in &cases {
        let mut bad = base.clone();
        edit(&mut bad);
        let is_payload = *field == "request";
        // gRPC
        let grpc_can_express = *what != "two motions";
        if grpc_can_express && (!is_payload || bad.to_proto().encoded_len_ok(64 * 1024)) {
            match c.rollout(&bad).await {
                Ok(_) => panic!("{what}: accepted over gRPC"),
                Err(dynaserve_client::ClientError::Status(s)) => {
                    assert_eq!(s.code(), Code::InvalidArgument, "{what}: {s:?}");
                    assert!(
                        s.message().starts_with(&format!("{field}:")),
                        "{what}: message {:?} does not name {field}",
                        s.message()
                    );
                }
                Err(e) => panic!("{what}: {e}"),
            }
        }
        // HTTP (JSON cannot carry infinities: send a number that overflows f32 instead)
        let mut body = serde_json::to_string(&bad).unwrap();
        body = body.replace("null", "1e39");
        let resp = http(
            server.http_addr,
            "POST",
            "/v1/rollout",
            &[],
            Some(body.as_bytes()),
        )
        .await;
        assert_eq!(resp.status, 422, "{what}: {}", resp.text());
        let e: json::ErrorResponse = resp.json();
        assert_eq!(e.error.code, "INVALID_ARGUMENT");
        assert_eq!(
            e.error.field.as_deref(),
            Some(*field),
            "{what}: {}",
            e.error.message
        );
    }
    // NaN can only be sent over gRPC.
    let mut nan = base.clone().to_proto();
    nan.scene.as_mut().unwrap().objects[0].mass = f32::NAN;
    let s = dynaserve_api::v1::world_model_client::WorldModelClient::connect(format!(
        "http://{}",
        server.grpc_addr
    ))
    .await
    .unwrap()
    .rollout(nan)
    .await
    .err()
    .unwrap();
    assert_eq!(s.code(), Code::InvalidArgument);
    assert!(
        s.message().starts_with("scene.objects[0].mass:"),
        "{}",
        s.message()
    );
    // A malformed flat cloud and malformed JSON name their fields too.
    let mut flat = base.clone().to_proto();
    if let Some(v1::object_spec::Shape::Points(p)) =
        &mut flat.scene.as_mut().unwrap().objects[1].shape
    {
        p.xyz.pop();
    }
    let s = dynaserve_api::v1::world_model_client::WorldModelClient::connect(format!(
        "http://{}",
        server.grpc_addr
    ))
    .await
    .unwrap()
    .rollout(flat)
    .await
    .err()
    .unwrap();
    assert!(
        s.message().starts_with("scene.objects[1].points.xyz:"),
        "{}",
        s.message()
    );
    let mut body = serde_json::to_value(&base).unwrap();
    body["scene"]["objects"][1]["mass"] = serde_json::json!("heavy");
    let resp = post_json(server.http_addr, "/v1/rollout", &body).await;
    assert_eq!(resp.status, 422);
    let e: json::ErrorResponse = resp.json();
    assert_eq!(e.error.field.as_deref(), Some("scene.objects[1].mass"));
    let mut body = serde_json::to_value(&base).unwrap();
    body["scene"]["objects"][0]["colour"] = serde_json::json!("red");
    let resp = post_json(server.http_addr, "/v1/rollout", &body).await;
    assert_eq!(resp.status, 422);
    // Predict variants are named by index.
    let mut p = json::PredictRequest {
        model: m.name.clone(),
        variants: vec![scene(1, 1, 16), scene(2, 1, 16)],
        steps: 2,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    };
    p.variants[1].objects[0].restitution = -1.0;
    let resp = post_json(server.http_addr, "/v1/predict", &p).await;
    let e: json::ErrorResponse = resp.json();
    assert_eq!(
        e.error.field.as_deref(),
        Some("variants[1].objects[0].restitution")
    );

    // The good stream ran on, undisturbed.
    while let Some(f) = running.frames.next().await {
        frames.push(f.unwrap());
    }
    assert!(max_diff(&frames, &expected) <= 1e-5);
    let text = metrics(&server).await;
    let failures = sample(
        &text,
        "dynaserve_request_failures_total{method=\"rollout\",protocol=\"http\",reason=\"invalid_argument\"}",
    )
    .unwrap();
    assert!(failures >= cases.len() as f64);
    server.shutdown();
    server.wait().await.unwrap();
}

trait EncodedLenOk {
    fn encoded_len_ok(&self, limit: usize) -> bool;
}

impl EncodedLenOk for v1::RolloutRequest {
    /// True when the message is over the server's limit but under tonic's hard cap (4x),
    /// i.e. when the server itself reports the size.
    fn encoded_len_ok(&self, limit: usize) -> bool {
        let n = prost::Message::encoded_len(self);
        n > limit && n <= 4 * limit
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_are_listed_before_the_first_request_and_parse() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let resp = http(server.http_addr, "GET", "/metrics", &[], None).await;
    assert_eq!(resp.status, 200);
    assert!(
        resp.header("content-type")
            .unwrap()
            .starts_with("text/plain")
    );
    let text = resp.text();
    assert!(!text.is_empty());
    let families = parse_prometheus(&text);
    for spec in dynaserve_server::metrics::METRICS {
        let kind = families
            .get(spec.name)
            .unwrap_or_else(|| panic!("{} not listed before the first request", spec.name));
        assert_eq!(kind, spec.kind.as_str(), "{}", spec.name);
    }
    assert_eq!(sample(&text, "dynaserve_ready"), Some(1.0));
    assert_eq!(
        sample(
            &text,
            "dynaserve_requests_total{method=\"rollout\",protocol=\"grpc\"}"
        ),
        Some(0.0)
    );
    // Liveness, readiness, models, OpenAPI.
    assert_eq!(
        http(server.http_addr, "GET", "/health", &[], None)
            .await
            .status,
        200
    );
    assert_eq!(
        http(server.http_addr, "GET", "/ready", &[], None)
            .await
            .status,
        200
    );
    let models: json::ListModelsResponse = http(server.http_addr, "GET", "/v1/models", &[], None)
        .await
        .json();
    assert_eq!(models.models[0].name, m.name);
    let doc: serde_json::Value = http(server.http_addr, "GET", "/openapi.json", &[], None)
        .await
        .json();
    assert!(doc["paths"]["/v1/rollout"]["post"].is_object());
    assert!(doc["components"]["schemas"]["RolloutRequest"].is_object());
    // gRPC health and ListModels.
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{}", server.grpc_addr))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut health = tonic_health::pb::health_client::HealthClient::new(channel);
    let status = health
        .check(tonic_health::pb::HealthCheckRequest {
            service: "dynaserve.v1.WorldModel".into(),
        })
        .await
        .unwrap()
        .into_inner()
        .status;
    assert_eq!(
        status,
        tonic_health::pb::health_check_response::ServingStatus::Serving as i32
    );
    let list = client(&server).await.list_models().await.unwrap();
    assert_eq!(list[0].name, m.name);
    server.shutdown();
    server.wait().await.unwrap();
}

/// A strict reader of the Prometheus text format (0.0.4): returns family name -> type, and
/// panics on any malformed line, sample without a TYPE, or histogram without its series.
fn parse_prometheus(text: &str) -> std::collections::BTreeMap<String, String> {
    dynaserve_client::prom::check_exposition(text).unwrap_or_else(|e| panic!("{e}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn predict_returns_every_kth_frame_matching_rollouts() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let model = load(&m.dir);
    let variants: Vec<json::Scene> = (0..6).map(|i| scene(60 + i, 2, 24)).collect();
    let req = json::PredictRequest {
        model: String::new(),
        variants: variants.clone(),
        steps: 10,
        dt_steps: 2,
        every: 4,
        timeout_ms: 0,
    };
    let resp = client(&server).await.predict(&req).await.unwrap();
    assert_eq!(resp.trajectories.len(), 6);
    for (v, t) in variants.iter().zip(&resp.trajectories) {
        let steps: Vec<u32> = t.frames.iter().map(|f| f.step).collect();
        assert_eq!(steps, vec![4, 8, 10]);
        let mut r = rollout_request(&m.name, v.clone(), 10);
        r.dt_steps = 2;
        let solo = in_process(&*model, &r);
        let picked: Vec<_> = [3usize, 7, 9].iter().map(|&i| solo[i].clone()).collect();
        let mut renumbered = t.frames.clone();
        for (i, f) in renumbered.iter_mut().enumerate() {
            f.step = i as u32 + 1;
        }
        assert!(max_diff(&renumbered, &picked) <= 1e-5);
    }
    let http_resp = post_json(server.http_addr, "/v1/predict", &req).await;
    assert_eq!(http_resp.status, 200);
    assert!(http_resp.header("x-dynaserve-total-ms").is_some());
    let body: json::PredictResponse = http_resp.json();
    assert_eq!(body.trajectories.len(), 6);
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn example_scenes_run_through_the_client_library_http_and_the_cli() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    assert!(files.len() >= 3, "{files:?}");
    let mut c = client(&server).await;
    for f in &files {
        let req = dynaserve_client::scene_file::load(f).unwrap();
        let frames = c.rollout_collect(&req).await.unwrap();
        assert_eq!(frames.len(), req.steps as usize, "{}", f.display());
        assert!(
            frames
                .iter()
                .flat_map(|f| &f.poses)
                .all(|p| p.translation.iter().all(|x| x.is_finite()))
        );
        // The same file is a valid HTTP body as it stands.
        let body = std::fs::read(f).unwrap();
        let resp = http(server.http_addr, "POST", "/v1/rollout", &[], Some(&body)).await;
        assert_eq!(resp.status, 200, "{}: {}", f.display(), resp.text());
    }
    // The CLI saves a trajectory.
    let out = TempDir::new("cli");
    let path = out.0.join("tower.json");
    let status = tokio::process::Command::new(env!("CARGO_BIN_EXE_dynaserve"))
        .arg("rollout")
        .arg(dir.join("box_tower.json"))
        .args([
            "--server",
            &format!("http://{}", server.grpc_addr),
            "--steps",
            "5",
            "--out",
        ])
        .arg(&path)
        .status()
        .await
        .unwrap();
    assert!(status.success());
    let saved: json::RolloutResponse =
        serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    assert_eq!(saved.frames.len(), 5);
    assert_eq!(saved.model, m.name);
    assert_eq!(saved.frames[0].poses.len(), 4);
    server.shutdown();
    server.wait().await.unwrap();
}
