//! Tests of the evaluation core and the baselines on hand-checkable trajectories, a random
//! RigidFormer and real simulated data; the shared scenes and helpers are here:
//!
//! - `baselines`: pooled errors, the static and ballistic baselines, horizons, options,
//!   misbehaving predictors and curves;
//! - `models`: a world model through the evaluation path and on simulated data, batched;
//! - `rapier_restart`: the simulator restarted from the observed frames;
//! - `rollouts`: resting drift, long rollouts past the data and occlusion;
//! - `suite`: the suite reports, printed and plotted.

use std::sync::Arc;

use super::*;
use dynaserve_model::{Device, ModelConfig, Pose, RigidFormer, SceneState, WorldModel};
use dynaserve_sim::{DatasetReader, ObjectRecord, SceneRecord};
use nalgebra::{UnitQuaternion, Vector3};

mod baselines;
mod models;
mod rapier_restart;
mod rollouts;
mod suite;

const DT: f32 = 1.0 / 24.0;

/// Corners of a unit cube (body frame).
fn cube_points() -> Vec<[f32; 3]> {
    let mut v = Vec::new();
    for x in [-0.5, 0.5] {
        for y in [-0.5, 0.5] {
            for z in [-0.5, 0.5] {
                v.push([x, y, z]);
            }
        }
    }
    v
}

/// A scene whose object `j` follows `pose(j, t_seconds)` for `frames` frames.
fn scene(objects: usize, frames: usize, pose: impl Fn(usize, f64) -> Pose) -> SceneRecord {
    SceneRecord {
        objects: (0..objects)
            .map(|j| {
                let poses: Vec<Pose> = (0..frames)
                    .map(|t| pose(j, t as f64 * f64::from(DT)))
                    .collect();
                ObjectRecord {
                    positions: poses.iter().map(|p| p.translation).collect(),
                    rotations: poses.iter().map(|p| p.rotation).collect(),
                    reference_points: cube_points(),
                    mass: 1.0,
                    friction: 0.5,
                    restitution: 0.5,
                    scale: [1.0; 3],
                    shape_id: 0,
                    material: 0,
                    kinematic: false,
                }
            })
            .collect(),
        dt_frame: DT,
    }
}

/// Two objects standing still 2 m apart for 101 frames, of shapes 5 and 3 (in that order).
fn resting_pair_of_shapes_5_and_3() -> SceneRecord {
    let mut s = scene(2, 101, |j, _| {
        pose(
            Vector3::new(2.0 * j as f64, 0.0, 0.5),
            UnitQuaternion::identity(),
        )
    });
    s.objects[0].shape_id = 5;
    s.objects[1].shape_id = 3;
    s
}

fn pose(p: Vector3<f64>, q: UnitQuaternion<f64>) -> Pose {
    let c = q.coords;
    Pose {
        translation: [p.x as f32, p.y as f32, p.z as f32],
        rotation: [c.x as f32, c.y as f32, c.z as f32, c.w as f32],
    }
}

fn entry(report: &EvalReport, k: u32, horizon_s: f64) -> &HorizonReport {
    report
        .step_sizes
        .iter()
        .find(|s| s.dt_steps == k)
        .and_then(|s| s.horizons.iter().find(|h| h.horizon_s == horizon_s))
        .expect("entry present")
}

/// Equal JSON trees, numbers to 1e-12 relative.
pub(crate) fn json_close(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            (x - y).abs() <= 1e-12 * x.abs().max(1.0)
        }
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(x, y)| json_close(x, y))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| json_close(v, w)))
        }
        _ => a == b,
    }
}
