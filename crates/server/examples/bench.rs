//! Ad-hoc throughput and latency measurement of the server on loopback.
//!
//! ```text
//! cargo run --release -p dynaserve-server --example bench -- [MODEL_DIR]
//! ```
//!
//! Without `MODEL_DIR` it serves `models/rigidformer-small` when present, otherwise a randomly
//! initialised RigidFormer of the small configuration saved to a temporary directory (same
//! cost per step as the trained one). Scenes: 4 boxes of 256 surface points each, MOVi-like
//! poses and velocities. Reports (1) step latency p50/p99 of one stream, as seen by the client
//! (time between consecutive frames) and as the server's forward time, and (2) aggregate
//! scene-steps per second with 1, 8, 32 and 64 concurrent streams, with batching on (scene cap
//! 64) and off (scene cap 1).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use dynaserve_proto::json;
use dynaserve_proto::v1::world_model_client::WorldModelClient;
use dynaserve_server::ServeConfig;

const POINTS: usize = 256;
const OBJECTS: usize = 4;

fn scene(seed: u64) -> json::Scene {
    let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    let mut uniform = |lo: f32, hi: f32| {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        lo + (hi - lo) * ((s >> 40) as f32 / (1u64 << 24) as f32)
    };
    let objects = (0..OBJECTS)
        .map(|i| {
            let size = [uniform(0.3, 0.8), uniform(0.3, 0.8), uniform(0.3, 0.8)];
            let mesh = dynaserve_geometry::mesh::cube().scaled(size);
            json::ObjectSpec {
                points: Some(dynaserve_geometry::sample_surface(
                    &mesh,
                    POINTS,
                    seed * 10 + i as u64,
                )),
                mesh: None,
                pose: json::Pose {
                    translation: [uniform(-3.0, 3.0), uniform(-3.0, 3.0), uniform(0.5, 3.0)],
                    rotation: json::IDENTITY_ROTATION,
                },
                previous_pose: None,
                velocity: Some(json::Velocity {
                    linear: [uniform(-3.0, 3.0), uniform(-3.0, 3.0), 0.0],
                    angular: [0.0; 3],
                }),
                mass: uniform(0.5, 3.0),
                friction: 0.5,
                restitution: 0.5,
            }
        })
        .collect();
    json::Scene { objects }
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

async fn serve(
    dir: &std::path::Path,
    cap: usize,
) -> anyhow::Result<dynaserve_server::RunningServer> {
    let mut config = ServeConfig::local(vec![dir.to_path_buf()]);
    config.max_batch_scenes = cap;
    config.max_batch_objects = 4096;
    let models = dynaserve_server::load_models(&config.models)?;
    let server = dynaserve_server::start(config, models).await?;
    server.wait_ready(Duration::from_secs(120)).await?;
    Ok(server)
}

async fn connect(
    server: &dynaserve_server::RunningServer,
) -> anyhow::Result<WorldModelClient<tonic::transport::Channel>> {
    Ok(WorldModelClient::connect(format!("http://{}", server.grpc_addr)).await?)
}

/// Runs `streams` concurrent rollouts for `warm + window` and returns scene-steps per second
/// over the window.
async fn throughput(
    server: &dynaserve_server::RunningServer,
    streams: usize,
    warm: Duration,
    window: Duration,
) -> anyhow::Result<f64> {
    let counting = Arc::new(AtomicBool::new(false));
    let stop = Arc::new(AtomicBool::new(false));
    let frames = Arc::new(AtomicU64::new(0));
    let mut tasks = Vec::new();
    // A few connections, as several clients would open.
    let mut clients = Vec::new();
    for _ in 0..4 {
        clients.push(connect(server).await?);
    }
    for i in 0..streams {
        let mut c = clients[i % clients.len()].clone();
        let (counting, stop, frames) = (counting.clone(), stop.clone(), frames.clone());
        tasks.push(tokio::spawn(async move {
            while !stop.load(Ordering::Relaxed) {
                let req = json::RolloutRequest {
                    model: String::new(),
                    scene: scene(1000 + i as u64),
                    steps: 10_000,
                    dt_steps: 1,
                    timeout_ms: 0,
                    stream: false,
                };
                let Ok(resp) = c.rollout(req.to_proto()).await else {
                    return;
                };
                let mut s = resp.into_inner();
                while let Ok(Some(_)) = s.message().await {
                    if stop.load(Ordering::Relaxed) {
                        return;
                    }
                    if counting.load(Ordering::Relaxed) {
                        frames.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        }));
    }
    tokio::time::sleep(warm).await;
    counting.store(true, Ordering::SeqCst);
    let t = Instant::now();
    tokio::time::sleep(window).await;
    let n = frames.load(Ordering::SeqCst);
    let secs = t.elapsed().as_secs_f64();
    stop.store(true, Ordering::SeqCst);
    for t in tasks {
        t.abort();
    }
    Ok(n as f64 / secs)
}

fn main() -> anyhow::Result<()> {
    // SAFETY: first statement of main; no other thread exists yet.
    unsafe { dynaserve_model::configure_compute(None) };
    let arg = std::env::args().nth(1).map(PathBuf::from);
    let shipped = PathBuf::from("models/rigidformer-small");
    let tmp = std::env::temp_dir().join(format!("dynaserve-bench-{}", std::process::id()));
    let (dir, label) = match arg {
        Some(d) => (d.clone(), format!("checkpoint {}", d.display())),
        None if shipped.join("config.json").is_file() => {
            (shipped.clone(), "shipped rigidformer-small".into())
        }
        None => {
            let d = tmp.join("rigidformer-small-random");
            dynaserve_model::RigidFormer::new(
                dynaserve_model::ModelConfig::small(),
                1,
                &dynaserve_model::Device::Cpu,
            )?
            .save(&d)?;
            (
                d,
                "random-init small RigidFormer (ModelConfig::small)".into(),
            )
        }
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let result = rt.block_on(async {
        println!("model: {label}; scene: {OBJECTS} objects x {POINTS} points; cores: {}", std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
        // (1) latency of one stream.
        let server = serve(&dir, 64).await?;
        let mut c = connect(&server).await?;
        let req = json::RolloutRequest {
            model: String::new(),
            scene: scene(7),
            steps: 300,
            dt_steps: 1,
            timeout_ms: 0,
            stream: false,
        };
        let mut s = c.rollout(req.to_proto()).await?.into_inner();
        let mut gaps = Vec::new();
        let mut forward = Vec::new();
        let mut last = Instant::now();
        let mut k = 0;
        while let Some(f) = s.message().await? {
            let now = Instant::now();
            k += 1;
            if k > 20 {
                gaps.push((now - last).as_secs_f64() * 1e3);
                if let Some(t) = f.timing {
                    forward.push(f64::from(t.forward_ms));
                }
            }
            last = now;
        }
        gaps.sort_by(f64::total_cmp);
        forward.sort_by(f64::total_cmp);
        println!(
            "one stream, {} steps: step latency p50 {:.2} ms, p99 {:.2} ms (client, between frames); forward p50 {:.2} ms, p99 {:.2} ms (server)",
            gaps.len(),
            percentile(&gaps, 0.5),
            percentile(&gaps, 0.99),
            percentile(&forward, 0.5),
            percentile(&forward, 0.99)
        );
        server.shutdown();
        server.wait().await?;
        // (2) throughput.
        println!("| streams | batching on (cap 64) scene-steps/s | scene cap 1 scene-steps/s |");
        println!("|---|---|---|");
        let warm = Duration::from_secs(2);
        let window = Duration::from_secs(6);
        let mut rows = Vec::new();
        for cap in [64usize, 1] {
            let server = serve(&dir, cap).await?;
            let mut col = Vec::new();
            for n in [1usize, 8, 32, 64] {
                col.push(throughput(&server, n, warm, window).await?);
                // Let cancelled streams drain out of the server before the next level.
                tokio::time::sleep(Duration::from_millis(500)).await;
            }
            let text = server.engine().metrics().render();
            for l in text.lines().filter(|l| l.starts_with("dynaserve_batch_scenes_sum") || l.starts_with("dynaserve_batch_scenes_count")) {
                eprintln!("cap {cap}: {l}");
            }
            server.shutdown();
            server.wait().await?;
            rows.push(col);
        }
        for (i, n) in [1, 8, 32, 64].iter().enumerate() {
            println!("| {n} | {:.1} | {:.1} |", rows[0][i], rows[1][i]);
        }
        Ok::<_, anyhow::Error>(())
    });
    let _ = std::fs::remove_dir_all(&tmp);
    result
}
