//! The inference interface every world model implements and every caller (server, trainer,
//! evaluator, client) uses.
//!
//! Conventions: metres, seconds, z up, ground plane at z = 0. A pose maps body coordinates
//! (origin at the centre of mass) to world coordinates: `x_world = R x_body + p`. Quaternions
//! are `[x, y, z, w]`. A *step* advances `dt_steps` recorded frames of the model's
//! `dt_frame` (see [`ModelConfig`]).

use nalgebra::{UnitQuaternion, Vector3};

use crate::{ModelConfig, ModelError};

/// Rigid pose of one object: centre-of-mass position (metres, world frame) and orientation
/// (unit quaternion `[x, y, z, w]`, body to world).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pose {
    /// Centre of mass in the world frame, metres.
    pub translation: [f32; 3],
    /// Unit quaternion `[x, y, z, w]`, body to world.
    pub rotation: [f32; 4],
}

impl Pose {
    /// The identity pose at the origin.
    pub const IDENTITY: Pose = Pose {
        translation: [0.0; 3],
        rotation: [0.0, 0.0, 0.0, 1.0],
    };

    /// Orientation as an nalgebra unit quaternion (renormalised).
    pub fn unit_quaternion(&self) -> UnitQuaternion<f32> {
        let [x, y, z, w] = self.rotation;
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z))
    }

    /// Builds a pose from an nalgebra rotation and a translation in metres.
    pub fn from_parts(translation: Vector3<f32>, rotation: UnitQuaternion<f32>) -> Pose {
        let c = rotation.coords;
        Pose {
            translation: [translation.x, translation.y, translation.z],
            rotation: [c.x, c.y, c.z, c.w],
        }
    }

    /// Maps a body-frame point (metres) to the world frame.
    pub fn transform_point(&self, x: [f32; 3]) -> [f32; 3] {
        let y = self.unit_quaternion() * Vector3::from(x) + Vector3::from(self.translation);
        [y.x, y.y, y.z]
    }
}

/// One rigid object as a model input: its surface point cloud in the body frame and its
/// physical parameters.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ObjectInput {
    /// Surface points `[n, 3]` in the body frame (origin at the centre of mass), metres.
    pub reference: Vec<[f32; 3]>,
    /// Mass in kilograms.
    pub mass: f32,
    /// Coulomb friction coefficient (dimensionless).
    pub friction: f32,
    /// Coefficient of restitution in `[0, 1]`.
    pub restitution: f32,
    /// Moved along given poses by the caller (a kinematic body, such as a pusher): its mass
    /// has no effect on the others' motion, so a relative-mass model neither takes its scale
    /// from it nor reads it ([`crate::model_masses`]). Absent means false.
    #[serde(default)]
    pub kinematic: bool,
}

/// The two most recent poses of every object, `dt_steps` frames apart, and optionally the
/// poses one step before those: the state a step advances. `previous[j]`, `current[j]` and
/// `earlier[j]` belong to object `j`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SceneState {
    /// Poses one step (`dt_steps` frames) before `current`.
    pub previous: Vec<Pose>,
    /// The latest poses.
    pub current: Vec<Pose>,
    /// Poses one step before `previous` (`2 dt_steps` frames before `current`), when known:
    /// a model with history inputs ([`crate::DynamicsConfig::history`]) reads from them how
    /// the motion changed over the previous step; others ignore them. `None` (absent in JSON)
    /// reads as unknown. [`SceneState::advance`] fills it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub earlier: Option<Vec<Pose>>,
    /// What a stepping family keeps of a scene beyond its poses (a simulator's contacts and
    /// velocities), valid for exactly these poses; empty for families that need nothing
    /// (RigidFormer). Never serialised; [`SceneState::advance`] empties it.
    #[serde(skip)]
    pub carry: Carry,
}

/// A family's opaque continuation of a [`SceneState`] (see [`SceneState::carry`]): shared
/// read-only between copies of the state, ignored by comparisons. A family that finds it
/// empty, or of a type it does not know, rebuilds what it needs from the poses.
#[derive(Clone, Default)]
pub struct Carry(Option<std::sync::Arc<dyn std::any::Any + Send + Sync>>);

impl Carry {
    /// A continuation holding `value`.
    pub fn new<T: std::any::Any + Send + Sync>(value: T) -> Carry {
        Carry(Some(std::sync::Arc::new(value)))
    }

    /// The value, when there is one of type `T`.
    pub fn get<T: std::any::Any + Send + Sync>(&self) -> Option<&T> {
        self.0.as_deref().and_then(|v| v.downcast_ref::<T>())
    }

    /// True when nothing is kept.
    pub fn is_empty(&self) -> bool {
        self.0.is_none()
    }
}

impl std::fmt::Debug for Carry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "Carry(..)"
        } else {
            "Carry(empty)"
        })
    }
}

/// Two continuations always compare equal: a state is its poses.
impl PartialEq for Carry {
    fn eq(&self, _: &Carry) -> bool {
        true
    }
}

