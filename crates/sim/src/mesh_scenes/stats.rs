//! Statistics of a mesh split for `dynaserve sim inspect`: counts, materials, templates,
//! starts, speeds, how rigid the rigid objects stay, how much elastic objects deform and keep
//! their volume, and how far any vertex gets outside the box.

use std::collections::BTreeMap;
use std::fmt;

use dynaserve_geometry::kabsch;
use serde::Serialize;

use super::reader::MeshDatasetReader;
use super::record::{MeshMaterial, MeshScene};
use crate::Result;

/// Smallest, mean and largest of a set of values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Summary {
    /// Smallest value.
    pub min: f64,
    /// Mean.
    pub mean: f64,
    /// Largest value.
    pub max: f64,
    /// Number of values.
    pub count: usize,
}

impl Summary {
    fn of(values: &[f64]) -> Self {
        if values.is_empty() {
            return Self::default();
        }
        Self {
            min: values.iter().copied().fold(f64::INFINITY, f64::min),
            mean: values.iter().sum::<f64>() / values.len() as f64,
            max: values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            count: values.len(),
        }
    }
}

/// What `sim inspect` reports on a mesh split.
#[derive(Clone, Debug, Serialize)]
pub struct MeshStats {
    /// Generator name.
    pub generator: String,
    /// Split name.
    pub split: String,
    /// Scenes examined.
    pub scenes: usize,
    /// Frames per scene.
    pub frames: usize,
    /// Interval between frames, seconds.
    pub dt_frame: f32,
    /// Objects per scene.
    pub objects_per_scene: Summary,
    /// Vertices per scene.
    pub vertices_per_scene: Summary,
    /// Vertices per object.
    pub vertices_per_object: Summary,
    /// Objects per material name.
    pub materials: BTreeMap<String, usize>,
    /// Objects per template name.
    pub templates: BTreeMap<String, usize>,
    /// Scenes per start (`floor`, `airborne`, with `+spin` when spinning).
    pub starts: BTreeMap<String, usize>,
    /// Mass per object, kilograms.
    pub mass: Summary,
    /// Initial speed of each object's vertex mean, metres per second.
    pub initial_speed: Summary,
    /// Largest speed of each object's vertex mean over the trajectory, metres per second.
    pub peak_speed: Summary,
    /// Rigid objects: largest relative change of any edge length over the trajectory.
    pub rigid_edge_change: Summary,
    /// Elastic objects: largest relative change of any edge length (strain) over the
    /// trajectory.
    pub elastic_edge_strain: Summary,
    /// Elastic objects: largest `|volume_t / volume_0 - 1|` over the trajectory.
    pub elastic_volume_change: Summary,
    /// Largest distance of any vertex outside the box over the trajectory, metres (0 inside).
    pub outside_box: Summary,
}

fn edges(scene: &MeshScene, object: usize) -> Vec<(usize, usize)> {
    let mut e: Vec<(usize, usize)> = scene.faces[scene.objects[object].faces.clone()]
        .iter()
        .flat_map(|f| {
            (0..3).map(move |k| {
                let (a, b) = (f[k] as usize, f[(k + 1) % 3] as usize);
                (a.min(b), a.max(b))
            })
        })
        .collect();
    e.sort_unstable();
    e.dedup();
    e
}

