//! Report types (serialised with `--json`), the human-readable tables, the A/B comparison and
//! the self-contained HTML chart.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde::Serialize;

use crate::stats::Summary;
use dynaserve_client::prom::{self, Histogram};

/// Request outcome counts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct RequestCounts {
    /// Requests sent.
    pub started: u64,
    /// Requests that completed with every frame.
    pub ok: u64,
    /// Requests that ended with an error (see `errors`).
    pub failed: u64,
    /// Requests cut at the end of a timed window or by Ctrl-C (neither ok nor failed).
    pub cut: u64,
    /// Poisson arrivals not sent because the in-flight limit was reached.
    pub skipped: u64,
}

/// Rates over the measured window.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Throughput {
    /// Scenes advanced by one step, per second.
    pub scene_steps_per_s: f64,
    /// Objects advanced by one step, per second.
    pub object_steps_per_s: f64,
    /// Completed requests per second.
    pub requests_per_s: f64,
}

/// A server histogram difference, summarised.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct HistStats {
    /// Observations in this run.
    pub count: f64,
    /// Exact mean (`sum / count`).
    pub mean: f64,
    /// Median estimate.
    pub p50: f64,
    /// 90th percentile estimate.
    pub p90: f64,
    /// 99th percentile estimate.
    pub p99: f64,
    /// How the percentiles were estimated: `bucket_upper_bound` (at least that fraction of
    /// observations is `<=` the value) or `interpolated` (like PromQL `histogram_quantile`).
    pub estimate: &'static str,
    /// Non-empty buckets: `[lower, upper, count]` (upper may be `null` for +Inf in JSON).
    pub buckets: Vec<(f64, Option<f64>, f64)>,
}

impl HistStats {
    /// Summarises a histogram, scaling values by `scale` (e.g. 1000 for seconds to ms).
    /// `counts` selects bucket-upper-bound percentiles (for integer-valued histograms).
    pub fn of(h: &Histogram, scale: f64, counts: bool) -> HistStats {
        let q = |p: f64| {
            scale
                * if counts {
                    h.quantile_upper(p)
                } else {
                    h.quantile_interpolated(p)
                }
        };
        HistStats {
            count: h.count,
            mean: h.mean() * scale,
            p50: q(0.5),
            p90: q(0.9),
            p99: q(0.99),
            estimate: if counts {
                "bucket_upper_bound"
            } else {
                "interpolated"
            },
            buckets: h
                .nonempty_buckets()
                .into_iter()
                .map(|(lo, hi, c)| (lo * scale, hi.is_finite().then_some(hi * scale), c))
                .collect(),
        }
    }
}

/// What the server's `/metrics` says about this run (difference of two scrapes).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ServerStats {
    /// Batched forward passes.
    pub batches: f64,
    /// Scenes per forward pass.
    pub batch_scenes: HistStats,
    /// Objects per forward pass.
    pub batch_objects: HistStats,
    /// Queue wait per priority (`interactive`, `bulk`), milliseconds.
    pub queue_wait_ms: BTreeMap<String, HistStats>,
    /// Forward pass duration, milliseconds.
    pub forward_ms: HistStats,
    /// Scene-steps the server computed.
    pub scene_steps: f64,
    /// Object-steps the server computed.
    pub object_steps: f64,
    /// Queued steps dropped, by reason.
    pub dropped_steps: BTreeMap<String, f64>,
    /// Failed requests by reason, as the server counted them.
    pub failures: BTreeMap<String, f64>,
}

