//! Ensembles: several RigidFormer checkpoints of one configuration served as one model whose
//! every step is the mean of the members' steps.
//!
//! An ensemble directory holds a `config.json` of the form
//! `{"architecture": "rigidformer-ensemble", "members": ["a", "b"]}` (member directories,
//! relative to the ensemble's own directory, or absolute), optionally `"weights": [2, 1]`
//! (each member's relative weight in the mean; equal when absent) and `"yaw_copies": 4`
//! (below), and a `card.md`. Each
//! member is an ordinary checkpoint directory. Members must serve scenes alike
//! ([`ModelConfig::serving_mismatch`]: frame interval, gravity, limits, scene-relative mass,
//! normal estimation, the kinematic lead); their sizes, input features and normalisation may
//! differ, so releases of different architectures can be combined. A scene is prepared once
//! for each distinct anchor and grouping size among the members ([`crate::PreparedKey`]):
//! once when all share them, as releases of one architecture do. The ensemble reports the first member's
//! configuration (its trained ranges among it) and its members' names
//! ([`WorldModel::member_names`]).
//!
//! A step runs every member from the same state and averages the new poses object by object:
//! the weighted arithmetic mean of the translations and the normalised weighted sum of the
//! rotations' unit quaternions, each first put on the first member's hemisphere (`q` and `-q`
//! are one rotation). For rotations a few degrees apart, as members' one-step predictions
//! are, that sum is the rotation mean to well under a thousandth of a degree. The rollout
//! continues from the mean, so the members never drift apart. Averaging predictions, unlike
//! averaging weights (`dynaserve train average`), needs no shared training history; it costs
//! one network pass per member.
//!
//! A step also reports, object by object, how far the members disagree
//! ([`WorldModel::step_with_spread`], [`weighted_pose_spread`]): the weighted root mean square
//! distance of the predicted translations from the mean translation (metres) and the weighted
//! root mean square rotation angle of the predicted rotations from the mean rotation
//! (degrees), over the same weighted predictions the mean averages (turned copies among them).
//! It describes that step's prediction from the state the rollout reached through the means.
//!
//! With `yaw_copies = n > 1` every member also steps `n - 1` copies of each scene turned
//! about the vertical through the scene's centre (the mean of its current centres) by
//! multiples of 360/n degrees; each copy's answer is turned back and weighs as much as the
//! original's. Rigid motion under vertical gravity above a horizontal floor is the same in
//! every turned copy, and a network trained with turned windows is close to, not exactly,
//! indifferent to the turn, so the mean cancels part of its error. The copies go through the
//! network in the same pass as the originals (one pass of `n` times the tokens per member).

use std::path::{Path, PathBuf};

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::Deserialize;

use crate::checkpoint::{dir_name, load_rigidformer, parse_config};
use crate::rigidformer::RigidFormer;
use crate::{
    ModelConfig, ModelError, ObjectInput, Pose, PoseSpread, PreparedScene, SceneState, SpreadStep,
    StepItem, WorldModel,
};

/// `architecture` of an ensemble directory's `config.json`.
pub const ENSEMBLE: &str = "rigidformer-ensemble";

/// Most members an ensemble may list (each costs one network pass per step).
pub const MAX_MEMBERS: usize = 8;

/// The `config.json` of an ensemble directory.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnsembleConfig {
    /// Always [`ENSEMBLE`].
    pub architecture: String,
    /// Member checkpoint directories, relative to the ensemble directory or absolute (1 to
    /// [`MAX_MEMBERS`]).
    pub members: Vec<PathBuf>,
    /// Each member's relative weight in the mean (positive and finite, one per member; they
    /// need not sum to 1). Equal weights when absent.
    #[serde(default)]
    pub weights: Option<Vec<f32>>,
    /// Turned copies of each scene every member steps, the original among them (module
    /// docs; 1 to [`MAX_YAW_COPIES`]). 1 when absent: no copies.
    #[serde(default)]
    pub yaw_copies: Option<u32>,
}

