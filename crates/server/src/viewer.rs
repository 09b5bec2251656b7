//! The browser viewer and operator dashboard, served from assets embedded in the binary.
//!
//! | route | |
//! |---|---|
//! | `GET /` | the viewer: pick a model and an example scene (or drop a scene file), watch the rollout in 3D as its frames stream in, scrub the timeline, see per-step server timings; with ground truth, the model's rollout over the ghosted truth and the error against time; for a PhysiFormer model, the denoising progress, then the sampled trajectory as deforming meshes |
//! | `GET /dashboard` | throughput, active streams, batch sizes and latency quantiles, read from `/metrics` |
//! | `GET /viewer/{file}` | the pages' scripts, style sheet and the vendored three.js bundle |
//! | `GET /v1/examples` | the example scenes, embedded at build time, as [`ExamplesResponse`]: rollout bodies (`examples/scenes/*.json`) and any comparison scene for RigidFormer models, generate bodies (`examples/scenes/generate/*.json`) for PhysiFormer models |
//!
//! The pages use relative URLs only, so they work behind a gateway that serves the server under
//! a path prefix. Nothing is fetched from elsewhere at run time. How the page draws frames
//! (rigid poses or per-frame vertex arrays) is described in `docs/viewer.md`.

use std::sync::{Arc, OnceLock};

use axum::Router;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use dynaserve_api::json;
use serde::{Deserialize, Serialize};

/// One scene the viewer offers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Example {
    /// Short name: the scene file's stem (`collision`), or the comparison's name.
    pub name: String,
    /// One line saying what it is, e.g. `collision: 3 objects, 48 steps`.
    pub title: String,
    /// A complete `POST /v1/rollout` body.
    pub request: json::RolloutRequest,
    /// Ground truth from the same start (e.g. the rapier trajectory of a dataset scene): one
    /// frame per step of `request`, step indices from 1, poses in request order. Empty when
    /// there is none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub ground_truth: Vec<json::StepFrame>,
}

impl Example {
    /// An example named `name` for `request`, titled with its object and step counts.
    pub fn new(name: impl Into<String>, request: json::RolloutRequest) -> Example {
        let name = name.into();
        let title = format!(
            "{name}: {} objects, {} steps",
            request.scene.objects.len(),
            request.steps
        );
        Example {
            name,
            title,
            request,
            ground_truth: Vec::new(),
        }
    }
}

/// One mesh scene the viewer offers to PhysiFormer models.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct GenerateExample {
    /// Short name: the scene file's stem (`elastic_drop`).
    pub name: String,
    /// One line saying what it is, e.g. `elastic_drop: 1 rigid + 1 elastic, 49 frames`.
    pub title: String,
    /// A complete `POST /v1/generate` body.
    pub request: json::GenerateRequest,
}

impl GenerateExample {
    /// An example named `name` for `request`, titled with its materials and frame count.
    pub fn new(name: impl Into<String>, request: json::GenerateRequest) -> GenerateExample {
        let name = name.into();
        let objects = &request.scene.objects;
        let elastic = objects
            .iter()
            .filter(|o| o.material == json::Material::Elastic)
            .count();
        let frames = match request.frames {
            0 => "the model's frames".to_string(),
            n => format!("{n} frames"),
        };
        let title = format!(
            "{name}: {} rigid + {elastic} elastic, {frames}",
            objects.len() - elastic
        );
        GenerateExample {
            name,
            title,
            request,
        }
    }
}

/// Result of `GET /v1/examples`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ExamplesResponse {
    /// Rollout scenes (for RigidFormer models) in display order; the viewer starts the first
    /// one when it opens.
    pub examples: Vec<Example>,
    /// Mesh scenes (for PhysiFormer models) in display order.
    #[serde(default)]
    pub generate_examples: Vec<GenerateExample>,
}

/// What the viewer offers: the example scenes of each model family, in display order.
#[derive(Clone, Debug, Default)]
pub struct Viewer {
    examples: Vec<Example>,
    generate_examples: Vec<GenerateExample>,
}

/// (file stem, JSON text) of every `examples/scenes/*.json`, sorted by name.
const EMBEDDED_EXAMPLES: &[(&str, &str)] = include!(concat!(env!("OUT_DIR"), "/examples.rs"));

/// (file stem, JSON text) of every `examples/scenes/generate/*.json`, sorted by name.
const EMBEDDED_GENERATE_EXAMPLES: &[(&str, &str)] =
    include!(concat!(env!("OUT_DIR"), "/generate_examples.rs"));

