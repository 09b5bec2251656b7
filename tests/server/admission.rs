//! Admission and release: a disconnected stream frees its slot before the next step, a
//! deadline in the queue ends the call on time (the server's default one too), overload is
//! refused with a retry hint.

use std::time::{Duration, Instant};

use crate::common::*;
use dynaserve_api::json;
use futures::StreamExt;
use tonic::Code;

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
    let err = c.rollout(&req).await.expect_err("slot should be taken");
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

/// Eight 10000-step rollouts of 3-object scenes (seeds from `first_seed`, each with
/// `timeout_ms`, 0 for none) read to their end in the background, given 300 ms to fill a
/// queue of scene cap 1.
async fn fill_queue(
    c: &dynaserve_client::Client,
    model: &str,
    first_seed: u64,
    timeout_ms: u32,
) -> Vec<tokio::task::JoinHandle<()>> {
    let busy = (0..8)
        .map(|i| {
            let mut c = c.clone();
            let mut req = rollout_request(model, scene(first_seed + i, 3, 48), 10_000);
            req.timeout_ms = timeout_ms;
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
    busy
}

/// A 5-step Predict of one 2-object scene naming no deadline.
fn small_predict(model: &str) -> json::PredictRequest {
    json::PredictRequest {
        model: model.to_string(),
        variants: vec![scene(5, 2, 32)],
        steps: 5,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    }
}

/// [`small_predict`] of one 48-object scene. Made bulk work (`--bulk-cost 0`) at the smallest
/// share (1%), a step of it needs the credit of about 1600 passes of the 3-object streams of
/// [`fill_queue`], so it stays queued for seconds behind them.
fn queued_bulk_predict(model: &str) -> json::PredictRequest {
    json::PredictRequest {
        variants: vec![scene(5, 48, 32)],
        ..small_predict(model)
    }
}

/// Scene cap 1 and every Predict bulk work (`--bulk-cost 0`) at the smallest share: while
/// [`fill_queue`]'s streams keep the queue full, a [`queued_bulk_predict`] waits in it until a
/// deadline ends it.
fn bulk_waits_behind_streams(c: &mut dynaserve_server::ServeConfig) {
    c.max_batch_scenes = 1;
    c.scheduling.bulk_cost = 0;
    c.scheduling.bulk_share = 0.01;
}

/// A request that names no deadline gets the server's `--default-timeout-s`; one that names
/// its own keeps it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_without_a_deadline_gets_the_server_default() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        bulk_waits_behind_streams(c);
        c.default_timeout_s = 0.15;
    })
    .await;
    let c = client(&server).await;
    // Interactive streams with their own long deadline keep the queue full.
    let busy = fill_queue(&c, &m.name, 60, 60_000).await;
    let predict = queued_bulk_predict(&m.name);
    let t = Instant::now();
    let resp = post_json(server.http_addr, "/v1/predict", &predict).await;
    assert_eq!(resp.status, 504, "{}", resp.text());
    assert!(
        t.elapsed() >= Duration::from_millis(145),
        "early: {:?}",
        t.elapsed()
    );
    assert!(
        busy.iter().all(|b| !b.is_finished()),
        "the streams naming their own deadline ended"
    );
    for b in busy {
        b.abort();
    }
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_deadline_in_the_queue_yields_deadline_exceeded_on_time() {
    let m = test_model();
    let server = start(&m.dir, bulk_waits_behind_streams).await;
    let c = client(&server).await;
    let busy = fill_queue(&c, &m.name, 40, 0).await;
    let predict = queued_bulk_predict(&m.name);
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
        .expect_err("third stream must be refused");
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
