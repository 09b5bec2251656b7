//! End to end: a real server on 127.0.0.1 with the shipped weights (models/rigidformer-small),
//! loaded by the load tester over gRPC and HTTP, and the in-process baseline.

use std::path::PathBuf;
use std::time::Duration;

use dynaserve_loadtest::report::{Report, SideReport};
use dynaserve_loadtest::run::{Load, Mode, Progress, Stop, Target, Transport, run_target};
use dynaserve_loadtest::scenes::SceneSource;
use dynaserve_server::{RunningServer, ServeConfig};

fn model_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/rigidformer-small")
}

async fn start(tweak: impl FnOnce(&mut ServeConfig)) -> RunningServer {
    let mut config = ServeConfig::local(vec![model_dir()]);
    tweak(&mut config);
    let models = dynaserve_server::load_models(&config.models).unwrap();
    let server = dynaserve_server::start(config, models).await.unwrap();
    server.wait_ready(Duration::from_secs(120)).await.unwrap();
    server
}

fn load(mode: Mode, steps: u32) -> Load {
    Load {
        mode,
        scenes: SceneSource::Generated {
            objects: 3,
            points: 64,
            seed: 11,
        },
        steps,
        dt_steps: 1,
        model: String::new(),
        timeout_ms: 0,
        warmup: Duration::ZERO,
    }
}

fn target(server: &RunningServer, transport: Transport) -> Target {
    Target {
        label: "A".into(),
        transport,
        url: match transport {
            Transport::Http => format!("http://{}", server.http_addr),
            _ => format!("http://{}", server.grpc_addr),
        },
        metrics_url: Some(format!("http://{}/metrics", server.http_addr)),
        connections: 2,
        model_dir: model_dir(),
        max_batch_scenes: 64,
        max_batch_objects: 2048,
        spawned: None,
        pid: None,
    }
}

const QUIET: Progress = Progress { quiet: true };

fn ordered(s: &dynaserve_loadtest::stats::Summary) {
    assert!(
        s.min <= s.p50 && s.p50 <= s.p90 && s.p90 <= s.p99 && s.p99 <= s.max,
        "{s:?}"
    );
}