/// Most turned copies of a scene an ensemble may step ([`EnsembleConfig::yaw_copies`]).
pub const MAX_YAW_COPIES: u32 = 16;

/// RigidFormer checkpoints that serve scenes alike, whose steps are averaged (module docs).
pub struct Ensemble {
    name: String,
    members: Vec<RigidFormer>,
    /// Each member's weight, summing to 1.
    weights: Vec<f32>,
    /// Turned copies of each scene every member steps ([`EnsembleConfig::yaw_copies`]).
    yaw_copies: u32,
}

impl Ensemble {
    /// Builds an ensemble of already loaded members; fails if there are none, more than
    /// [`MAX_MEMBERS`], or one serves scenes differently from the first
    /// ([`ModelConfig::serving_mismatch`]).
    pub fn new(name: impl Into<String>, members: Vec<RigidFormer>) -> Result<Ensemble, ModelError> {
        let name = name.into();
        let weights = member_weights(&name, members.len(), None)?;
        Ensemble::assemble(name, members, weights)
    }

    /// [`Ensemble::new`] with each member's relative weight in the mean (one per member,
    /// positive and finite; scaled here to sum to 1).
    pub fn weighted(
        name: impl Into<String>,
        members: Vec<RigidFormer>,
        weights: &[f32],
    ) -> Result<Ensemble, ModelError> {
        let name = name.into();
        let weights = member_weights(&name, members.len(), Some(weights))?;
        Ensemble::assemble(name, members, weights)
    }

    /// The ensemble of `members` with `weights` already checked and normalised
    /// ([`member_weights`]), after checking that every member serves scenes as the first does.
    fn assemble(
        name: String,
        members: Vec<RigidFormer>,
        weights: Vec<f32>,
    ) -> Result<Ensemble, ModelError> {
        for (i, m) in members.iter().enumerate().skip(1) {
            if let Some(field) = members[0].config().serving_mismatch(m.config()) {
                return Err(ModelError::Checkpoint(format!(
                    "ensemble {name:?}: member {i} ({}) differs from member 0 ({}) in {field}; \
                     members must step the same scenes from the same states",
                    m.name(),
                    members[0].name()
                )));
            }
        }
        Ok(Ensemble {
            name,
            members,
            weights,
            yaw_copies: 1,
        })
    }

    /// This ensemble stepping `copies` turned copies of every scene (module docs); refuses 0
    /// and more than [`MAX_YAW_COPIES`].
    pub fn with_yaw_copies(mut self, copies: u32) -> Result<Ensemble, ModelError> {
        if copies == 0 || copies > MAX_YAW_COPIES {
            return Err(ModelError::Checkpoint(format!(
                "ensemble {:?}: yaw_copies is {copies}; give 1 to {MAX_YAW_COPIES}",
                self.name
            )));
        }
        self.yaw_copies = copies;
        Ok(self)
    }

    /// Turned copies of each scene every member steps (1: none besides the original).
    pub fn yaw_copies(&self) -> u32 {
        self.yaw_copies
    }

