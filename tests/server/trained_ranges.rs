//! Requests whose objects leave the model's trained parameter ranges are answered in full and
//! warned about: `x-dynaserve-warning` on HTTP and gRPC, one line per parameter naming the
//! objects, and `dynaserve_out_of_range_scenes_total`.

use crate::common::*;
use dynaserve_api::json;
use dynaserve_model::TrainedRanges;

/// A model trained (as its config says) on friction 0.1-1.0 and restitution 0.05-0.8.
fn ranged_model() -> TestModel {
    random_model_with("ranged", 11, |c| {
        c.trained_ranges = Some(TrainedRanges {
            mass: [0.01, 10.0],
            friction: [0.1, 1.0],
            restitution: [0.05, 0.8],
            mass_relative: false,
        });
    })
}

fn with_params(mut scene: json::Scene, params: &[(f32, f32)]) -> json::Scene {
    for (o, (friction, restitution)) in scene.objects.iter_mut().zip(params) {
        o.mass = 1.0;
        o.friction = *friction;
        o.restitution = *restitution;
    }
    scene
}

/// POSTs `body` to `path`, checks that it was answered (200) and returns the answer with its
/// `x-dynaserve-warning` lines.
async fn warned<T: serde::Serialize>(
    addr: std::net::SocketAddr,
    path: &str,
    body: &T,
) -> (HttpResponse, Vec<String>) {
    let resp = post_json(addr, path, body).await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    let w = resp
        .headers
        .iter()
        .filter(|(k, _)| k == dynaserve_api::WARNING_HEADER)
        .map(|(_, v)| v.clone())
        .collect();
    (resp, w)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn parameters_outside_the_trained_ranges_are_warned_about_and_still_answered() {
    let m = ranged_model();
    let server = start(&m.dir, |_| {}).await;

    // Inside: no warning.
    let inside = with_params(scene(3, 3, 64), &[(0.5, 0.2), (0.1, 0.05), (1.0, 0.8)]);
    let (_, w) = warned(
        server.http_addr,
        "/v1/rollout",
        &rollout_request(&m.name, inside, 4),
    )
    .await;
    assert!(w.is_empty(), "{w:?}");

    // Two objects with friction 0 (the value an omitted field reads as), one bouncier than
    // trained: the rollout still answers, with one warning per parameter.
    let outside = with_params(scene(3, 3, 64), &[(0.0, 0.2), (0.5, 0.95), (0.0, 0.2)]);
    let (resp, w) = warned(
        server.http_addr,
        "/v1/rollout",
        &rollout_request(&m.name, outside.clone(), 4),
    )
    .await;
    let body: json::RolloutResponse = resp.json();
    assert_eq!(body.frames.len(), 4);
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(
        w[0].starts_with("scene.objects[0,2].friction: 0 is outside the range the model was trained on (0.1 to 1)"),
        "{}",
        w[0]
    );
    assert!(
        w[1].starts_with("scene.objects[1].restitution: 0.95 is outside"),
        "{}",
        w[1]
    );

    // Predict names the variant; gRPC carries the same lines as metadata.
    let predict = json::PredictRequest {
        model: m.name.clone(),
        variants: vec![
            with_params(scene(4, 2, 64), &[(0.5, 0.2); 2]),
            outside.clone(),
        ],
        steps: 2,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    };
    let (_, w) = warned(server.http_addr, "/v1/predict", &predict).await;
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(
        w[0].starts_with("variants[1].objects[0,2].friction"),
        "{}",
        w[0]
    );
    let mut c = client(&server).await;
    let rollout = c
        .rollout(&rollout_request(&m.name, outside, 2))
        .await
        .unwrap();
    assert_eq!(rollout.warnings.len(), 2, "{:?}", rollout.warnings);
    assert!(rollout.warnings[1].starts_with("scene.objects[1].restitution"));

    // Counted once per scene and parameter: HTTP rollout, predict variant 1, gRPC rollout.
    let text = metrics(&server).await;
    let count = |p: &str| {
        sample(
            &text,
            &format!(
                "dynaserve_out_of_range_scenes_total{{model=\"{}\",parameter=\"{p}\"}}",
                m.name
            ),
        )
    };
    assert_eq!(count("friction"), Some(3.0));
    assert_eq!(count("restitution"), Some(3.0));
    assert_eq!(count("mass"), Some(0.0));

    // A Predict of many such variants answers with at most 8 lines, the last counting the rest.
    let slippery = with_params(scene(5, 1, 64), &[(0.0, 0.2)]);
    let many = json::PredictRequest {
        variants: vec![slippery; 10],
        ..predict
    };
    let (_, w) = warned(server.http_addr, "/v1/predict", &many).await;
    assert_eq!(w.len(), 8, "{w:?}");
    assert!(
        w[6].starts_with("variants[6].objects[0].friction"),
        "{}",
        w[6]
    );
    assert!(w[7].starts_with("3 more parameters outside"), "{}", w[7]);
    server.shutdown();
    server.wait().await.unwrap();
}
