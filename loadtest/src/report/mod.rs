//! Report types (serialised with `--json`) and the A/B comparison; the human-readable tables
//! are in `text`, the self-contained HTML chart in `html`, the soak's section in `soak`.

mod html;
mod soak;
mod text;

pub use html::to_html;
pub use soak::{SoakCounts, SoakReport};
pub use text::{level_detail, level_table};

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
    /// The soak's checks and memory record (`soak` mode only).
    pub soak: Option<SoakReport>,
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
