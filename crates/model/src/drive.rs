//! One driven step: a scene whose kinematic objects (a pusher) follow given poses while the
//! network moves the others. Serving (a session's `Step` with actions), driven evaluation and
//! pushforward training all step such scenes by this one rule, in two halves around the
//! network call, which each caller makes its own way (a scheduler, a predictor, a batched
//! [`crate::WorldModel::step`]):
//!
//! 1. [`Drive::input`]: the state the network reads. It is the scene's state itself, or, for a
//!    model with [`crate::DynamicsConfig::kinematic_lead`], that state with every kinematic
//!    object led into its pose after the step ([`SceneState::lead_kinematic`]).
//! 2. [`Drive::finish`]: the network's output with every kinematic object's pose replaced by
//!    its given pose, or by its current pose when none is given (it holds still), and the
//!    state advanced to it ([`SceneState::advance`]). [`Drive::overwrite`] is the first half
//!    of that alone, for a caller that advances the state itself.
//!
//! Poses are in metres and unit quaternions `[x, y, z, w]` ([`Pose`]); every per-object slice
//! has one entry per object of the scene, `[objects]`.

use crate::api::{Pose, SceneState};

/// The kinematic objects of one scene and the poses given to them for the end of one step.
///
/// `targets` lists `(object index, pose)`, each object at most once; an entry that names an
/// object that is not kinematic, or none of the scene, is ignored. A kinematic object without
/// an entry holds its current pose.
#[derive(Clone, Copy, Debug)]
pub struct Drive<'a> {
    /// `[objects]`: true for an object moved along given poses rather than by the network.
    pub kinematic: &'a [bool],
    /// Poses for the end of the step, `(object index, pose)`.
    pub targets: &'a [(usize, Pose)],
}

/// The targets that give every kinematic object its pose in `frame` (`[objects]`, e.g. a
/// recorded frame): `(object index, frame[index])` for each kinematic object that `frame`
/// covers, in object order.
pub fn frame_targets(kinematic: &[bool], frame: &[Pose]) -> Vec<(usize, Pose)> {
    kinematic
        .iter()
        .zip(frame)
        .enumerate()
        .filter(|(_, (k, _))| **k)
        .map(|(j, (_, pose))| (j, *pose))
        .collect()
}

