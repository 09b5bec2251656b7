//! Validation of session inputs against a session's scene: the set of kinematic objects, object
//! states (SetState, Predict overrides, Interact corrections) and per-step actions. Poses and
//! motions are held to the rules of a request's scene ([`crate::families::built_scene`]).
//! Errors name the field.
//!
//! Kinematic objects: the model's inputs for a step are the state's previous and current poses,
//! which for a kinematic object are the poses the caller gave (or its initial ones); its output
//! is replaced by the pose given for the end of the step, or by its current pose when none is
//! given (it holds still): [`dynaserve_model::Drive`], where the driven step is defined once
//! for serving, evaluation and training.

use dynaserve_api::FieldError;
use dynaserve_api::spec::session::{Action, ObjectState};
use dynaserve_model::{Pose, SceneState};

use crate::families::built_scene::{check_implied_speed, check_pose, previous_pose};

/// Kinematic poses of one step, validated: `(object index, normalised pose)`, each object at
/// most once, every one kinematic.
pub type Targets = Vec<(usize, Pose)>;

fn index(object: u32, objects: usize, seen: &mut [bool], field: &str) -> Result<usize, FieldError> {
    let j = object as usize;
    if j >= objects {
        return Err(FieldError::new(
            field,
            format!("object {object} does not exist (the scene has {objects})"),
        ));
    }
    if std::mem::replace(&mut seen[j], true) {
        return Err(FieldError::new(
            field,
            format!("object {object} is named twice"),
        ));
    }
    Ok(j)
}

/// The kinematic mask `[objects]` of a session from its list of indices (field `kinematic`).
pub fn kinematic_mask(indices: &[u32], objects: usize) -> Result<Vec<bool>, FieldError> {
    let mut mask = vec![false; objects];
    for (i, &k) in indices.iter().enumerate() {
        index(k, objects, &mut mask, &format!("kinematic[{i}]"))?;
    }
    Ok(mask)
}

/// Overwrites the listed objects' states in `state` (each object at most once; `field` names
/// the list, e.g. `objects`). A velocity is turned into a previous pose `dt_seconds` earlier.
/// The poses one step before (`earlier`, which history inputs read) no longer belong to the
/// new motion, so when any object is overwritten they are dropped for the whole scene: its
/// next step reads as a rollout's first. Nothing is changed when any entry is invalid.
pub fn apply_states(
    state: &mut SceneState,
    objects: &[ObjectState],
    dt_seconds: f32,
    field: &str,
) -> Result<(), FieldError> {
    let n = state.len();
    let mut seen = vec![false; n];
    let mut updates = Vec::with_capacity(objects.len());
    for (i, o) in objects.iter().enumerate() {
        let f = format!("{field}[{i}]");
        let j = index(o.object, n, &mut seen, &format!("{f}.object"))?;
        let now = check_pose(&o.pose, &format!("{f}.pose"))?;
        let before = previous_pose(now, &o.motion, dt_seconds, &f)?;
        updates.push((j, before, now));
    }
    if !updates.is_empty() {
        state.earlier = None;
    }
    for (j, before, now) in updates {
        state.previous[j] = before;
        state.current[j] = now;
    }
    Ok(())
}

/// Checks one action (`field`, e.g. `actions[3]`) against the kinematic mask.
pub fn check_action(
    action: &Action,
    kinematic: &[bool],
    field: &str,
) -> Result<Targets, FieldError> {
    let mut seen = vec![false; kinematic.len()];
    action
        .kinematic
        .iter()
        .enumerate()
        .map(|(i, (object, pose))| {
            let f = format!("{field}.kinematic[{i}]");
            let j = index(*object, kinematic.len(), &mut seen, &format!("{f}.object"))?;
            if !kinematic[j] {
                return Err(FieldError::new(
                    format!("{f}.object"),
                    format!("object {object} is not kinematic; only kinematic objects take poses"),
                ));
            }
            Ok((j, check_pose(pose, &format!("{f}.pose"))?))
        })
        .collect()
}

/// Checks a list of actions (`field`, e.g. `actions`): empty, or exactly `steps` of them.
/// Returns one [`Targets`] per step (all empty for an empty list).
pub fn check_actions(
    actions: &[Action],
    steps: u32,
    kinematic: &[bool],
    field: &str,
) -> Result<Vec<Targets>, FieldError> {
    if actions.is_empty() {
        return Ok(vec![Vec::new(); steps as usize]);
    }
    if actions.len() != steps as usize {
        return Err(FieldError::new(
            field,
            format!(
                "{} actions given for {steps} steps; give none or one per step",
                actions.len()
            ),
        ));
    }
    actions
        .iter()
        .enumerate()
        .map(|(i, a)| check_action(a, kinematic, &format!("{field}[{i}]")))
        .collect()
}

/// Checks that the kinematic poses of one step (`targets`, of an action at path `field`)
/// imply no speed above the velocity bound from the objects' poses one step before
/// (`before`, one per object).
pub fn check_target_speeds(
    targets: &Targets,
    before: &[Pose],
    dt_seconds: f32,
    field: &str,
) -> Result<(), FieldError> {
    for (k, (j, pose)) in targets.iter().enumerate() {
        if let Some(b) = before.get(*j) {
            check_implied_speed(
                b,
                pose,
                dt_seconds,
                &format!("{field}.kinematic[{k}].pose"),
                &format!("pose of object {j} one step before"),
            )?;
        }
    }
    Ok(())
}

