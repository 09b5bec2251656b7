//! Shared helpers of the end-to-end tests: a real RigidFormer checkpoint on disk, a server on
//! 127.0.0.1 with free ports, scenes (the client crate's random scenes), the in-process
//! reference rollout (scenes built by the server crate's `families::built_scene`, as the
//! server builds them), and one-shot HTTP calls through the client crate's HTTP client.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use dynaserve_api::json;
use dynaserve_api::limits::{Caps, Limits};
use dynaserve_api::spec::Scene;
use dynaserve_client::http::{HttpBase, HttpConn, SseParser, read_all};
use dynaserve_model::{ModelConfig, Pose, RigidFormer, WorldModel};
use dynaserve_server::families::built_scene::build_scene;
use dynaserve_server::{RunningServer, ServeConfig};

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

/// The shipped ensemble of the shipped checkpoint and the twentieth release.
pub const SHIPPED_ENSEMBLE: &str = "models/ensembles/rigidformer-small-ensemble";

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
    random_model_with(name, seed, |_| {})
}

/// [`random_model`] with its configuration adjusted by `tweak` before the weights are drawn.
pub fn random_model_with(name: &str, seed: u64, tweak: impl FnOnce(&mut ModelConfig)) -> TestModel {
    let tmp = TempDir::new("model");
    let dir = tmp.0.join(name);
    let mut config = ModelConfig::tiny();
    config.points_per_object = 64;
    tweak(&mut config);
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

/// The client crate's gRPC client on `server` (both services).
pub async fn client(server: &RunningServer) -> dynaserve_client::Client {
    dynaserve_client::Client::connect(&format!("http://{}", server.grpc_addr))
        .await
        .unwrap()
}

/// The server's error status in a client error (which must be one, not a local error).
pub fn status_of(e: dynaserve_client::ClientError) -> tonic::Status {
    match e {
        dynaserve_client::ClientError::Status(s) => s,
        e => panic!("expected an error status, got {e}"),
    }
}

/// The status of a call that must fail with one.
pub fn grpc_error<T>(r: Result<T, dynaserve_client::ClientError>) -> tonic::Status {
    match r {
        Ok(_) => panic!("the call succeeded; expected an error status"),
        Err(e) => status_of(e),
    }
}

/// The generated WorldModel gRPC stub on `server`, for what the client must not do: send
/// requests it would not (malformed messages, metadata that is not sent that way) and read
/// the answer's raw metadata. Ordinary calls go through [`client`].
pub async fn grpc_world_model(
    server: &RunningServer,
) -> dynaserve_api::v1::world_model_client::WorldModelClient<tonic::transport::Channel> {
    dynaserve_api::v1::world_model_client::WorldModelClient::connect(format!(
        "http://{}",
        server.grpc_addr
    ))
    .await
    .unwrap()
}

/// The generated Sessions gRPC stub on `server`, for the same uses as [`grpc_world_model`].
pub async fn grpc_sessions(
    server: &RunningServer,
) -> dynaserve_api::v1::sessions_client::SessionsClient<tonic::transport::Channel> {
    dynaserve_api::v1::sessions_client::SessionsClient::connect(format!(
        "http://{}",
        server.grpc_addr
    ))
    .await
    .unwrap()
}

/// A scene of `objects` boxes given as point clouds (`points` surface samples each), all in
/// the air and moving; scene `seed` decides everything.
pub fn scene(seed: u64, objects: usize, points: usize) -> json::Scene {
    dynaserve_client::random_scene::generate_moving(seed, objects, points)
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
    let limits = Limits::new(&Caps::DEFAULT, model.config());
    let dt = req.dt_steps.max(1);
    let built = build_scene(
        &Scene::from_json(&req.scene, "scene").unwrap(),
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

/// Sends one HTTP/1.1 request on a new connection and reads the whole response.
pub async fn http(
    addr: std::net::SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: Option<&[u8]>,
) -> HttpResponse {
    let mut conn = HttpConn::new(HttpBase::from_addr(addr));
    let resp = conn
        .request(method, path, headers, body.map(|b| b.to_vec().into()))
        .await
        .unwrap();
    let headers = resp
        .headers
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_str().unwrap_or_default().to_string()))
        .collect();
    HttpResponse {
        status: resp.status,
        headers,
        body: read_all(resp.body).await.unwrap().to_vec(),
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

/// Creates a session over HTTP (asserting 201) and returns its info.
pub async fn create_session_http(
    addr: std::net::SocketAddr,
    model: &str,
    scene: json::Scene,
    kinematic: Vec<u32>,
) -> json::SessionInfo {
    let req = json::CreateSessionRequest {
        model: model.to_string(),
        scene,
        dt_steps: 1,
        kinematic,
        shared: false,
    };
    let created = post_json(addr, "/v1/sessions", &req).await;
    assert_eq!(created.status, 201, "{}", created.text());
    created.json()
}

/// Server-Sent Events as (event, data) pairs.
pub fn parse_sse(text: &str) -> Vec<(String, String)> {
    SseParser::parse_all(text)
}

/// Value of one sample (exact name with labels, e.g. `dynaserve_ready`) in a Prometheus text.
pub fn sample(text: &str, series: &str) -> Option<f64> {
    dynaserve_client::prom::value(text, series)
}

pub async fn metrics(server: &RunningServer) -> String {
    http(server.http_addr, "GET", "/metrics", &[], None)
        .await
        .text()
}
