//! The published PhysiFormer's path end to end: `dynaserve import physiformer` on a
//! checkpoint written by the official code (the parity fixture's `.pt`), a real server on
//! loopback serving the imported directory, and `POST /v1/generate` on the official
//! in-distribution example scene the fixture was sampled on (its frame-0 vertices and
//! per-vertex velocities, the official run's starting noise). The returned trajectory must
//! equal the official code's within 1e-3 (largest absolute difference over the largest
//! absolute coordinate).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use candle_core::Device;
use common::{TempDir, post_json};
use dynaserve_api::json;
use dynaserve_server::ServeConfig;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/model/tests/fixtures/physiformer-official")
}

fn values(t: &std::collections::HashMap<String, candle_core::Tensor>, name: &str) -> Vec<f32> {
    t[name].flatten_all().unwrap().to_vec1().unwrap()
}

fn triples(v: &[f32]) -> Vec<[f32; 3]> {
    v.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn imported_official_checkpoint_serves_the_official_trajectory() {
    let tmp = TempDir::new("official");
    let dir = tmp.0.join("official-tiny");
    let out = Command::new(env!("CARGO_BIN_EXE_dynaserve"))
        .args(["import", "physiformer", "--checkpoint"])
        .arg(fixture().join("checkpoint.pt"))
        .arg("--out")
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "import failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("official architecture"));

    let config = ServeConfig::local(vec![dir.clone()]);
    let models = dynaserve_server::load_all(&config.models).unwrap();
    let server = dynaserve_server::start(config, models).await.unwrap();
    server.wait_ready(Duration::from_secs(60)).await.unwrap();

    let r = candle_core::safetensors::load(fixture().join("reference.safetensors"), &Device::Cpu)
        .unwrap();
    let reference: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture().join("reference.json")).unwrap())
            .unwrap();
    let counts: Vec<usize> = reference["sample"]["counts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_u64().unwrap() as usize)
        .collect();
    let positions = triples(&values(&r, "sample.positions"));
    let velocities = triples(&values(&r, "sample.velocities"));
    let mut objects = Vec::new();
    let mut at = 0;
    for n in &counts {
        objects.push(json::MeshObject {
            vertices: positions[at..at + n].to_vec(),
            faces: vec![],
            material: json::Material::Rigid,
            velocity: None,
            vertex_velocities: Some(velocities[at..at + n].to_vec()),
        });
        at += n;
    }
    let noise_scale = 0.1;
    let noise: Vec<f32> = values(&r, "sample.z0")
        .iter()
        .map(|z| z / noise_scale)
        .collect();
    let mut req = json::GenerateRequest {
        model: String::new(),
        scene: json::MeshScene { objects },
        frames: reference["frames"].as_u64().unwrap() as u32,
        denoise_steps: reference["steps"].as_u64().unwrap() as u32,
        sampler: json::Sampler::Heun,
        samples: 1,
        seed: 0,
        timeout_ms: 0,
        raw_vertices: true,
        noise: Some(vec![noise]),
        stream: false,
    };
    let resp = post_json(server.http_addr, "/v1/generate", &req).await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    let got: json::GenerateResponse = resp.json();
    let sampled: Vec<f32> = got.samples[0]
        .frames
        .iter()
        .flat_map(|f| {
            f.objects
                .iter()
                .flat_map(|o| o.vertices.iter().flatten().copied())
        })
        .collect();
    let want = values(&r, "sample.out_metres");
    assert_eq!(sampled.len(), want.len());
    let diff = sampled
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0f32, f32::max);
    let scale = want.iter().map(|x| x.abs()).fold(0f32, f32::max);
    assert!(diff / scale < 1e-3, "relative error {:e}", diff / scale);

    // Bad per-vertex velocities and noise are refused with the field named.
    let refused = |req: json::GenerateRequest, field: &'static str| {
        let addr = server.http_addr;
        async move {
            let resp = post_json(addr, "/v1/generate", &req).await;
            assert_eq!(resp.status, 422, "{}", resp.text());
            assert!(resp.text().contains(field), "{field}: {}", resp.text());
        }
    };
    req.scene.objects[0]
        .vertex_velocities
        .as_mut()
        .unwrap()
        .pop();
    refused(req.clone(), "scene.objects[0].vertex_velocities").await;
    req.scene.objects[0].vertex_velocities = None;
    req.scene.objects[0].velocity = Some(json::Velocity {
        linear: [1.0, 0.0, 0.0],
        angular: [0.0; 3],
    });
    req.scene.objects[1].velocity = req.scene.objects[0].velocity;
    refused(req.clone(), "scene.objects[1].vertex_velocities").await;
    req.scene.objects[1].vertex_velocities = None;
    req.noise.as_mut().unwrap()[0].truncate(10);
    refused(req, "noise[0]").await;
    server.shutdown();
}