impl SceneState {
    /// Builds a state from current poses and velocities by stepping back `dt_seconds`
    /// (`dt_steps * dt_frame`): `p_prev = p - v dt`, `R_prev = exp(-w dt) R`.
    ///
    /// `linear`: `[objects, 3]` m/s; `angular`: `[objects, 3]` rad/s, world frame.
    pub fn from_velocities(
        current: Vec<Pose>,
        linear: &[[f32; 3]],
        angular: &[[f32; 3]],
        dt_seconds: f32,
    ) -> Result<SceneState, ModelError> {
        if linear.len() != current.len() || angular.len() != current.len() {
            return Err(ModelError::InvalidInput(format!(
                "velocities: expected {} objects, got {} linear and {} angular",
                current.len(),
                linear.len(),
                angular.len()
            )));
        }
        let previous = current
            .iter()
            .zip(linear.iter().zip(angular))
            .map(|(pose, (v, w))| {
                let p = Vector3::from(pose.translation) - Vector3::from(*v) * dt_seconds;
                let back = UnitQuaternion::from_scaled_axis(-Vector3::from(*w) * dt_seconds);
                Pose::from_parts(p, back * pose.unit_quaternion())
            })
            .collect();
        Ok(SceneState::new(previous, current))
    }

    /// A state of two poses per object (`previous` one step before `current`), nothing earlier.
    pub fn new(previous: Vec<Pose>, current: Vec<Pose>) -> SceneState {
        SceneState {
            previous,
            current,
            earlier: None,
            carry: Carry::default(),
        }
    }

    /// Moves the state one step on: `previous` becomes `earlier`, `current` becomes
    /// `previous` and `next` (the poses the step produced, one per object) becomes `current`.
    pub fn advance(&mut self, next: Vec<Pose>) {
        let previous = std::mem::replace(&mut self.current, next);
        self.earlier = Some(std::mem::replace(&mut self.previous, previous));
        self.carry = Carry::default();
    }

    /// The state as a step reads it when the kinematic objects' poses after the step are
    /// known ([`crate::DynamicsConfig::kinematic_lead`]): each object flagged in `kinematic`
    /// gets the `previous` (and, when known, `earlier`) poses from which constant motion
    /// arrives at `next` (the rigid-body extrapolation run backwards: centre `2 p_t - p_{t+k}`,
    /// rotation `R_t R_{t+k}^T R_t`), so its increments are the coming one, not the last.
    /// Other objects are unchanged. `kinematic` and `next` have one entry per object (a
    /// shorter slice leaves the objects past its end unchanged).
    pub fn lead_kinematic(&self, kinematic: &[bool], next: &[Pose]) -> SceneState {
        let mut led = self.clone();
        let back = |from: &Pose, to: &Pose| {
            let (pf, pt) = (
                Vector3::from(from.translation),
                Vector3::from(to.translation),
            );
            let (rf, rt) = (from.unit_quaternion(), to.unit_quaternion());
            Pose::from_parts(2.0 * pf - pt, rf * rt.inverse() * rf)
        };
        for (j, (&k, n)) in kinematic.iter().zip(next).enumerate() {
            let Some(now) = self.current.get(j) else {
                break;
            };
            if !k {
                continue;
            }
            let previous = back(now, n);
            if let Some(e) = led.earlier.as_mut().and_then(|e| e.get_mut(j)) {
                *e = back(&previous, now);
            }
            if let Some(p) = led.previous.get_mut(j) {
                *p = previous;
            }
        }
        led
    }

    /// Number of objects.
    pub fn len(&self) -> usize {
        self.current.len()
    }

    /// True for a scene without objects.
    pub fn is_empty(&self) -> bool {
        self.current.is_empty()
    }
}

/// One scene's request inside a batched step.
#[derive(Clone, Copy, Debug)]
pub struct StepItem<'a> {
    /// The prepared (validated, cached) scene.
    pub scene: &'a crate::PreparedScene,
    /// Its two most recent poses, `dt_steps` frames apart.
    pub state: &'a SceneState,
    /// Step size in recorded frames (the model's `dt_frame` units), `>= 1`.
    pub dt_steps: u32,
}

/// How far the predictions a step combines disagree on one object's new pose: the model's own
/// estimate of its uncertainty there (an ensemble's members' disagreement).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PoseSpread {
    /// Root mean square distance of the predicted positions from the served one, metres.
    pub position_m: f32,
    /// Root mean square rotation angle of the predicted orientations from the served one,
    /// degrees.
    pub orientation_deg: f32,
}

/// One scene's result of [`WorldModel::step_with_spread`].
#[derive(Clone, Debug, PartialEq)]
pub struct SpreadStep {
    /// Every object's new pose, as [`WorldModel::step`] gives it, `[objects]`.
    pub poses: Vec<Pose>,
    /// Every object's spread, `[objects]`; `None` when the model estimates none.
    pub spread: Option<Vec<PoseSpread>>,
}

