//! Where does the resting drift's tail come from? Rolls every scene of a split out from frame
//! 4 at step size 1 (the evaluation's resting-drift rollout) with a model and with rapier
//! restarted from the same two frames, and for every object rapier's recording has at rest
//! over the evaluation's resting window (its last second, frames 76-100 of MOVi-B, with the
//! evaluation's thresholds: [`RestingOptions::at_rest`]) compares each predictor's state at
//! the window's first frame with the truth's: is the object *upright* (body z within 30 degrees of
//! vertical) in both, and is it still moving (faster than 0.05 m/s)? Prints, per shape and in
//! total, the mean drift over the window and the share of the summed drift carried by objects
//! whose upright-or-not attitude differs from the truth's at its first frame.
//!
//! ```sh
//! cargo run --release -p dynaserve-train --example drift_tail -- \
//!     models/rigidformer-small data/movi-b/test
//! ```
use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use dynaserve_model::Pose;
use dynaserve_sim::DatasetReader;
use dynaserve_train::eval::{
    DEFAULT_START_FRAME, ModelPredictor, PointSelection, Predictor, RapierRestart, RestingOptions,
    RolloutRequest, observed_state,
};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// Start frame of the rollout (the evaluation's).
const START: usize = DEFAULT_START_FRAME;
/// A predicted object still moving at the window's first frame: faster than this, m/s.
const MOVING_SPEED: f32 = 0.05;

#[derive(Default, Clone, Copy)]
struct Acc {
    objects: usize,
    drift: f64,
    /// Summed drift of the objects whose upright-or-not attitude at the window's first frame differs from the truth's.
    drift_attitude: f64,
    /// Objects whose attitude differs.
    attitude: usize,
    /// Summed drift of the objects still moving at the window's first frame.
    drift_moving: f64,
    /// Objects over 5 cm of drift.
    over_5cm: usize,
}

fn upright(q: [f32; 4]) -> bool {
    let q = UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2]));
    (q * Vector3::z()).z.abs() >= 30f32.to_radians().cos()
}

fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
    (Vector3::from(a) - Vector3::from(b)).norm()
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(model), Some(split)) = (args.get(1), args.get(2)) else {
        anyhow::bail!("usage: drift_tail MODEL_DIR SPLIT_DIR");
    };
    let reader = DatasetReader::open(split)?;
    let dt = reader.manifest().dt_frame;
    let rest = RestingOptions::default();
    let window = rest
        .window(reader.manifest().frames, f64::from(dt))
        .filter(|&(a, _)| a > START)
        .ok_or_else(|| anyhow::anyhow!("{split}: too few frames for the resting window"))?;
    let scenes = (0..reader.len())
        .map(|i| reader.get(i))
        .collect::<Result<Vec<_>, _>>()?;
    let model = ModelPredictor::load(Path::new(model))
        .with_context(|| format!("loading {model}"))?
        .with_points(PointSelection::Nominal);
    let rapier = RapierRestart::from_manifest(reader.manifest())?;
    let requests = scenes
        .iter()
        .map(|scene| {
            Ok(RolloutRequest {
                scene,
                observed: observed_state(scene, START, 1)?,
                dt_steps: 1,
                steps: window.1 - START,
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let predictors: [(&str, &dyn Predictor); 2] = [("model", &model), ("rapier", &rapier)];
    // Predicted poses at frame f are entry f - START - 1 of a rollout.
    let at = |r: &Vec<Vec<Pose>>, f: usize| r[f - START - 1].clone();
    for (label, p) in predictors {
        eprintln!("rolling out {} scenes with {label} ...", scenes.len());
        let rollouts = p.rollout_batch(&requests)?;
        let mut by_shape: BTreeMap<String, Acc> = BTreeMap::new();
        for (scene, r) in scenes.iter().zip(&rollouts) {
            let (first, next, last) = (at(r, window.0), at(r, window.0 + 1), at(r, window.1));
            for (i, o) in scene.objects.iter().enumerate() {
                if !rest.at_rest(o, window.0, window.1, f64::from(dt)) {
                    continue;
                }
                let drift = dist(last[i].translation, first[i].translation) as f64;
                let moving = dist(next[i].translation, first[i].translation) / dt > MOVING_SPEED;
                let differs = upright(o.rotations[window.0]) != upright(first[i].rotation);
                let name = reader.manifest().shape_name(o.shape_id);
                for key in [name, "all".to_string()] {
                    let a = by_shape.entry(key).or_default();
                    a.objects += 1;
                    a.drift += drift;
                    a.over_5cm += usize::from(drift > 0.05);
                    if differs {
                        a.attitude += 1;
                        a.drift_attitude += drift;
                    }
                    if moving {
                        a.drift_moving += drift;
                    }
                }
            }
        }
        println!(
            "{label} on {split}: objects at rest over frames {}-{} (truth)",
            window.0, window.1
        );
        println!(
            "{:<12} {:>7} {:>11} {:>8} {:>15} {:>16} {:>18}",
            "shape",
            "objects",
            "drift (m)",
            "> 5 cm",
            "attitude off",
            "drift share (att)",
            "drift share (moving)"
        );
        let mut rows: Vec<_> = by_shape.into_iter().collect();
        rows.sort_by_key(|(k, _)| k == "all");
        for (name, a) in rows {
            let share = |x: f64| 100.0 * x / a.drift.max(1e-12);
            println!(
                "{name:<12} {:>7} {:>11.4} {:>8} {:>15} {:>15.0}% {:>17.0}%",
                a.objects,
                a.drift / a.objects.max(1) as f64,
                a.over_5cm,
                a.attitude,
                share(a.drift_attitude),
                share(a.drift_moving)
            );
        }
    }
    Ok(())
}
