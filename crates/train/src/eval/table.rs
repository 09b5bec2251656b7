//! The plain-text table of one report (what `dynaserve eval` prints).

use super::EvalReport;

fn fmt_metric(v: Option<f64>, decimals: usize) -> String {
    match v {
        Some(x) => format!("{x:.decimals$}"),
        None => "-".to_string(),
    }
}

/// The report as a plain-text table: one row per horizon, translation RMSE (m) and
/// orientation RMSE (deg) per step size as columns, missing entries as `-` with the reasons
/// listed below the table.
pub fn format_table(report: &EvalReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let source = match &report.dataset {
        Some(d) => format!(
            "{} ({} split, seed {}, {})",
            d.generator, d.split, d.seed, d.dir
        ),
        None => "in-memory scenes".to_string(),
    };
    let _ = writeln!(s, "predictor: {}   data: {source}", report.predictor);
    let _ = writeln!(
        s,
        "{} scenes, {} objects, {} frames of {:.4} s; observed frames s-k and s = {}; {}",
        report.scenes,
        report.objects,
        report.frames,
        report.dt_frame,
        report.start_frame,
        report.pooling
    );
    let mut header = format!("{:<18}", "horizon");
    for k in &report.step_sizes {
        let _ = write!(
            header,
            " | {:>11} {:>11}",
            format!("k={} trans m", k.dt_steps),
            format!("k={} rot deg", k.dt_steps)
        );
    }
    let _ = writeln!(s, "{header}");
    let _ = writeln!(s, "{}", "-".repeat(header.len()));
    let rows = report
        .step_sizes
        .first()
        .map(|k| k.horizons.len())
        .unwrap_or(0);
    for r in 0..rows {
        let h = &report.step_sizes[0].horizons[r];
        let label = match h.frames {
            Some(f) => format!("{} s ({f} fr)", h.horizon_s),
            None => format!("{} s", h.horizon_s),
        };
        let mut line = format!("{label:<18}");
        for k in &report.step_sizes {
            let e = &k.horizons[r];
            let _ = write!(
                line,
                " | {:>11} {:>11}",
                fmt_metric(e.translation_rmse_m, 4),
                fmt_metric(e.orientation_rmse_deg, 2)
            );
        }
        let _ = writeln!(s, "{line}");
    }
    write_missing_horizons(&mut s, report);
    s
}

/// Appends the horizons `report` could not score, with the reason, to a text report.
pub(crate) fn write_missing_horizons(s: &mut String, report: &EvalReport) {
    use std::fmt::Write;
    let mut notes = Vec::new();
    for k in &report.step_sizes {
        for h in &k.horizons {
            if let Some(why) = &h.missing {
                notes.push(format!("  k={} at {} s: {why}", k.dt_steps, h.horizon_s));
            }
        }
    }
    if !notes.is_empty() {
        let _ = writeln!(s, "missing (never shifted to another frame):");
        for n in notes {
            let _ = writeln!(s, "{n}");
        }
    }
}
