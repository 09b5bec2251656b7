//! The browser viewer as a person uses it: a real server on loopback with the real checkpoint,
//! Debian's Chromium headless opening the page (which starts the first example by itself),
//! then another example run with a click, the frames drawn as they arrive, the timeline
//! scrubbed, and the operator dashboard; plus the viewer's routes over plain HTTP.
//!
//! `DYNASERVE_VIEWER_SCREENSHOT=path.png` saves the page after the clicked run.

mod browser;
mod common;

use std::time::Duration;

use browser::{Browser, Image};
use common::{http, start, test_model};

/// Generous: a debug build on two shared cores.
const WAIT: Duration = Duration::from_secs(90);

/// What the page reports about itself, for failure messages.
const PAGE_STATE: &str = "JSON.stringify({...document.body.dataset, \
     status: document.getElementById('status')?.textContent, \
     error: document.getElementById('error')?.textContent})";

fn example_stems() -> Vec<String> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes");
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
    let server = start(&model.dir, |_| {}).await;
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
    assert_eq!(names, example_stems());
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

    let api: serde_json::Value = http(addr, "GET", "/openapi.json", &[], None).await.json();
    assert!(api["paths"]["/v1/examples"]["get"].is_object());
    server.shutdown();
    server.wait().await.unwrap();
}

#[test]
fn a_person_opens_the_viewer_runs_an_example_and_scrubs_the_timeline() {
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let model = test_model();
    let server = runtime.block_on(start(&model.dir, |_| {}));
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
    drop(b);
    server.shutdown();
    runtime.block_on(server.wait()).unwrap();
}