/// The example shown first when the page opens: a short, lively scene.
const FIRST_EXAMPLE: &str = "collision";

impl Viewer {
    /// The example scenes embedded at build time: the rollout scenes `collision` first, then
    /// the generate scenes. A file that does not parse as its directory's kind of request is
    /// left out with a warning.
    pub fn builtin() -> Viewer {
        let mut examples: Vec<Example> = EMBEDDED_EXAMPLES
            .iter()
            .filter_map(
                |(name, text)| match serde_json::from_str::<json::RolloutRequest>(text) {
                    Ok(req) => Some(Example::new(*name, req)),
                    Err(e) => {
                        tracing::warn!(example = name, error = %e, "example is not a rollout request; not offered by the viewer");
                        None
                    }
                },
            )
            .collect();
        examples.sort_by_key(|e| e.name != FIRST_EXAMPLE);
        let generate_examples = EMBEDDED_GENERATE_EXAMPLES
            .iter()
            .filter_map(
                |(name, text)| match serde_json::from_str::<json::GenerateRequest>(text) {
                    Ok(req) => Some(GenerateExample::new(*name, req)),
                    Err(e) => {
                        tracing::warn!(example = name, error = %e, "example is not a generate request; not offered by the viewer");
                        None
                    }
                },
            )
            .collect();
        Viewer {
            examples,
            generate_examples,
        }
    }

    /// Puts `example` first (the page starts it when it opens).
    pub fn with_first(mut self, example: Example) -> Viewer {
        self.examples.insert(0, example);
        self
    }

    /// The rollout examples in display order.
    pub fn examples(&self) -> &[Example] {
        &self.examples
    }

    /// The generate examples in display order.
    pub fn generate_examples(&self) -> &[GenerateExample] {
        &self.generate_examples
    }
}

/// A file served under `/viewer/`.
struct Asset {
    path: &'static str,
    content_type: &'static str,
    body: &'static [u8],
}

macro_rules! asset {
    ($path:literal, $ct:expr) => {
        Asset {
            path: $path,
            content_type: $ct,
            body: include_bytes!(concat!("../viewer/", $path)),
        }
    };
}

const JS: &str = "text/javascript; charset=utf-8";
const HTML: &str = "text/html; charset=utf-8";
const CSS: &str = "text/css; charset=utf-8";
const TEXT: &str = "text/plain; charset=utf-8";
const SVG: &str = "image/svg+xml";

const ASSETS: &[Asset] = &[
    asset!("index.html", HTML),
    asset!("dashboard.html", HTML),
    asset!("style.css", CSS),
    asset!("viewer.js", JS),
    asset!("scene.js", JS),
    asset!("sse.js", JS),
    asset!("charts.js", JS),
    asset!("dashboard.js", JS),
    asset!("prom.js", JS),
    asset!("vendor/three.min.js", JS),
    asset!("vendor/three.LICENSE", TEXT),
    asset!("favicon.svg", SVG),
];

/// The pages load scripts, styles and data from this server only.
const CSP: &str = "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: \
                   blob:; connect-src 'self'; object-src 'none'; base-uri 'none'; \
                   frame-ancestors 'none'";

fn etags() -> &'static [String] {
    static ETAGS: OnceLock<Vec<String>> = OnceLock::new();
    ETAGS.get_or_init(|| {
        ASSETS
            .iter()
            .map(|a| {
                // FNV-1a: a content tag for revalidation, not a security measure.
                let h = a.body.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
                    (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3)
                });
                format!("\"{h:016x}\"")
            })
            .collect()
    })
}

fn serve_asset(path: &str, headers: &HeaderMap) -> Response {
    let Some(i) = ASSETS.iter().position(|a| a.path == path) else {
        return (StatusCode::NOT_FOUND, "no such viewer file").into_response();
    };
    let asset = &ASSETS[i];
    let etag = &etags()[i];
    let fresh = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.split(',').any(|t| t.trim() == etag));
    let mut resp = if fresh {
        StatusCode::NOT_MODIFIED.into_response()
    } else {
        ([(header::CONTENT_TYPE, asset.content_type)], asset.body).into_response()
    };
    let h = resp.headers_mut();
    // Revalidate every time: the binary (and so the page) may change under the same URL.
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    if let Ok(v) = HeaderValue::from_str(etag) {
        h.insert(header::ETAG, v);
    }
    if asset.content_type == HTML {
        h.insert(
            header::CONTENT_SECURITY_POLICY,
            HeaderValue::from_static(CSP),
        );
    }
    resp
}

async fn index(headers: HeaderMap) -> Response {
    serve_asset("index.html", &headers)
}

