//! Gradients of a driven rollout's cost for planners: the request ([`GradientItem`]: a scene,
//! its start state, candidate paths of its kinematic objects and a [`PathCost`]) and the
//! answer ([`PathGradient`]: each candidate's cost, its gradient with respect to every
//! kinematic pose of its path, and the rollout it was measured on).
//!
//! A candidate is rolled out exactly as a driven Predict rolls it out ([`crate::Drive`]: the
//! kinematic objects are put at their given poses after each step, the network moves the
//! others), and its cost is
//!
//! `sum over targets of  w_p |p_j(s) - p*| + w_r (1 - cos angle(R_j(s), R*))`
//! `+ smoothness * sum over kinematic objects and steps of |p(t+1) - 2 p(t) + p(t-1)|^2`
//!
//! with `p_j(s)`, `R_j(s)` object `j`'s position (metres) and rotation after step `s`, and the
//! smoothness term over the kinematic translations of the path, the start state's two poses
//! included (metres squared). Rotation gradients are per radian of a small rotation about a
//! world axis applied to the pose, `R -> exp([w]x) R`.
//!
//! How the gradient is formed and where it is only piecewise defined: `docs/gradients.md`.

use std::time::Instant;

use crate::api::{Pose, SceneState};
use crate::{ModelError, PreparedScene};

/// One term of a [`PathCost`]: how far object `object` is after step `step` from a target pose.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CostTarget {
    /// Object index, in scene order.
    pub object: usize,
    /// The step after which the distance is measured, `1..=steps`.
    pub step: usize,
    /// Target centre of mass, metres, world frame.
    pub position: [f32; 3],
    /// Weight of the Euclidean distance to `position`, per metre (0: position ignored).
    pub position_weight: f32,
    /// Target orientation, unit quaternion `[x, y, z, w]`; `None` ignores the orientation.
    pub rotation: Option<[f32; 4]>,
    /// Weight of `1 - cos(angle)` between the orientation and `rotation` (0 to 2).
    pub rotation_weight: f32,
}

/// The cost of a candidate path (module docs): weighted distances to target poses plus the
/// path's smoothness.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PathCost {
    /// Distance terms, each object and step any number of times.
    pub targets: Vec<CostTarget>,
    /// Weight of the kinematic objects' squared second differences of translation, per m^2.
    pub smoothness: f32,
}

/// One call's share of a gradient pass: a scene, its start state and candidate paths of its
/// kinematic objects, each rolled out `steps` steps of `dt_steps` frames and scored by `cost`.
pub struct GradientItem<'a> {
    /// The prepared scene (for the model that computes the gradient).
    pub scene: &'a PreparedScene,
    /// The start state.
    pub state: &'a SceneState,
    /// `[objects]`: which objects follow the paths (at least one).
    pub kinematic: &'a [bool],
    /// Candidate paths `[candidates][steps][kinematic objects]`: the pose of every kinematic
    /// object (in object order) after each step.
    pub paths: &'a [Vec<Vec<Pose>>],
    /// Frames per step, `>= 1`.
    pub dt_steps: u32,
    /// The cost every candidate is scored by.
    pub cost: &'a PathCost,
    /// The work is abandoned between steps once this passes.
    pub deadline: Option<Instant>,
}

/// The answer for one candidate path.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PathGradient {
    /// The candidate's cost (module docs).
    pub cost: f64,
    /// d cost / d translation of every kinematic pose of the path, `[steps][kinematic][3]`,
    /// per metre.
    pub translation: Vec<Vec<[f32; 3]>>,
    /// d cost / d rotation of every kinematic pose of the path, `[steps][kinematic][3]`, per
    /// radian of a small world-axis rotation applied to the pose.
    pub rotation: Vec<Vec<[f32; 3]>>,
    /// The rollout the cost was measured on, `[steps][objects]` (what a driven Predict of
    /// the same path returns, within float rounding).
    pub poses: Vec<Vec<Pose>>,
}

