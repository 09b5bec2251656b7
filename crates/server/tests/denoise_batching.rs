//! Continuous batching of PhysiFormer denoising steps on the shipped weights: two generation
//! requests started at different times share passes, and each returns, bit for bit, the
//! trajectory it returns alone.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use dynaserve_model::physiformer::flow::SamplerKind;
use dynaserve_model::physiformer::scene::{Material, MeshScene};
use dynaserve_model::{Device, PhysiFormer};
use dynaserve_server::families::physiformer::denoise::{DenoiseSteps, GenerateJob, generate};
use dynaserve_server::metrics::Metrics;
use dynaserve_server::scheduler::{Priority, Scheduler, SchedulerConfig};

fn cube(c: [f32; 3], h: f32) -> Vec<[f32; 3]> {
    (0..8)
        .map(|i| {
            let s = |b: usize| if i >> b & 1 == 1 { h } else { -h };
            [c[0] + s(0), c[1] + s(1), c[2] + s(2)]
        })
        .collect()
}

fn scene(centres: &[[f32; 3]], materials: &[Material], speed: f32) -> Arc<MeshScene> {
    let mut positions = vec![];
    let mut offsets = vec![0];
    for c in centres {
        positions.extend(cube(*c, 0.15));
        offsets.push(positions.len());
    }
    Arc::new(MeshScene {
        velocities: vec![[speed, 0.0, 0.0]; positions.len()],
        positions,
        vertex_offsets: offsets,
        materials: materials.to_vec(),
    })
}

fn job(scene: &Arc<MeshScene>, stream_id: u64, seed: u64) -> GenerateJob {
    GenerateJob {
        scene: scene.clone(),
        frames: 49,
        steps: 8,
        sampler: SamplerKind::Heun,
        seed,
        noise: None,
        priority: Priority::Interactive,
        deadline: None,
        stream_id,
        caller: stream_id,
        request_id: Arc::from(format!("test-{stream_id}")),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn requests_at_different_denoising_steps_share_passes_and_keep_their_results() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/physiformer-small");
    let model = Arc::new(PhysiFormer::load(&dir, &Device::Cpu, false).unwrap());
    let name = model.name().to_string();
    let scheduler = Arc::new(
        Scheduler::start(
            Arc::new(DenoiseSteps::new(model)),
            SchedulerConfig {
                max_batch_scenes: 8,
                max_batch_objects: 4096,
                max_queue_delay: Duration::from_millis(50),
                bulk_share: 0.25,
                gate: None,
            },
            Metrics::new(&[name]),
        )
        .unwrap(),
    );
    let a = scene(
        &[[-0.5, 0.0, -0.84], [0.3, 0.2, -0.84]],
        &[Material::Rigid, Material::Elastic],
        1.0,
    );
    let b = scene(&[[0.0, 0.0, 0.2]], &[Material::Elastic], -0.5);
    let alone_a = generate(&scheduler, job(&a, 1, 11), |_| {}).await.unwrap();
    let alone_b = generate(&scheduler, job(&b, 2, 22), |_| {}).await.unwrap();

    // A starts; B starts once A has finished three denoising steps.
    let (started_tx, started_rx) = tokio::sync::oneshot::channel();
    let sa = scheduler.clone();
    let ja = job(&a, 3, 11);
    let task_a = tokio::spawn(async move {
        let mut tx = Some(started_tx);
        let mut shared = 0;
        let out = generate(&sa, ja, |p| {
            if p.step == 3
                && let Some(tx) = tx.take()
            {
                let _ = tx.send(());
            }
            if p.batch_scenes > 1 {
                shared += 1;
            }
        })
        .await
        .unwrap();
        (out, shared)
    });
    started_rx.await.unwrap();
    let mut b_steps = vec![];
    let together_b = generate(&scheduler, job(&b, 4, 22), |p| b_steps.push(p))
        .await
        .unwrap();
    let (together_a, a_shared) = task_a.await.unwrap();

    // Each scene of a pass runs its own forward: bit for bit what it gives alone.
    assert_eq!(together_a, alone_a, "shared passes changed A");
    assert_eq!(together_b, alone_b, "shared passes changed B");
    let b_shared = b_steps.iter().filter(|p| p.batch_scenes > 1).count();
    assert!(
        a_shared > 0 && b_shared > 0,
        "no shared pass: A {a_shared} steps, B {b_shared} steps"
    );
    assert_eq!(b_steps.len(), 8);
    scheduler.shutdown();
}
