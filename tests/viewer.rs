//! The browser viewer as a person uses it: a real server on loopback with the real
//! checkpoints (a RigidFormer and the shipped PhysiFormer), Debian's Chromium headless opening
//! the page (which starts the first example by itself), then another example run with a
//! click, the frames drawn as they arrive, the timeline scrubbed, a PhysiFormer scene sampled
//! and played back as meshes, and the operator dashboard; plus the viewer's routes over plain
//! HTTP.
//!
//! `DYNASERVE_VIEWER_SCREENSHOT=path.png` saves the page after the clicked rollout,
//! `DYNASERVE_VIEWER_MESH_SCREENSHOT=path.png` after the sampled mesh scene.

mod browser;
mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use browser::{Browser, Image};
use common::{http, test_model};
use dynaserve_server::{RunningServer, ServeConfig};

/// Generous: a debug build on two shared cores.
const WAIT: Duration = Duration::from_secs(90);

/// What the page reports about itself, for failure messages.
const PAGE_STATE: &str = "JSON.stringify({...document.body.dataset, \
     status: document.getElementById('status')?.textContent, \
     error: document.getElementById('error')?.textContent})";

/// The shipped PhysiFormer checkpoint.
fn physiformer_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models/physiformer-small")
}

/// A server on free loopback ports with the test RigidFormer and the shipped PhysiFormer.
async fn start(rigid: &Path) -> RunningServer {
    let config = ServeConfig::local(vec![rigid.to_path_buf(), physiformer_dir()]);
    let models = dynaserve_server::load_all(&config.models).unwrap();
    let server = dynaserve_server::start(config, models).await.unwrap();
    server.wait_ready(Duration::from_secs(60)).await.unwrap();
    server
}