impl ServerStats {
    /// Difference between two `/metrics` texts.
    pub fn from_scrapes(before: &str, after: &str) -> Result<ServerStats, String> {
        let b = prom::parse(before);
        let a = prom::parse(after);
        let hist = |name: &str, filter: &dyn Fn(&prom::Sample) -> bool| {
            let ha = Histogram::from_samples(&a, name, filter)
                .ok_or_else(|| format!("the server exports no {name}"))?;
            let hb = Histogram::from_samples(&b, name, filter).unwrap_or_default();
            Ok::<_, String>(ha.diff(&hb))
        };
        let all = |_: &prom::Sample| true;
        let batch_scenes = hist("dynaserve_batch_scenes", &all)?;
        let batch_objects = hist("dynaserve_batch_objects", &all)?;
        let forward = hist("dynaserve_forward_duration_seconds", &all)?;
        let mut queue_wait_ms = BTreeMap::new();
        for p in ["interactive", "bulk"] {
            let Ok(h) = hist("dynaserve_queue_wait_seconds", &|s: &prom::Sample| {
                s.label("priority") == Some(p)
            }) else {
                continue;
            };
            if h.count > 0.0 {
                queue_wait_ms.insert(p.to_string(), HistStats::of(&h, 1000.0, false));
            }
        }
        let counter = |name: &str| prom::sum(&a, name, all) - prom::sum(&b, name, all);
        let by_label = |name: &str, label: &str| {
            let mut m = BTreeMap::new();
            for s in a.iter().filter(|s| s.name == name) {
                let Some(v) = s.label(label) else { continue };
                let before = b
                    .iter()
                    .find(|x| x.name == name && x.labels == s.labels)
                    .map_or(0.0, |x| x.value);
                let d = s.value - before;
                if d > 0.0 {
                    *m.entry(v.to_string()).or_insert(0.0) += d;
                }
            }
            m
        };
        Ok(ServerStats {
            batches: batch_scenes.count,
            batch_scenes: HistStats::of(&batch_scenes, 1.0, true),
            batch_objects: HistStats::of(&batch_objects, 1.0, true),
            queue_wait_ms,
            forward_ms: HistStats::of(&forward, 1000.0, false),
            scene_steps: counter("dynaserve_scene_steps_total"),
            object_steps: counter("dynaserve_object_steps_total"),
            dropped_steps: by_label("dynaserve_dropped_steps_total", "reason"),
            failures: by_label("dynaserve_request_failures_total", "reason"),
        })
    }
}

/// Results of one load level (one concurrency, one Poisson rate, one set of Predict calls).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Report {
    /// Concurrency of this level (streams, Predict callers), or the Poisson rate rounded.
    pub concurrency: usize,
    /// Offered request rate for Poisson runs, per second.
    pub offered_rate: Option<f64>,
    /// Measured window, seconds.
    pub duration_s: f64,
    /// True when Ctrl-C ended the run early (the figures cover what was received).
    pub interrupted: bool,
    /// Request outcomes.
    pub requests: RequestCounts,
    /// Frames received (rollouts) or returned step frames (Predict).
    pub frames: u64,
    /// Frames expected when every request completes, if known in advance.
    pub expected_frames: Option<u64>,
    /// Scene-steps received.
    pub scene_steps: u64,
    /// Object-steps received.
    pub object_steps: u64,
    /// Rates over the window.
    pub throughput: Throughput,
    /// Time between consecutive frames of one stream (the step latency), ms.
    pub step_latency_ms: Summary,
    /// Time from sending a request to its first frame, ms.
    pub first_frame_ms: Summary,
    /// Time from sending a request to its last frame or response, ms.
    pub request_latency_ms: Summary,
    /// Scenes in the batch that computed each frame, as the server reported it per frame.
    pub frame_batch_scenes: Summary,
    /// Server-side queue wait per frame (rollouts) or per call (Predict), ms.
    pub server_queue_ms: Summary,
    /// Server-side forward time per frame (rollouts) or per call (Predict), ms.
    pub server_forward_ms: Summary,
    /// Failed requests by error code.
    pub errors: BTreeMap<String, u64>,
    /// A few error messages, for diagnosis.
    pub error_examples: Vec<String>,
    /// The server's own metrics for this level, when scraped.
    pub server: Option<ServerStats>,
    /// Why the server metrics are missing, when they are.
    pub server_metrics_error: Option<String>,
}

