//! Scheduling classes end to end: while a Predict call above `--bulk-cost` keeps bulk work
//! queued, an interactive rollout and a small Predict complete in passes that hold only their
//! share of bulk steps, and the bulk call keeps advancing meanwhile. Pass sizes and the order
//! of completion are asserted, never wall-clock figures (those are in BENCHMARKS.md).

use std::time::{Duration, Instant};

use crate::common::*;
use dynaserve_api::json;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn interactive_work_completes_beside_queued_bulk_work_in_short_passes() {
    let m = test_model();
    let server = start(&m.dir, |c| c.scheduling.bulk_share = 0.25).await;
    let c = client(&server).await;
    let work = |class: &str| {
        format!(
            "dynaserve_class_work_total{{model=\"{}\",priority=\"{class}\"}}",
            m.name
        )
    };
    // 64 variants x 3 objects x 2000 steps = 384,000 object-steps: bulk, and far more work
    // than this test waits for.
    let bulk_req = json::PredictRequest {
        model: m.name.clone(),
        variants: (0..64).map(|i| scene(100 + i, 3, 32)).collect(),
        steps: 2000,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    };
    assert!(server_bulk(&bulk_req));
    let bulk = tokio::spawn({
        let mut c = c.clone();
        async move { c.predict(&bulk_req).await }
    });
    // Wait until its steps are running (a guard against a hang, not a speed check).
    let since = Instant::now();
    while sample(&metrics(&server).await, &work("bulk")).unwrap_or(0.0) == 0.0 {
        assert!(
            since.elapsed() < Duration::from_secs(120),
            "no bulk work ran"
        );
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let bulk_before = sample(&metrics(&server).await, &work("bulk")).unwrap();

    // A 30-step rollout of a 3-object scene. With share 0.25 each of its passes earns one
    // object of bulk credit, so a 3-object bulk step joins every third pass: no step of the
    // rollout ran in a pass of more than two scenes, although 64 bulk scenes were queued
    // and the pass budget holds 64.
    let mut rc = c.clone();
    let frames = rc
        .rollout_collect(&rollout_request(&m.name, scene(1, 3, 32), 30))
        .await
        .unwrap();
    assert_eq!(frames.len(), 30);
    for f in &frames {
        let scenes = f.timing.as_ref().unwrap().batch_scenes;
        assert!(scenes <= 2, "step {} ran in a pass of {scenes}", f.step);
    }
    // A Predict below --bulk-cost (2 variants x 3 objects x 10 steps) is interactive too.
    let small = json::PredictRequest {
        model: m.name.clone(),
        variants: vec![scene(7, 3, 32), scene(8, 3, 32)],
        steps: 10,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    };
    assert!(!server_bulk(&small));
    let mut pc = c.clone();
    let p = pc.predict(&small).await.unwrap();
    assert_eq!(p.trajectories.len(), 2);
    // Both finished while the bulk call was still running...
    assert!(!bulk.is_finished(), "the bulk call finished first");
    // ...and the bulk call was not starved: its steps kept running beside them.
    let bulk_after = sample(&metrics(&server).await, &work("bulk")).unwrap();
    assert!(
        bulk_after > bulk_before,
        "no bulk work ran beside the interactive calls"
    );
    let interactive = sample(&metrics(&server).await, &work("interactive")).unwrap();
    assert!(interactive >= (30 * 3 + 2 * 10 * 3) as f64, "{interactive}");
    bulk.abort();
    server.shutdown();
    server.wait().await.unwrap();
}

/// True when the server's default `--bulk-cost` makes `req` bulk work.
fn server_bulk(req: &json::PredictRequest) -> bool {
    let cost: u64 = req
        .variants
        .iter()
        .map(|v| v.objects.len() as u64 * u64::from(req.steps))
        .sum();
    dynaserve_server::config::SchedulingConfig::default().predict_is_bulk(cost)
}
