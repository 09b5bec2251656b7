//! Dataset statistics for `dynaserve sim inspect`: object counts, shapes, materials, speeds,
//! contacts and how many objects rest at the end.
//!
//! Speeds are finite differences of recorded poses over `dt_frame`. An object *rests* at the
//! end when its centre of mass moves slower than [`REST_LINEAR`] and turns slower than
//! [`REST_ANGULAR`] over the last frame interval. Contacts at the end are judged on the posed
//! reference clouds: an object touches the ground when its lowest point is below
//! [`CONTACT_DISTANCE`], and two objects touch when some pair of their points (256-point
//! subsamples) is closer than [`CONTACT_DISTANCE`].

use std::collections::BTreeMap;
use std::fmt;

use rayon::prelude::*;
use serde::Serialize;

use crate::dataset::{DatasetReader, Manifest, ObjectRecord, SceneRecord};
use crate::{Result, SimError};

/// Largest centre-of-mass speed of a resting object, metres per second.
pub const REST_LINEAR: f32 = 0.02;
/// Largest angular speed of a resting object, radians per second.
pub const REST_ANGULAR: f32 = 0.1;
/// Distance below which points count as touching, metres.
pub const CONTACT_DISTANCE: f32 = 0.02;

/// Rotates `v` by the unit quaternion `q = [x, y, z, w]`.
pub fn rotate(q: [f32; 4], v: [f32; 3]) -> [f32; 3] {
    let (x, y, z, w) = (q[0], q[1], q[2], q[3]);
    // t = 2 (q_vec x v); v' = v + w t + q_vec x t
    let t = [
        2.0 * (y * v[2] - z * v[1]),
        2.0 * (z * v[0] - x * v[2]),
        2.0 * (x * v[1] - y * v[0]),
    ];
    [
        v[0] + w * t[0] + (y * t[2] - z * t[1]),
        v[1] + w * t[1] + (z * t[0] - x * t[2]),
        v[2] + w * t[2] + (x * t[1] - y * t[0]),
    ]
}

/// The reference cloud of `o` posed at frame `t` (world frame, metres).
pub fn posed_cloud(o: &ObjectRecord, t: usize) -> Vec<[f32; 3]> {
    let (p, q) = (o.positions[t], o.rotations[t]);
    o.reference_points
        .iter()
        .map(|&r| {
            let w = rotate(q, r);
            [w[0] + p[0], w[1] + p[1], w[2] + p[2]]
        })
        .collect()
}

fn norm(v: [f32; 3]) -> f32 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Linear and angular speed of `o` between frames `t - 1` and `t` (m/s, rad/s).
pub fn speeds(o: &ObjectRecord, t: usize, dt: f32) -> (f32, f32) {
    let (a, b) = (o.positions[t - 1], o.positions[t]);
    let lin = norm([b[0] - a[0], b[1] - a[1], b[2] - a[2]]) / dt;
    let (qa, qb) = (o.rotations[t - 1], o.rotations[t]);
    let d: f32 = (0..4).map(|k| qa[k] * qb[k]).sum();
    let ang = 2.0 * d.abs().min(1.0).acos() / dt;
    (lin, ang)
}

/// Running minimum, mean and maximum.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Summary {
    /// Number of values.
    pub count: usize,
    /// Smallest value.
    pub min: f64,
    /// Mean.
    pub mean: f64,
    /// Largest value.
    pub max: f64,
}

impl Summary {
    fn add(&mut self, v: f64) {
        if self.count == 0 {
            self.min = v;
            self.max = v;
        } else {
            self.min = self.min.min(v);
            self.max = self.max.max(v);
        }
        self.mean += (v - self.mean) / (self.count + 1) as f64;
        self.count += 1;
    }

    fn merge(&mut self, other: &Summary) {
        if other.count == 0 {
            return;
        }
        if self.count == 0 {
            *self = *other;
            return;
        }
        let n = (self.count + other.count) as f64;
        self.mean = (self.mean * self.count as f64 + other.mean * other.count as f64) / n;
        self.min = self.min.min(other.min);
        self.max = self.max.max(other.max);
        self.count += other.count;
    }
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "min {:.3}  mean {:.3}  max {:.3}",
            self.min, self.mean, self.max
        )
    }
}

