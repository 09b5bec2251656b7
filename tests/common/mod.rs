//! Shared helpers of the end-to-end tests: a real RigidFormer checkpoint on disk, a server on
//! 127.0.0.1 with free ports, scenes, the in-process reference rollout, and a minimal HTTP/1.1
//! client (with chunked decoding for SSE).

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use dynaserve_model::{ModelConfig, Pose, RigidFormer, WorldModel};
use dynaserve_proto::json;
use dynaserve_server::scene::{Limits, build_scene};
use dynaserve_server::{RunningServer, ServeConfig};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Directory removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> TempDir {
        use std::sync::atomic::{AtomicU64, Ordering};
        static N: AtomicU64 = AtomicU64::new(0);
        let p = std::env::temp_dir().join(format!(
            "dynaserve-e2e-{tag}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&p).unwrap();
        TempDir(p)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The shipped checkpoint, when present.
pub const SHIPPED: &str = "models/rigidformer-small";

/// A model checkpoint directory for the tests: the shipped trained checkpoint when it exists
/// (or `DYNASERVE_TEST_MODEL` names one), otherwise a randomly initialised tiny RigidFormer
/// saved to a temporary directory. Either way the server loads real weights from disk.
pub struct TestModel {
    pub dir: PathBuf,
    pub name: String,
    _tmp: Option<TempDir>,
}

pub fn test_model() -> TestModel {
    let explicit = std::env::var("DYNASERVE_TEST_MODEL")
        .ok()
        .map(PathBuf::from);
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join(SHIPPED);
    let dir = explicit.or_else(|| shipped.join("config.json").is_file().then_some(shipped));
    if let Some(dir) = dir {
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        return TestModel {
            dir,
            name,
            _tmp: None,
        };
    }
    random_model("rigidformer-test", 7)
}

/// A randomly initialised tiny RigidFormer saved as a checkpoint directory named `name`.
pub fn random_model(name: &str, seed: u64) -> TestModel {
    let tmp = TempDir::new("model");
    let dir = tmp.0.join(name);
    let mut config = ModelConfig::tiny();
    config.points_per_object = 64;
    RigidFormer::new(config, seed, &dynaserve_model::Device::Cpu)
        .unwrap()
        .save(&dir)
        .unwrap();
    TestModel {
        dir,
        name: name.to_string(),
        _tmp: Some(tmp),
    }
}

/// Loads a checkpoint directory like the server does.
pub fn load(dir: &Path) -> Arc<dyn WorldModel> {
    dynaserve_server::load_models(&[dir.to_path_buf()])
        .unwrap()
        .pop()
        .unwrap()
}

/// Starts a server on 127.0.0.1 (free ports) serving `dir`, after `tweak` adjusts the
/// configuration, and waits until it is ready.
pub async fn start(dir: &Path, tweak: impl FnOnce(&mut ServeConfig)) -> RunningServer {
    let mut config = ServeConfig::local(vec![dir.to_path_buf()]);
    tweak(&mut config);
    let models = dynaserve_server::load_models(&config.models).unwrap();
    let server = dynaserve_server::start(config, models).await.unwrap();
    server.wait_ready(Duration::from_secs(60)).await.unwrap();
    server
}

pub async fn client(server: &RunningServer) -> dynaserve_client::Client {
    dynaserve_client::Client::connect(&format!("http://{}", server.grpc_addr))
        .await
        .unwrap()
}

/// Small deterministic pseudo-random numbers (splitmix64), so scenes need no extra crates.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15).wrapping_add(1))
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    pub fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * ((self.next_u64() >> 40) as f32 / (1u64 << 24) as f32)
    }
}

fn quat(rng: &mut Rng) -> [f32; 4] {
    let q = [
        rng.uniform(-1.0, 1.0),
        rng.uniform(-1.0, 1.0),
        rng.uniform(-1.0, 1.0),
        rng.uniform(0.2, 1.0),
    ];
    let n = q.iter().map(|c| c * c).sum::<f32>().sqrt();
    q.map(|c| c / n)
}

/// A scene of `objects` boxes given as point clouds (`points` surface samples each), placed
/// above the ground with random rotations and velocities; scene `seed` decides everything.
pub fn scene(seed: u64, objects: usize, points: usize) -> json::Scene {
    let mut rng = Rng::new(seed);
    let objs = (0..objects)
        .map(|i| {
            let half = [
                rng.uniform(0.1, 0.3),
                rng.uniform(0.1, 0.3),
                rng.uniform(0.1, 0.3),
            ];
            let cube = dynaserve_geometry::mesh::cube().scaled(half.map(|h| 2.0 * h));
            let pts = dynaserve_geometry::sample_surface(&cube, points, seed * 100 + i as u64);
            json::ObjectSpec {
                points: Some(pts),
                mesh: None,
                pose: json::Pose {
                    translation: [
                        rng.uniform(-1.0, 1.0) + i as f32 * 0.8,
                        rng.uniform(-1.0, 1.0),
                        rng.uniform(0.3, 1.5),
                    ],
                    rotation: quat(&mut rng),
                },
                previous_pose: None,
                velocity: Some(json::Velocity {
                    linear: [rng.uniform(-2.0, 2.0), rng.uniform(-2.0, 2.0), 0.0],
                    angular: [0.0, 0.0, rng.uniform(-1.0, 1.0)],
                }),
                mass: rng.uniform(0.5, 3.0),
                friction: rng.uniform(0.2, 0.9),
                restitution: rng.uniform(0.1, 0.8),
            }
        })
        .collect();
    json::Scene { objects: objs }
}

pub fn rollout_request(model: &str, scene: json::Scene, steps: u32) -> json::RolloutRequest {
    json::RolloutRequest {
        model: model.to_string(),
        scene,
        steps,
        dt_steps: 1,
        timeout_ms: 0,
        stream: false,
    }
}

/// The reference: the same scene built and rolled out in-process, one scene per forward pass.
pub fn in_process(model: &dyn WorldModel, req: &json::RolloutRequest) -> Vec<Vec<Pose>> {
    let limits = Limits::new(&ServeConfig::default(), model.config());
    let dt = req.dt_steps.max(1);
    let built = build_scene(
        &req.scene,
        "scene",
        &limits,
        dt as f32 * model.config().dt_frame,
    )
    .unwrap();
    let prepared = model.prepare(built.objects).unwrap();
    dynaserve_model::rollout(
        model,
        &prepared,
        built.state,
        dt,
        req.steps as usize,
        |_, _| {},
    )
    .unwrap()
}

/// Largest absolute difference over translations and rotations (sign-aligned).
pub fn max_diff(frames: &[json::StepFrame], expected: &[Vec<Pose>]) -> f32 {
    assert_eq!(frames.len(), expected.len(), "frame count");
    let mut worst = 0.0f32;
    for (i, (f, e)) in frames.iter().zip(expected).enumerate() {
        assert_eq!(f.step as usize, i + 1, "step index");
        assert_eq!(f.poses.len(), e.len(), "object count");
        for (a, b) in f.poses.iter().zip(e) {
            for k in 0..3 {
                worst = worst.max((a.translation[k] - b.translation[k]).abs());
            }
            let dot: f32 = (0..4).map(|k| a.rotation[k] * b.rotation[k]).sum();
            let s = if dot < 0.0 { -1.0 } else { 1.0 };
            for k in 0..4 {
                worst = worst.max((a.rotation[k] - s * b.rotation[k]).abs());
            }
        }
    }
    worst
}

/// A parsed HTTP/1.1 response.
#[derive(Debug)]
pub struct HttpResponse {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl HttpResponse {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
    pub fn json<T: serde::de::DeserializeOwned>(&self) -> T {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("bad JSON ({e}): {}", self.text()))
    }
}

fn dechunk(mut data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    while let Some(pos) = data.windows(2).position(|w| w == b"\r\n") {
        let line = std::str::from_utf8(&data[..pos]).unwrap();
        let size = usize::from_str_radix(line.split(';').next().unwrap().trim(), 16).unwrap();
        data = &data[pos + 2..];
        if size == 0 {
            break;
        }
        out.extend_from_slice(&data[..size]);
        data = &data[size + 2..];
    }
    out
}

/// Sends one HTTP/1.1 request (Connection: close) and reads the whole response.
pub async fn http(
    addr: std::net::SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: Option<&[u8]>,
) -> HttpResponse {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    let mut req = format!("{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n");
    for (k, v) in headers {
        req.push_str(&format!("{k}: {v}\r\n"));
    }
    if let Some(b) = body {
        req.push_str(&format!(
            "Content-Type: application/json\r\nContent-Length: {}\r\n",
            b.len()
        ));
    }
    req.push_str("\r\n");
    s.write_all(req.as_bytes()).await.unwrap();
    if let Some(b) = body {
        s.write_all(b).await.unwrap();
    }
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).await.unwrap();
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("header end");
    let head = std::str::from_utf8(&raw[..split]).unwrap();
    let mut lines = head.split("\r\n");
    let status: u16 = lines
        .next()
        .unwrap()
        .split_whitespace()
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect();
    let mut body = raw[split + 4..].to_vec();
    let chunked = headers.iter().any(|(k, v)| {
        k.eq_ignore_ascii_case("transfer-encoding") && v.eq_ignore_ascii_case("chunked")
    });
    if chunked {
        body = dechunk(&body);
    }
    HttpResponse {
        status,
        headers,
        body,
    }
}

