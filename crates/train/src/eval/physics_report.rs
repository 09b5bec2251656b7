//! Text and Markdown renderings of a [`PhysicsSuiteReport`]: the scenario figures (rapier next
//! to every predictor) and the one-step error table by contact regime.

use std::fmt::Write;

use super::physics_suite::{FigureStat, PhysicsSuiteReport};

fn stat_cell(s: &FigureStat, samples: u64, decimals: usize) -> String {
    let met = s
        .met
        .map(|m| format!(" ({m}/{samples} met)"))
        .unwrap_or_default();
    format!("{:.d$} / {:.d$}{met}", s.mean, s.max, d = decimals)
}

fn decimals(unit: &str) -> usize {
    match unit {
        "deg" | "kg m/s" => 2,
        _ => 4,
    }
}

fn opt(v: Option<f64>, decimals: usize) -> String {
    v.map(|x| format!("{x:.decimals$}"))
        .unwrap_or_else(|| "-".into())
}

/// The figure table: header and rows of cells.
fn figure_table(r: &PhysicsSuiteReport) -> (Vec<String>, Vec<Vec<String>>) {
    let mut header: Vec<String> = ["scenario", "group", "figure", "unit", "n", "rapier"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    header.extend(r.predictors.iter().map(|p| p.label.clone()));
    header.push("target".into());
    let rows = r
        .figures
        .iter()
        .map(|f| {
            let d = decimals(&f.unit);
            let mut row = vec![
                f.scenario.clone(),
                f.group.clone(),
                f.figure.clone(),
                f.unit.clone(),
                f.samples.to_string(),
                f.rapier
                    .as_ref()
                    .map(|s| stat_cell(s, f.samples, d))
                    .unwrap_or_else(|| "-".into()),
            ];
            row.extend(f.predictors.iter().map(|s| stat_cell(s, f.samples, d)));
            row.push(f.target.clone().unwrap_or_else(|| "-".into()));
            row
        })
        .collect();
    (header, rows)
}

/// The regime table: header and rows of cells.
fn regime_table(r: &PhysicsSuiteReport) -> (Vec<String>, Vec<Vec<String>>) {
    let mut header: Vec<String> = vec!["regime".into(), "k".into(), "count".into()];
    header.extend(
        r.predictors
            .iter()
            .map(|p| format!("{} (m / deg)", p.label)),
    );
    let ratios = r
        .regimes
        .iter()
        .any(|row| row.ballistic_over_model.is_some());
    if ratios {
        header.push("ballistic / model".into());
    }
    let rows = r
        .regimes
        .iter()
        .map(|row| {
            let mut cells = vec![
                row.regime.name().to_string(),
                row.k.to_string(),
                row.count.to_string(),
            ];
            cells.extend(row.predictors.iter().map(|c| {
                format!(
                    "{} / {}",
                    opt(c.translation_rmse_m, 4),
                    opt(c.orientation_rmse_deg, 2)
                )
            }));
            if ratios {
                cells.push(match row.ballistic_over_model {
                    Some([t, o]) => format!("{} / {}", opt(t, 2), opt(o, 2)),
                    None => "-".into(),
                });
            }
            cells
        })
        .collect();
    (header, rows)
}

fn aligned(out: &mut String, header: &[String], rows: &[Vec<String>]) {
    let widths: Vec<usize> = (0..header.len())
        .map(|c| {
            rows.iter()
                .map(|r| r[c].chars().count())
                .chain([header[c].chars().count()])
                .max()
                .unwrap_or(0)
        })
        .collect();
    for row in std::iter::once(header).chain(rows.iter().map(|r| r.as_slice())) {
        let line: Vec<String> = row
            .iter()
            .zip(&widths)
            .map(|(cell, w)| format!("{cell:<w$}"))
            .collect();
        let _ = writeln!(out, "  {}", line.join("  ").trim_end());
    }
}

fn markdown(out: &mut String, header: &[String], rows: &[Vec<String>]) {
    let _ = writeln!(out, "| {} |", header.join(" | "));
    let _ = writeln!(out, "|{}", " --- |".repeat(header.len()));
    for row in rows {
        let _ = writeln!(out, "| {} |", row.join(" | "));
    }
}

fn preamble(r: &PhysicsSuiteReport) -> Vec<String> {
    let total: u64 = r.scenes.iter().map(|c| c.scenes).sum();
    let groups: Vec<String> = r
        .scenes
        .iter()
        .map(|c| {
            if c.variant.is_empty() {
                format!("{} {}", c.scenario, c.scenes)
            } else {
                format!("{}/{} {}", c.scenario, c.variant, c.scenes)
            }
        })
        .collect();
    let predictors: Vec<String> = r
        .predictors
        .iter()
        .map(|p| format!("{} = {}", p.label, p.name))
        .collect();
    vec![
        format!(
            "physics suite on {}: {total} scenes ({})",
            r.source,
            groups.join(", ")
        ),
        format!("predictors: {}", predictors.join("; ")),
    ]
}

fn figures_caption(r: &PhysicsSuiteReport) -> String {
    format!(
        "Scenario figures: k = 1 rollout from frames {} and {} to the last frame; mean / max \
         over the samples (scenes; objects for slide), (met) = samples meeting the target",
        r.options.start_frame - 1,
        r.options.start_frame
    )
}

fn regimes_caption(r: &PhysicsSuiteReport) -> String {
    let which = match r.options.window_stride {
        0 | 1 => "every window".to_string(),
        n => format!("every {n}th window"),
    };
    format!(
        "One-step error by ground-truth regime of the window t -> t+k ({which}): translation \
         RMSE m / orientation RMSE deg; contact within {:.0} mm plus the cloud spacing, resting \
         below {} m/s and {} deg/s",
        1e3 * r.contact_distance_m,
        r.resting_thresholds[0],
        r.resting_thresholds[1]
    )
}

/// The report as aligned text for a terminal.
pub fn format_physics_text(r: &PhysicsSuiteReport) -> String {
    let mut out = String::new();
    for line in preamble(r) {
        let _ = writeln!(out, "{line}");
    }
    let _ = writeln!(out, "\n{}", figures_caption(r));
    let (h, rows) = figure_table(r);
    aligned(&mut out, &h, &rows);
    let _ = writeln!(out, "\n{}", regimes_caption(r));
    let (h, rows) = regime_table(r);
    aligned(&mut out, &h, &rows);
    out
}

/// The report as Markdown tables (for model cards).
pub fn format_physics_markdown(r: &PhysicsSuiteReport) -> String {
    let mut out = String::from("## Physics scenario suite\n\n");
    for line in preamble(r) {
        let _ = writeln!(out, "{line}  ");
    }
    let _ = writeln!(out, "\n{}.\n", figures_caption(r));
    let (h, rows) = figure_table(r);
    markdown(&mut out, &h, &rows);
    let _ = writeln!(out, "\n{}.\n", regimes_caption(r));
    let (h, rows) = regime_table(r);
    markdown(&mut out, &h, &rows);
    out
}