impl GradientItem<'_> {
    /// Rollout length in steps (every candidate's path has this many poses).
    pub fn steps(&self) -> usize {
        self.paths.first().map_or(0, Vec::len)
    }

    /// Checks the item's shapes and cost against its scene: at least one candidate and one
    /// step, every path `[steps][kinematic objects]` with finite poses, cost targets naming
    /// an object and a step of the rollout, finite non-negative weights. `what` names the
    /// item in messages.
    pub fn validate(&self, what: &str) -> Result<(), ModelError> {
        let bad = |m: String| Err(ModelError::InvalidInput(format!("{what}: {m}")));
        let objects = self.scene.len();
        if self.kinematic.len() != objects {
            return bad(format!(
                "{} kinematic flags for {objects} objects",
                self.kinematic.len()
            ));
        }
        let driven = self.kinematic.iter().filter(|&&k| k).count();
        if driven == 0 {
            return bad("a gradient needs at least one kinematic object to differentiate".into());
        }
        if self.dt_steps == 0 {
            return bad("dt_steps must be at least 1".into());
        }
        let steps = self.steps();
        if self.paths.is_empty() || steps == 0 {
            return bad("at least one candidate path of at least one step is needed".into());
        }
        for (c, path) in self.paths.iter().enumerate() {
            if path.len() != steps {
                return bad(format!(
                    "candidate {c} has {} steps, candidate 0 has {steps}",
                    path.len()
                ));
            }
            for (s, poses) in path.iter().enumerate() {
                if poses.len() != driven {
                    return bad(format!(
                        "candidate {c} step {}: {} poses for {driven} kinematic objects",
                        s + 1,
                        poses.len()
                    ));
                }
                if let Some(p) = poses.iter().find(|p| !pose_is_finite(p)) {
                    return bad(format!(
                        "candidate {c} step {}: pose {p:?} is not finite or has a zero quaternion",
                        s + 1
                    ));
                }
            }
        }
        let c = self.cost;
        if !(c.smoothness.is_finite() && c.smoothness >= 0.0) {
            return bad(format!(
                "cost smoothness {} must be finite and >= 0",
                c.smoothness
            ));
        }
        for (i, t) in c.targets.iter().enumerate() {
            if t.object >= objects {
                return bad(format!(
                    "cost target {i} names object {} of {objects}",
                    t.object
                ));
            }
            if t.step == 0 || t.step > steps {
                return bad(format!(
                    "cost target {i} names step {}, the rollout has steps 1 to {steps}",
                    t.step
                ));
            }
            let weights_ok = [t.position_weight, t.rotation_weight]
                .iter()
                .all(|w| w.is_finite() && *w >= 0.0);
            if !weights_ok || t.position.iter().any(|v| !v.is_finite()) {
                return bad(format!(
                    "cost target {i}: weights must be finite and >= 0 and the position finite"
                ));
            }
            if let Some(q) = t.rotation
                && (q.iter().any(|v| !v.is_finite())
                    || q.iter().map(|v| v * v).sum::<f32>() < 1e-12)
            {
                return bad(format!(
                    "cost target {i}: rotation {q:?} is not a quaternion"
                ));
            }
        }
        Ok(())
    }
}

fn pose_is_finite(p: &Pose) -> bool {
    p.translation
        .iter()
        .chain(&p.rotation)
        .all(|v| v.is_finite())
        && p.rotation.iter().map(|v| v * v).sum::<f32>() > 1e-12
}

/// The cost of one rollout by `cost` (module docs), computed on the host in f64: `poses` is
/// `[steps][objects]` after each step, `start` the state before the first step and
/// `kinematic` the scene's mask. The reference the gradient pass's cost is checked against.
pub fn path_cost(
    cost: &PathCost,
    start: &SceneState,
    kinematic: &[bool],
    poses: &[Vec<Pose>],
) -> f64 {
    let mut total = 0.0f64;
    for t in &cost.targets {
        let Some(p) = poses
            .get(t.step.wrapping_sub(1))
            .and_then(|f| f.get(t.object))
        else {
            continue;
        };
        if t.position_weight > 0.0 {
            let d2: f64 = (0..3)
                .map(|i| (f64::from(p.translation[i]) - f64::from(t.position[i])).powi(2))
                .sum();
            total += f64::from(t.position_weight) * d2.sqrt();
        }
        if let (Some(q), true) = (t.rotation, t.rotation_weight > 0.0) {
            let a = p.unit_quaternion().cast::<f64>();
            let b = Pose {
                translation: [0.0; 3],
                rotation: q,
            }
            .unit_quaternion()
            .cast::<f64>();
            total += f64::from(t.rotation_weight) * (1.0 - a.angle_to(&b).cos());
        }
    }
    if cost.smoothness > 0.0 {
        for (j, _) in kinematic.iter().enumerate().filter(|(_, k)| **k) {
            let mut track: Vec<[f64; 3]> = vec![
                start.previous[j].translation.map(f64::from),
                start.current[j].translation.map(f64::from),
            ];
            track.extend(poses.iter().map(|f| f[j].translation.map(f64::from)));
            for w in track.windows(3) {
                total += f64::from(cost.smoothness)
                    * (0..3)
                        .map(|i| (w[2][i] - 2.0 * w[1][i] + w[0][i]).powi(2))
                        .sum::<f64>();
            }
        }
    }
    total
}
