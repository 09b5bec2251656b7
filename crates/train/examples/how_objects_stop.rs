//! How do the objects that rapier has at rest at the end of a scene get there? For every
//! object at rest over the evaluation's resting-drift window (its last second, with the
//! evaluation's thresholds: [`RestingOptions::at_rest`]), finds the last frame it moved faster
//! than 0.02 m/s and classifies the six frames before that: *rolled*
//! when the surface speed its spin gives at its centre height (angular speed x height) is at
//! least half its centre's speed, else *slid*; and prints, per shape, how many stopped each
//! way, their mean deceleration (m/s^2) and how many were upright (body z within 30 degrees of
//! the world's).
//!
//! `cargo run --release -p dynaserve-train --example how_objects_stop -- data/movi-b/test`
use std::collections::BTreeMap;

use dynaserve_sim::DatasetReader;
use dynaserve_train::eval::RestingOptions;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

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
    let rest = RestingOptions::default();
    let mut by_shape: BTreeMap<String, Tally> = BTreeMap::new();
    for scene in reader.iter() {
        let scene = scene?;
        let dt = scene.dt_frame;
        for o in &scene.objects {
            let frames = o.positions.len();
            let (a, b) = rest.window(frames, f64::from(dt)).ok_or_else(|| {
                anyhow::anyhow!("{dir}: {frames} frames, shorter than the window")
            })?;
            if !rest.at_rest(o, a, b, f64::from(dt)) {
                continue;
            }
            let speed: Vec<f32> = (0..frames - 1)
                .map(|f| {
                    (Vector3::from(o.positions[f + 1]) - Vector3::from(o.positions[f])).norm() / dt
                })
                .collect();
            let t = by_shape
                .entry(reader.manifest().shape_name(o.shape_id))
                .or_default();
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
        "{dir}: objects at rest over the last {} s (the evaluation's resting set) and how they stopped",
        rest.window_s
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
