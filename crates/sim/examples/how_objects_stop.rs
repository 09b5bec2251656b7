//! How do the objects that rapier has at rest at the end of a scene get there? For every
//! object at rest over the resting-drift window of the evaluation (frames 76-100 of a
//! 101-frame split, the same 0.01 m/s threshold on the frame-to-frame speed), finds the last
//! frame it moved faster than 0.02 m/s and classifies the six frames before that: *rolled*
//! when the surface speed its spin gives at its centre height (angular speed x height) is at
//! least half its centre's speed, else *slid*; and prints, per shape, how many stopped each
//! way, their mean deceleration (m/s^2) and how many were upright (body z within 30 degrees of
//! the world's).
//!
//! `cargo run --release -p dynaserve-sim --example how_objects_stop -- data/movi-b/test`
use std::collections::BTreeMap;

use dynaserve_sim::dataset::DatasetReader;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// First and last frame of the window an object must rest over.
const REST_WINDOW: (usize, usize) = (76, 100);
/// Speed below which an object counts as at rest, m/s (the evaluation's threshold).
const REST_SPEED: f32 = 0.01;
/// Speed above which an object counts as still moving, m/s.
const MOVING_SPEED: f32 = 0.02;
/// Frames before the last moving frame that are classified.
const LOOKBACK: usize = 6;

#[derive(Default)]
struct Tally {
    at_rest: usize,
    rolled: usize,
    slid: usize,
    upright: usize,
    decel_sum: f32,
    decel_n: usize,
}

fn quat(q: [f32; 4]) -> UnitQuaternion<f32> {
    UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2]))
}

fn main() -> anyhow::Result<()> {
    let dir = std::env::args()
        .nth(1)
        .ok_or_else(|| anyhow::anyhow!("usage: how_objects_stop SPLIT_DIR"))?;
    let reader = DatasetReader::open(&dir)?;
    let names: BTreeMap<i32, String> = reader
        .manifest()
        .shapes
        .iter()
        .map(|s| (s.id, s.name.clone()))
        .collect();
    let mut by_shape: BTreeMap<String, Tally> = BTreeMap::new();
    for scene in reader.iter() {
        let scene = scene?;
        let dt = scene.dt_frame;
        for o in &scene.objects {
            let frames = o.positions.len();
            if frames <= REST_WINDOW.1 {
                anyhow::bail!("{dir}: scenes of {frames} frames, the window needs 101");
            }
            let speed: Vec<f32> = (0..frames - 1)
                .map(|f| {
                    (Vector3::from(o.positions[f + 1]) - Vector3::from(o.positions[f])).norm() / dt
                })
                .collect();
            if speed[REST_WINDOW.0..REST_WINDOW.1]
                .iter()
                .any(|&v| v > REST_SPEED)
            {
                continue;
            }
            let name = names
                .get(&o.shape_id)
                .cloned()
                .unwrap_or_else(|| format!("shape {}", o.shape_id));
            let t = by_shape.entry(name).or_default();
            t.at_rest += 1;
            let Some(last) = (0..frames - 1).rev().find(|&f| speed[f] > MOVING_SPEED) else {
                continue;
            };
            if last < LOOKBACK + 1 {
                continue;
            }
            let span = last - LOOKBACK..last;
            let n = LOOKBACK as f32;
            let v = span.clone().map(|f| speed[f]).sum::<f32>() / n;
            let spin_speed = span
                .clone()
                .map(|f| {
                    let w = quat(o.rotations[f]).angle_to(&quat(o.rotations[f + 1])) / dt;
                    w * o.positions[f][2].max(0.0)
                })
                .sum::<f32>()
                / n;
            if spin_speed >= 0.5 * v {
                t.rolled += 1;
            } else {
                t.slid += 1;
            }
            t.decel_sum += (speed[last - LOOKBACK] - speed[last]) / (LOOKBACK as f32 * dt);
            t.decel_n += 1;
            let up = quat(o.rotations[last]) * Vector3::z();
            if up.z.abs() >= 30f32.to_radians().cos() {
                t.upright += 1;
            }
        }
    }
    println!(
        "{dir}: objects at rest over frames {}-{} and how they stopped",
        REST_WINDOW.0, REST_WINDOW.1
    );
    println!(
        "{:<12} {:>7} {:>7} {:>7} {:>8} {:>14}",
        "shape", "at rest", "rolled", "slid", "upright", "decel (m/s^2)"
    );
    let mut all = Tally::default();
    for (name, t) in &by_shape {
        let decel = t.decel_sum / t.decel_n.max(1) as f32;
        println!(
            "{name:<12} {:>7} {:>7} {:>7} {:>8} {decel:>14.2}",
            t.at_rest, t.rolled, t.slid, t.upright
        );
        all.at_rest += t.at_rest;
        all.rolled += t.rolled;
        all.slid += t.slid;
        all.upright += t.upright;
        all.decel_sum += t.decel_sum;
        all.decel_n += t.decel_n;
    }
    println!(
        "{:<12} {:>7} {:>7} {:>7} {:>8} {:>14.2}",
        "all",
        all.at_rest,
        all.rolled,
        all.slid,
        all.upright,
        all.decel_sum / all.decel_n.max(1) as f32
    );
    println!(
        "(objects that never moved faster than {MOVING_SPEED} m/s or stopped within the first {} frames are counted at rest only)",
        LOOKBACK + 1
    );
    Ok(())
}