/// A learned world model that advances rigid scenes one step at a time.
///
/// Implementations are resident in memory, thread-safe, and give every scene of a batch the
/// same result it would get alone (up to floating-point reassociation, about 1e-5 m).
pub trait WorldModel: Send + Sync {
    /// The model's name (its checkpoint directory name).
    fn name(&self) -> &str;
    /// Architecture and data conventions (from `config.json`).
    fn config(&self) -> &ModelConfig;
    /// Validates a scene and computes what stays fixed over a rollout (anchors, grouping).
    fn prepare(&self, objects: Vec<ObjectInput>) -> Result<crate::PreparedScene, ModelError>;
    /// Advances every scene of `batch` by one step in one pass. `output[i][j]` is the new pose
    /// of object `j` of scene `i`, `batch[i].dt_steps` frames after `batch[i].state.current`.
    fn step(&self, batch: &[StepItem<'_>]) -> Result<Vec<Vec<Pose>>, ModelError>;
    /// [`WorldModel::step`] with each object's [`PoseSpread`] when the model can estimate
    /// one (an ensemble; zero for a kinematic object, whose pose is given); the poses are
    /// those `step` gives. By default `step` and no spread.
    fn step_with_spread(&self, batch: &[StepItem<'_>]) -> Result<Vec<SpreadStep>, ModelError> {
        Ok(self
            .step(batch)?
            .into_iter()
            .map(|poses| SpreadStep {
                poses,
                spread: None,
            })
            .collect())
    }
    /// Names of the networks whose predictions each step averages (an ensemble's members, in
    /// order); empty for a single network.
    fn member_names(&self) -> Vec<String> {
        Vec::new()
    }
    /// Costs and gradients of candidate paths of kinematic objects, by backpropagation
    /// through the driven rollout ([`crate::gradient`]): `output[i][c]` answers candidate `c`
    /// of `items[i]`; items of many calls share each step's pass. By default the model cannot
    /// ([`ModelError::Unsupported`]). An empty `items` asks whether it can: `Ok` (empty) or
    /// `Unsupported` with the reason.
    fn path_gradients(
        &self,
        items: &[crate::GradientItem<'_>],
    ) -> Result<Vec<Vec<crate::PathGradient>>, ModelError> {
        let _ = items;
        Err(ModelError::Unsupported(format!(
            "model {} does not compute gradients",
            self.name()
        )))
    }
}

/// Rolls a scene forward `steps` steps of `dt_steps` frames from `state`, calling
/// `on_step(step_index, poses)` after each (step indices start at 1). Returns the poses of
/// every step, `[steps][objects]`.
pub fn rollout(
    model: &dyn WorldModel,
    scene: &crate::PreparedScene,
    mut state: SceneState,
    dt_steps: u32,
    steps: usize,
    mut on_step: impl FnMut(usize, &[Pose]),
) -> Result<Vec<Vec<Pose>>, ModelError> {
    let mut out = Vec::with_capacity(steps);
    for step in 1..=steps {
        let next = model
            .step(&[StepItem {
                scene,
                state: &state,
                dt_steps,
            }])?
            .pop()
            .ok_or_else(|| ModelError::Internal("model returned no scene".into()))?;
        on_step(step, &next);
        state.advance(next.clone());
        out.push(next);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(x: f32, yaw: f32) -> Pose {
        Pose::from_parts(
            Vector3::new(x, 0.5, 0.2),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
        )
    }

    #[test]
    fn a_led_kinematic_object_moves_on_at_its_coming_increment() {
        let state = SceneState {
            previous: vec![pose(0.0, 0.0), pose(1.0, 0.0)],
            current: vec![pose(0.1, 0.0), pose(1.0, 0.0)],
            earlier: Some(vec![pose(-0.1, 0.0), pose(1.0, 0.0)]),
            carry: Default::default(),
        };
        // The kinematic object (1), at rest so far, is about to move 0.2 m and turn 0.3 rad.
        let next = [pose(0.3, 0.0), pose(1.2, 0.3)];
        let led = state.lead_kinematic(&[false, true], &next);
        let close = |a: &Pose, b: &Pose| {
            let dt = (Vector3::from(a.translation) - Vector3::from(b.translation)).norm();
            dt < 1e-6 && a.unit_quaternion().angle_to(&b.unit_quaternion()) < 1e-5
        };
        assert!(
            close(&led.previous[1], &pose(0.8, -0.3)),
            "{:?}",
            led.previous[1]
        );
        assert!(close(&led.earlier.as_ref().unwrap()[1], &pose(0.6, -0.6)));
        // The dynamic object and the current poses are untouched.
        assert_eq!(led.previous[0], state.previous[0]);
        assert_eq!(
            led.earlier.as_ref().unwrap()[0],
            state.earlier.as_ref().unwrap()[0]
        );
        assert_eq!(led.current, state.current);
        // An unknown earlier stays unknown.
        let short = SceneState::new(state.previous.clone(), state.current.clone());
        assert!(
            short
                .lead_kinematic(&[false, true], &next)
                .earlier
                .is_none()
        );
    }
}