/// All levels run against one side (server or in-process model).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SideReport {
    /// Side name (`A`, `B` or `--label`).
    pub label: String,
    /// `grpc`, `http` or `inprocess`.
    pub transport: String,
    /// Target URL, or the model directory for in-process runs.
    pub target: String,
    /// Command that launched the server, for `--spawn` sides.
    pub spawned: Option<String>,
    /// Model name that served the load.
    pub model: String,
    /// One report per level, in order.
    pub levels: Vec<Report>,
    /// Why a ramp stopped, or other remarks.
    pub notes: Vec<String>,
}

/// Ratios of side B to side A at one level.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Ratio {
    /// The level's concurrency (side A's).
    pub concurrency: usize,
    /// Scene-steps/s of B over A.
    pub throughput: f64,
    /// Step latency p50 of B over A.
    pub step_p50: f64,
    /// Step latency p99 of B over A.
    pub step_p99: f64,
    /// Request latency p50 of B over A.
    pub request_p50: f64,
    /// Request latency p99 of B over A.
    pub request_p99: f64,
}

/// The whole run, as written by `--json`.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct RunReport {
    /// Version of the load tester.
    pub version: String,
    /// `streams`, `predict`, `poisson` or `ramp`.
    pub mode: String,
    /// Load description (scenes, steps, variants, ...).
    pub load: String,
    /// Cores of this machine.
    pub cores: usize,
    /// One entry per side.
    pub sides: Vec<SideReport>,
    /// B/A ratios per level, when two sides ran.
    pub comparison: Vec<Ratio>,
}

fn ratio(b: f64, a: f64) -> f64 {
    if a > 0.0 { b / a } else { f64::NAN }
}

impl RunReport {
    /// Fills `comparison` from the first two sides (levels matched by position).
    pub fn compute_ratios(&mut self) {
        self.comparison.clear();
        if self.sides.len() < 2 {
            return;
        }
        let (a, b) = (&self.sides[0], &self.sides[1]);
        for (la, lb) in a.levels.iter().zip(&b.levels) {
            self.comparison.push(Ratio {
                concurrency: la.concurrency,
                throughput: ratio(
                    lb.throughput.scene_steps_per_s,
                    la.throughput.scene_steps_per_s,
                ),
                step_p50: ratio(lb.step_latency_ms.p50, la.step_latency_ms.p50),
                step_p99: ratio(lb.step_latency_ms.p99, la.step_latency_ms.p99),
                request_p50: ratio(lb.request_latency_ms.p50, la.request_latency_ms.p50),
                request_p99: ratio(lb.request_latency_ms.p99, la.request_latency_ms.p99),
            });
        }
    }

    /// The human-readable report.
    pub fn to_text(&self) -> String {
        let mut o = String::new();
        let _ = writeln!(
            o,
            "dynaserve-loadtest {} | mode {} | {} | {} cores",
            self.version, self.mode, self.load, self.cores
        );
        for side in &self.sides {
            let _ = writeln!(o);
            let _ = writeln!(
                o,
                "== {}: {} {} (model {}){}",
                side.label,
                side.transport,
                side.target,
                if side.model.is_empty() {
                    "?"
                } else {
                    &side.model
                },
                side.spawned
                    .as_ref()
                    .map(|c| format!("\n   spawned: {c}"))
                    .unwrap_or_default()
            );
            if side.levels.len() == 1 {
                o.push_str(&level_detail(&side.levels[0]));
            } else {
                o.push_str(&level_table(&side.levels));
            }
            for n in &side.notes {
                let _ = writeln!(o, "note: {n}");
            }
        }
        if !self.comparison.is_empty() {
            let (a, b) = (&self.sides[0].label, &self.sides[1].label);
            let _ = writeln!(o);
            let _ = writeln!(o, "== comparison: {b} / {a}");
            let _ = writeln!(
                o,
                "{:>6} {:>12} {:>12} {:>12} {:>12} {:>12}",
                "level", "throughput", "step p50", "step p99", "req p50", "req p99"
            );
            for r in &self.comparison {
                let _ = writeln!(
                    o,
                    "{:>6} {:>11.2}x {:>11.2}x {:>11.2}x {:>11.2}x {:>11.2}x",
                    r.concurrency,
                    r.throughput,
                    r.step_p50,
                    r.step_p99,
                    r.request_p50,
                    r.request_p99
                );
            }
        }
        o
    }
}

