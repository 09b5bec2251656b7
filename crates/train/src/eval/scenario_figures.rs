//! Each physics scenario's own figures, measured the same way on a predictor's `k = 1`
//! rollout and on the ground truth (rapier) of the same scene.
//!
//! The rollout starts from frames `s - 1` and `s` and runs to the last frame `T - 1`; frames up
//! to `s` are the ground truth for both. The definitions (all per scene unless stated):
//! - `rest`: largest centre displacement from frame `s` of any object over frames `s..T`, m;
//!   largest rotation from frame `s`, deg;
//! - `drop`: the centre's height at the last frame, m; the depth of the deepest reference point
//!   below the floor over frames `s..T` (0 if none), m;
//! - `slide`: per object, the horizontal distance from frame `s` to the last frame, m;
//! - `roll`: the same per rolling object (`rolled distance`; no target: many still roll at
//!   the last frame, so it is the distance covered, not a stopping distance);
//! - `collide`: the momentum object 0 exchanges in the impact, `|m (v_after - v_before) -
//!   m g (t_after - t_before)|` (air) or the horizontal part of `m (v_after - v_before)`
//!   (floor), kg m/s, with velocities from the frame pairs `(c - 2, c - 1)` (or `(s - 1, s)` if
//!   `c - 2 < s`) and `(c + 2, c + 3)` around the ground truth's impact frame `c`, the first
//!   frame with a point of object 0 within the impact distance of object 1
//!   ([`ContactFlags::impact_distance_m`]; no sample unless `s < c` and `c + 3` is a frame);
//! - `stack-hit`: the mean over the tower's boxes (every object but the last) of their centre
//!   displacement from frame `s` to the last frame, m, and (predictor only) the mean distance
//!   of the boxes' final centres from rapier's, m;
//! - `push` (the pusher driven along its recorded path): per pushed object (every
//!   non-kinematic one), the distance of its centre from frame `s` to the last frame, m, and
//!   (predictor only) the distance of its final centre from rapier's and the mean over frames
//!   `s + 1..T` of the distance from rapier's centre, m. The static baseline's errors are those
//!   of "the pushed objects stay still".

use dynaserve_model::Pose;
use dynaserve_sim::stats::rotate;
use dynaserve_sim::{SceneLabel, SceneRecord};

use super::EvalError;
use super::regimes::ContactFlags;

/// Displacement under which a resting object counts as still, m (the suite's acceptance).
pub const REST_TARGET_M: f64 = 0.02;
/// Largest error of a dropped object's settling height, m.
pub const DROP_HEIGHT_TARGET_M: f64 = 0.02;
/// Deepest accepted penetration of the floor, m.
pub const PENETRATION_TARGET_M: f64 = 0.01;
/// Largest relative error of a stopping distance.
pub const SLIDE_TARGET: f64 = 0.15;
/// Largest relative error of the momentum exchanged in a collision.
pub const COLLIDE_TARGET: f64 = 0.10;

/// How a figure's target is judged, per sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Target {
    /// The predictor's value is below this.
    Below(f64),
    /// The predictor's value is within this relative error of rapier's.
    Relative(f64),
    /// `|predictor - rapier|` is below this.
    Absolute(f64),
}

impl Target {
    /// Whether `value` meets the target against `rapier`.
    pub fn met(self, value: f64, rapier: f64) -> bool {
        match self {
            Target::Below(x) => value < x,
            Target::Relative(r) => rapier != 0.0 && ((value - rapier) / rapier).abs() <= r,
            Target::Absolute(x) => (value - rapier).abs() < x,
        }
    }

    /// Short description for reports, e.g. `< 0.020 m` or `within 15%`.
    pub fn describe(self, unit: &str) -> String {
        match self {
            Target::Below(x) => format!("< {x:.3} {unit}"),
            Target::Relative(r) => format!("within {:.0}% of rapier", 100.0 * r),
            Target::Absolute(x) => format!("within {x:.3} {unit} of rapier"),
        }
    }
}

/// One measurement of one figure on one scene (or object).
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    /// Scenario name (`rest`, `drop`, ...).
    pub scenario: String,
    /// Variant (`tower`, `single`, `air`, ...).
    pub group: String,
    /// Figure name.
    pub figure: &'static str,
    /// Unit of the values.
    pub unit: &'static str,
    /// The predictor's value.
    pub value: f64,
    /// Rapier's value (`None` for figures that compare with rapier inside `value`).
    pub rapier: Option<f64>,
    /// The target, if the figure has one.
    pub target: Option<Target>,
}