/// Statistics of a dataset split (or its first scenes).
#[derive(Clone, Debug, Default, Serialize)]
pub struct DatasetStats {
    /// Generator name.
    pub generator: String,
    /// Split name.
    pub split: String,
    /// Scenes examined.
    pub scenes: usize,
    /// Objects examined.
    pub objects: usize,
    /// Frames per scene.
    pub frames: usize,
    /// Interval between frames, seconds.
    pub dt_frame: f32,
    /// Objects per scene.
    pub objects_per_scene: Summary,
    /// Objects per shape name.
    pub shapes: BTreeMap<String, usize>,
    /// Objects per (friction, restitution) pair, as text.
    pub materials: BTreeMap<String, usize>,
    /// Friction coefficient per object.
    pub friction: Summary,
    /// Restitution coefficient per object.
    pub restitution: Summary,
    /// Mass, kilograms.
    pub mass: Summary,
    /// Scale (first axis).
    pub scale: Summary,
    /// Speed over the first frame interval, metres per second.
    pub initial_speed: Summary,
    /// Largest speed reached per object, metres per second.
    pub max_speed: Summary,
    /// Mean speed at a few times `(seconds, summary)`.
    pub speed_at: Vec<(f32, Summary)>,
    /// Highest centre of mass per object, metres.
    pub max_height: Summary,
    /// Lowest point of the posed reference cloud over all frames, per object, metres (negative:
    /// below the floor's top).
    pub lowest_point: Summary,
    /// Objects whose lowest point ever goes below -1 cm.
    pub below_floor_1cm: usize,
    /// Horizontal distance from the origin at the end, metres.
    pub final_distance: Summary,
    /// Fraction of objects at rest at the end.
    pub resting_fraction: f64,
    /// Fraction of objects touching the ground at the end.
    pub ground_contact_fraction: f64,
    /// Object pairs in contact per scene at the end.
    pub contact_pairs_per_scene: Summary,
}

/// Most (friction, restitution) pairs `inspect` lists one by one.
const MATERIALS_LISTED: usize = 8;

#[derive(Default)]
struct SceneStats {
    objects: usize,
    shapes: BTreeMap<i32, usize>,
    materials: BTreeMap<String, usize>,
    friction: Summary,
    restitution: Summary,
    mass: Summary,
    scale: Summary,
    initial_speed: Summary,
    max_speed: Summary,
    speed_at: Vec<Summary>,
    max_height: Summary,
    lowest_point: Summary,
    below_floor_1cm: usize,
    final_distance: Summary,
    resting: usize,
    ground: usize,
    pairs: usize,
}