async fn dashboard(headers: HeaderMap) -> Response {
    serve_asset("dashboard.html", &headers)
}

/// The page icon (an SVG, which browsers take under the conventional `.ico` path too).
async fn favicon(headers: HeaderMap) -> Response {
    serve_asset("favicon.svg", &headers)
}

async fn file(Path(path): Path<String>, headers: HeaderMap) -> Response {
    serve_asset(&path, &headers)
}

/// The example scenes the viewer offers, the first one started when the page opens.
#[utoipa::path(
    get,
    path = "/v1/examples",
    responses((status = 200, description = "Example scenes", body = ExamplesResponse))
)]
async fn examples(State(viewer): State<Arc<Viewer>>) -> Response {
    axum::Json(ExamplesResponse {
        examples: viewer.examples.clone(),
        generate_examples: viewer.generate_examples.clone(),
    })
    .into_response()
}

/// The OpenAPI document of the viewer's data route (merged into `/openapi.json`).
#[derive(utoipa::OpenApi)]
#[openapi(
    paths(examples),
    components(schemas(ExamplesResponse, Example, GenerateExample))
)]
pub struct ViewerDoc;

/// Routes of the viewer, the dashboard and `/v1/examples`.
pub fn router(viewer: Viewer) -> Router {
    Router::new()
        .route("/", get(index))
        .route("/dashboard", get(dashboard))
        .route("/favicon.ico", get(favicon))
        .route("/viewer/{*path}", get(file))
        .route("/v1/examples", get(examples))
        .with_state(Arc::new(viewer))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every file of the page directory is served (a new file missing from [`ASSETS`] would
    /// be a silent 404), except the vendoring inputs, which the page never loads.
    #[test]
    fn every_page_file_is_embedded() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("viewer");
        let not_served = [
            "vendor/update.sh",
            "vendor/three-entry.js",
            "vendor/three.VERSION",
        ];
        let mut on_disk = Vec::new();
        for dir in [root.clone(), root.join("vendor")] {
            for e in std::fs::read_dir(&dir).unwrap() {
                let path = e.unwrap().path();
                if path.is_file() {
                    let rel = path
                        .strip_prefix(&root)
                        .unwrap()
                        .to_string_lossy()
                        .into_owned();
                    if !not_served.contains(&rel.as_str()) {
                        on_disk.push(rel);
                    }
                }
            }
        }
        on_disk.sort();
        let mut served: Vec<String> = ASSETS.iter().map(|a| a.path.to_string()).collect();
        served.sort();
        assert_eq!(on_disk, served);
    }

    #[test]
    fn every_embedded_example_is_offered_collision_first() {
        let v = Viewer::builtin();
        assert_eq!(v.examples().len(), EMBEDDED_EXAMPLES.len());
        assert!(v.examples().len() >= 3, "examples/scenes has three scenes");
        assert_eq!(v.examples()[0].name, FIRST_EXAMPLE);
        for e in v.examples() {
            assert!(e.request.steps > 0 && !e.request.scene.objects.is_empty());
        }
    }

    #[test]
    fn every_embedded_generate_example_is_offered() {
        let v = Viewer::builtin();
        assert_eq!(
            v.generate_examples().len(),
            EMBEDDED_GENERATE_EXAMPLES.len()
        );
        assert!(
            v.generate_examples()
                .iter()
                .any(|e| e.name == "elastic_drop"),
            "examples/scenes/generate has elastic_drop"
        );
        for e in v.generate_examples() {
            assert!(!e.request.scene.objects.is_empty(), "{}", e.name);
            assert!(e.title.starts_with(&e.name), "{}", e.title);
        }
    }

    #[test]
    fn assets_have_types_and_the_pages_load_only_relative_urls() {
        for a in ASSETS {
            assert!(!a.body.is_empty(), "{}", a.path);
            if a.content_type == HTML {
                let text = std::str::from_utf8(a.body).unwrap();
                for attr in ["src=\"", "href=\""] {
                    for part in text.split(attr).skip(1) {
                        assert!(
                            !part.starts_with('/') && !part.starts_with("http"),
                            "{}: absolute URL {attr}{}",
                            a.path,
                            &part[..part.find('"').unwrap_or(part.len())]
                        );
                    }
                }
            }
            if a.content_type == JS && !a.path.starts_with("vendor/") {
                let text = std::str::from_utf8(a.body).unwrap();
                assert!(!text.contains("fetch('/"), "{}: absolute fetch", a.path);
                assert!(!text.contains("http://"), "{}: absolute URL", a.path);
            }
        }
    }
}
