//! The self-contained HTML page of a run: inline SVG charts of throughput and p99 step latency
//! against concurrency, one line per side.

use std::fmt::Write as _;

use super::{Report, RunReport};

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
