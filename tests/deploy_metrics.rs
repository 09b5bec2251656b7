//! The deployment files read only metrics the server exports.
//!
//! Every `dynaserve_*` series named by the Grafana dashboard, the Prometheus alert rules and the
//! Prometheus adapter rules (`deploy/`) must appear in the server's `/metrics` text as rendered
//! before the first request, with every label the files select on, and counters or histogram
//! series wherever the files take a `rate`/`increase`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use dynaserve_server::metrics::{METRICS, MetricKind, Metrics};

/// The files under `deploy/` whose queries read server metrics.
const FILES: &[&str] = &[
    "deploy/grafana/dashboards/dynaserve.json",
    "deploy/prometheus/rules/dynaserve.rules.yml",
    "deploy/k8s/prometheus-adapter/values.yaml",
];

/// Labels Prometheus attaches at scrape time (target labels, `prometheus-kubernetes.yml`
/// relabelling); the server never exports them.
const TARGET_LABELS: &[&str] = &["job", "instance", "namespace", "pod", "node", "service"];

/// One occurrence of a metric name in a deployment file.
#[derive(Debug)]
struct Use {
    name: String,
    /// Label names of the selector right after the name (`name{a="x", b=~"y"}`).
    labels: Vec<String>,
    /// Followed by a selector or a range (`{` or `[`): a query, not prose.
    in_query: bool,
    /// Directly inside `rate(` or `increase(`.
    rated: bool,
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_' || c == ':'
}

/// Label names of a selector body such as `job=\"$job\", reason="x"` (JSON-escaped quotes are
/// fine: names come before the operator).
fn selector_labels(body: &str) -> Vec<String> {
    let mut labels = Vec::new();
    let mut in_quotes = false;
    let mut start = 0;
    let mut parts = Vec::new();
    let chars: Vec<char> = body.chars().collect();
    for (i, &c) in chars.iter().enumerate() {
        if c == '"' && (i == 0 || chars[i - 1] != '\\') {
            in_quotes = !in_quotes;
        } else if c == ',' && !in_quotes {
            parts.push(chars[start..i].iter().collect::<String>());
            start = i + 1;
        }
    }
    parts.push(chars[start..].iter().collect::<String>());
    for part in parts {
        let name: String = part.trim().chars().take_while(|&c| is_ident(c)).collect();
        // `<<.LabelMatchers>>` (adapter template) and empty parts name no label.
        if !name.is_empty() {
            labels.push(name);
        }
    }
    labels
}

/// Every `dynaserve_*` occurrence in `text`.
fn uses(text: &str) -> Vec<Use> {
    let mut out = Vec::new();
    let bytes = text.as_bytes();
    let mut from = 0;
    while let Some(off) = text[from..].find("dynaserve_") {
        let start = from + off;
        let preceded = start > 0 && is_ident(bytes[start - 1] as char);
        let end = start
            + text[start..]
                .find(|c: char| !is_ident(c))
                .unwrap_or(text.len() - start);
        from = end;
        if preceded {
            continue;
        }
        let name = text[start..end].to_string();
        let next = text[end..].chars().next();
        let labels = if next == Some('{') {
            match text[end + 1..].find('}') {
                Some(close) => selector_labels(&text[end + 1..end + 1 + close]),
                None => Vec::new(),
            }
        } else {
            Vec::new()
        };
        let before = text[..start].trim_end();
        let rated = before.ends_with("rate(") || before.ends_with("increase(");
        out.push(Use {
            name,
            labels,
            in_query: matches!(next, Some('{') | Some('[')),
            rated,
        });
    }
    out
}

