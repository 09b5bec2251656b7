//! Generate end to end through a real server on loopback, serving the shipped RigidFormer and
//! PhysiFormer checkpoints together: both protocols answer the same samples, the same seed
//! gives the same trajectories, calls started at different times share denoising passes and
//! each still returns exactly what it returns alone, and bad input gets a clear error. Scenes
//! are small (two cubes), with few frames and few denoising steps.

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use common::{client, grpc_error, http, metrics, parse_sse, post_json, sample};
use dynaserve_api::json;
use dynaserve_api::v1;
use dynaserve_client::{Client, ClientError};
use dynaserve_server::{RunningServer, ServeConfig};
use futures::StreamExt;

const PHYSI: &str = "physiformer-small";
const RIGID: &str = "rigidformer-small";

fn model_dir(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("models")
        .join(name)
}

/// A server on free loopback ports with both shipped models, after `tweak`.
async fn start(tweak: impl FnOnce(&mut ServeConfig)) -> RunningServer {
    let mut config = ServeConfig::local(vec![model_dir(RIGID), model_dir(PHYSI)]);
    tweak(&mut config);
    let models = dynaserve_server::load_all(&config.models).unwrap();
    let server = dynaserve_server::start(config, models).await.unwrap();
    server.wait_ready(Duration::from_secs(60)).await.unwrap();
    server
}

/// The models ListModels reports over gRPC.
async fn list_models(c: &mut Client) -> Vec<v1::ModelInfo> {
    c.list_models().await.unwrap()
}

fn cube(c: [f32; 3], h: f32) -> Vec<[f32; 3]> {
    let mut v = Vec::new();
    for x in [-h, h] {
        for y in [-h, h] {
            for z in [-h, h] {
                v.push([c[0] + x, c[1] + y, c[2] + z]);
            }
        }
    }
    v
}

/// A rigid cube on the floor and an elastic cube falling onto it.
fn request(frames: u32, steps: u32, samples: u32, seed: u64) -> json::GenerateRequest {
    json::GenerateRequest {
        model: String::new(),
        scene: json::MeshScene {
            objects: vec![
                json::MeshObject {
                    vertices: cube([0.0, 0.0, -0.85], 0.15),
                    faces: vec![[0, 1, 3], [0, 3, 2]],
                    material: json::Material::Rigid,
                    velocity: None,
                    vertex_velocities: None,
                },
                json::MeshObject {
                    vertices: cube([0.05, 0.0, 0.1], 0.15),
                    faces: vec![],
                    material: json::Material::Elastic,
                    velocity: Some(json::Velocity {
                        linear: [0.5, 0.0, -1.0],
                        angular: [0.0, 0.0, 1.0],
                    }),
                    vertex_velocities: None,
                },
            ],
        },
        frames,
        denoise_steps: steps,
        sampler: json::Sampler::Heun,
        samples,
        seed,
        timeout_ms: 0,
        raw_vertices: false,
        noise: None,
        stream: false,
    }
}

/// A Generate call over gRPC: its progress events and samples (JSON form).
async fn generate_grpc(
    c: &mut Client,
    req: &json::GenerateRequest,
) -> Result<(Vec<json::GenerateProgress>, Vec<json::GeneratedSample>), ClientError> {
    let out = c.generate_collect(req.to_proto()).await?;
    Ok((
        out.progress
            .iter()
            .map(json::GenerateProgress::from_proto)
            .collect(),
        out.samples
            .iter()
            .map(json::GeneratedSample::from_proto)
            .collect(),
    ))
}

fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn max_vertex_diff(a: &[json::GeneratedSample], b: &[json::GeneratedSample]) -> f32 {
    assert_eq!(a.len(), b.len(), "sample count");
    let mut worst = 0f32;
    for (x, y) in a.iter().zip(b) {
        assert_eq!(x.frames.len(), y.frames.len(), "frame count");
        for (f, g) in x.frames.iter().zip(&y.frames) {
            for (o, p) in f.objects.iter().zip(&g.objects) {
                for (u, v) in o.vertices.iter().zip(&p.vertices) {
                    for k in 0..3 {
                        worst = worst.max((u[k] - v[k]).abs());
                    }
                }
            }
        }
    }
    worst
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn generate_over_grpc_and_http_with_both_models_resident() {
    let server = start(|_| {}).await;
    let mut c = client(&server).await;

    // ListModels shows both families with their limits.
    let models = list_models(&mut c).await;
    let physi = models.iter().find(|m| m.name == PHYSI).unwrap();
    let rigid = models.iter().find(|m| m.name == RIGID).unwrap();
    assert_eq!(physi.architecture, "physiformer");
    assert_eq!(rigid.architecture, "rigidformer");
    assert_eq!((physi.max_vertices, physi.max_frames), (512, 49));
    assert_eq!(physi.default_denoise_steps, 50);
    assert!(physi.max_denoise_steps >= 50 && physi.max_samples >= 1);
    assert_eq!(rigid.max_vertices, 0);

    let req = request(5, 3, 2, 5);
    let (progress, samples) = generate_grpc(&mut c, &req).await.unwrap();
    let steps: Vec<u32> = progress.iter().map(|p| p.step).collect();
    assert_eq!(steps, vec![1, 2, 3]);
    assert!(
        progress
            .iter()
            .all(|p| p.steps == 3 && p.timing.batch_scenes >= 1)
    );
    assert_eq!(progress[2].t, 1.0);
    assert_eq!(samples.len(), 2);
    assert_eq!((samples[0].seed, samples[1].seed), (5, 6));
    for s in &samples {
        assert_eq!(s.frames.len(), 5);
        // Frame 0 is the given state; the rigid cube's fitted pose there is the identity
        // about its centroid.
        assert_eq!(
            s.frames[0].objects[0].vertices,
            req.scene.objects[0].vertices
        );
        assert_eq!(
            s.frames[0].objects[1].vertices,
            req.scene.objects[1].vertices
        );
        let p0 = s.frames[0].objects[0].pose.unwrap();
        assert!((p0.translation[2] + 0.85).abs() < 1e-5 && (p0.rotation[3] - 1.0).abs() < 1e-5);
        for f in &s.frames {
            assert!(f.objects[0].pose.is_some() && f.objects[0].fit_rms.is_some());
            assert!(f.objects[1].pose.is_none(), "elastic objects have no pose");
            assert_eq!(f.objects[1].vertices.len(), 8);
        }
        assert!((s.frames[4].time - 4.0 * 5.0 / 240.0).abs() < 1e-6);
    }
    // The samples start from different noise, so they differ.
    assert!(max_vertex_diff(&samples[..1], &samples[1..]) > 1e-4);
    // Rigid objects come back exactly rigid: every frame keeps frame 0's pairwise distances.
    let rigid_error = |samples: &[json::GeneratedSample]| {
        let v0 = &req.scene.objects[0].vertices;
        let mut worst = 0f32;
        for f in samples.iter().flat_map(|s| &s.frames) {
            let v = &f.objects[0].vertices;
            for i in 0..v.len() {
                for j in 0..i {
                    worst = worst.max((dist(v[i], v[j]) - dist(v0[i], v0[j])).abs());
                }
            }
        }
        worst
    };
    assert!(rigid_error(&samples) < 1e-4, "{}", rigid_error(&samples));
    // raw_vertices: the same samples and fits, the rigid cube's vertices as the network drew
    // them (not rigid: its fit residual is what the projection removed).
    let mut raw_req = req.clone();
    raw_req.raw_vertices = true;
    let (_, raw) = generate_grpc(&mut c, &raw_req).await.unwrap();
    let (last, last_raw) = (
        &samples[0].frames[4].objects[0],
        &raw[0].frames[4].objects[0],
    );
    let rms = last_raw.fit_rms.unwrap();
    assert!((last.fit_rms.unwrap() - rms).abs() < 1e-5);
    assert!(
        rms > 0.0 && rigid_error(&raw) > 1e-4,
        "raw sample rigid to {rms} m"
    );
    let moved = last
        .vertices
        .iter()
        .zip(&last_raw.vertices)
        .map(|(a, b)| dist(*a, *b).powi(2))
        .sum::<f32>()
        / 8.0;
    assert!(
        (moved.sqrt() - rms).abs() < 1e-4,
        "{} vs {rms}",
        moved.sqrt()
    );
    let elastic = samples[0].frames[4].objects[1]
        .vertices
        .iter()
        .zip(&raw[0].frames[4].objects[1].vertices)
        .map(|(a, b)| dist(*a, *b))
        .fold(0f32, f32::max);
    assert!(elastic < 1e-5, "elastic vertices {elastic} m apart");

    // Same request, same seed: the same trajectories (to float rounding: the two samples may
    // share a pass or not, and a pass's layout reorders a few sums); another seed: others.
    let (_, again) = generate_grpc(&mut c, &req).await.unwrap();
    let d = max_vertex_diff(&again, &samples);
    assert!(d <= 1e-5, "same seed, trajectories {d} m apart");
    let mut other = req.clone();
    other.seed = 99;
    let (_, other) = generate_grpc(&mut c, &other).await.unwrap();
    assert!(max_vertex_diff(&other, &samples) > 1e-4);

    // HTTP JSON answers the same samples.
    let r = post_json(server.http_addr, "/v1/generate", &req).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.header("x-dynaserve-model"), Some(PHYSI));
    let body: json::GenerateResponse = r.json();
    assert_eq!((body.model.as_str(), body.denoise_steps), (PHYSI, 3));
    assert!(max_vertex_diff(&body.samples, &samples) <= 1e-5);
    assert_eq!(body.samples[1].frames[4].frame, 4);
    assert!(body.timing.forward_ms > 0.0);

    // HTTP SSE: progress per step, a sample event per sample, then done.
    let b = serde_json::to_vec(&req).unwrap();
    let r = http(
        server.http_addr,
        "POST",
        "/v1/generate",
        &[("accept", "text/event-stream")],
        Some(&b),
    )
    .await;
    assert_eq!(r.status, 200);
    let events = parse_sse(&r.text());
    let names: Vec<&str> = events.iter().map(|(e, _)| e.as_str()).collect();
    assert_eq!(
        names,
        [
            "progress", "progress", "progress", "sample", "sample", "done"
        ]
    );
    let sse: Vec<json::GeneratedSample> = events[3..5]
        .iter()
        .map(|(_, d)| serde_json::from_str(d).unwrap())
        .collect();
    assert!(max_vertex_diff(&sse, &samples) <= 1e-5);
    let done: json::GenerateDone = serde_json::from_str(&events[5].1).unwrap();
    assert_eq!(done.samples, 2);

    // The Euler sampler takes one evaluation per step: a different, valid trajectory.
    let mut euler = req.clone();
    euler.sampler = json::Sampler::Euler;
    let (p, e) = generate_grpc(&mut c, &euler).await.unwrap();
    assert_eq!(p.len(), 3);
    assert!(max_vertex_diff(&e, &samples) > 0.0);

    // Rollouts still run on the rigid model without naming it.
    let rollout = common::rollout_request("", common::scene(3, 2, 32), 2);
    let r = post_json(server.http_addr, "/v1/rollout", &rollout).await;
    assert_eq!(r.status, 200, "{}", r.text());

    // The metrics count denoising steps and sample times of the PhysiFormer model.
    let text = metrics(&server).await;
    let steps = sample(
        &text,
        &format!("dynaserve_denoise_steps_total{{model=\"{PHYSI}\"}}"),
    );
    // 7 calls of 2 samples x 3 steps (the warm-up is not counted).
    assert_eq!(steps, Some(42.0), "{steps:?}");
    let timed = sample(
        &text,
        &format!("dynaserve_generate_sample_seconds_count{{model=\"{PHYSI}\"}}"),
    );
    assert_eq!(timed, Some(14.0));
    server.shutdown();
    server.wait().await.unwrap();
}