fn latency_row(o: &mut String, name: &str, s: &Summary) {
    if s.count == 0 {
        let _ = writeln!(o, "  {name:<22} -");
        return;
    }
    let _ = writeln!(
        o,
        "  {name:<22} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>8}",
        s.p50, s.p90, s.p99, s.max, s.mean, s.count
    );
}

fn errors_line(r: &Report) -> String {
    if r.errors.is_empty() {
        return "none".into();
    }
    r.errors
        .iter()
        .map(|(k, v)| format!("{k} x{v}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Detailed block for a single level.
pub fn level_detail(r: &Report) -> String {
    let mut o = String::new();
    let q = &r.requests;
    let _ = writeln!(
        o,
        "  window {:.2} s{} | requests: {} sent, {} ok, {} failed, {} cut{}",
        r.duration_s,
        if r.interrupted {
            " (interrupted: partial)"
        } else {
            ""
        },
        q.started,
        q.ok,
        q.failed,
        q.cut,
        if q.skipped > 0 {
            format!(", {} arrivals skipped (in-flight limit)", q.skipped)
        } else {
            String::new()
        }
    );
    if let Some(rate) = r.offered_rate {
        let _ = writeln!(o, "  offered rate {rate:.2} req/s");
    }
    let _ = writeln!(
        o,
        "  frames {}{} | throughput {:.1} scene-steps/s, {:.1} object-steps/s, {:.2} req/s",
        r.frames,
        r.expected_frames
            .map(|e| format!(" of {e}"))
            .unwrap_or_default(),
        r.throughput.scene_steps_per_s,
        r.throughput.object_steps_per_s,
        r.throughput.requests_per_s
    );
    let _ = writeln!(
        o,
        "  {:<22} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8}",
        "latency (ms)", "p50", "p90", "p99", "max", "mean", "n"
    );
    latency_row(&mut o, "step (between frames)", &r.step_latency_ms);
    latency_row(&mut o, "first frame", &r.first_frame_ms);
    latency_row(&mut o, "request", &r.request_latency_ms);
    latency_row(&mut o, "server queue", &r.server_queue_ms);
    latency_row(&mut o, "server forward", &r.server_forward_ms);
    if r.frame_batch_scenes.count > 0 {
        let s = &r.frame_batch_scenes;
        let _ = writeln!(
            o,
            "  batch scenes per frame: mean {:.1}, p50 {}, p99 {}, max {}",
            s.mean, s.p50, s.p99, s.max
        );
    }
    let _ = writeln!(o, "  errors: {}", errors_line(r));
    for e in &r.error_examples {
        let _ = writeln!(o, "    e.g. {e}");
    }
    match (&r.server, &r.server_metrics_error) {
        (Some(s), _) => {
            let _ = writeln!(
                o,
                "  server /metrics: {} batches, {} scene-steps, {} object-steps",
                s.batches, s.scene_steps, s.object_steps
            );
            let b = &s.batch_scenes;
            let _ = writeln!(
                o,
                "    scenes/batch   mean {:.2}, p50 <= {}, p90 <= {}, p99 <= {}",
                b.mean, b.p50, b.p90, b.p99
            );
            let _ = writeln!(
                o,
                "      histogram: {}",
                b.buckets
                    .iter()
                    .map(|(lo, hi, c)| match hi {
                        Some(hi) => format!("({lo},{hi}]:{c}"),
                        None => format!(">{lo}:{c}"),
                    })
                    .collect::<Vec<_>>()
                    .join(" ")
            );
            let b = &s.batch_objects;
            let _ = writeln!(
                o,
                "    objects/batch  mean {:.1}, p50 <= {}, p99 <= {}",
                b.mean, b.p50, b.p99
            );
            for (p, h) in &s.queue_wait_ms {
                let _ = writeln!(
                    o,
                    "    queue wait {p} (ms) mean {:.3}, p50 ~{:.3}, p90 ~{:.3}, p99 ~{:.3} ({} steps)",
                    h.mean, h.p50, h.p90, h.p99, h.count
                );
            }
            let f = &s.forward_ms;
            let _ = writeln!(
                o,
                "    forward (ms)   mean {:.2}, p50 ~{:.2}, p99 ~{:.2}",
                f.mean, f.p50, f.p99
            );
            if !s.dropped_steps.is_empty() || !s.failures.is_empty() {
                let _ = writeln!(
                    o,
                    "    server-side failures {:?}, dropped steps {:?}",
                    s.failures, s.dropped_steps
                );
            }
        }
        (None, Some(e)) => {
            let _ = writeln!(o, "  server /metrics: not available ({e})");
        }
        (None, None) => {}
    }
    o
}

/// One row per level.
pub fn level_table(levels: &[Report]) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "  {:>5} {:>11} {:>12} {:>7} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>7} {:>6}",
        "conc",
        "scn-steps/s",
        "obj-steps/s",
        "req/s",
        "step p50",
        "p90",
        "p99",
        "max",
        "1st p50",
        "req p99",
        "batch",
        "errors"
    );
    for r in levels {
        let batch = r
            .server
            .as_ref()
            .map(|s| format!("{:.1}", s.batch_scenes.mean))
            .unwrap_or_else(|| format!("{:.1}", r.frame_batch_scenes.mean));
        let _ = writeln!(
            o,
            "  {:>5} {:>11.1} {:>12.1} {:>7.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.1} {:>7} {:>6}{}",
            r.concurrency,
            r.throughput.scene_steps_per_s,
            r.throughput.object_steps_per_s,
            r.throughput.requests_per_s,
            r.step_latency_ms.p50,
            r.step_latency_ms.p90,
            r.step_latency_ms.p99,
            r.step_latency_ms.max,
            r.first_frame_ms.p50,
            r.request_latency_ms.p99,
            batch,
            r.requests.failed,
            if r.interrupted { " (interrupted)" } else { "" }
        );
    }
    let errs: BTreeMap<&String, u64> =
        levels
            .iter()
            .flat_map(|r| r.errors.iter())
            .fold(BTreeMap::new(), |mut m, (k, v)| {
                *m.entry(k).or_insert(0) += v;
                m
            });
    if !errs.is_empty() {
        let _ = writeln!(o, "  errors: {errs:?}");
    }
    let _ = writeln!(
        o,
        "  (latencies in ms; step = time between frames of one stream; batch = mean scenes per forward pass)"
    );
    o
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// One SVG line chart: x = concurrency (log2 axis), one polyline per series.
fn svg_chart(title: &str, y_label: &str, series: &[(String, Vec<(f64, f64)>)]) -> String {
    const W: f64 = 560.0;
    const H: f64 = 320.0;
    const L: f64 = 70.0;
    const R: f64 = 20.0;
    const T: f64 = 30.0;
    const B: f64 = 50.0;
    const COLOURS: [&str; 4] = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd"];
    let pts: Vec<(f64, f64)> = series.iter().flat_map(|s| s.1.iter().copied()).collect();
    let xs: Vec<f64> = pts.iter().map(|p| p.0.max(1.0).log2()).collect();
    let (x0, x1) = xs
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let (x0, x1) = if x0.is_finite() && x1 > x0 {
        (x0, x1)
    } else {
        (x0.min(0.0), x0.max(0.0) + 1.0)
    };
    let y1 = pts
        .iter()
        .map(|p| p.1)
        .filter(|y| y.is_finite())
        .fold(0.0f64, f64::max)
        .max(1e-9)
        * 1.1;
    let sx = |x: f64| L + (x.max(1.0).log2() - x0) / (x1 - x0) * (W - L - R);
    let sy = |y: f64| H - B - y / y1 * (H - T - B);
    let mut o = String::new();
    let _ = write!(
        o,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">"#
    );
    let _ = write!(
        o,
        r#"<text x="{}" y="18" text-anchor="middle" font-size="14">{}</text>"#,
        W / 2.0,
        esc(title)
    );
    let _ = write!(
        o,
        r##"<line x1="{L}" y1="{}" x2="{}" y2="{}" stroke="#000"/><line x1="{L}" y1="{T}" x2="{L}" y2="{}" stroke="#000"/>"##,
        H - B,
        W - R,
        H - B,
        H - B
    );
    for k in 0..=4 {
        let y = y1 * f64::from(k) / 4.0;
        let _ = write!(
            o,
            r##"<line x1="{L}" y1="{0}" x2="{1}" y2="{0}" stroke="#ddd"/><text x="{2}" y="{3}" text-anchor="end">{4}</text>"##,
            sy(y),
            W - R,
            L - 6.0,
            sy(y) + 4.0,
            if y1 >= 100.0 {
                format!("{y:.0}")
            } else {
                format!("{y:.2}")
            }
        );
    }
    let mut ticks: Vec<f64> = pts.iter().map(|p| p.0).collect();
    ticks.sort_by(f64::total_cmp);
    ticks.dedup();
    for x in ticks {
        let _ = write!(
            o,
            r#"<text x="{}" y="{}" text-anchor="middle">{x}</text>"#,
            sx(x),
            H - B + 16.0
        );
    }
    let _ = write!(
        o,
        r#"<text x="{}" y="{}" text-anchor="middle">concurrency (streams)</text><text x="16" y="{}" transform="rotate(-90 16 {})" text-anchor="middle">{}</text>"#,
        (L + W - R) / 2.0,
        H - 12.0,
        (T + H - B) / 2.0,
        (T + H - B) / 2.0,
        esc(y_label)
    );
    for (i, (name, p)) in series.iter().enumerate() {
        let c = COLOURS[i % COLOURS.len()];
        let line: Vec<String> = p
            .iter()
            .filter(|q| q.1.is_finite())
            .map(|&(x, y)| format!("{:.1},{:.1}", sx(x), sy(y)))
            .collect();
        let _ = write!(
            o,
            r#"<polyline fill="none" stroke="{c}" stroke-width="2" points="{}"/>"#,
            line.join(" ")
        );
        for &(x, y) in p.iter().filter(|q| q.1.is_finite()) {
            let _ = write!(
                o,
                r#"<circle cx="{:.1}" cy="{:.1}" r="3" fill="{c}"><title>{name}: {x} -> {y:.2}</title></circle>"#,
                sx(x),
                sy(y)
            );
        }
        let _ = write!(
            o,
            r#"<rect x="{}" y="{}" width="10" height="10" fill="{c}"/><text x="{}" y="{}">{}</text>"#,
            L + 10.0,
            T + 4.0 + 16.0 * i as f64,
            L + 26.0,
            T + 13.0 + 16.0 * i as f64,
            esc(name)
        );
    }
    o.push_str("</svg>");
    o
}

/// A self-contained HTML page with inline SVG charts of throughput and p99 step latency (and
/// p99 request latency) against concurrency, one line per side, plus the text report.
pub fn to_html(run: &RunReport) -> String {
    let series = |f: &dyn Fn(&Report) -> f64| -> Vec<(String, Vec<(f64, f64)>)> {
        run.sides
            .iter()
            .map(|s| {
                (
                    format!("{} ({})", s.label, s.transport),
                    s.levels
                        .iter()
                        .map(|r| (r.concurrency as f64, f(r)))
                        .collect(),
                )
            })
            .collect()
    };
    let mut o = String::from(
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>dynaserve-loadtest</title></head><body style=\"font-family:sans-serif\">",
    );
    let _ = write!(
        o,
        "<h2>dynaserve-loadtest: {}</h2><p>{}</p>",
        esc(&run.mode),
        esc(&run.load)
    );
    o.push_str(&svg_chart(
        "Throughput",
        "scene-steps/s",
        &series(&|r| r.throughput.scene_steps_per_s),
    ));
    o.push_str(&svg_chart(
        "p99 step latency (between frames)",
        "ms",
        &series(&|r| r.step_latency_ms.p99),
    ));
    o.push_str(&svg_chart(
        "p99 request latency",
        "ms",
        &series(&|r| r.request_latency_ms.p99),
    ));
    let _ = writeln!(o, "<pre>{}</pre></body></html>", esc(&run.to_text()));
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level(c: usize, tput: f64, p99: f64) -> Report {
        Report {
            concurrency: c,
            throughput: Throughput {
                scene_steps_per_s: tput,
                ..Default::default()
            },
            step_latency_ms: Summary {
                count: 10,
                p50: p99 / 2.0,
                p99,
                ..Default::default()
            },
            ..Default::default()
        }
    }

    #[test]
    fn ratios_text_and_html() {
        let mut run = RunReport {
            mode: "streams".into(),
            sides: vec![
                SideReport {
                    label: "A".into(),
                    levels: vec![level(1, 100.0, 10.0), level(8, 400.0, 20.0)],
                    ..Default::default()
                },
                SideReport {
                    label: "B".into(),
                    levels: vec![level(1, 50.0, 20.0), level(8, 100.0, 80.0)],
                    ..Default::default()
                },
            ],
            ..Default::default()
        };
        run.compute_ratios();
        assert_eq!(run.comparison.len(), 2);
        assert_eq!(run.comparison[1].throughput, 0.25);
        assert_eq!(run.comparison[1].step_p99, 4.0);
        let text = run.to_text();
        assert!(text.contains("comparison: B / A"), "{text}");
        assert!(text.contains("0.25x"), "{text}");
        let html = to_html(&run);
        assert!(html.starts_with("<!DOCTYPE html>") && html.contains("<svg"));
        assert_eq!(html.matches("<polyline").count(), 6);
    }

    #[test]
    fn server_stats_from_two_scrapes() {
        let before = "dynaserve_batch_scenes_bucket{model=\"m\",le=\"1\"} 1\n\
            dynaserve_batch_scenes_bucket{model=\"m\",le=\"+Inf\"} 1\n\
            dynaserve_batch_scenes_sum{model=\"m\"} 1\ndynaserve_batch_scenes_count{model=\"m\"} 1\n";
        let after = "dynaserve_batch_scenes_bucket{model=\"m\",le=\"1\"} 1\n\
            dynaserve_batch_scenes_bucket{model=\"m\",le=\"+Inf\"} 3\n\
            dynaserve_batch_scenes_sum{model=\"m\"} 9\ndynaserve_batch_scenes_count{model=\"m\"} 3\n";
        // Missing histograms are an error naming the metric.
        let e = ServerStats::from_scrapes(before, after).unwrap_err();
        assert!(e.contains("dynaserve_batch_objects"), "{e}");
        let add = |t: &str, steps: u32| {
            let mut s = format!("{t}dynaserve_scene_steps_total{{model=\"m\"}} {steps}\n");
            for name in [
                "dynaserve_batch_objects",
                "dynaserve_forward_duration_seconds",
            ] {
                s.push_str(&t.replace("dynaserve_batch_scenes", name));
            }
            s
        };
        let s = ServerStats::from_scrapes(&add(before, 1), &add(after, 9)).unwrap();
        assert_eq!(s.batches, 2.0);
        assert_eq!(s.batch_scenes.mean, 4.0);
        assert_eq!(s.scene_steps, 8.0);
        assert_eq!(s.batch_scenes.buckets, vec![(1.0, None, 2.0)]);
    }
}
