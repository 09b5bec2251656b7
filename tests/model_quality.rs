//! What a person trying the service sees first, held against the shipped model: the example
//! tower of four resting boxes, rolled out through a real server on loopback, must stand.

mod common;

use std::path::Path;

use common::{SHIPPED, SHIPPED_ENSEMBLE, client, start};

/// Largest displacement any box of the example tower may reach over its 48 steps: the goal,
/// 0.05 m. The shipped (twenty-fifth) release reaches 0.004 m; the twenty-fourth 0.005 m; the twenty-third, twenty-second, twenty-first and
/// twentieth 0.006 m; the thirteenth 0.010 m; every earlier release missed it (the twelfth 0.20 m, the
/// eleventh 0.21 m, ..., the first 2.9 m, the tower fell apart), because they had seen only Kubric's two materials and this tower's
/// friction 0.5 and restitution 0.2 lie off that pair (the twelfth release held the same tower
/// in metal to 0.017 m).
const TOWER_LIMIT_M: f32 = 0.05;

/// `examples/scenes/box_tower.json` (four 0.5 m boxes resting in a stack), 48 steps of one
/// frame through gRPC: every box stays within 5 cm of its start (see [`TOWER_LIMIT_M`]), under
/// the shipped model and under the shipped ensemble (`models/ensembles/`, which averages copies
/// of the twenty-fifth and twentieth releases; 0.005 m).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_example_box_tower_stands_for_two_seconds() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for dir in [SHIPPED, SHIPPED_ENSEMBLE] {
        let dir = root.join(dir);
        let server = start(&dir, |_| {}).await;
        let mut c = client(&server).await;
        let mut req = example_tower();
        assert_eq!(req.steps, 48);
        assert_eq!(req.scene.objects.len(), 4);
        req.model = dir.file_name().unwrap().to_string_lossy().into_owned();
        let (worst, box_index, step) = largest_displacement(&mut c, &req).await;
        eprintln!(
            "{}: example tower: largest displacement {worst:.3} m (box {box_index}, step {step})",
            req.model
        );
        assert!(
            worst <= TOWER_LIMIT_M,
            "{}: box {box_index} moved {worst:.3} m by step {step} (limit {TOWER_LIMIT_M} m)",
            req.model
        );
        server.shutdown();
        server.wait().await.unwrap();
    }
}

/// The same tower in materials away from Kubric's metal / rubber pair (friction and
/// restitution varied on their own, one heavier set): it stands in every one.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_example_box_tower_stands_in_other_materials() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let server = start(&root.join(SHIPPED), |_| {}).await;
    let mut c = client(&server).await;
    // (mass kg, friction, restitution)
    for (mass, friction, restitution) in [
        (0.3375, 0.8, 0.3),
        (0.3375, 0.4, 0.7),
        (0.3375, 0.2, 0.1),
        (1.0, 1.0, 0.5),
    ] {
        let mut req = example_tower();
        for o in &mut req.scene.objects {
            (o.mass, o.friction, o.restitution) = (mass, friction, restitution);
        }
        let (worst, box_index, step) = largest_displacement(&mut c, &req).await;
        eprintln!(
            "mass {mass} friction {friction} restitution {restitution}: largest displacement {worst:.3} m"
        );
        assert!(
            worst <= TOWER_LIMIT_M,
            "mass {mass} friction {friction} restitution {restitution}: box {box_index} moved {worst:.3} m by step {step} (limit {TOWER_LIMIT_M} m)"
        );
    }
    server.shutdown();
    server.wait().await.unwrap();
}

fn example_tower() -> dynaserve_client::json::RolloutRequest {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    dynaserve_client::scene_file::load(root.join("examples/scenes/box_tower.json")).unwrap()
}

/// Rolls `req` out and returns the largest distance of any object from its start, metres,
/// with the object and the step (1-based) where it was reached.
async fn largest_displacement(
    c: &mut dynaserve_client::Client,
    req: &dynaserve_client::json::RolloutRequest,
) -> (f32, usize, usize) {
    let start_positions: Vec<[f32; 3]> = req
        .scene
        .objects
        .iter()
        .map(|o| o.pose.translation)
        .collect();
    let frames = c.rollout_collect(req).await.unwrap();
    assert_eq!(frames.len(), req.steps as usize);
    let mut worst = (0.0f32, 0, 0);
    for (step, frame) in frames.iter().enumerate() {
        for (j, pose) in frame.poses.iter().enumerate() {
            let d = (0..3)
                .map(|k| (pose.translation[k] - start_positions[j][k]).powi(2))
                .sum::<f32>()
                .sqrt();
            if d > worst.0 {
                worst = (d, j, step + 1);
            }
        }
    }
    worst
}