fn aabb(points: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

fn scene_stats(scene: &SceneRecord, sample_frames: &[usize]) -> SceneStats {
    let dt = scene.dt_frame;
    let mut s = SceneStats {
        objects: scene.objects.len(),
        speed_at: vec![Summary::default(); sample_frames.len()],
        ..Default::default()
    };
    let mut finals = Vec::with_capacity(scene.objects.len());
    for o in &scene.objects {
        let t_end = o.positions.len() - 1;
        *s.shapes.entry(o.shape_id).or_default() += 1;
        *s.materials
            .entry(format!(
                "friction {:.2} restitution {:.2}",
                o.friction, o.restitution
            ))
            .or_default() += 1;
        s.friction.add(o.friction as f64);
        s.restitution.add(o.restitution as f64);
        s.mass.add(o.mass as f64);
        s.scale.add(o.scale[0] as f64);
        if t_end >= 1 {
            s.initial_speed.add(speeds(o, 1, dt).0 as f64);
            let fastest = (1..=t_end).map(|t| speeds(o, t, dt).0).fold(0.0, f32::max);
            s.max_speed.add(fastest as f64);
            for (k, &t) in sample_frames.iter().enumerate() {
                if t >= 1 && t <= t_end {
                    s.speed_at[k].add(speeds(o, t, dt).0 as f64);
                }
            }
            let (lin, ang) = speeds(o, t_end, dt);
            if lin < REST_LINEAR && ang < REST_ANGULAR {
                s.resting += 1;
            }
        }
        let top = o.positions.iter().map(|p| p[2]).fold(f32::MIN, f32::max);
        s.max_height.add(top as f64);
        let mut lowest = f32::INFINITY;
        for t in 0..=t_end {
            let p = o.positions[t];
            let q = o.rotations[t];
            for &r in &o.reference_points {
                lowest = lowest.min(rotate(q, r)[2] + p[2]);
            }
        }
        s.lowest_point.add(lowest as f64);
        if lowest < -0.01 {
            s.below_floor_1cm += 1;
        }
        let end = o.positions[t_end];
        s.final_distance.add((end[0] as f64).hypot(end[1] as f64));
        let step = (o.reference_points.len() / 256).max(1);
        let cloud: Vec<[f32; 3]> = posed_cloud(o, t_end).into_iter().step_by(step).collect();
        let low_end = posed_cloud(o, t_end)
            .iter()
            .map(|p| p[2])
            .fold(f32::INFINITY, f32::min);
        if low_end < CONTACT_DISTANCE {
            s.ground += 1;
        }
        let bb = aabb(&cloud);
        finals.push((cloud, bb));
    }
    let d2 = CONTACT_DISTANCE * CONTACT_DISTANCE;
    for i in 0..finals.len() {
        for j in i + 1..finals.len() {
            let ((a, (alo, ahi)), (b, (blo, bhi))) = (&finals[i], &finals[j]);
            let apart = (0..3)
                .any(|k| alo[k] > bhi[k] + CONTACT_DISTANCE || blo[k] > ahi[k] + CONTACT_DISTANCE);
            if apart {
                continue;
            }
            let touching = a.iter().any(|p| {
                b.iter().any(|q| {
                    let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
                    d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < d2
                })
            });
            if touching {
                s.pairs += 1;
            }
        }
    }
    s
}

/// Computes statistics over the first `limit` scenes (all when `None`), shard by shard, scenes
/// of a shard in parallel.
pub fn inspect(reader: &DatasetReader, limit: Option<usize>) -> Result<DatasetStats> {
    let m: &Manifest = reader.manifest();
    let limit = limit.unwrap_or(usize::MAX).min(reader.len());
    let times = [0.5f32, 1.0, 2.0, 4.0];
    let sample_frames: Vec<usize> = times
        .iter()
        .map(|t| (t / m.dt_frame).round() as usize)
        .collect();
    let mut acc = SceneStats {
        speed_at: vec![Summary::default(); times.len()],
        ..Default::default()
    };
    let mut per_scene = Summary::default();
    let mut pairs = Summary::default();
    let mut scenes = 0usize;
    for k in 0..m.shards.len() {
        if scenes >= limit {
            break;
        }
        let shard = reader.read_shard(k)?;
        let take = shard.len().min(limit - scenes);
        let parts: Vec<SceneStats> = shard[..take]
            .par_iter()
            .map(|s| scene_stats(s, &sample_frames))
            .collect();
        for p in parts {
            scenes += 1;
            per_scene.add(p.objects as f64);
            pairs.add(p.pairs as f64);
            acc.objects += p.objects;
            for (id, n) in p.shapes {
                *acc.shapes.entry(id).or_default() += n;
            }
            for (name, n) in p.materials {
                *acc.materials.entry(name).or_default() += n;
            }
            acc.friction.merge(&p.friction);
            acc.restitution.merge(&p.restitution);
            acc.mass.merge(&p.mass);
            acc.scale.merge(&p.scale);
            acc.initial_speed.merge(&p.initial_speed);
            acc.max_speed.merge(&p.max_speed);
            for (a, b) in acc.speed_at.iter_mut().zip(&p.speed_at) {
                a.merge(b);
            }
            acc.max_height.merge(&p.max_height);
            acc.lowest_point.merge(&p.lowest_point);
            acc.below_floor_1cm += p.below_floor_1cm;
            acc.final_distance.merge(&p.final_distance);
            acc.resting += p.resting;
            acc.ground += p.ground;
        }
    }
    if scenes == 0 {
        return Err(SimError::Invalid("the dataset holds no scene".into()));
    }
    let objects = acc.objects.max(1) as f64;
    Ok(DatasetStats {
        generator: m.generator.clone(),
        split: m.split.clone(),
        scenes,
        objects: acc.objects,
        frames: m.frames,
        dt_frame: m.dt_frame,
        objects_per_scene: per_scene,
        shapes: acc
            .shapes
            .iter()
            .map(|(&id, &n)| (m.shape_name(id), n))
            .collect(),
        materials: acc.materials,
        friction: acc.friction,
        restitution: acc.restitution,
        mass: acc.mass,
        scale: acc.scale,
        initial_speed: acc.initial_speed,
        max_speed: acc.max_speed,
        speed_at: times
            .iter()
            .zip(acc.speed_at)
            .filter(|(_, s)| s.count > 0)
            .map(|(&t, s)| (t, s))
            .collect(),
        max_height: acc.max_height,
        lowest_point: acc.lowest_point,
        below_floor_1cm: acc.below_floor_1cm,
        final_distance: acc.final_distance,
        resting_fraction: acc.resting as f64 / objects,
        ground_contact_fraction: acc.ground as f64 / objects,
        contact_pairs_per_scene: pairs,
    })
}

impl fmt::Display for DatasetStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} / {}: {} scenes, {} objects, {} frames at {:.4} s ({:.2} s)",
            self.generator,
            self.split,
            self.scenes,
            self.objects,
            self.frames,
            self.dt_frame,
            (self.frames.saturating_sub(1)) as f32 * self.dt_frame
        )?;
        writeln!(f, "objects per scene      {}", self.objects_per_scene)?;
        let shapes: Vec<String> = self
            .shapes
            .iter()
            .map(|(k, v)| format!("{k} {v}"))
            .collect();
        writeln!(f, "shapes                 {}", shapes.join(", "))?;
        // A few named materials are listed; drawn ones (one per object) are summarised.
        if self.materials.len() <= MATERIALS_LISTED {
            for (k, v) in &self.materials {
                writeln!(f, "material               {k}: {v}")?;
            }
        } else {
            writeln!(
                f,
                "materials              {} distinct",
                self.materials.len()
            )?;
        }
        writeln!(f, "friction               {}", self.friction)?;
        writeln!(f, "restitution            {}", self.restitution)?;
        writeln!(f, "mass (kg)              {}", self.mass)?;
        writeln!(f, "scale                  {}", self.scale)?;
        writeln!(f, "initial speed (m/s)    {}", self.initial_speed)?;
        writeln!(f, "peak speed (m/s)       {}", self.max_speed)?;
        for (t, s) in &self.speed_at {
            writeln!(f, "speed at {t:.1} s (m/s)   {s}")?;
        }
        writeln!(f, "peak height (m)        {}", self.max_height)?;
        writeln!(
            f,
            "lowest point (m)       {}  ({} objects ever below -1 cm)",
            self.lowest_point, self.below_floor_1cm
        )?;
        writeln!(f, "final distance (m)     {}", self.final_distance)?;
        writeln!(
            f,
            "at the end             {:.1}% resting (< {REST_LINEAR} m/s, < {REST_ANGULAR} rad/s), \
             {:.1}% on the ground, contact pairs per scene {}",
            100.0 * self.resting_fraction,
            100.0 * self.ground_contact_fraction,
            self.contact_pairs_per_scene
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotate_matches_axis_angle() {
        // 90 degrees about z maps x to y.
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let v = rotate([0.0, 0.0, h, h], [1.0, 0.0, 0.0]);
        assert!((v[0]).abs() < 1e-6 && (v[1] - 1.0).abs() < 1e-6 && v[2].abs() < 1e-6);
        // 180 degrees about x maps z to -z.
        let v = rotate([1.0, 0.0, 0.0, 0.0], [0.0, 0.3, 1.0]);
        assert!((v[1] + 0.3).abs() < 1e-6 && (v[2] + 1.0).abs() < 1e-6);
    }

    #[test]
    fn summary_merges_like_one_pass() {
        let (mut a, mut b, mut all) = (Summary::default(), Summary::default(), Summary::default());
        for i in 0..10 {
            let v = (i * i) as f64;
            if i < 4 {
                a.add(v)
            } else {
                b.add(v)
            }
            all.add(v);
        }
        a.merge(&b);
        assert_eq!((a.count, a.min, a.max), (all.count, all.min, all.max));
        assert!((a.mean - all.mean).abs() < 1e-12);
    }
}