    /// Loads the ensemble directory `dir` (module docs) with its members' weights on `device`.
    pub fn load(dir: &Path, device: &crate::Device) -> Result<Ensemble, ModelError> {
        let config: EnsembleConfig = parse_config(dir, "ensemble configuration")?;
        if config.architecture != ENSEMBLE {
            return Err(ModelError::Checkpoint(format!(
                "{}: architecture {:?} is not {ENSEMBLE:?}",
                dir.display(),
                config.architecture
            )));
        }
        // Checked before any member's weights are read.
        let weights = member_weights(
            &dir.display().to_string(),
            config.members.len(),
            config.weights.as_deref(),
        )?;
        let members = config
            .members
            .iter()
            .map(|m| {
                let member = dir.join(m);
                load_rigidformer(&member, device, false).map_err(|e| {
                    ModelError::Checkpoint(format!("ensemble member {}: {e}", member.display()))
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ensemble::assemble(dir_name(dir, ENSEMBLE), members, weights)?
            .with_yaw_copies(config.yaw_copies.unwrap_or(1))
    }

    /// The members, in the order of `config.json`.
    pub fn members(&self) -> &[RigidFormer] {
        &self.members
    }

    /// Each member's weight in the mean, in member order; they sum to 1.
    pub fn weights(&self) -> &[f32] {
        &self.weights
    }
}

/// The weights of an ensemble (`what` names it) of `n` members, scaled to sum to 1: `weights`,
/// or equal weights when `None`. Refuses `n` outside `1..=MAX_MEMBERS`, a count of weights
/// other than `n`, and a weight that is not positive and finite.
fn member_weights(what: &str, n: usize, weights: Option<&[f32]>) -> Result<Vec<f32>, ModelError> {
    if n == 0 || n > MAX_MEMBERS {
        return Err(ModelError::Checkpoint(format!(
            "{what}: an ensemble lists 1 to {MAX_MEMBERS} members, this one {n}"
        )));
    }
    let Some(weights) = weights else {
        return Ok(vec![1.0 / n as f32; n]);
    };
    if weights.len() != n {
        return Err(ModelError::Checkpoint(format!(
            "{what}: {} weights for {n} members; give one weight per member",
            weights.len()
        )));
    }
    if let Some(i) = weights.iter().position(|w| !(w.is_finite() && *w > 0.0)) {
        return Err(ModelError::Checkpoint(format!(
            "{what}: weight {i} is {}; weights must be positive and finite",
            weights[i]
        )));
    }
    // Scaled by the largest first, so that no sum of finite weights overflows.
    let largest = weights.iter().fold(0.0f32, |m, w| m.max(*w));
    let total: f32 = weights.iter().map(|w| w / largest).sum();
    Ok(weights.iter().map(|w| w / largest / total).collect())
}

/// The mean of several predictions of one object's pose (module docs); `poses` is not empty.
pub fn mean_pose(poses: &[Pose]) -> Pose {
    weighted_mean_pose(poses, &vec![1.0; poses.len()])
}

/// The weighted mean of several predictions of one object's pose (module docs): `weights[i]`
/// (positive, with a finite sum; the ensemble's sum to 1) weighs `poses[i]`; `poses` is not
/// empty and as long as `weights`.
pub fn weighted_mean_pose(poses: &[Pose], weights: &[f32]) -> Pose {
    let total: f32 = weights.iter().sum();
    let total = if total > 0.0 { total } else { 1.0 };
    let translation = poses
        .iter()
        .zip(weights)
        .fold(Vector3::zeros(), |s, (p, w)| {
            s + Vector3::from(p.translation) * *w
        })
        / total;
    let first = poses.first().map(|p| p.unit_quaternion().into_inner());
    let sum = poses
        .iter()
        .zip(weights)
        .fold(Quaternion::new(0.0, 0.0, 0.0, 0.0), |s, (p, w)| {
            let q = p.unit_quaternion().into_inner() * *w;
            match first {
                Some(f) if q.dot(&f) < 0.0 => s - q,
                _ => s + q,
            }
        });
    // A positively weighted sum of unit quaternions on one hemisphere is never zero.
    let rotation = UnitQuaternion::try_new(sum, 1e-12).unwrap_or_else(UnitQuaternion::identity);
    Pose::from_parts(translation, rotation)
}

/// How far weighted predictions of one object's pose lie from their mean `mean` (module docs):
/// the weighted root mean square distance of the translations from the mean's (metres) and of
/// the rotation angles from the mean's rotation (degrees, `q` and `-q` alike). `weights[i]`
/// (positive, with a finite sum) weighs `poses[i]`; `poses` is as long as `weights`.
pub fn weighted_pose_spread(poses: &[Pose], weights: &[f32], mean: &Pose) -> PoseSpread {
    let total: f64 = weights.iter().map(|w| f64::from(*w)).sum();
    if poses.is_empty() || total.is_nan() || total <= 0.0 {
        return PoseSpread::default();
    }
    let quaternion = |p: &Pose| {
        let [x, y, z, w] = p.rotation.map(f64::from);
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
    };
    let centre = Vector3::from(mean.translation.map(f64::from));
    let inverse = quaternion(mean).inverse();
    let (mut distance, mut angle) = (0.0f64, 0.0f64);
    for (p, w) in poses.iter().zip(weights) {
        let w = f64::from(*w) / total;
        distance += w * (Vector3::from(p.translation.map(f64::from)) - centre).norm_squared();
        // The relative rotation's angle, 2 atan2(|v|, |s|): accurate for small angles too.
        let r = (inverse * quaternion(p)).into_inner();
        let a = 2.0 * r.imag().norm().atan2(r.scalar().abs());
        angle += w * a * a;
    }
    PoseSpread {
        position_m: distance.sqrt() as f32,
        orientation_deg: angle.sqrt().to_degrees() as f32,
    }
}

impl Ensemble {
    /// Every scene's mean poses and, with `spread`, each object's spread around them.
    fn combine(&self, batch: &[StepItem<'_>], spread: bool) -> Result<Vec<SpreadStep>, ModelError> {
        let copies = self.yaw_copies as usize;
        let turns: Vec<Yaw> = (1..copies)
            .flat_map(|c| {
                let angle = std::f32::consts::TAU * c as f32 / copies as f32;
                batch
                    .iter()
                    .map(move |it| Yaw::about_centre(angle, &it.state.current))
            })
            .collect();
        let turned_states: Vec<SceneState> = turns
            .iter()
            .zip(batch.iter().cycle())
            .map(|(yaw, it)| yaw.state(it.state))
            .collect();
        let items: Vec<StepItem<'_>> = batch
            .iter()
            .copied()
            .chain(
                turned_states
                    .iter()
                    .zip(batch.iter().cycle())
                    .map(|(state, it)| StepItem { state, ..*it }),
            )
            .collect();
        let outputs = self
            .members
            .iter()
            .map(|m| m.step(&items))
            .collect::<Result<Vec<_>, _>>()?;
        let shaped = |o: &Vec<Vec<Pose>>| {
            o.len() == items.len()
                && o.iter()
                    .zip(&items)
                    .all(|(s, it)| s.len() == it.scene.len())
        };
        if !outputs.iter().all(shaped) {
            return Err(ModelError::Internal(
                "an ensemble member returned another number of scenes or objects".into(),
            ));
        }
        // Weight of one member's answer on one copy.
        let weights: Vec<f32> = self
            .weights
            .iter()
            .flat_map(|w| std::iter::repeat_n(w / copies as f32, copies))
            .collect();
        let mut poses = Vec::with_capacity(weights.len());
        Ok((0..batch.len())
            .map(|scene| {
                let objects = batch[scene].scene.len();
                let mut step = SpreadStep {
                    poses: Vec::with_capacity(objects),
                    spread: spread.then(|| Vec::with_capacity(objects)),
                };
                for object in 0..objects {
                    poses.clear();
                    for o in &outputs {
                        poses.push(o[scene][object]);
                        poses.extend((1..copies).map(|c| {
                            let k = (c - 1) * batch.len() + scene;
                            turns[k].back(o[batch.len() + k][object])
                        }));
                    }
                    let mean = weighted_mean_pose(&poses, &weights);
                    if let Some(s) = step.spread.as_mut() {
                        // A kinematic object's pose is given, not predicted: nothing to be
                        // unsure of.
                        s.push(if batch[scene].scene.objects[object].kinematic {
                            PoseSpread::default()
                        } else {
                            weighted_pose_spread(&poses, &weights, &mean)
                        });
                    }
                    step.poses.push(mean);
                }
                step
            })
            .collect())
    }
}

impl WorldModel for Ensemble {
    fn name(&self) -> &str {
        &self.name
    }

    fn config(&self) -> &ModelConfig {
        self.members[0].config()
    }

    fn prepare(&self, objects: Vec<ObjectInput>) -> Result<PreparedScene, ModelError> {
        // The first member of each anchor and grouping size prepares the scene for all members
        // of that size; the first member's preparation carries the others.
        let key = |m: &RigidFormer| m.config().prepared_key();
        let first = &self.members[0];
        if self.members.iter().all(|m| key(m) == key(first)) {
            return first.prepare(objects);
        }
        let mut scene = first.prepare(objects.clone())?;
        for m in &self.members[1..] {
            if scene.for_key(key(m)).is_none() {
                scene.attach(m.prepare(objects.clone())?)?;
            }
        }
        Ok(scene)
    }

    fn step(&self, batch: &[StepItem<'_>]) -> Result<Vec<Vec<Pose>>, ModelError> {
        Ok(self
            .combine(batch, false)?
            .into_iter()
            .map(|s| s.poses)
            .collect())
    }

    fn step_with_spread(&self, batch: &[StepItem<'_>]) -> Result<Vec<SpreadStep>, ModelError> {
        self.combine(batch, true)
    }

    fn member_names(&self) -> Vec<String> {
        self.members.iter().map(|m| m.name().to_string()).collect()
    }
}

/// A turn about the vertical through a pivot: how a copy of a scene is made and its answer
/// turned back ([`EnsembleConfig::yaw_copies`]).
struct Yaw {
    /// The turn, body to world of the copy.
    rotation: UnitQuaternion<f32>,
    /// Point of the vertical axis, metres (z is 0).
    pivot: Vector3<f32>,
}

impl Yaw {
    /// The turn by `angle` radians about the vertical through the mean horizontal position of
    /// `poses` (the origin for no poses).
    fn about_centre(angle: f32, poses: &[Pose]) -> Yaw {
        let n = poses.len().max(1) as f32;
        let sum = poses.iter().fold(Vector3::zeros(), |s, p| {
            s + Vector3::new(p.translation[0], p.translation[1], 0.0)
        });
        Yaw {
            rotation: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), angle),
            pivot: sum / n,
        }
    }

    /// `pose` turned by `rotation` about the pivot.
    fn apply(&self, rotation: &UnitQuaternion<f32>, pose: Pose) -> Pose {
        let t = Vector3::from(pose.translation) - self.pivot;
        Pose::from_parts(self.pivot + rotation * t, rotation * pose.unit_quaternion())
    }

    /// `pose` in the turned copy.
    fn turn(&self, pose: Pose) -> Pose {
        self.apply(&self.rotation, pose)
    }

    /// A pose of the turned copy brought back to the original scene.
    fn back(&self, pose: Pose) -> Pose {
        self.apply(&self.rotation.inverse(), pose)
    }

    /// `state` with every pose turned.
    fn state(&self, state: &SceneState) -> SceneState {
        let turn = |poses: &[Pose]| poses.iter().map(|p| self.turn(*p)).collect::<Vec<_>>();
        SceneState {
            previous: turn(&state.previous),
            current: turn(&state.current),
            earlier: state.earlier.as_deref().map(turn),
            carry: Default::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Device;

    /// A box's surface, `n` points per face side, half extents `h` (metres).
    fn box_points(n: usize, h: [f32; 3]) -> Vec<[f32; 3]> {
        let mut points = Vec::new();
        for axis in 0..3 {
            for side in [-1.0, 1.0] {
                for i in 0..n {
                    for j in 0..n {
                        let u = (i as f32 + 0.5) / n as f32 * 2.0 - 1.0;
                        let v = (j as f32 + 0.5) / n as f32 * 2.0 - 1.0;
                        let mut p = [0.0; 3];
                        p[axis] = side * h[axis];
                        p[(axis + 1) % 3] = u * h[(axis + 1) % 3];
                        p[(axis + 2) % 3] = v * h[(axis + 2) % 3];
                        points.push(p);
                    }
                }
            }
        }
        points
    }

    #[test]
    fn the_spread_of_two_members_is_their_weighted_rms_disagreement() {
        let member = |seed| RigidFormer::new(ModelConfig::tiny(), seed, &Device::Cpu).unwrap();
        let ensemble = Ensemble::weighted("pair", vec![member(1), member(2)], &[3.0, 1.0]).unwrap();
        let objects: Vec<ObjectInput> = [[0.2, 0.3, 0.25], [0.4, 0.2, 0.3]]
            .into_iter()
            .map(|h| ObjectInput {
                reference: box_points(4, h),
                mass: 1.5,
                friction: 0.5,
                restitution: 0.3,
                kinematic: false,
            })
            .collect();
        let scene = ensemble.prepare(objects).unwrap();
        let at = |x: f32, z: f32, yaw: f32| {
            Pose::from_parts(
                Vector3::new(x, 0.1, z),
                UnitQuaternion::from_euler_angles(0.3, 0.1, yaw),
            )
        };
        let state = SceneState::new(
            vec![at(0.0, 1.0, 0.0), at(1.0, 0.6, 0.5)],
            vec![at(0.1, 0.95, 0.1), at(0.95, 0.5, 0.6)],
        );
        let batch = [StepItem {
            scene: &scene,
            state: &state,
            dt_steps: 2,
        }];
        let got = ensemble.step_with_spread(&batch).unwrap().remove(0);
        // The poses are the plain step's; a single network estimates no spread.
        assert_eq!(got.poses, ensemble.step(&batch).unwrap()[0]);
        let single = ensemble.members()[0].step_with_spread(&batch).unwrap();
        assert_eq!(single[0].spread, None);
        let spread = got.spread.expect("an ensemble estimates a spread");
        assert_eq!(spread.len(), 2);

        let a = ensemble.members()[0].step(&batch).unwrap().remove(0);
        let b = ensemble.members()[1].step(&batch).unwrap().remove(0);
        let (w0, w1) = (0.75f64, 0.25f64);
        for j in 0..2 {
            // Two points weighted w0, w1 lie w1 d and w0 d from their mean (d apart), so their
            // RMS distance is sqrt(w0 w1) d.
            let d = (0..3)
                .map(|k| f64::from(a[j].translation[k] - b[j].translation[k]).powi(2))
                .sum::<f64>()
                .sqrt();
            let position = (w0 * w1).sqrt() * d;
            // Two rotations theta apart: the normalised weighted quaternion sum lies on the
            // geodesic between them, half-angle phi from the first with
            // tan(phi) = w1 sin(theta/2) / (w0 + w1 cos(theta/2)).
            let dot: f64 = (0..4)
                .map(|k| f64::from(a[j].rotation[k]) * f64::from(b[j].rotation[k]))
                .sum();
            let theta = 2.0 * dot.abs().min(1.0).acos();
            let phi = (w1 * (theta / 2.0).sin()).atan2(w0 + w1 * (theta / 2.0).cos());
            let orientation = (w0 * (2.0 * phi).powi(2) + w1 * (theta - 2.0 * phi).powi(2))
                .sqrt()
                .to_degrees();
            assert!(position > 1e-4 && orientation > 1e-3, "members agree");
            let s = spread[j];
            assert!(
                (f64::from(s.position_m) - position).abs() < 1e-6,
                "object {j}: {s:?} vs {position} m"
            );
            assert!(
                (f64::from(s.orientation_deg) - orientation).abs() < 1e-3,
                "object {j}: {s:?} vs {orientation} deg"
            );
        }
    }

    #[test]
    fn identical_predictions_have_no_spread() {
        let p = Pose::from_parts(
            Vector3::new(1.0, 2.0, 0.5),
            UnitQuaternion::from_euler_angles(0.2, 0.4, 1.0),
        );
        let mut q = p;
        q.rotation = q.rotation.map(|c| -c);
        let s = weighted_pose_spread(
            &[p, q],
            &[0.5, 0.5],
            &weighted_mean_pose(&[p, q], &[0.5; 2]),
        );
        assert!(s.position_m < 1e-7 && s.orientation_deg < 1e-3, "{s:?}");
    }
}