pub async fn post_json<T: serde::Serialize>(
    addr: std::net::SocketAddr,
    path: &str,
    body: &T,
) -> HttpResponse {
    let b = serde_json::to_vec(body).unwrap();
    http(addr, "POST", path, &[], Some(&b)).await
}

/// Server-Sent Events as (event, data) pairs.
pub fn parse_sse(text: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for block in text.split("\n\n") {
        let mut event = String::from("message");
        let mut data = String::new();
        let mut any = false;
        for line in block.lines() {
            if let Some(v) = line.strip_prefix("event:") {
                event = v.trim().to_string();
                any = true;
            } else if let Some(v) = line.strip_prefix("data:") {
                data.push_str(v.trim_start());
                any = true;
            }
        }
        if any && !data.is_empty() {
            out.push((event, data));
        }
    }
    out
}

/// Value of one sample (exact name with labels, e.g. `dynaserve_ready`) in a Prometheus text.
pub fn sample(text: &str, series: &str) -> Option<f64> {
    text.lines().filter(|l| !l.starts_with('#')).find_map(|l| {
        let (name, value) = l.rsplit_once(' ')?;
        (name == series).then(|| value.parse().ok()).flatten()
    })
}

pub async fn metrics(server: &RunningServer) -> String {
    http(server.http_addr, "GET", "/metrics", &[], None)
        .await
        .text()
}