impl<'a> Drive<'a> {
    /// A step of the scene with mask `kinematic` (`[objects]`) to the poses `targets`.
    pub fn new(kinematic: &'a [bool], targets: &'a [(usize, Pose)]) -> Drive<'a> {
        Drive { kinematic, targets }
    }

    /// Whether any object of the scene is kinematic (otherwise the step is a plain one).
    pub fn any_kinematic(&self) -> bool {
        self.kinematic.contains(&true)
    }

    /// The targets that name a kinematic object.
    fn kinematic_targets(&self) -> impl Iterator<Item = &(usize, Pose)> {
        self.targets
            .iter()
            .filter(|(j, _)| self.kinematic.get(*j).copied().unwrap_or(false))
    }

    /// The poses after the step as far as they are given, `[objects]`: each kinematic object at
    /// its target, or at its current pose in `state` when it has none; every other object at
    /// its current pose (a placeholder: the network moves it).
    pub fn given_poses(&self, state: &SceneState) -> Vec<Pose> {
        let mut next = state.current.clone();
        self.overwrite(state, &mut next);
        next
    }

    /// The state the network reads for this step from `state`: `state` itself, or, with
    /// `lead` (the model's [`crate::DynamicsConfig::kinematic_lead`]), `state` with each
    /// kinematic object's previous (and earlier) poses those of constant motion into its pose
    /// after the step ([`Drive::given_poses`], [`SceneState::lead_kinematic`]). The current
    /// poses are never changed.
    pub fn input(&self, state: &SceneState, lead: bool) -> SceneState {
        if lead && self.any_kinematic() {
            state.lead_kinematic(self.kinematic, &self.given_poses(state))
        } else {
            state.clone()
        }
    }

    /// Replaces the network's output for the kinematic objects: `output` (`[objects]`, the
    /// poses the network predicted one step after `state.current`) gets each kinematic
    /// object's target, or its current pose in `state` (the state before the step) when none
    /// is given. Other objects keep the network's poses.
    pub fn overwrite(&self, state: &SceneState, output: &mut [Pose]) {
        for (j, (&k, now)) in self.kinematic.iter().zip(&state.current).enumerate() {
            if let (true, Some(o)) = (k, output.get_mut(j)) {
                *o = *now;
            }
        }
        for (j, pose) in self.kinematic_targets() {
            if let Some(o) = output.get_mut(*j) {
                *o = *pose;
            }
        }
    }

    /// Finishes the step: the network's `output` (`[objects]`) with the kinematic objects
    /// overwritten ([`Drive::overwrite`]), then `state` advanced to it. Returns the new
    /// current poses, `[objects]`.
    pub fn finish<'s>(&self, state: &'s mut SceneState, mut output: Vec<Pose>) -> &'s [Pose] {
        self.overwrite(state, &mut output);
        state.advance(output);
        &state.current
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(x: f32) -> Pose {
        Pose {
            translation: [x, 0.0, 0.5],
            rotation: [0.0, 0.0, 0.0, 1.0],
        }
    }

    fn state() -> SceneState {
        SceneState {
            previous: vec![at(0.0), at(1.0), at(2.0)],
            current: vec![at(0.1), at(1.1), at(2.1)],
            earlier: Some(vec![at(-0.1), at(0.9), at(1.9)]),
            carry: Default::default(),
        }
    }

    const MASK: [bool; 3] = [true, false, true];

    #[test]
    fn unposed_kinematic_objects_hold_and_posed_ones_are_placed() {
        let targets = [(2, at(3.0))];
        let drive = Drive::new(&MASK, &targets);
        let mut out = vec![at(0.2), at(1.2), at(2.2)];
        drive.overwrite(&state(), &mut out);
        assert_eq!(out, vec![at(0.1), at(1.2), at(3.0)]);
        assert_eq!(drive.given_poses(&state()), vec![at(0.1), at(1.1), at(3.0)]);
    }

    #[test]
    fn targets_of_dynamic_or_missing_objects_are_ignored() {
        let targets = [(1, at(7.0)), (5, at(7.0))];
        let drive = Drive::new(&MASK, &targets);
        let mut out = vec![at(0.2), at(1.2), at(2.2)];
        drive.overwrite(&state(), &mut out);
        assert_eq!(out, vec![at(0.1), at(1.2), at(2.1)]);
    }

    #[test]
    fn the_input_is_led_only_for_a_leading_model_with_kinematic_objects() {
        let s = state();
        let targets = [(2, at(3.0))];
        let drive = Drive::new(&MASK, &targets);
        assert_eq!(drive.input(&s, false), s);
        let led = drive.input(&s, true);
        assert_eq!(led, s.lead_kinematic(&MASK, &[at(0.1), at(1.1), at(3.0)]));
        // Object 0 holds: constant motion into its current pose is rest.
        assert_eq!(led.previous[0].translation, s.current[0].translation);
        // Object 2 is about to move 0.9 m.
        assert!((led.previous[2].translation[0] - (2.1 - 0.9)).abs() < 1e-5);
        assert_eq!(led.previous[1], s.previous[1]);
        assert_eq!(led.current, s.current);
        let none = [false; 3];
        assert_eq!(Drive::new(&none, &[]).input(&s, true), s);
    }

    #[test]
    fn finish_overwrites_then_advances() {
        let mut s = state();
        let before = s.clone();
        let targets = frame_targets(&MASK, &[at(5.0), at(6.0), at(7.0)]);
        assert_eq!(targets, vec![(0, at(5.0)), (2, at(7.0))]);
        let drive = Drive::new(&MASK, &targets);
        let now = drive
            .finish(&mut s, vec![at(0.2), at(1.2), at(2.2)])
            .to_vec();
        assert_eq!(now, vec![at(5.0), at(1.2), at(7.0)]);
        assert_eq!(s.current, now);
        assert_eq!(s.previous, before.current);
        assert_eq!(s.earlier, Some(before.previous));
    }
}
