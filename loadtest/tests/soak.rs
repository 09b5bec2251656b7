//! The soak mode against a real server on 127.0.0.1 with the shipped weights, for a few
//! seconds: clients drop rollouts and reconnect, every frame is checked, memory is read.

use std::path::PathBuf;
use std::time::Duration;

use dynaserve_loadtest::run::{
    Load, Mode, Progress, SoakPlan, Stop, Target, Transport, run_target,
};
use dynaserve_loadtest::scenes::SceneSource;
use dynaserve_server::{RunningServer, ServeConfig};

fn model_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/rigidformer-small")
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
        connections: 1,
        model_dir: model_dir(),
        max_batch_scenes: 64,
        max_batch_objects: 2048,
        spawned: None,
        // The server runs in this process.
        pid: Some(std::process::id()),
    }
}

fn soak(streams: usize, seconds: f64, drop_probability: f64, steps: u32) -> Load {
    Load {
        mode: Mode::Soak(SoakPlan {
            streams,
            duration: Duration::from_secs_f64(seconds),
            drop_probability,
            rss_interval: Duration::from_millis(500),
            seed: 5,
        }),
        scenes: SceneSource::Generated {
            objects: 3,
            points: 64,
            seed: 2,
        },
        steps,
        dt_steps: 1,
        model: String::new(),
        timeout_ms: 0,
        warmup: Duration::ZERO,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streams_that_drop_and_reconnect_get_every_frame_in_order_in_their_own_stream() {
    let config = ServeConfig::local(vec![model_dir()]);
    let models = dynaserve_server::load_models(&config.models).unwrap();
    let server = dynaserve_server::start(config, models).await.unwrap();
    server.wait_ready(Duration::from_secs(120)).await.unwrap();
    let (_tx, stop) = Stop::new();
    let quiet = Progress { quiet: true };

    for (transport, seconds) in [(Transport::Grpc, 4.0), (Transport::Http, 2.5)] {
        let load = soak(6, seconds, 0.5, 12);
        let side = run_target(&load, &target(&server, transport), &stop, quiet)
            .await
            .unwrap();
        let level = &side.levels[0];
        let s = level.soak.as_ref().expect("a soak report");
        let c = &s.counts;
        let text = s.to_text();
        assert!(s.passed(), "{transport:?}:\n{text}");
        assert!(text.contains("result: PASS"), "{text}");
        // Both kinds of client happened, and every drop was followed by a new connection
        // (except a stream's last, after the soak's end).
        assert!(c.kept_complete >= 6, "{text}");
        assert!(c.dropped >= 2, "{text}");
        assert!(
            c.reconnects <= c.dropped && c.reconnects + 6 >= c.dropped,
            "{text}"
        );
        assert_eq!(
            (c.failed, c.refused, c.stalled, c.cut),
            (0, 0, 0, 0),
            "{text}"
        );
        // Every kept rollout brought all its steps; dropped ones brought fewer.
        assert!(c.frames >= c.kept_complete * 12, "{text}");
        assert!(c.frames < (c.kept_complete + c.dropped) * 12, "{text}");
        assert_eq!(
            level.frames, c.frames,
            "the recorder and the checks saw the same frames"
        );
        // Memory read at the start, every 0.5 s and at the end; the peak bounds both ends.
        let rss = s.rss.as_ref().expect("an RSS record");
        assert!(rss.samples.len() >= 3, "{rss:?}");
        let (a, p, e) = (
            rss.start().unwrap(),
            rss.peak().unwrap(),
            rss.end().unwrap(),
        );
        assert!(a > 0 && p >= a && p >= e, "{rss:?}");
        // The server computed at least every frame the clients received.
        let server_steps = level.server.as_ref().map_or(0.0, |m| m.scene_steps);
        assert!(
            server_steps >= c.frames as f64,
            "{server_steps} < {}",
            c.frames
        );
    }
    server.shutdown();
}
