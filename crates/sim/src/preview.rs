//! `dynaserve sim preview`: a PNG of a few trajectories (top-down paths and height over time).
//!
//! Text (captions and axis labels) needs a system font; when none can be loaded the figure is
//! drawn without text rather than failing.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::dataset::SceneRecord;
use crate::{Result, SimError};

fn range(values: impl Iterator<Item = f32>, pad: f32) -> (f32, f32) {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for v in values {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() || !hi.is_finite() {
        return (-1.0, 1.0);
    }
    let span = (hi - lo).max(1e-3);
    (lo - pad * span, hi + pad * span)
}

/// Outcome of drawing a figure; the error is plotters' message.
pub(crate) type DrawResult = std::result::Result<(), String>;

/// A white canvas of `size` pixels drawing into the PNG `out`, with `title` on top when `text`.
pub(crate) fn canvas<'a>(
    out: &'a Path,
    size: (u32, u32),
    title: &str,
    text: bool,
) -> std::result::Result<DrawingArea<BitMapBackend<'a>, Shift>, String> {
    let root = BitMapBackend::new(out, size).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    if text {
        root.titled(title, ("sans-serif", 22))
            .map_err(|e| e.to_string())
    } else {
        Ok(root)
    }
}

/// Runs `draw(true)` (with text) and, when that fails (no usable font), `draw(false)`; returns
/// whether text was drawn, or an error giving both failures.
pub(crate) fn draw_with_text_fallback(
    out: &Path,
    draw: impl Fn(bool) -> DrawResult,
) -> Result<bool> {
    match draw(true) {
        Ok(()) => Ok(true),
        Err(first) => draw(false).map(|_| false).map_err(|e| {
            SimError::Invalid(format!(
                "cannot draw {}: {e} (with text: {first})",
                out.display()
            ))
        }),
    }
}

/// Draws a panel's axes: labelled with a light mesh when `text`, bare otherwise (fonts
/// unavailable).
fn draw_axes(
    chart: &mut ChartContext<
        '_,
        BitMapBackend<'_>,
        Cartesian2d<plotters::coord::types::RangedCoordf32, plotters::coord::types::RangedCoordf32>,
    >,
    text: bool,
    x_desc: &str,
    y_desc: &str,
) -> DrawResult {
    let mut mesh = chart.configure_mesh();
    if text {
        mesh.x_desc(x_desc).y_desc(y_desc);
    } else {
        mesh.disable_x_mesh()
            .disable_y_mesh()
            .x_labels(0)
            .y_labels(0);
    }
    mesh.draw().map_err(|e| e.to_string())
}

fn draw(scenes: &[(usize, SceneRecord)], title: &str, out: &Path, text: bool) -> DrawResult {
    let root = canvas(out, (1400, 640), title, text)?;
    let (left, right) = root.split_horizontally(640);
    let objects = || scenes.iter().flat_map(|(_, s)| s.objects.iter());
    let (x0, x1) = range(
        objects().flat_map(|o| o.positions.iter().map(|p| p[0])),
        0.05,
    );
    let (y0, y1) = range(
        objects().flat_map(|o| o.positions.iter().map(|p| p[1])),
        0.05,
    );
    // Same scale on both axes for the top-down view.
    let half = 0.5 * (x1 - x0).max(y1 - y0);
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (x0, x1, y0, y1) = (cx - half, cx + half, cy - half, cy + half);
    let label = if text { 40 } else { 0 };

    let mut top = ChartBuilder::on(&left);
    top.margin(15)
        .x_label_area_size(label)
        .y_label_area_size(label);
    if text {
        top.caption(
            "top-down path of the centre of mass (m)",
            ("sans-serif", 18),
        );
    }
    let mut top = top
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| e.to_string())?;
    draw_axes(&mut top, text, "x (m)", "y (m)")?;

    let frames = scenes
        .iter()
        .flat_map(|(_, s)| s.objects.iter().map(|o| o.positions.len()))
        .max()
        .unwrap_or(1);
    let dt = scenes.first().map(|(_, s)| s.dt_frame).unwrap_or(1.0);
    let (z0, z1) = range(
        objects().flat_map(|o| o.positions.iter().map(|p| p[2])),
        0.05,
    );
    let mut side = ChartBuilder::on(&right);
    side.margin(15)
        .x_label_area_size(label)
        .y_label_area_size(label);
    if text {
        side.caption("height of the centre of mass over time", ("sans-serif", 18));
    }
    let t_end = (frames.saturating_sub(1)) as f32 * dt;
    let mut side = side
        .build_cartesian_2d(0f32..t_end.max(dt), z0.min(0.0)..z1)
        .map_err(|e| e.to_string())?;
    draw_axes(&mut side, text, "time (s)", "z (m)")?;

    let mut colour = 0usize;
    for (_, scene) in scenes {
        for o in &scene.objects {
            let c = Palette99::pick(colour).to_rgba();
            colour += 1;
            top.draw_series(LineSeries::new(
                o.positions.iter().map(|p| (p[0], p[1])),
                c.stroke_width(2),
            ))
            .map_err(|e| e.to_string())?;
            if let (Some(a), Some(b)) = (o.positions.first(), o.positions.last()) {
                top.draw_series([
                    Circle::new((a[0], a[1]), 4, c.filled()),
                    Circle::new((b[0], b[1]), 6, c.stroke_width(2)),
                ])
                .map_err(|e| e.to_string())?;
            }
            side.draw_series(LineSeries::new(
                o.positions
                    .iter()
                    .enumerate()
                    .map(|(t, p)| (t as f32 * dt, p[2])),
                c.stroke_width(2),
            ))
            .map_err(|e| e.to_string())?;
        }
    }
    root.present().map_err(|e| e.to_string())
}

/// Draws the given scenes (index, record) into a PNG at `out`: left, top-down centre-of-mass
/// paths (filled dot at the start, ring at the end); right, centre-of-mass height over time.
/// Returns whether text could be drawn.
pub fn write_preview(scenes: &[(usize, SceneRecord)], title: &str, out: &Path) -> Result<bool> {
    if scenes.is_empty() {
        return Err(SimError::Invalid("no scene to preview".into()));
    }
    draw_with_text_fallback(out, |text| draw(scenes, title, out, text))
}
