//! The example scene files run through the client library, HTTP and the command line.

use crate::common::*;
use dynaserve_api::json;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn example_scenes_run_through_the_client_library_http_and_the_cli() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    assert!(files.len() >= 3, "{files:?}");
    let mut c = client(&server).await;
    for f in &files {
        let req = dynaserve_client::scene_file::load(f).unwrap();
        let frames = c.rollout_collect(&req).await.unwrap();
        assert_eq!(frames.len(), req.steps as usize, "{}", f.display());
        assert!(
            frames
                .iter()
                .flat_map(|f| &f.poses)
                .all(|p| p.translation.iter().all(|x| x.is_finite()))
        );
        // The same file is a valid HTTP body as it stands.
        let body = std::fs::read(f).unwrap();
        let resp = http(server.http_addr, "POST", "/v1/rollout", &[], Some(&body)).await;
        assert_eq!(resp.status, 200, "{}: {}", f.display(), resp.text());
    }
    // The CLI saves a trajectory.
    let out = TempDir::new("cli");
    let path = out.0.join("tower.json");
    let status = tokio::process::Command::new(env!("CARGO_BIN_EXE_dynaserve"))
        .arg("rollout")
        .arg(dir.join("box_tower.json"))
        .args([
            "--server",
            &format!("http://{}", server.grpc_addr),
            "--steps",
            "5",
            "--out",
        ])
        .arg(&path)
        .status()
        .await
        .unwrap();
    assert!(status.success());
    let saved: json::RolloutResponse =
        serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    assert_eq!(saved.frames.len(), 5);
    assert_eq!(saved.model, m.name);
    assert_eq!(saved.frames[0].poses.len(), 4);
    server.shutdown();
    server.wait().await.unwrap();
}