/// The text of a deployment file without the names the Prometheus adapter publishes its own
/// metrics under (`as:` lines): those are custom-metrics API names, not server series.
fn queried_text(text: &str) -> String {
    text.lines()
        .filter(|l| !l.trim_start().starts_with("as:"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// What the server exports: sample name -> label names, and family name -> kind.
struct Exported {
    samples: BTreeMap<String, BTreeSet<String>>,
    families: BTreeMap<String, MetricKind>,
}

fn exported() -> Exported {
    let text = Metrics::new(&["rigidformer".to_string()]).render();
    let mut samples: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for s in dynaserve_client::prom::parse(&text) {
        samples
            .entry(s.name)
            .or_default()
            .extend(s.labels.into_iter().map(|(k, _)| k));
    }
    let families = METRICS
        .iter()
        .map(|m| (m.name.to_string(), m.kind))
        .collect();
    Exported { samples, families }
}

/// The family a sample name belongs to (`x_bucket` -> `x` for histograms).
fn family_of<'a>(sample: &'a str, exp: &Exported) -> Option<(&'a str, MetricKind)> {
    if let Some(kind) = exp.families.get(sample) {
        return Some((sample, *kind));
    }
    for suffix in ["_bucket", "_sum", "_count"] {
        if let Some(base) = sample.strip_suffix(suffix)
            && let Some(MetricKind::Histogram) = exp.families.get(base)
        {
            return Some((base, MetricKind::Histogram));
        }
    }
    None
}

/// Problems with one file's metric uses against what the server exports.
fn problems(file: &str, text: &str, exp: &Exported) -> Vec<String> {
    let mut out = Vec::new();
    for u in uses(text) {
        let sample = exp.samples.get(&u.name);
        let family = family_of(&u.name, exp);
        match (sample, family) {
            (None, None) => out.push(format!("{file}: `{}` is not exported", u.name)),
            (None, Some(_)) if u.in_query => out.push(format!(
                "{file}: `{}` is a histogram family; query its _bucket/_sum/_count series",
                u.name
            )),
            _ => {}
        }
        if let Some(present) = sample {
            for l in &u.labels {
                if !present.contains(l) && !TARGET_LABELS.contains(&l.as_str()) {
                    out.push(format!(
                        "{file}: `{}` has no label `{l}` (it has {present:?})",
                        u.name
                    ));
                }
            }
        }
        if u.rated
            && let Some((base, MetricKind::Gauge)) = family
        {
            out.push(format!("{file}: rate() of the gauge `{base}`"));
        }
    }
    out
}

#[test]
fn deployment_files_read_only_exported_metrics() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let exp = exported();
    assert!(
        exp.samples.len() >= METRICS.len(),
        "the server rendered fewer series than it lists"
    );
    let mut all = Vec::new();
    let mut names = BTreeSet::new();
    for file in FILES {
        let text = std::fs::read_to_string(root.join(file))
            .unwrap_or_else(|e| panic!("cannot read {file}: {e}"));
        let text = queried_text(&text);
        let found = uses(&text);
        assert!(!found.is_empty(), "{file} reads no dynaserve_* metric");
        names.extend(found.into_iter().map(|u| u.name));
        all.extend(problems(file, &text, &exp));
    }
    assert!(
        all.is_empty(),
        "deployment files disagree with /metrics:\n{}",
        all.join("\n")
    );
    // The views the deployment exists for are really read (FPS, latency, queue, batches,
    // admission, readiness).
    for needed in [
        "dynaserve_scene_steps_total",
        "dynaserve_forward_duration_seconds_bucket",
        "dynaserve_request_duration_seconds_bucket",
        "dynaserve_queue_wait_seconds_bucket",
        "dynaserve_batch_scenes_bucket",
        "dynaserve_batch_objects_bucket",
        "dynaserve_active_rollouts",
        "dynaserve_request_failures_total",
        "dynaserve_ready",
    ] {
        assert!(names.contains(needed), "no deployment file reads {needed}");
    }
}

#[test]
fn the_check_rejects_unknown_names_labels_and_rated_gauges() {
    let exp = exported();
    let ok =
        r#"sum by (le) (rate(dynaserve_queue_wait_seconds_bucket{job="x", priority="bulk"}[5m]))"#;
    assert_eq!(problems("ok", ok, &exp), Vec::<String>::new());
    let bad_name = "rate(dynaserve_no_such_metric_total[1m])";
    assert_eq!(problems("f", bad_name, &exp).len(), 1);
    let bad_label = r#"dynaserve_active_rollouts{priority="bulk"}"#;
    assert!(problems("f", bad_label, &exp)[0].contains("no label `priority`"));
    let rated_gauge = "rate(dynaserve_active_rollouts[5m])";
    assert!(problems("f", rated_gauge, &exp)[0].contains("gauge"));
    let bare_histogram = "rate(dynaserve_batch_scenes[5m])";
    assert!(problems("f", bare_histogram, &exp)[0].contains("histogram family"));
    // JSON-escaped selectors (the dashboard) parse the same way.
    let escaped =
        r#"rate(dynaserve_scene_steps_total{job=\"$job\", model=~\"$model\"}[$__rate_interval])"#;
    assert_eq!(problems("json", escaped, &exp), Vec::<String>::new());
}
