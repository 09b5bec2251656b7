//! `dynaserve sim preview` on a mesh split: the scene seen from the side inside its box
//! (vertex-mean paths, outlines at the first and last frame), and one object's wireframe at six
//! frames (five evenly spaced and the most deformed one), each moved by its best rigid fit onto
//! frame 0 and drawn over the frame-0 shape (grey), so that what differs is deformation; each
//! panel gives the RMS distance left.
//!
//! The object drawn is the one whose edges stretch most (an elastic one when there is any).
//! Text needs a system font; without one the figure is drawn without text.

use std::path::Path;

use plotters::coord::types::RangedCoordf32;
use plotters::prelude::*;

use super::record::MeshScene;
use super::stats::{max_edge_strain, rigid_fit_to_first_frame, vertex_mean};
use crate::preview::{DrawResult, canvas, draw_with_text_fallback};
use crate::{Result, SimError};

type Chart<'a> = ChartContext<'a, BitMapBackend<'a>, Cartesian2d<RangedCoordf32, RangedCoordf32>>;

/// Draws `object`'s edges (x, z) with its vertices at `xs` (indexed from the object's first
/// vertex), shifted by `-shift`.
fn wire_at(
    chart: &mut Chart<'_>,
    scene: &MeshScene,
    object: usize,
    xs: &[[f32; 3]],
    shift: [f32; 3],
    style: ShapeStyle,
) -> DrawResult {
    // One segment per edge; zero-length segments (edges seen end-on) are skipped, as thick
    // lines through them would be drawn as spikes.
    let mut edges: Vec<(u32, u32)> = scene
        .object_faces(object)
        .iter()
        .flat_map(|f| (0..3).map(move |k| (f[k].min(f[(k + 1) % 3]), f[k].max(f[(k + 1) % 3]))))
        .collect();
    edges.sort_unstable();
    edges.dedup();
    let at = |v: u32| {
        let p = xs[v as usize];
        (p[0] - shift[0], p[2] - shift[2])
    };
    let segments = edges.into_iter().filter_map(|(a, b)| {
        let (pa, pb) = (at(a), at(b));
        let long = (pa.0 - pb.0).abs() + (pa.1 - pb.1).abs() > 1e-5;
        long.then(|| PathElement::new(vec![pa, pb], style))
    });
    chart.draw_series(segments).map_err(|e| e.to_string())?;
    Ok(())
}

fn wire(
    chart: &mut Chart<'_>,
    scene: &MeshScene,
    object: usize,
    t: usize,
    shift: [f32; 3],
    style: ShapeStyle,
) -> DrawResult {
    let xs: Vec<[f32; 3]> = scene.objects[object]
        .vertices
        .clone()
        .map(|v| scene.position(v, t))
        .collect();
    wire_at(chart, scene, object, &xs, shift, style)
}

fn draw(
    scene: &MeshScene,
    object: usize,
    bounds: [[f32; 3]; 2],
    title: &str,
    out: &Path,
    text: bool,
) -> DrawResult {
    let root = canvas(out, (1500, 760), title, text)?;
    let (left, right) = root.split_horizontally(620);
    let last = scene.frames - 1;
    let mut side = ChartBuilder::on(&left);
    side.margin(15)
        .x_label_area_size(if text { 35 } else { 0 })
        .y_label_area_size(if text { 45 } else { 0 });
    if text {
        side.caption(
            "side view (x, z), m: paths, first (light) and last frame",
            ("sans-serif", 16),
        );
    }
    let mut side = side
        .build_cartesian_2d(bounds[0][0]..bounds[1][0], bounds[0][2]..bounds[1][2])
        .map_err(|e| e.to_string())?;
    if text {
        side.configure_mesh().draw().map_err(|e| e.to_string())?;
    }
    for (i, _) in scene.objects.iter().enumerate() {
        let c = Palette99::pick(i).to_rgba();
        wire(&mut side, scene, i, 0, [0.0; 3], c.mix(0.3).stroke_width(1))?;
        wire(&mut side, scene, i, last, [0.0; 3], c.stroke_width(2))?;
        side.draw_series(LineSeries::new(
            (0..scene.frames).map(|t| {
                let m = vertex_mean(scene, i, t);
                (m[0], m[2])
            }),
            c.stroke_width(1),
        ))
        .map_err(|e| e.to_string())?;
    }
    // Six frames of the chosen object, rigidly aligned onto frame 0, same scale everywhere.
    // Five frames evenly spaced and the most deformed one.
    let fits = (0..scene.frames)
        .map(|t| rigid_fit_to_first_frame(scene, object, t).map_err(|e| e.to_string()))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    let worst = (0..scene.frames)
        .max_by(|&a, &b| fits[a].1.total_cmp(&fits[b].1))
        .unwrap_or(0);
    let mut frames: Vec<usize> = (0..5).map(|k| k * last / 4).collect();
    frames.push(worst);
    frames.sort_unstable();
    frames.dedup();
    let aligned: Vec<&(Vec<[f32; 3]>, f64)> = frames.iter().map(|&t| &fits[t]).collect();
    let m0 = vertex_mean(scene, object, 0);
    let half = aligned
        .iter()
        .flat_map(|(xs, _)| xs.iter())
        .map(|p| (p[0] - m0[0]).abs().max((p[2] - m0[2]).abs()))
        .fold(0.01f32, f32::max)
        * 1.15;
    let panels = right.split_evenly((2, 3));
    let c = Palette99::pick(object).to_rgba();
    for ((panel, &t), (xs, rms)) in panels.iter().zip(&frames).zip(&aligned) {
        let mut ch = ChartBuilder::on(panel);
        ch.margin(8);
        if text {
            ch.caption(
                format!(
                    "object {object} ({}), frame {t} ({:.2} s): {:.1} mm",
                    scene.objects[object].material.name(),
                    t as f32 * scene.dt_frame,
                    1e3 * rms
                ),
                ("sans-serif", 14),
            );
        }
        let mut ch = ch
            .build_cartesian_2d(-half..half, -half..half)
            .map_err(|e| e.to_string())?;
        wire(
            &mut ch,
            scene,
            object,
            0,
            m0,
            RGBColor(190, 190, 190).stroke_width(3),
        )?;
        wire_at(&mut ch, scene, object, xs, m0, c.stroke_width(2))?;
    }
    root.present().map_err(|e| e.to_string())
}

/// Draws scene `scene` into a PNG at `out` (see the module docs). Returns the object drawn in
/// the frame panels and whether text could be drawn.
pub fn write_mesh_preview(
    scene: &MeshScene,
    bounds: [[f32; 3]; 2],
    title: &str,
    out: &Path,
) -> Result<(usize, bool)> {
    if scene.objects.is_empty() || scene.frames == 0 {
        return Err(SimError::Invalid("scene has no object to preview".into()));
    }
    let object = (0..scene.objects.len())
        .map(|i| (i, max_edge_strain(scene, i)))
        .fold((0, -1.0), |best, x| if x.1 > best.1 { x } else { best })
        .0;
    let with_text =
        draw_with_text_fallback(out, |text| draw(scene, object, bounds, title, out, text))?;
    Ok((object, with_text))
}
