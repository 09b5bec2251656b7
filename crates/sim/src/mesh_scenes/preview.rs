//! `dynaserve sim preview` on a mesh split: the scene seen from the side inside its box
//! (vertex-mean paths, outlines at the first and last frame), and one object's wireframe at six
//! frames, each centred on its vertex mean so that deformation (or its absence) shows.
//!
//! The object drawn is the one whose edges stretch most (an elastic one when there is any).
//! Text needs a system font; without one the figure is drawn without text.

use std::path::Path;

use plotters::coord::types::RangedCoordf32;
use plotters::prelude::*;

use super::record::MeshScene;
use super::stats::{max_edge_strain, vertex_mean};
use crate::{Result, SimError};

type Chart<'a> = ChartContext<'a, BitMapBackend<'a>, Cartesian2d<RangedCoordf32, RangedCoordf32>>;
type DrawResult = std::result::Result<(), String>;

fn wire(
    chart: &mut Chart<'_>,
    scene: &MeshScene,
    object: usize,
    t: usize,
    shift: [f32; 3],
    style: ShapeStyle,
) -> DrawResult {
    for f in &scene.faces[scene.objects[object].faces.clone()] {
        let pts: Vec<(f32, f32)> = [f[0], f[1], f[2], f[0]]
            .iter()
            .map(|&v| {
                let p = scene.position(v as usize, t);
                (p[0] - shift[0], p[2] - shift[2])
            })
            .collect();
        chart
            .draw_series(LineSeries::new(pts, style))
            .map_err(|e| e.to_string())?;
    }
    Ok(())
}

fn draw(
    scene: &MeshScene,
    object: usize,
    bounds: [[f32; 3]; 2],
    title: &str,
    out: &Path,
    text: bool,
) -> DrawResult {
    let root = BitMapBackend::new(out, (1500, 760)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let root = if text {
        root.titled(title, ("sans-serif", 22))
            .map_err(|e| e.to_string())?
    } else {
        root
    };
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
    // Six frames of the chosen object, centred on its vertex mean, same scale in every panel.
    let frames: Vec<usize> = (0..6).map(|k| k * last / 5).collect();
    let half = frames
        .iter()
        .flat_map(|&t| {
            let m = vertex_mean(scene, object, t);
            scene.objects[object]
                .vertices
                .clone()
                .map(move |v| (v, t, m))
        })
        .map(|(v, t, m)| {
            let p = scene.position(v, t);
            (p[0] - m[0]).abs().max((p[2] - m[2]).abs())
        })
        .fold(0.01f32, f32::max)
        * 1.15;
    let panels = right.split_evenly((2, 3));
    let c = Palette99::pick(object).to_rgba();
    for (panel, &t) in panels.iter().zip(&frames) {
        let mut ch = ChartBuilder::on(panel);
        ch.margin(8);
        if text {
            ch.caption(
                format!(
                    "object {object} ({}), frame {t} ({:.2} s)",
                    scene.objects[object].material.name(),
                    t as f32 * scene.dt_frame
                ),
                ("sans-serif", 14),
            );
        }
        let mut ch = ch
            .build_cartesian_2d(-half..half, -half..half)
            .map_err(|e| e.to_string())?;
        let m = vertex_mean(scene, object, t);
        wire(
            &mut ch,
            scene,
            object,
            0,
            vertex_mean(scene, object, 0),
            RGBColor(200, 200, 200).stroke_width(1),
        )?;
        wire(&mut ch, scene, object, t, m, c.stroke_width(2))?;
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
    match draw(scene, object, bounds, title, out, true) {
        Ok(()) => Ok((object, true)),
        Err(first) => draw(scene, object, bounds, title, out, false)
            .map(|_| (object, false))
            .map_err(|e| {
                SimError::Invalid(format!(
                    "cannot draw {}: {e} (with text: {first})",
                    out.display()
                ))
            }),
    }
}
