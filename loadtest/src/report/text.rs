//! The human-readable tables: one detailed block for a single level, one row per level for a
//! sweep.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use super::Report;
use crate::stats::Summary;

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
    if let Some(soak) = &r.soak {
        o.push_str(&soak.to_text());
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