/// A trajectory view: ground truth up to frame `s`, the rollout after it.
struct Track<'a> {
    scene: &'a SceneRecord,
    start: usize,
    rollout: Option<&'a [Vec<Pose>]>,
}

impl Track<'_> {
    fn frames(&self) -> usize {
        self.scene.objects[0].positions.len()
    }

    fn pose(&self, j: usize, t: usize) -> ([f32; 3], [f32; 4]) {
        match self.rollout {
            Some(r) if t > self.start => {
                let p = &r[t - self.start - 1][j];
                (p.translation, p.rotation)
            }
            _ => {
                let o = &self.scene.objects[j];
                (o.positions[t], o.rotations[t])
            }
        }
    }

    fn position(&self, j: usize, t: usize) -> [f64; 3] {
        self.pose(j, t).0.map(f64::from)
    }

    fn lowest(&self, j: usize, t: usize) -> f64 {
        let (p, q) = self.pose(j, t);
        self.scene.objects[j]
            .reference_points
            .iter()
            .map(|&x| f64::from(rotate(q, x)[2] + p[2]))
            .fold(f64::INFINITY, f64::min)
    }

    fn velocity(&self, j: usize, a: usize, b: usize) -> [f64; 3] {
        let (pa, pb) = (self.position(j, a), self.position(j, b));
        let dt = f64::from(self.scene.dt_frame) * (b - a) as f64;
        std::array::from_fn(|c| (pb[c] - pa[c]) / dt)
    }
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|c| (a[c] - b[c]).powi(2)).sum::<f64>().sqrt()
}

