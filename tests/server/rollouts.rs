//! Rollouts over gRPC, HTTP JSON and Server-Sent Events, alone, concurrent and as Predict
//! calls, each equal to the in-process rollout of the same scene.

use crate::common::*;
use dynaserve_api::json;
use futures::StreamExt;

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
async fn an_ensemble_directory_is_served_as_one_model_stepping_the_members_mean() {
    let (a, b) = (random_model("member-a", 11), random_model("member-b", 12));
    let tmp = TempDir::new("ensemble");
    let dir = tmp.0.join("rigidformer-pair");
    std::fs::create_dir_all(&dir).unwrap();
    let config = serde_json::json!({
        "architecture": "rigidformer-ensemble",
        "members": [a.dir, b.dir],
    });
    std::fs::write(dir.join("config.json"), config.to_string()).unwrap();
    let server = start(&dir, |_| {}).await;
    let req = rollout_request("rigidformer-pair", scene(5, 3, 48), 20);
    let mut c = client(&server).await;
    // Both model lists name the members, in order, beside the first member's configuration.
    let members = vec![a.name.clone(), b.name.clone()];
    let listed = c.list_models().await.unwrap();
    assert_eq!(listed[0].members, members);
    assert_eq!(listed[0].architecture, "rigidformer");
    let models: json::ListModelsResponse = http(server.http_addr, "GET", "/v1/models", &[], None)
        .await
        .json();
    assert_eq!(models.models[0].members, members);
    let frames = c.rollout_collect(&req).await.unwrap();
    // The served rollout is the in-process ensemble's, one mean step after another ...
    let ensemble = load(&dir);
    assert_eq!(ensemble.name(), "rigidformer-pair");
    let diff = max_diff(&frames, &in_process(&*ensemble, &req));
    assert!(diff <= 1e-5, "max difference {diff}");
    // ... and neither member's alone.
    for member in [&a, &b] {
        let alone = in_process(&*load(&member.dir), &req);
        let apart = max_diff(&frames, &alone);
        assert!(
            apart > 1e-4,
            "{} alone gives the ensemble's rollout",
            member.name
        );
    }
    server.shutdown();
    server.wait().await.unwrap();
}
