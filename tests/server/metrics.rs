//! The Prometheus exposition: every family listed before the first request, in valid text
//! format; health and model listing.

use crate::common::*;
use dynaserve_api::json;

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
    assert!(
        models.models[0].members.is_empty(),
        "a single network has no members"
    );
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
    assert!(list[0].members.is_empty());
    server.shutdown();
    server.wait().await.unwrap();
}

/// A strict reader of the Prometheus text format (0.0.4): returns family name -> type, and
/// panics on any malformed line, sample without a TYPE, or histogram without its series.
fn parse_prometheus(text: &str) -> std::collections::BTreeMap<String, String> {
    dynaserve_client::prom::check_exposition(text).unwrap_or_else(|e| panic!("{e}"))
}