/// [`check_target_speeds`] over a sequence of actions (`field`, e.g. `actions`), one entry
/// per step, from the objects' poses `start`: a kinematic object is where its last given pose
/// put it (or at its start when none was given yet).
pub fn check_action_speeds(
    targets: &[Targets],
    start: &[Pose],
    dt_seconds: f32,
    field: &str,
) -> Result<(), FieldError> {
    let mut at = start.to_vec();
    for (i, t) in targets.iter().enumerate() {
        check_target_speeds(t, &at, dt_seconds, &format!("{field}[{i}]"))?;
        for (j, pose) in t {
            if let Some(a) = at.get_mut(*j) {
                *a = *pose;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynaserve_api::spec::Motion;

    fn at(x: f32) -> Pose {
        Pose {
            translation: [x, 0.0, 0.5],
            rotation: [0.0, 0.0, 0.0, 1.0],
        }
    }

    #[test]
    fn kinematic_indices_must_exist_and_be_unique() {
        assert_eq!(kinematic_mask(&[1], 3).unwrap(), vec![false, true, false]);
        assert_eq!(kinematic_mask(&[3], 3).unwrap_err().field, "kinematic[0]");
        assert_eq!(
            kinematic_mask(&[0, 0], 3).unwrap_err().field,
            "kinematic[1]"
        );
    }

    #[test]
    fn actions_take_only_kinematic_objects_and_one_per_step() {
        let mask = [true, false];
        let a = Action {
            kinematic: vec![(0, at(1.0))],
        };
        let t = check_actions(&[a.clone(), a.clone()], 2, &mask, "actions").unwrap();
        assert_eq!(t[1], vec![(0, at(1.0))]);
        assert_eq!(
            check_actions(std::slice::from_ref(&a), 2, &mask, "actions")
                .unwrap_err()
                .field,
            "actions"
        );
        let wrong = Action {
            kinematic: vec![(1, at(1.0))],
        };
        let e = check_actions(&[a, wrong], 2, &mask, "actions").unwrap_err();
        assert_eq!(e.field, "actions[1].kinematic[0].object");
        let bad = Action {
            kinematic: vec![(
                0,
                Pose {
                    rotation: [0.0; 4],
                    ..at(0.0)
                },
            )],
        };
        let e = check_action(&bad, &mask, "action").unwrap_err();
        assert_eq!(e.field, "action.kinematic[0].pose.rotation");
    }

    #[test]
    fn states_overwrite_only_the_listed_objects_or_nothing() {
        let mut s = SceneState {
            previous: vec![at(0.0), at(5.0)],
            current: vec![at(0.0), at(5.0)],
            earlier: Some(vec![at(0.0), at(5.0)]),
            carry: Default::default(),
        };
        apply_states(&mut s, &[], 0.5, "objects").unwrap();
        assert!(s.earlier.is_some(), "an empty list changes nothing");
        let moving = ObjectState {
            object: 1,
            pose: at(2.0),
            motion: Motion::Velocity {
                linear: [1.0, 0.0, 0.0],
                angular: [0.0; 3],
            },
        };
        apply_states(&mut s, &[moving], 0.5, "objects").unwrap();
        assert_eq!(s.earlier, None, "the step before belongs to the old motion");
        assert_eq!(s.current[1], at(2.0));
        assert!((s.previous[1].translation[0] - 1.5).abs() < 1e-6);
        assert_eq!(s.current[0], at(0.0));
        s.earlier = Some(s.previous.clone());
        let before = s.clone();
        let twice = [moving, moving];
        assert_eq!(
            apply_states(&mut s, &twice, 0.5, "objects")
                .unwrap_err()
                .field,
            "objects[1].object"
        );
        assert_eq!(s, before);
    }

    #[test]
    fn poses_implying_more_than_the_speed_bound_are_refused_naming_the_object() {
        let start = [at(0.0), at(5.0)];
        // 0.5 m in 1 ms is 500 m/s: accepted; 10 m in 1 ms is 1e4 m/s: refused.
        let ok = vec![vec![(0, at(0.5))], vec![], vec![(0, at(1.0))]];
        check_action_speeds(&ok, &start, 1e-3, "actions").unwrap();
        let fast = vec![vec![(0, at(0.5))], vec![(0, at(10.5))]];
        let e = check_action_speeds(&fast, &start, 1e-3, "actions").unwrap_err();
        assert_eq!(e.field, "actions[1].kinematic[0].pose");
        assert!(
            e.message.contains("object 0") && e.message.contains("1000 m/s"),
            "{e:?}"
        );
        // A previous pose is held to the same bound.
        let mut s = SceneState {
            previous: start.to_vec(),
            current: start.to_vec(),
            earlier: None,
            carry: Default::default(),
        };
        let jump = ObjectState {
            object: 1,
            pose: at(2400.0),
            motion: Motion::PreviousPose(at(0.0)),
        };
        let e = apply_states(&mut s, &[jump], 1e-3, "objects").unwrap_err();
        assert_eq!(e.field, "objects[0].previous_pose");
    }
}