/// Passes of `model` so far and how many held more than one scene.
fn passes(text: &str, model: &str) -> (f64, f64) {
    let total = sample(
        text,
        &format!("dynaserve_batch_scenes_count{{model=\"{model}\"}}"),
    );
    let single = sample(
        text,
        &format!("dynaserve_batch_scenes_bucket{{model=\"{model}\",le=\"1\"}}"),
    );
    let (total, single) = (total.unwrap(), single.unwrap());
    (total, total - single)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn calls_started_at_different_steps_share_passes_and_return_what_they_return_alone() {
    // A longer wait for expected pass-mates than the default, so that the two calls meet on a
    // busy machine too; it changes when passes start, never what they compute.
    let server = start(|c| c.max_queue_delay_ms = 20.0).await;
    let mut c = client(&server).await;
    let a = request(6, 8, 1, 11);
    let mut b = request(6, 8, 1, 22);
    b.scene.objects.remove(0);
    b.scene.objects[0].velocity = None;

    let (_, alone_a) = generate_grpc(&mut c, &a).await.unwrap();
    let (_, alone_b) = generate_grpc(&mut c, &b).await.unwrap();
    let (_, shared_before) = passes(&metrics(&server).await, PHYSI);

    // A starts; B starts once A has completed three denoising steps.
    let mut stream_a = c.generate(a.to_proto()).await.unwrap().events;
    let mut progress_a = vec![];
    while progress_a.len() < 3 {
        match stream_a.next().await.unwrap().unwrap().event.unwrap() {
            v1::generate_event::Event::Progress(p) => progress_a.push(p),
            v1::generate_event::Event::Sample(_) => panic!("A finished before B started"),
        }
    }
    let rest_a = tokio::spawn(async move {
        let (mut progress, mut samples) = (vec![], vec![]);
        while let Some(ev) = stream_a.next().await {
            let ev = ev.unwrap();
            match ev.event.unwrap() {
                v1::generate_event::Event::Progress(p) => progress.push(p),
                v1::generate_event::Event::Sample(s) => {
                    samples.push(json::GeneratedSample::from_proto(&s))
                }
            }
        }
        (progress, samples)
    });
    let mut cb = client(&server).await;
    let (progress_b, together_b) = generate_grpc(&mut cb, &b).await.unwrap();
    let (later_a, together_a) = rest_a.await.unwrap();
    progress_a.extend(later_a);
    assert_eq!(progress_a.len(), 8);
    assert_eq!(progress_b.len(), 8);

    // Both saw passes with the other in them, and the batch metric counts them.
    let shared_a = progress_a
        .iter()
        .filter(|p| p.timing.unwrap().batch_scenes > 1)
        .count();
    let shared_b = progress_b
        .iter()
        .filter(|p| p.timing.batch_scenes > 1)
        .count();
    assert!(
        shared_a > 0 && shared_b > 0,
        "no shared pass: A {shared_a} steps, B {shared_b} steps"
    );
    let (_, shared_after) = passes(&metrics(&server).await, PHYSI);
    assert!(
        shared_after > shared_before,
        "{shared_before} -> {shared_after}"
    );

    // Each returns, bit for bit, what it returns alone (every scene of a pass runs its own
    // forward).
    let (da, db) = (
        max_vertex_diff(&together_a, &alone_a),
        max_vertex_diff(&together_b, &alone_b),
    );
    assert!(
        da == 0.0 && db == 0.0,
        "sharing passes changed A by {da} m, B by {db} m"
    );
    assert_eq!(together_a, alone_a);
    assert_eq!(together_b, alone_b);
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_generate_input_gets_a_clear_error_and_slots_are_freed() {
    let server = start(|c| c.max_generate_samples = 2).await;
    let mut c = client(&server).await;
    let good = request(4, 2, 1, 0);

    // gRPC: INVALID_ARGUMENT whose message starts with the field path.
    let mut p = good.to_proto();
    p.scene.as_mut().unwrap().objects[1].material = 0;
    let e = grpc_error(c.generate(p).await);
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(
        e.message().starts_with("scene.objects[1].material"),
        "{}",
        e.message()
    );
    let mut far = good.clone();
    far.scene.objects[0].vertices[2] = [0.0, 0.0, 3.0];
    let e = grpc_error(c.generate(far.to_proto()).await);
    assert!(
        e.message().starts_with("scene.objects[0].vertices[2]"),
        "{}",
        e.message()
    );
    let mut p = good.to_proto();
    p.scene.as_mut().unwrap().objects[0].vertices.pop();
    let e = grpc_error(c.generate(p).await);
    assert!(
        e.message().starts_with("scene.objects[0].vertices"),
        "{}",
        e.message()
    );

    // HTTP: 422 naming the field.
    type Edit = Box<dyn Fn(&mut json::GenerateRequest)>;
    let cases: Vec<(Edit, &str)> = vec![
        (Box::new(|r| r.frames = 1), "frames"),
        (Box::new(|r| r.frames = 50), "frames"),
        (Box::new(|r| r.denoise_steps = 100_000), "denoise_steps"),
        (Box::new(|r| r.samples = 3), "samples"),
        (Box::new(|r| r.scene.objects.clear()), "scene.objects"),
        (
            Box::new(|r| r.scene.objects[0].faces = vec![[0, 1, 2], [0, 1, 8]]),
            "scene.objects[0].faces[1]",
        ),
        (
            Box::new(|r| {
                r.scene.objects[1].velocity = Some(json::Velocity {
                    linear: [80.0, 0.0, 0.0],
                    angular: [0.0; 3],
                })
            }),
            "scene.objects[1].velocity",
        ),
        (Box::new(|r| r.model = "nope".into()), "model"),
        (Box::new(|r| r.model = RIGID.into()), "model"),
    ];
    for (edit, field) in cases {
        let mut r = good.clone();
        edit(&mut r);
        let resp = post_json(server.http_addr, "/v1/generate", &r).await;
        assert_eq!(resp.status, 422, "{field}: {}", resp.text());
        let err: json::ErrorResponse = resp.json();
        assert_eq!(err.error.field.as_deref(), Some(field), "{}", resp.text());
        assert_eq!(err.error.code, "INVALID_ARGUMENT");
    }
    // A material that is not one: serde names the path.
    let raw = br#"{"scene":{"objects":[{"vertices":[[0,0,0]],"material":"rubber"}]}}"#;
    let resp = http(server.http_addr, "POST", "/v1/generate", &[], Some(raw)).await;
    assert_eq!(resp.status, 422, "{}", resp.text());
    let err: json::ErrorResponse = resp.json();
    assert!(
        err.error
            .field
            .as_deref()
            .unwrap_or_default()
            .starts_with("scene.objects[0]"),
        "{}",
        resp.text()
    );
    // A rollout naming the PhysiFormer model is told why.
    let rollout = common::rollout_request(PHYSI, common::scene(3, 2, 32), 2);
    let resp = post_json(server.http_addr, "/v1/rollout", &rollout).await;
    assert_eq!(resp.status, 422);
    assert!(resp.text().contains("Generate"), "{}", resp.text());

    // A deadline that passes mid-way answers DEADLINE_EXCEEDED.
    let mut slow = request(49, 200, 1, 0);
    slow.timeout_ms = 50;
    let e = grpc_error(generate_grpc(&mut c, &slow).await);
    assert_eq!(e.code(), tonic::Code::DeadlineExceeded, "{e:?}");

    // Admission counts samples: two in flight fill the server; a third waits for a cancel.
    let busy = request(49, 200, 2, 0);
    let stream = c.generate(busy.to_proto()).await.unwrap();
    let resp = post_json(server.http_addr, "/v1/generate", &good).await;
    assert_eq!(resp.status, 429, "{}", resp.text());
    drop(stream);
    let mut admitted = false;
    for _ in 0..100 {
        let resp = post_json(server.http_addr, "/v1/generate", &good).await;
        if resp.status == 200 {
            admitted = true;
            break;
        }
        assert_eq!(resp.status, 429, "{}", resp.text());
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(admitted, "the cancelled call's slots were not freed");
    server.shutdown();
    server.wait().await.unwrap();
}

/// A Generate call above `--max-generate-cost` (vertices x frames x network evaluations x
/// samples) is refused at admission with INVALID_ARGUMENT / 422 naming `denoise_steps`, its
/// factors and the flag; one at the ceiling runs (Euler takes fewer evaluations than Heun for
/// the same steps), and ListModels reports each family's ceiling.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn generate_above_the_cost_ceiling_is_refused_naming_denoise_steps_and_the_flag() {
    // Two cubes of 8 vertices, 4 frames: Heun with 2 steps takes 3 evaluations (192
    // vertex-frame evaluations), with 3 steps 5 (320); Euler with 3 steps takes 3 (192).
    let server = start(|c| {
        c.max_generate_cost = 192;
        c.max_request_cost = 5000;
    })
    .await;
    let mut c = client(&server).await;
    let models = list_models(&mut c).await;
    let physi = models.iter().find(|m| m.name == PHYSI).unwrap();
    let rigid = models.iter().find(|m| m.name == RIGID).unwrap();
    assert_eq!(physi.max_request_cost, 192);
    assert_eq!(rigid.max_request_cost, 5000);
    let listed: json::ListModelsResponse = http(server.http_addr, "GET", "/v1/models", &[], None)
        .await
        .json();
    let physi = listed.models.iter().find(|m| m.name == PHYSI).unwrap();
    assert_eq!(physi.max_request_cost, 192);

    let over = request(4, 3, 1, 0);
    let want = "denoise_steps: 16 vertices x 4 frames x 5 network evaluations (Heun: 2 x 3 \
                denoise steps - 1) x 1 sample = 320 vertex-frame evaluations exceeds the \
                server's limit of 192 (--max-generate-cost); lower denoise_steps, frames, \
                samples or vertices";
    let e = grpc_error(generate_grpc(&mut c, &over).await);
    assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");
    assert_eq!(e.message(), want);
    let resp = post_json(server.http_addr, "/v1/generate", &over).await;
    assert_eq!(resp.status, 422, "{}", resp.text());
    let err: json::ErrorResponse = resp.json();
    assert_eq!(err.error.code, "INVALID_ARGUMENT");
    assert_eq!(err.error.field.as_deref(), Some("denoise_steps"));
    assert_eq!(err.error.message, want);
    // Two samples at the ceiling of one are above it too.
    let resp = post_json(server.http_addr, "/v1/generate", &request(4, 2, 2, 0)).await;
    assert_eq!(resp.status, 422, "{}", resp.text());
    assert!(resp.text().contains("x 2 samples = 384"), "{}", resp.text());
    // Refused at admission: no denoising step ran.
    let text = metrics(&server).await;
    let steps_metric = format!("dynaserve_denoise_steps_total{{model=\"{PHYSI}\"}}");
    assert_eq!(sample(&text, &steps_metric).unwrap_or(0.0), 0.0);

    // At the ceiling: Heun with 2 steps, and Euler with 3.
    let (_, samples) = generate_grpc(&mut c, &request(4, 2, 1, 0)).await.unwrap();
    assert_eq!(samples.len(), 1);
    let mut euler = over.clone();
    euler.sampler = json::Sampler::Euler;
    let resp = post_json(server.http_addr, "/v1/generate", &euler).await;
    assert_eq!(resp.status, 200, "{}", resp.text());
    server.shutdown();
    server.wait().await.unwrap();
}