fn dist(a: [f32; 3], b: [f32; 3]) -> f64 {
    (0..3)
        .map(|k| ((a[k] - b[k]) as f64).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Largest relative change of an edge length of `object` over the trajectory (against frame
/// 0).
pub fn max_edge_strain(scene: &MeshScene, object: usize) -> f64 {
    let mut worst = 0.0f64;
    for (a, b) in edges(scene, object) {
        let rest = dist(scene.position(a, 0), scene.position(b, 0));
        for t in 1..scene.frames {
            let l = dist(scene.position(a, t), scene.position(b, t));
            worst = worst.max((l / rest - 1.0).abs());
        }
    }
    worst
}

/// `object`'s vertices at frame `t` moved by the best rigid fit (Kabsch) onto their frame-0
/// positions, and the root-mean-square distance left (metres): zero for a rigid object, the
/// deformation for an elastic one.
pub fn rigid_fit_to_first_frame(
    scene: &MeshScene,
    object: usize,
    t: usize,
) -> Result<(Vec<[f32; 3]>, f64)> {
    let r = scene.objects[object].vertices.clone();
    let at = |t: usize| -> Vec<[f64; 3]> {
        r.clone()
            .map(|v| scene.position(v, t).map(|c| c as f64))
            .collect()
    };
    let (xt, x0) = (at(t), at(0));
    let fit = kabsch(&xt, &x0, None)?;
    let moved: Vec<[f64; 3]> = xt.iter().map(|&p| fit.apply(p)).collect();
    let ms = moved
        .iter()
        .zip(&x0)
        .map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>())
        .sum::<f64>()
        / moved.len().max(1) as f64;
    Ok((
        moved.iter().map(|p| p.map(|c| c as f32)).collect(),
        ms.sqrt(),
    ))
}

/// Largest `|volume_t / volume_0 - 1|` of `object` over the trajectory.
pub fn max_volume_change(scene: &MeshScene, object: usize) -> f64 {
    let v0 = scene.object_volume(object, 0);
    (1..scene.frames)
        .map(|t| (scene.object_volume(object, t) / v0 - 1.0).abs())
        .fold(0.0, f64::max)
}

/// Mean of `object`'s vertices at frame `t`, metres.
pub fn vertex_mean(scene: &MeshScene, object: usize, t: usize) -> [f32; 3] {
    let r = scene.objects[object].vertices.clone();
    let n = r.len() as f32;
    let mut c = [0.0f32; 3];
    for v in r {
        let p = scene.position(v, t);
        for k in 0..3 {
            c[k] += p[k] / n;
        }
    }
    c
}

/// Largest distance of any vertex of the scene outside the box `bounds` over the trajectory.
pub fn max_outside(scene: &MeshScene, bounds: [[f32; 3]; 2]) -> f64 {
    let mut worst = 0.0f32;
    for v in 0..scene.num_vertices() {
        for t in 0..scene.frames {
            let p = scene.position(v, t);
            for k in 0..3 {
                worst = worst.max(bounds[0][k] - p[k]).max(p[k] - bounds[1][k]);
            }
        }
    }
    worst as f64
}

/// Statistics of the first `limit` scenes (all when `None`).
pub fn inspect_mesh(reader: &MeshDatasetReader, limit: Option<usize>) -> Result<MeshStats> {
    let m = reader.manifest();
    let n = limit.unwrap_or(m.scenes).min(m.scenes);
    let mut v = BTreeMap::<&str, Vec<f64>>::new();
    let (mut materials, mut templates, mut starts) =
        (BTreeMap::new(), BTreeMap::new(), BTreeMap::new());
    let mut seen = 0usize;
    for scene in reader.iter().take(n) {
        let scene = scene?;
        let label = &m.scene_starts[seen];
        let key = if label.spin {
            format!("{}+spin", label.start)
        } else {
            label.start.clone()
        };
        *starts.entry(key).or_insert(0) += 1;
        seen += 1;
        v.entry("objects")
            .or_default()
            .push(scene.objects.len() as f64);
        v.entry("vertices")
            .or_default()
            .push(scene.num_vertices() as f64);
        v.entry("outside")
            .or_default()
            .push(max_outside(&scene, m.bounds));
        for (i, o) in scene.objects.iter().enumerate() {
            *materials.entry(o.material.name().to_string()).or_insert(0) += 1;
            let name = m
                .templates
                .get(o.template_id as usize)
                .map(|t| t.name.clone())
                .unwrap_or_else(|| format!("#{}", o.template_id));
            *templates.entry(name).or_insert(0) += 1;
            v.entry("vpo").or_default().push(o.vertices.len() as f64);
            v.entry("mass").or_default().push(o.mass as f64);
            let n = o.vertices.len() as f64;
            let v0: [f64; 3] = o.vertices.clone().fold([0.0; 3], |acc, k| {
                let u = scene.initial_velocity(k);
                [0, 1, 2].map(|j| acc[j] + u[j] as f64 / n)
            });
            v.entry("speed0")
                .or_default()
                .push((v0[0] * v0[0] + v0[1] * v0[1] + v0[2] * v0[2]).sqrt());
            let peak = (1..scene.frames)
                .map(|t| {
                    dist(vertex_mean(&scene, i, t), vertex_mean(&scene, i, t - 1))
                        / scene.dt_frame as f64
                })
                .fold(0.0, f64::max);
            v.entry("peak").or_default().push(peak);
            match o.material {
                MeshMaterial::Rigid => v
                    .entry("rigid")
                    .or_default()
                    .push(max_edge_strain(&scene, i)),
                MeshMaterial::Elastic => {
                    v.entry("strain")
                        .or_default()
                        .push(max_edge_strain(&scene, i));
                    v.entry("volume")
                        .or_default()
                        .push(max_volume_change(&scene, i));
                }
            }
        }
    }
    let s = |k: &str| Summary::of(v.get(k).map(|x| x.as_slice()).unwrap_or(&[]));
    Ok(MeshStats {
        generator: m.generator.clone(),
        split: m.split.clone(),
        scenes: seen,
        frames: m.frames,
        dt_frame: m.dt_frame,
        objects_per_scene: s("objects"),
        vertices_per_scene: s("vertices"),
        vertices_per_object: s("vpo"),
        materials,
        templates,
        starts,
        mass: s("mass"),
        initial_speed: s("speed0"),
        peak_speed: s("peak"),
        rigid_edge_change: s("rigid"),
        elastic_edge_strain: s("strain"),
        elastic_volume_change: s("volume"),
        outside_box: s("outside"),
    })
}

fn counts(m: &BTreeMap<String, usize>) -> String {
    m.iter()
        .map(|(k, v)| format!("{k} {v}"))
        .collect::<Vec<_>>()
        .join(", ")
}

impl fmt::Display for MeshStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} / {}: {} scenes, {} frames at {:.4} s ({:.2} s)",
            self.generator,
            self.split,
            self.scenes,
            self.frames,
            self.dt_frame,
            self.dt_frame as f64 * (self.frames.saturating_sub(1)) as f64
        )?;
        let row = |f: &mut fmt::Formatter<'_>, name: &str, s: &Summary, p: usize| {
            writeln!(
                f,
                "{name:<34} min {:.p$}  mean {:.p$}  max {:.p$}  ({} values)",
                s.min, s.mean, s.max, s.count
            )
        };
        row(f, "objects per scene", &self.objects_per_scene, 2)?;
        row(f, "vertices per scene", &self.vertices_per_scene, 1)?;
        row(f, "vertices per object", &self.vertices_per_object, 1)?;
        writeln!(f, "{:<34} {}", "materials", counts(&self.materials))?;
        writeln!(f, "{:<34} {}", "starts", counts(&self.starts))?;
        writeln!(f, "{:<34} {}", "templates", counts(&self.templates))?;
        row(f, "mass (kg)", &self.mass, 3)?;
        row(f, "initial speed (m/s)", &self.initial_speed, 3)?;
        row(f, "peak speed (m/s)", &self.peak_speed, 3)?;
        row(
            f,
            "rigid: max edge length change",
            &self.rigid_edge_change,
            7,
        )?;
        row(f, "elastic: max edge strain", &self.elastic_edge_strain, 4)?;
        row(
            f,
            "elastic: max |volume change|",
            &self.elastic_volume_change,
            4,
        )?;
        row(f, "outside the box (m)", &self.outside_box, 4)
    }
}
