//! End-to-end: every frame of the bundled ensemble carries each object's spread (its members'
//! disagreement), over gRPC and HTTP, in Rollout, Predict and a session's Step; the single
//! checkpoint's frames carry none, and its JSON frames have no `spread` key at all.

mod common;

use std::path::PathBuf;
use std::time::Duration;

use common::*;
use dynaserve_api::{json, v1};
use dynaserve_server::ServeConfig;

const ENSEMBLE: &str = "rigidformer-small-ensemble";
const SINGLE: &str = "rigidformer-small";
const OBJECTS: usize = 3;

async fn start_both() -> dynaserve_server::RunningServer {
    let dirs = vec![PathBuf::from(SHIPPED), PathBuf::from(SHIPPED_ENSEMBLE)];
    let config = ServeConfig::local(dirs.clone());
    let models = dynaserve_server::load_models(&dirs).unwrap();
    let server = dynaserve_server::start(config, models).await.unwrap();
    server.wait_ready(Duration::from_secs(60)).await.unwrap();
    server
}

/// Every frame holds one spread per object, finite and positive (the scene moves, so the
/// members never agree exactly); `what` names the frames in messages.
fn assert_spread(frames: &[json::StepFrame], what: &str) {
    assert!(!frames.is_empty(), "{what}: no frames");
    for f in frames {
        assert_eq!(f.spread.len(), f.poses.len(), "{what}: step {}", f.step);
        for (j, s) in f.spread.iter().enumerate() {
            let ok = |v: f32| v.is_finite() && v > 0.0;
            assert!(
                ok(s.position_m) && ok(s.orientation_deg),
                "{what}: step {} object {j}: {s:?}",
                f.step
            );
            // Members of one release family disagree by centimetres and degrees, not metres.
            assert!(
                s.position_m < 1.0 && s.orientation_deg < 90.0,
                "{what}: {s:?}"
            );
        }
    }
}

fn predict_request(model: &str) -> json::PredictRequest {
    json::PredictRequest {
        model: model.into(),
        variants: (0..2).map(|s| scene(30 + s, OBJECTS, 32)).collect(),
        steps: 10,
        dt_steps: 1,
        every: 5,
        timeout_ms: 0,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_ensemble_serves_its_spread_and_a_single_network_none() {
    let server = start_both().await;
    let mut c = client(&server).await;
    let moving = scene(7, OBJECTS, 32);

    // Rollout over gRPC and HTTP.
    let frames = c
        .rollout_collect(&rollout_request(ENSEMBLE, moving.clone(), 12))
        .await
        .unwrap();
    assert_eq!(frames.len(), 12);
    assert_spread(&frames, "gRPC rollout");
    let resp = post_json(
        server.http_addr,
        "/v1/rollout",
        &rollout_request(ENSEMBLE, moving.clone(), 12),
    )
    .await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    let body: json::RolloutResponse = resp.json();
    assert_spread(&body.frames, "HTTP rollout");
    // Both transports serve the same spread of the same scene.
    for (g, h) in frames.iter().zip(&body.frames) {
        for (a, b) in g.spread.iter().zip(&h.spread) {
            assert!((a.position_m - b.position_m).abs() < 1e-4, "{a:?} vs {b:?}");
        }
    }

    // Predict, every variant's kept frames.
    let predicted = c.predict(&predict_request(ENSEMBLE)).await.unwrap();
    assert_eq!(predicted.trajectories.len(), 2);
    for t in &predicted.trajectories {
        assert_eq!(t.frames.len(), 2);
        assert_spread(&t.frames, "gRPC predict");
    }
    let resp = post_json(server.http_addr, "/v1/predict", &predict_request(ENSEMBLE)).await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    let body: json::PredictResponse = resp.json();
    for t in &body.trajectories {
        assert_spread(&t.frames, "HTTP predict");
    }

    // A session's Step with a kinematic object: given, not predicted, so its spread is 0.
    let created = c
        .create_session(v1::CreateSessionRequest {
            model: ENSEMBLE.into(),
            scene: Some(moving.to_proto()),
            dt_steps: 1,
            kinematic: vec![2],
            shared: false,
        })
        .await
        .unwrap();
    let stepped = c
        .step_collect(v1::StepRequest {
            session_id: created.info.session_id.clone(),
            steps: 3,
            actions: Vec::new(),
            timeout_ms: 0,
        })
        .await
        .unwrap();
    let stepped: Vec<json::StepFrame> = stepped.iter().map(json::StepFrame::from_proto).collect();
    for f in &stepped {
        assert_eq!(f.spread.len(), OBJECTS);
        assert_eq!(f.spread[2], json::ObjectSpread::default());
        assert_spread(
            &[json::StepFrame {
                poses: f.poses[..2].to_vec(),
                spread: f.spread[..2].to_vec(),
                ..f.clone()
            }],
            "session step",
        );
    }

    // The single network: no spread anywhere, and no `spread` key in its JSON frames.
    let frames = c
        .rollout_collect(&rollout_request(SINGLE, moving.clone(), 5))
        .await
        .unwrap();
    assert!(frames.iter().all(|f| f.spread.is_empty()));
    let predicted = c.predict(&predict_request(SINGLE)).await.unwrap();
    assert!(
        predicted
            .trajectories
            .iter()
            .flat_map(|t| &t.frames)
            .all(|f| f.spread.is_empty())
    );
    let resp = post_json(
        server.http_addr,
        "/v1/rollout",
        &rollout_request(SINGLE, moving, 5),
    )
    .await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    assert!(!resp.text().contains("spread"), "{}", resp.text());
    let resp = post_json(server.http_addr, "/v1/predict", &predict_request(SINGLE)).await;
    assert!(!resp.text().contains("spread"), "{}", resp.text());
    server.shutdown();
}