fn horizontal(a: [f64; 3], b: [f64; 3]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Largest displacement (m) and rotation (deg) of any object from frame `s`.
fn rest_drift(t: &Track<'_>) -> (f64, f64) {
    let mut d: f64 = 0.0;
    let mut a: f64 = 0.0;
    for j in 0..t.scene.objects.len() {
        let (p0, q0) = t.pose(j, t.start);
        for f in t.start..t.frames() {
            let (p, q) = t.pose(j, f);
            d = d.max(distance(p.map(f64::from), p0.map(f64::from)));
            a = a.max(dynaserve_geometry::geodesic_angle(q, q0).to_degrees());
        }
    }
    (d, a)
}

/// Depth below the floor of the deepest reference point over frames `s..T`, m.
fn deepest(t: &Track<'_>, j: usize) -> f64 {
    (t.start..t.frames())
        .map(|f| (-t.lowest(j, f)).max(0.0))
        .fold(0.0, f64::max)
}

/// Momentum object 0 exchanges in the impact at frame `c` (see the module docs), kg m/s.
fn exchanged(t: &Track<'_>, c: usize, air: bool, gravity: [f32; 3]) -> f64 {
    let (b0, b1) = if c >= t.start + 2 {
        (c - 2, c - 1)
    } else {
        (t.start - 1, t.start)
    };
    let (a0, a1) = (c + 2, c + 3);
    let (vb, va) = (t.velocity(0, b0, b1), t.velocity(0, a0, a1));
    let m = f64::from(t.scene.objects[0].mass);
    let dt = f64::from(t.scene.dt_frame) * (a1 - b1) as f64;
    let d: [f64; 3] = std::array::from_fn(|k| {
        let g = if air { f64::from(gravity[k]) * dt } else { 0.0 };
        m * (va[k] - vb[k] - g)
    });
    if air {
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
    } else {
        d[0].hypot(d[1])
    }
}

/// The figures of one labelled scene for a predictor's `k = 1` rollout from frame `start`
/// (`rollout[i]` = poses at frame `start + 1 + i`, through the last frame).
pub fn scene_samples(
    scene: &SceneRecord,
    label: &SceneLabel,
    flags: &ContactFlags,
    start: usize,
    rollout: &[Vec<Pose>],
    gravity: [f32; 3],
) -> Result<Vec<Sample>, EvalError> {
    let n = scene.objects.len();
    let frames = scene
        .objects
        .first()
        .map(|o| o.positions.len())
        .unwrap_or(0);
    if n == 0 || start == 0 || start + 1 + rollout.len() != frames {
        return Err(EvalError::Invalid(format!(
            "scenario figures need a rollout from frame {start} to the last of {frames} frames, \
             got {} steps",
            rollout.len()
        )));
    }
    if rollout.iter().any(|poses| poses.len() != n) {
        return Err(EvalError::Invalid(
            "rollout pose count differs from the scene".into(),
        ));
    }
    let pred = Track {
        scene,
        start,
        rollout: Some(rollout),
    };
    let truth = Track {
        scene,
        start,
        rollout: None,
    };
    let last = frames - 1;
    let sample = |figure, unit, value, rapier, target| Sample {
        scenario: label.scenario.clone(),
        group: label.variant.clone(),
        figure,
        unit,
        value,
        rapier,
        target,
    };
    let mut out = Vec::new();
    match label.scenario.as_str() {
        "rest" => {
            let ((dp, ap), (dt, at)) = (rest_drift(&pred), rest_drift(&truth));
            out.push(sample(
                "max displacement",
                "m",
                dp,
                Some(dt),
                Some(Target::Below(REST_TARGET_M)),
            ));
            out.push(sample("max rotation", "deg", ap, Some(at), None));
        }
        "drop" => {
            let (hp, ht) = (pred.position(0, last)[2], truth.position(0, last)[2]);
            out.push(sample("final centre height", "m", hp, Some(ht), None));
            out.push(sample(
                "final height error",
                "m",
                (hp - ht).abs(),
                None,
                Some(Target::Below(DROP_HEIGHT_TARGET_M)),
            ));
            out.push(sample(
                "deepest penetration",
                "m",
                deepest(&pred, 0),
                Some(deepest(&truth, 0)),
                Some(Target::Below(PENETRATION_TARGET_M)),
            ));
        }
        "slide" | "roll" => {
            let slide = label.scenario == "slide";
            for j in 0..n {
                let dp = horizontal(pred.position(j, last), pred.position(j, start));
                let dt = horizontal(truth.position(j, last), truth.position(j, start));
                out.push(sample(
                    if slide {
                        "stopping distance"
                    } else {
                        "rolled distance"
                    },
                    "m",
                    dp,
                    Some(dt),
                    slide.then_some(Target::Relative(SLIDE_TARGET)),
                ));
            }
        }
        "collide" if n == 2 => {
            // The first contact of the scene; measurable only if the predictor has to make it.
            let impact = (0..frames).find(|&f| flags.near_object[f][0]);
            if let Some(c) = impact.filter(|&c| c > start && c + 3 < frames) {
                let air = label.variant == "air";
                out.push(sample(
                    "momentum exchanged",
                    "kg m/s",
                    exchanged(&pred, c, air, gravity),
                    Some(exchanged(&truth, c, air, gravity)),
                    Some(Target::Relative(COLLIDE_TARGET)),
                ));
            }
        }
        "stack-hit" if n >= 2 => {
            let boxes = n - 1;
            let moved = |t: &Track<'_>| {
                (0..boxes)
                    .map(|j| distance(t.position(j, last), t.position(j, start)))
                    .sum::<f64>()
                    / boxes as f64
            };
            out.push(sample(
                "tower displacement",
                "m",
                moved(&pred),
                Some(moved(&truth)),
                None,
            ));
            let err = (0..boxes)
                .map(|j| distance(pred.position(j, last), truth.position(j, last)))
                .sum::<f64>()
                / boxes as f64;
            out.push(sample("final box position error", "m", err, None, None));
        }
        "push" => {
            for j in (0..n).filter(|&j| !scene.objects[j].kinematic) {
                let moved = |t: &Track<'_>| distance(t.position(j, last), t.position(j, start));
                out.push(sample(
                    "pushed displacement",
                    "m",
                    moved(&pred),
                    Some(moved(&truth)),
                    None,
                ));
                let error = |f: usize| distance(pred.position(j, f), truth.position(j, f));
                out.push(sample("pushed final error", "m", error(last), None, None));
                let mean = (start + 1..frames).map(error).sum::<f64>() / (last - start) as f64;
                out.push(sample("pushed mean error", "m", mean, None, None));
            }
        }
        _ => {}
    }
    Ok(out)
}
