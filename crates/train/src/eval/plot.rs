//! Error against horizon as a PNG: translation RMSE (m) and orientation RMSE (deg) against
//! time after the start frame, one line per (predictor, step size).

use std::path::Path;

use plotters::prelude::*;

use super::{EvalError, EvalReport};

/// One line of the figure: a report's curve at one step size.
struct Line {
    name: String,
    /// `(time s, translation m, orientation deg)`.
    points: Vec<(f64, f64, f64)>,
    color: RGBColor,
    dashed: bool,
}

const MODEL_COLORS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(23, 190, 207),
    RGBColor(188, 189, 34),
    RGBColor(140, 86, 75),
];
const BASELINE_COLORS: [RGBColor; 3] = [
    RGBColor(127, 127, 127),
    RGBColor(214, 39, 40),
    RGBColor(255, 127, 14),
];

fn plot_err(e: impl std::fmt::Display) -> EvalError {
    EvalError::Invalid(format!("plot: {e}"))
}

/// How an entry of [`plot_errors`] is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlotStyle {
    /// One solid line per step size.
    EveryStepSize,
    /// One solid line, at the smallest step size.
    SmallestStepSize,
    /// One dashed line at the smallest step size (baselines barely depend on it).
    Baseline,
}

/// Draws error against time for every entry `(label, report, style)` into a 1200 x 520 PNG at
/// `path`: translation RMSE (m) on the left, orientation RMSE (deg) on the right, against the
/// time after the start frame (s), from each report's curve.
pub fn plot_errors(
    path: &Path,
    title: &str,
    entries: &[(&str, &EvalReport, PlotStyle)],
) -> Result<(), EvalError> {
    let mut lines = Vec::new();
    let (mut model_color, mut baseline_color) = (0, 0);
    for (label, report, style) in entries {
        let mut sizes: Vec<_> = report.step_sizes.iter().collect();
        sizes.sort_by_key(|k| k.dt_steps);
        if *style != PlotStyle::EveryStepSize {
            sizes.truncate(1);
        }
        for k in sizes {
            let color = if *style == PlotStyle::Baseline {
                baseline_color += 1;
                BASELINE_COLORS[(baseline_color - 1) % BASELINE_COLORS.len()]
            } else {
                model_color += 1;
                MODEL_COLORS[(model_color - 1) % MODEL_COLORS.len()]
            };
            lines.push(Line {
                name: format!("{label} k={}", k.dt_steps),
                points: k
                    .curve
                    .iter()
                    .map(|c| (c.time_s, c.translation_rmse_m, c.orientation_rmse_deg))
                    .collect(),
                color,
                dashed: *style == PlotStyle::Baseline,
            });
        }
    }
    lines.retain(|l| !l.points.is_empty());
    if lines.is_empty() {
        return Err(EvalError::Invalid(
            "plot: no curve to draw (no step inside the data)".into(),
        ));
    }
    let max = |f: &dyn Fn(&(f64, f64, f64)) -> f64| {
        lines
            .iter()
            .flat_map(|l| l.points.iter().map(f))
            .filter(|v| v.is_finite())
            .fold(0.0f64, f64::max)
    };
    let t_max = max(&|p| p.0).max(1e-3);
    let tr_max = max(&|p| p.1).max(1e-6) * 1.05;
    let rot_max = max(&|p| p.2).max(1e-6) * 1.05;

    let root = BitMapBackend::new(path, (1200, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let root = root.titled(title, ("sans-serif", 22)).map_err(plot_err)?;
    let panels = root.split_evenly((1, 2));
    // Translation grows steadily (legend top left); orientation saturates (legend bottom right).
    for (panel, (y_label, y_max, pick, legend)) in panels.iter().zip([
        (
            "translation RMSE (m)",
            tr_max,
            (|p: &(f64, f64, f64)| p.1) as fn(&(f64, f64, f64)) -> f64,
            SeriesLabelPosition::UpperLeft,
        ),
        (
            "orientation RMSE (deg)",
            rot_max,
            |p: &(f64, f64, f64)| p.2,
            SeriesLabelPosition::LowerRight,
        ),
    ]) {
        let mut chart = ChartBuilder::on(panel)
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(64)
            .build_cartesian_2d(0.0..t_max, 0.0..y_max)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc("time after the start frame (s)")
            .y_desc(y_label)
            .draw()
            .map_err(plot_err)?;
        for l in &lines {
            let pts: Vec<(f64, f64)> = l
                .points
                .iter()
                .map(|p| (p.0, pick(p)))
                .filter(|p| p.1.is_finite())
                .collect();
            let style = l.color.stroke_width(2);
            let c = l.color;
            if l.dashed {
                chart
                    .draw_series(DashedLineSeries::new(pts, 8, 5, style))
                    .map_err(plot_err)?
                    .label(l.name.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c));
            } else {
                chart
                    .draw_series(LineSeries::new(pts, style))
                    .map_err(plot_err)?
                    .label(l.name.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c));
            }
        }
        chart
            .configure_series_labels()
            .position(legend)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .draw()
            .map_err(plot_err)?;
    }
    root.present().map_err(plot_err)?;
    Ok(())
}