fn check_streams(side: &SideReport, streams: u64, steps: u64, objects: u64) -> &Report {
    assert_eq!(side.levels.len(), 1);
    assert_eq!(side.model, "rigidformer-small");
    let r = &side.levels[0];
    assert!(r.errors.is_empty(), "{:?} {:?}", r.errors, r.error_examples);
    assert_eq!(r.requests.started, streams);
    assert_eq!(r.requests.ok, streams);
    assert_eq!((r.requests.failed, r.requests.cut), (0, 0));
    assert_eq!(r.frames, streams * steps);
    assert_eq!(r.expected_frames, Some(streams * steps));
    assert_eq!(r.object_steps, streams * steps * objects);
    // One gap per frame after the first, one first-frame time and one latency per request.
    assert_eq!(r.step_latency_ms.count as u64, streams * (steps - 1));
    assert_eq!(r.first_frame_ms.count as u64, streams);
    assert_eq!(r.request_latency_ms.count as u64, streams);
    ordered(&r.step_latency_ms);
    ordered(&r.first_frame_ms);
    ordered(&r.request_latency_ms);
    assert!(r.request_latency_ms.max >= r.first_frame_ms.min);
    assert!(r.throughput.scene_steps_per_s > 0.0);
    assert!(
        (r.throughput.object_steps_per_s / r.throughput.scene_steps_per_s - objects as f64).abs()
            < 1e-6
    );
    r
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streams_and_predict_over_grpc_and_http_with_server_metrics() {
    let server = start(|_| {}).await;
    let (_tx, stop) = Stop::new();

    // 4 streams x 5 steps over gRPC.
    let l = load(
        Mode::Streams {
            levels: vec![4],
            duration: None,
        },
        5,
    );
    let side = run_target(&l, &target(&server, Transport::Grpc), &stop, QUIET)
        .await
        .unwrap();
    let r = check_streams(&side, 4, 5, 3);
    let s = r
        .server
        .as_ref()
        .unwrap_or_else(|| panic!("{:?}", r.server_metrics_error));
    // The diff counts this run only (warm-up steps happened before the first scrape).
    assert!(s.batches > 0.0);
    assert_eq!(s.scene_steps, 20.0);
    assert_eq!(s.object_steps, 60.0);
    assert!(s.batch_scenes.mean >= 1.0 && s.batch_scenes.mean <= 4.0);
    assert!((s.batches * s.batch_scenes.mean - 20.0).abs() < 1e-9);
    assert!(s.batch_scenes.p50 <= s.batch_scenes.p99);
    let q = &s.queue_wait_ms["interactive"];
    assert_eq!(q.count, 20.0);
    assert!(q.p50 <= q.p99);
    assert!(r.frame_batch_scenes.count == 20 && r.frame_batch_scenes.max <= 4.0);

    // The same over HTTP (Server-Sent Events).
    let side = run_target(&l, &target(&server, Transport::Http), &stop, QUIET)
        .await
        .unwrap();
    let r = check_streams(&side, 4, 5, 3);
    assert_eq!(r.server.as_ref().unwrap().scene_steps, 20.0);

    // Planner calls: 3 calls of 8 variants x 5 steps, 2 at a time, every 2nd frame.
    let p = load(
        Mode::Predict {
            variants: 8,
            calls: 3,
            concurrency: 2,
            every: 2,
        },
        5,
    );
    for transport in [Transport::Grpc, Transport::Http] {
        let side = run_target(&p, &target(&server, transport), &stop, QUIET)
            .await
            .unwrap();
        let r = &side.levels[0];
        assert!(r.errors.is_empty(), "{:?}", r.error_examples);
        assert_eq!((r.requests.started, r.requests.ok), (3, 3));
        // Frames 2, 4 and the final 5 of each variant.
        assert_eq!(r.frames, 3 * 8 * 3);
        assert_eq!(r.scene_steps, 3 * 8 * 5);
        assert_eq!(r.object_steps, 3 * 8 * 5 * 3);
        assert_eq!(r.request_latency_ms.count, 3);
        ordered(&r.request_latency_ms);
        let s = r.server.as_ref().unwrap();
        assert_eq!(s.scene_steps, 120.0);
        assert!(s.batches > 0.0 && s.batches <= 30.0, "{}", s.batches);
        // 120 object-steps per call, below --bulk-cost: interactive work.
        assert!(s.queue_wait_ms.contains_key("interactive"));
    }
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn server_errors_are_counted_and_unreachable_targets_are_clear_errors() {
    let server = start(|c| c.max_steps = 3).await;
    let (_tx, stop) = Stop::new();
    let l = load(
        Mode::Streams {
            levels: vec![3],
            duration: None,
        },
        5,
    );
    for (transport, code) in [
        (Transport::Grpc, "grpc INVALID_ARGUMENT"),
        (Transport::Http, "http 422 INVALID_ARGUMENT"),
    ] {
        let side = run_target(&l, &target(&server, transport), &stop, QUIET)
            .await
            .unwrap();
        let r = &side.levels[0];
        assert_eq!((r.requests.started, r.requests.failed), (3, 3));
        assert_eq!(r.errors.get(code), Some(&3), "{:?}", r.errors);
        assert!(
            r.error_examples[0].contains("steps"),
            "{:?}",
            r.error_examples
        );
        assert_eq!(r.frames, 0);
        let s = r.server.as_ref().unwrap();
        assert_eq!(s.failures.get("invalid_argument"), Some(&3.0));
    }
    // A port nobody listens on: a clear error, not a panic.
    let closed = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap()
    };
    let mut t = target(&server, Transport::Grpc);
    t.url = format!("http://{closed}");
    let e = run_target(&l, &t, &stop, QUIET)
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("cannot reach the gRPC server"), "{e}");
    t.transport = Transport::Http;
    let e = run_target(&l, &t, &stop, QUIET)
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("cannot reach the HTTP server"), "{e}");
    // An unknown model name is named.
    let mut bad = l.clone();
    bad.model = "nope".into();
    let e = run_target(&bad, &target(&server, Transport::Grpc), &stop, QUIET)
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("nope"), "{e}");
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn in_process_baseline_and_timed_streams() {
    let (_tx, stop) = Stop::new();
    let t = Target {
        label: "in".into(),
        transport: Transport::Inprocess,
        url: String::new(),
        metrics_url: None,
        connections: 1,
        model_dir: model_dir(),
        max_batch_scenes: 2,
        max_batch_objects: 2048,
        spawned: None,
        pid: None,
    };
    let l = load(
        Mode::Streams {
            levels: vec![4],
            duration: None,
        },
        5,
    );
    let side = run_target(&l, &t, &stop, QUIET).await.unwrap();
    let r = check_streams(&side, 4, 5, 3);
    // Scene cap 2: every pass holds 2 of the 4 scenes.
    assert_eq!(
        (r.frame_batch_scenes.min, r.frame_batch_scenes.max),
        (2.0, 2.0)
    );
    assert!(r.server.is_none());

    // Timed closed loop on a server: streams restart rollouts until the window ends.
    let server = start(|_| {}).await;
    let l = load(
        Mode::Streams {
            levels: vec![2],
            duration: Some(Duration::from_millis(1500)),
        },
        3,
    );
    let side = run_target(&l, &target(&server, Transport::Grpc), &stop, QUIET)
        .await
        .unwrap();
    let r = &side.levels[0];
    assert!(r.errors.is_empty(), "{:?}", r.error_examples);
    assert!(r.requests.ok > 2, "{:?}", r.requests);
    assert!(r.frames >= 3 * r.requests.ok);
    assert!((r.duration_s - 1.5).abs() < 0.2, "{}", r.duration_s);
    server.shutdown();
    server.wait().await.unwrap();
}