/// File stems of the JSON files directly in `examples/scenes/{sub}`, sorted.
fn example_stems(sub: &str) -> Vec<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples/scenes")
        .join(sub);
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn viewer_routes_serve_embedded_pages_and_every_example_scene_rolls_out() {
    let model = test_model();
    let server = start(&model.dir).await;
    let addr = server.http_addr;

    let page = http(addr, "GET", "/", &[], None).await;
    assert_eq!(page.status, 200);
    assert!(
        page.header("content-type")
            .unwrap()
            .starts_with("text/html")
    );
    let csp = page.header("content-security-policy").unwrap();
    assert!(csp.contains("default-src 'self'"), "{csp}");
    assert!(page.text().contains("viewer/viewer.js"));

    let dash = http(addr, "GET", "/dashboard", &[], None).await;
    assert_eq!(dash.status, 200);
    assert!(dash.text().contains("viewer/dashboard.js"));

    // The vendored renderer, revalidated by its tag rather than sent again.
    let js = http(addr, "GET", "/viewer/vendor/three.min.js", &[], None).await;
    assert_eq!(js.status, 200);
    assert!(
        js.header("content-type")
            .unwrap()
            .starts_with("text/javascript")
    );
    assert!(js.text().contains("OrbitControls"));
    let etag = js.header("etag").unwrap().to_string();
    let again = http(
        addr,
        "GET",
        "/viewer/vendor/three.min.js",
        &[("if-none-match", &etag)],
        None,
    )
    .await;
    assert_eq!(again.status, 304);
    assert!(again.body.is_empty());
    let licence = http(addr, "GET", "/viewer/vendor/three.LICENSE", &[], None).await;
    assert!(licence.text().contains("MIT License"));
    // The page icon, under the path browsers ask for by themselves.
    let icon = http(addr, "GET", "/favicon.ico", &[], None).await;
    assert_eq!(icon.status, 200);
    assert_eq!(icon.header("content-type"), Some("image/svg+xml"));
    assert!(icon.text().starts_with("<svg"));
    for missing in ["/viewer/nope.js", "/viewer/../Cargo.toml", "/viewer/"] {
        let r = http(addr, "GET", missing, &[], None).await;
        assert_eq!(r.status, 404, "{missing}");
    }

    // Every scene of examples/scenes is offered, collision first, and rolls out as given.
    let doc: serde_json::Value = http(addr, "GET", "/v1/examples", &[], None).await.json();
    let examples = doc["examples"].as_array().unwrap();
    let mut names: Vec<String> = examples
        .iter()
        .map(|e| e["name"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(names[0], "collision");
    names.sort();
    assert_eq!(names, example_stems(""));
    for e in examples {
        let mut req = e["request"].clone();
        req["steps"] = 2.into();
        let body = serde_json::to_vec(&req).unwrap();
        let r = http(
            addr,
            "POST",
            "/v1/rollout",
            &[("content-type", "application/json")],
            Some(&body),
        )
        .await;
        assert_eq!(r.status, 200, "{}: {}", e["name"], r.text());
        let out: serde_json::Value = r.json();
        assert_eq!(out["frames"].as_array().unwrap().len(), 2);
    }

    // Every scene of examples/scenes/generate is offered for PhysiFormer models and samples
    // as given (here shortened to 4 frames of 2 denoising steps).
    let generate = doc["generate_examples"].as_array().unwrap();
    let mut names: Vec<String> = generate
        .iter()
        .map(|e| e["name"].as_str().unwrap().to_string())
        .collect();
    names.sort();
    assert_eq!(names, example_stems("generate"));
    for e in generate {
        assert!(e["title"].as_str().unwrap().contains("elastic"), "{e}");
        let mut req = e["request"].clone();
        req["frames"] = 4.into();
        req["denoise_steps"] = 2.into();
        req["model"] = "physiformer-small".into();
        let body = serde_json::to_vec(&req).unwrap();
        let r = http(
            addr,
            "POST",
            "/v1/generate",
            &[("content-type", "application/json")],
            Some(&body),
        )
        .await;
        assert_eq!(r.status, 200, "{}: {}", e["name"], r.text());
        let out: serde_json::Value = r.json();
        let frames = out["samples"][0]["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 4);
        assert_eq!(
            frames[3]["objects"].as_array().unwrap().len(),
            req["scene"]["objects"].as_array().unwrap().len()
        );
    }

    let api: serde_json::Value = http(addr, "GET", "/openapi.json", &[], None).await.json();
    assert!(api["paths"]["/v1/examples"]["get"].is_object());
    server.shutdown();
    server.wait().await.unwrap();
}

#[test]
fn a_person_opens_the_viewer_runs_an_example_and_scrubs_the_timeline() {
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let model = test_model();
    let server = runtime.block_on(start(&model.dir));
    let base = format!("http://{}/", server.http_addr);
    let mut b = Browser::launch(1280, 800).unwrap();

    // Opening the page starts the first example (collision) by itself.
    b.navigate(&base).unwrap();
    let collision: serde_json::Value = serde_json::from_str(include_str!(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/examples/scenes/collision.json"
    )))
    .unwrap();
    let auto = b
        .wait_for(
            "document.body.dataset.state === 'done' && ({...document.body.dataset})",
            WAIT,
            PAGE_STATE,
        )
        .unwrap();
    assert_eq!(auto["frames"], collision["steps"].to_string(), "{auto}");
    assert_eq!(auto["requested"], collision["steps"].to_string(), "{auto}");

    // Pick another example, ask for 20 steps of 2 frames, click Run.
    b.eval(
        "(() => { const s = document.getElementById('example'); \
         s.value = [...s.options].find(o => o.textContent.startsWith('drop_pile')).value; \
         s.dispatchEvent(new Event('change')); \
         document.getElementById('steps').value = '20'; \
         document.getElementById('dt-steps').value = '2'; })()",
    )
    .unwrap();
    b.click("#run").unwrap();
    let run = b
        .wait_for(
            "document.body.dataset.requested === '20' && document.body.dataset.state !== 'running' \
             && ({...document.body.dataset})",
            WAIT,
            PAGE_STATE,
        )
        .unwrap();
    assert_eq!(run["state"], "done", "{run}");
    assert_eq!(run["frames"], "20", "the page's frame count: {run}");
    let timing = b
        .eval("document.getElementById('timing-text').textContent")
        .unwrap();
    assert!(timing.as_str().unwrap().contains("forward"), "{timing}");

    // Scrub to the last frame, then back to the start: both drawn, and different.
    let scrub = |b: &mut Browser, to: u32| {
        b.eval(&format!(
            "(() => {{ const t = document.getElementById('timeline'); t.value = '{to}'; \
             t.dispatchEvent(new Event('input')); \
             return new Promise(r => requestAnimationFrame(() => requestAnimationFrame(() => \
             r(document.body.dataset.shown)))); }})()"
        ))
        .unwrap()
    };
    assert_eq!(scrub(&mut b, 20), "20");
    let last = Image::from_png(&b.screenshot("#view canvas").unwrap()).unwrap();
    if let Some(path) = std::env::var_os("DYNASERVE_VIEWER_SCREENSHOT") {
        std::fs::write(path, b.screenshot("body").unwrap()).unwrap();
    }
    assert_eq!(scrub(&mut b, 0), "0");
    let first = Image::from_png(&b.screenshot("#view canvas").unwrap()).unwrap();
    assert!(last.width > 400 && last.height > 200);
    assert!(
        last.distinct_colours() > 50 && last.non_background_share() > 0.05,
        "the canvas looks blank: {} colours, {:.3} non-background",
        last.distinct_colours(),
        last.non_background_share()
    );
    let moved = last.differing_share(&first, 8);
    assert!(
        moved > 0.001,
        "step 0 and step 20 look the same ({moved:.4})"
    );

    // A PhysiFormer model and its mesh scene: the page samples it (2 denoising steps, to be
    // quick), follows the denoising progress, then plays the trajectory back as meshes.
    let mesh_scene: serde_json::Value = serde_json::from_str(include_str!(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/examples/scenes/generate/elastic_drop.json"
    )))
    .unwrap();
    let frames = mesh_scene["frames"].as_u64().unwrap();
    let family = b
        .eval(
            "(() => { const m = document.getElementById('model'); \
             m.value = 'physiformer-small'; m.dispatchEvent(new Event('change')); \
             const s = document.getElementById('example'); \
             s.value = [...s.options].find(o => o.textContent.startsWith('elastic_drop')).value; \
             s.dispatchEvent(new Event('change')); \
             document.getElementById('denoise-steps').value = '2'; \
             return document.body.dataset.family; })()",
        )
        .unwrap();
    assert_eq!(family, "generate");
    b.click("#run").unwrap();
    let sampled = b
        .wait_for(
            &format!(
                "document.body.dataset.requested === '{frames}' && \
                 document.body.dataset.state !== 'running' && ({{...document.body.dataset}})"
            ),
            WAIT,
            PAGE_STATE,
        )
        .unwrap();
    assert_eq!(sampled["state"], "done", "{sampled}");
    assert_eq!(sampled["frames"], frames.to_string(), "{sampled}");
    assert_eq!(sampled["denoised"], "2", "{sampled}");
    let bar = b
        .eval("[document.getElementById('denoise').value, document.getElementById('denoise').max]")
        .unwrap();
    assert_eq!(bar, serde_json::json!([2, 2]), "the progress bar");
    let end = u32::try_from(frames - 1).unwrap();
    assert_eq!(scrub(&mut b, end), end.to_string());
    let last = Image::from_png(&b.screenshot("#view canvas").unwrap()).unwrap();
    assert_eq!(scrub(&mut b, 0), "0");
    let first = Image::from_png(&b.screenshot("#view canvas").unwrap()).unwrap();
    assert!(
        last.distinct_colours() > 50 && last.non_background_share() > 0.01,
        "the mesh view looks blank: {} colours, {:.3} non-background",
        last.distinct_colours(),
        last.non_background_share()
    );
    // Both meshes are drawn in their colours (object 0 orange-red, object 1 blue), not just
    // the grey box: flat shading darkens them, so a hue test rather than exact colours.
    let red = last.share_matching(|[r, g, b]| r > g.saturating_add(40) && r > b.saturating_add(40));
    let blue = last.share_matching(|[r, _, b]| b > r.saturating_add(40));
    assert!(
        red > 0.0005 && blue > 0.0005,
        "the meshes are not drawn: {red:.4} red, {blue:.4} blue pixels"
    );
    let moved = last.differing_share(&first, 8);
    assert!(
        moved > 0.001,
        "frame 0 and frame {end} look the same ({moved:.4})"
    );
    if let Some(path) = std::env::var_os("DYNASERVE_VIEWER_MESH_SCREENSHOT") {
        // For the picture, the scene's own denoising steps and a frame mid-flight.
        let steps = mesh_scene["denoise_steps"].as_u64().unwrap();
        b.eval(&format!(
            "document.getElementById('denoise-steps').value = '{steps}'"
        ))
        .unwrap();
        b.click("#run").unwrap();
        b.wait_for(
            &format!(
                "document.body.dataset.denoised === '{steps}' && \
                 document.body.dataset.state === 'done'"
            ),
            WAIT,
            PAGE_STATE,
        )
        .unwrap();
        scrub(&mut b, end / 2);
        std::fs::write(path, b.screenshot("body").unwrap()).unwrap();
    }

    // The dashboard reads the server's metrics: both rollouts are counted.
    b.navigate(&format!("{base}dashboard")).unwrap();
    b.wait_for(
        "Number(document.body.dataset.scrapes) >= 1",
        WAIT,
        "document.body.innerText",
    )
    .unwrap();
    let count = b
        .eval(
            "[...document.querySelectorAll('#latency tr')].find(r => \
             r.cells[0].textContent.startsWith('rollout')).lastChild.textContent",
        )
        .unwrap();
    assert!(
        count.as_str().unwrap().parse::<u32>().unwrap() >= 2,
        "rollouts counted: {count}"
    );

    // A link can open the viewer on a model and a scene: ?model=NAME&scene=NAME.
    b.navigate(&format!(
        "{base}?model=physiformer-small&scene=elastic_drop&autoplay=0"
    ))
    .unwrap();
    let picked = b
        .wait_for(
            "document.body.dataset.state === 'idle' && [document.getElementById('model').value, \
             document.getElementById('example').selectedOptions[0].textContent, \
             document.body.dataset.family]",
            WAIT,
            PAGE_STATE,
        )
        .unwrap();
    assert_eq!(picked[0], "physiformer-small", "{picked}");
    assert!(
        picked[1].as_str().unwrap().starts_with("elastic_drop"),
        "{picked}"
    );
    assert_eq!(picked[2], "generate", "{picked}");
    drop(b);
    server.shutdown();
    runtime.block_on(server.wait()).unwrap();
}

/// The simulator beside a learned model: `?beside=rapier` rolls the same scene out on the
/// served rapier family and draws it as the ghost, with the error chart against it.
#[test]
fn the_viewer_shows_the_simulator_beside_a_learned_model() {
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let model = test_model();
    let server = runtime.block_on(async {
        let dirs = vec![
            model.dir.clone(),
            Path::new(env!("CARGO_MANIFEST_DIR")).join("models/simulators/rapier"),
        ];
        let config = ServeConfig::local(dirs.clone());
        let models = dynaserve_server::load_all(&dirs).unwrap();
        let server = dynaserve_server::start(config, models).await.unwrap();
        server.wait_ready(Duration::from_secs(60)).await.unwrap();
        server
    });
    let url = format!(
        "http://{}/?model={}&beside=rapier&scene=collision",
        server.http_addr, model.name
    );
    let mut b = Browser::launch(1280, 800).unwrap();
    b.navigate(&url).unwrap();
    let done = b
        .wait_for(
            "document.body.dataset.state === 'done' && \
             document.getElementById('error-text').textContent.includes('rapier (ghost)') && \
             ({...document.body.dataset, legend: document.getElementById('legend').textContent, \
               error: document.getElementById('error-text').textContent})",
            WAIT,
            PAGE_STATE,
        )
        .unwrap();
    assert!(
        done["legend"].as_str().unwrap().contains("ghost: rapier"),
        "{done}"
    );
    assert!(
        done["error"]
            .as_str()
            .unwrap()
            .contains("cm mean point error"),
        "{done}"
    );
    server.shutdown();
}

/// An ensemble estimates its uncertainty: the page charts each object's spread against time
/// and gives the widest for the step on screen.
#[test]
fn the_viewer_charts_an_ensembles_spread() {
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join(common::SHIPPED_ENSEMBLE);
    let server = runtime.block_on(async {
        let config = ServeConfig::local(vec![dir.clone()]);
        let models = dynaserve_server::load_all(&config.models).unwrap();
        let server = dynaserve_server::start(config, models).await.unwrap();
        server.wait_ready(Duration::from_secs(60)).await.unwrap();
        server
    });
    let name = dir.file_name().unwrap().to_string_lossy().into_owned();
    let url = format!("http://{}/?model={name}&scene=collision", server.http_addr);
    let mut b = Browser::launch(1280, 800).unwrap();
    b.navigate(&url).unwrap();
    let done = b
        .wait_for(
            "document.body.dataset.state === 'done' && \
             ({...document.body.dataset, \
               hidden: document.getElementById('spread-figure').hidden, \
               spread: document.getElementById('spread-text').textContent})",
            WAIT,
            PAGE_STATE,
        )
        .unwrap();
    assert_eq!(done["hidden"], false, "{done}");
    let text = done["spread"].as_str().unwrap();
    assert!(text.contains(" cm, ") && text.contains(" deg"), "{done}");
    server.shutdown();
}
