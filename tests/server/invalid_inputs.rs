//! Bad input over both protocols is refused naming the field while a good stream runs on.

use crate::common::*;
use dynaserve_api::json;
use dynaserve_api::v1;
use futures::StreamExt;
use tonic::Code;

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
    let s = grpc_world_model(&server)
        .await
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
    let s = grpc_world_model(&server)
        .await
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

/// A request above `--max-request-cost` (objects x steps, summed over a Predict's variants) is
/// refused at admission, before any step runs, with INVALID_ARGUMENT / 422 naming `steps`, its
/// factors and the flag: Predict over both protocols, Rollout, and a session's Step and
/// Predict. A Predict at the ceiling runs, and ListModels reports the ceiling.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn requests_above_the_cost_ceiling_are_refused_naming_steps_and_the_flag() {
    let m = test_model();
    let server = start(&m.dir, |c| c.max_request_cost = 100).await;
    let mut c = client(&server).await;
    // ListModels reports the ceiling, over both protocols.
    let listed = c.list_models().await.unwrap();
    assert_eq!(listed[0].max_request_cost, 100);
    let listed: json::ListModelsResponse = http(server.http_addr, "GET", "/v1/models", &[], None)
        .await
        .json();
    assert_eq!(listed.models[0].max_request_cost, 100);

    // 5 variants of 2 objects: 10 steps cost 100 object-steps, 11 steps 110.
    let predict = |steps: u32| json::PredictRequest {
        model: m.name.clone(),
        variants: (0..5).map(|i| scene(40 + i, 2, 16)).collect(),
        steps,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    };
    let want = "steps: 2 objects x 11 steps x 5 variants = 110 object-steps exceeds the server's \
                limit of 100 (--max-request-cost); lower steps, variants or objects";
    match c.predict(&predict(11)).await {
        Err(dynaserve_client::ClientError::Status(s)) => {
            assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
            assert_eq!(s.message(), want);
        }
        other => panic!("a Predict above the ceiling over gRPC: {other:?}"),
    }
    let resp = post_json(server.http_addr, "/v1/predict", &predict(11)).await;
    assert_eq!(resp.status, 422, "{}", resp.text());
    let e: json::ErrorResponse = resp.json();
    assert_eq!(e.error.code, "INVALID_ARGUMENT");
    assert_eq!(e.error.field.as_deref(), Some("steps"));
    assert_eq!(e.error.message, want);
    // Variants of different sizes count each its own objects: 1 + 2 + 3 objects x 17 steps.
    let mut mixed = predict(17);
    mixed.variants = (1..=3).map(|k| scene(60 + k as u64, k, 16)).collect();
    let resp = post_json(server.http_addr, "/v1/predict", &mixed).await;
    assert_eq!(resp.status, 422, "{}", resp.text());
    assert_eq!(
        resp.json::<json::ErrorResponse>().error.message,
        "steps: 6 objects (summed over 3 variants) x 17 steps = 102 object-steps exceeds the \
         server's limit of 100 (--max-request-cost); lower steps, variants or objects"
    );
    // A rollout: 2 objects x 51 steps.
    let resp = post_json(
        server.http_addr,
        "/v1/rollout",
        &rollout_request(&m.name, scene(50, 2, 16), 51),
    )
    .await;
    assert_eq!(resp.status, 422, "{}", resp.text());
    let e: json::ErrorResponse = resp.json();
    assert_eq!(e.error.field.as_deref(), Some("steps"));
    assert_eq!(
        e.error.message,
        "steps: 2 objects x 51 steps = 102 object-steps exceeds the server's limit of 100 \
         (--max-request-cost); lower steps or objects"
    );
    // A session of 2 objects: Step and Predict.
    let info = create_session_http(server.http_addr, &m.name, scene(51, 2, 16), vec![]).await;
    let path = format!("/v1/sessions/{}", info.session_id);
    let step = json::StepRequest {
        steps: 51,
        actions: vec![],
        timeout_ms: 0,
    };
    let resp = post_json(server.http_addr, &format!("{path}/step"), &step).await;
    assert_eq!(resp.status, 422, "{}", resp.text());
    let e: json::ErrorResponse = resp.json();
    assert_eq!(e.error.field.as_deref(), Some("steps"));
    assert!(
        e.error
            .message
            .contains("2 objects x 51 steps = 102 object-steps")
            && e.error.message.contains("(--max-request-cost)"),
        "{}",
        e.error.message
    );
    let session_predict = json::SessionPredictRequest {
        variants: vec![json::SessionVariant::default(); 5],
        steps: 11,
        every: 0,
        timeout_ms: 0,
    };
    let resp = post_json(
        server.http_addr,
        &format!("{path}/predict"),
        &session_predict,
    )
    .await;
    assert_eq!(resp.status, 422, "{}", resp.text());
    assert_eq!(resp.json::<json::ErrorResponse>().error.message, want);

    // Refused at admission: not one step ran.
    let steps_metric = format!("dynaserve_scene_steps_total{{model=\"{}\"}}", m.name);
    assert_eq!(sample(&metrics(&server).await, &steps_metric), Some(0.0));
    // At the ceiling the call runs, over both protocols.
    let done = c.predict(&predict(10)).await.unwrap();
    assert_eq!(done.trajectories.len(), 5);
    assert_eq!(done.trajectories[0].frames.last().unwrap().step, 10);
    let resp = post_json(server.http_addr, "/v1/predict", &predict(10)).await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    server.shutdown();
    server.wait().await.unwrap();
}

/// A Predict whose second variant is invalid (non-finite, out of range, malformed) is refused
/// with 422 naming that variant by index, not as a whole.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn predict_with_one_invalid_variant_is_refused_naming_its_index() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let good = json::PredictRequest {
        model: m.name.clone(),
        variants: vec![scene(1, 2, 16), scene(2, 2, 16)],
        steps: 2,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    };
    let resp = post_json(server.http_addr, "/v1/predict", &good).await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    type Edit = fn(&mut serde_json::Value);
    let cases: Vec<(&str, Edit)> = vec![
        // 1e39 overflows f32: the position arrives as infinity.
        ("non-finite position", |o| {
            o["pose"]["translation"][0] = serde_json::json!(1e39)
        }),
        ("non-finite mass", |o| o["mass"] = serde_json::json!(1e39)),
        ("negative mass", |o| o["mass"] = serde_json::json!(-1.0)),
        ("friction above range", |o| {
            o["friction"] = serde_json::json!(1e6)
        }),
        ("mass of the wrong type", |o| {
            o["mass"] = serde_json::json!("heavy")
        }),
        ("no points", |o| o["points"] = serde_json::json!([])),
    ];
    for (what, edit) in cases {
        let mut body = serde_json::to_value(&good).unwrap();
        edit(&mut body["variants"][1]["objects"][1]);
        let resp = post_json(server.http_addr, "/v1/predict", &body).await;
        assert_eq!(resp.status, 422, "{what}: {}", resp.text());
        let e: json::ErrorResponse = resp.json();
        let field = e.error.field.clone().unwrap_or_default();
        assert!(
            field.starts_with("variants[1].objects[1]"),
            "{what}: field {field:?}, message {:?}",
            e.error.message
        );
    }
    server.shutdown();
    server.wait().await.unwrap();
}
