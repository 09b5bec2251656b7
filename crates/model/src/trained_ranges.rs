//! The physical parameters a model was trained on, stored in its `config.json`, and the check
//! that names the objects of a request outside them: a learned model forecasts well only on
//! what it has seen, and a caller should hear when a scene leaves that.

use serde::{Deserialize, Serialize};

use crate::ObjectInput;

/// Closed interval `[low, high]` of one parameter over every object of the training data.
pub type Interval = [f32; 2];

/// Smallest and largest mass, friction and restitution of the objects a model was trained on
/// (`trained_ranges` in `config.json`; written by `dynaserve train export` from the run's
/// training data).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainedRanges {
    /// Mass, kilograms; with [`TrainedRanges::mass_relative`], the ratio of each dynamic
    /// object's mass to its scene's geometric mean dynamic mass (dimensionless,
    /// [`mass_ratios`]).
    pub mass: Interval,
    /// Coulomb friction coefficient (dimensionless).
    pub friction: Interval,
    /// Coefficient of restitution (dimensionless).
    pub restitution: Interval,
    /// `mass` holds mass ratios within a scene ([`mass_ratios`]), as for a model with
    /// [`crate::DynamicsConfig::relative_mass`], which sees only those; absent means false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub mass_relative: bool,
}

/// One parameter of a scene's objects outside the trained interval.
#[derive(Clone, Debug, PartialEq)]
pub struct OutOfRange {
    /// Parameter name as in the request (`mass`, `friction`, `restitution`).
    pub field: &'static str,
    /// Indices of the objects outside, in request order.
    pub objects: Vec<usize>,
    /// Smallest and largest value among those objects (for `mass` with `relative`, ratios to
    /// the scene's geometric mean mass).
    pub values: Interval,
    /// The trained interval.
    pub trained: Interval,
    /// The values are mass ratios ([`TrainedRanges::mass_relative`]).
    pub relative: bool,
}

/// Each dynamic object's mass over the geometric mean of the dynamic objects' masses
/// (dimensionless; `None` for a kinematic one, whose mass a relative-mass model does not
/// read): what a model with [`crate::DynamicsConfig::relative_mass`] distinguishes.
/// `(mass kg, kinematic)` per object; masses must be > 0.
pub fn mass_ratios(objects: &[(f32, bool)]) -> Vec<Option<f32>> {
    let dynamic: Vec<f64> = objects
        .iter()
        .filter(|o| !o.1)
        .map(|o| f64::from(o.0).ln())
        .collect();
    let mean = dynamic.iter().sum::<f64>() / dynamic.len().max(1) as f64;
    objects
        .iter()
        .map(|&(m, kinematic)| (!kinematic).then(|| (f64::from(m).ln() - mean).exp() as f32))
        .collect()
}

/// `x` to 3 significant digits, as a person writes it (`0.100038625` -> `0.1`,
/// `0.9999935` -> `1`, `1234.5` -> `1230`).
fn human(x: f32) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    let digits = 2 - x.abs().log10().floor() as i32;
    let scale = 10f64.powi(digits);
    let r = (f64::from(x) * scale).round() / scale;
    // Shortest form of the rounded value (f32 keeps out f64 tails such as 0.30000000000000004).
    format!("{}", r as f32)
}

impl OutOfRange {
    /// One line for a caller, ASCII only (it travels in HTTP headers and gRPC metadata);
    /// `path` names the scene (`scene`, `variants[2]`).
    pub fn message(&self, path: &str) -> String {
        const SHOWN: usize = 6;
        let mut list: Vec<String> = self
            .objects
            .iter()
            .take(SHOWN)
            .map(|i| i.to_string())
            .collect();
        if self.objects.len() > SHOWN {
            list.push(format!("{} more", self.objects.len() - SHOWN));
        }
        let [lo, hi] = self.values;
        let value = if lo == hi {
            format!("{lo}")
        } else {
            format!("{lo} to {hi}")
        };
        let (value, range) = if self.relative {
            (
                format!("{value} times the scene's geometric mean mass"),
                "the ratios",
            )
        } else {
            (value, "the range")
        };
        format!(
            "{path}.objects[{}].{}: {value} is outside {range} the model was trained on \
             ({} to {}); its forecast there is less accurate",
            list.join(","),
            self.field,
            human(self.trained[0]),
            human(self.trained[1])
        )
    }
}

impl TrainedRanges {
    /// The smallest ranges holding every object of `scenes` (each scene a list of
    /// `([mass kg, friction, restitution], kinematic)`), masses as ratios within their scene
    /// when `mass_relative` (kinematic objects' masses then left out: [`mass_ratios`]); `None`
    /// when no object gives a mass.
    pub fn of<S: AsRef<[([f32; 3], bool)]>>(
        scenes: impl IntoIterator<Item = S>,
        mass_relative: bool,
    ) -> Option<TrainedRanges> {
        let widen = |acc: &mut Option<Interval>, v: f32| {
            *acc = Some(acc.map_or([v, v], |[lo, hi]| [lo.min(v), hi.max(v)]));
        };
        let (mut mass, mut friction, mut restitution) = (None, None, None);
        for scene in scenes {
            let scene = scene.as_ref();
            let masses: Vec<Option<f32>> = if mass_relative {
                let pairs: Vec<(f32, bool)> = scene.iter().map(|(p, k)| (p[0], *k)).collect();
                mass_ratios(&pairs)
            } else {
                scene.iter().map(|(p, _)| Some(p[0])).collect()
            };
            for ((p, _), m) in scene.iter().zip(masses) {
                if let Some(m) = m {
                    widen(&mut mass, m);
                }
                widen(&mut friction, p[1]);
                widen(&mut restitution, p[2]);
            }
        }
        Some(TrainedRanges {
            mass: mass?,
            friction: friction?,
            restitution: restitution?,
            mass_relative,
        })
    }

    /// The smallest ranges holding both. Mass intervals of different kinds
    /// ([`TrainedRanges::mass_relative`]) do not join: `other`'s is kept.
    fn union(&self, other: &TrainedRanges) -> TrainedRanges {
        let join = |a: Interval, b: Interval| [a[0].min(b[0]), a[1].max(b[1])];
        TrainedRanges {
            mass: if self.mass_relative == other.mass_relative {
                join(self.mass, other.mass)
            } else {
                other.mass
            },
            friction: join(self.friction, other.friction),
            restitution: join(self.restitution, other.restitution),
            mass_relative: other.mass_relative,
        }
    }

    /// The ranges of everything a model's weights have seen: `inherited` (what its initial
    /// weights had seen) joined with each of `measured` (its run's data), for a model that
    /// reads masses as ratios within a scene when `mass_relative`. Mass intervals of the other
    /// kind cannot be joined with the model's: a later one replaces an earlier one (friction
    /// and restitution still join), and `None` is returned when the result's masses are not
    /// of the model's kind (no data measured them as it sees them). The one rule for
    /// joining ranges, used by the export.
    pub fn seen(
        inherited: Option<TrainedRanges>,
        measured: impl IntoIterator<Item = TrainedRanges>,
        mass_relative: bool,
    ) -> Option<TrainedRanges> {
        measured
            .into_iter()
            .fold(inherited, |acc, r| Some(acc.map_or(r, |a| a.union(&r))))
            .filter(|r| r.mass_relative == mass_relative)
    }

    /// Every parameter some of `objects` hold outside the trained ranges (at most one entry
    /// per parameter; empty when all are inside); masses are compared as ratios within the
    /// scene when [`TrainedRanges::mass_relative`] (kinematic objects' masses then not at
    /// all). Values within 1e-4 (relative) of a bound count as inside, so a value written with
    /// fewer digits than the bound is not flagged.
    pub fn check(&self, objects: &[ObjectInput]) -> Vec<OutOfRange> {
        let masses: Vec<Option<f32>> = if self.mass_relative {
            let pairs: Vec<(f32, bool)> = objects.iter().map(|o| (o.mass, o.kinematic)).collect();
            mass_ratios(&pairs)
        } else {
            objects.iter().map(|o| Some(o.mass)).collect()
        };
        let fields: [(&'static str, Interval, Vec<Option<f32>>); 3] = [
            ("mass", self.mass, masses),
            (
                "friction",
                self.friction,
                objects.iter().map(|o| Some(o.friction)).collect(),
            ),
            (
                "restitution",
                self.restitution,
                objects.iter().map(|o| Some(o.restitution)).collect(),
            ),
        ];
        fields
            .into_iter()
            .filter_map(|(field, trained, values)| {
                let slack = 1e-4 * trained[0].abs().max(trained[1].abs()).max(1e-3);
                let outside: Vec<(usize, f32)> = values
                    .into_iter()
                    .enumerate()
                    .filter_map(|(i, v)| Some((i, v?)))
                    .filter(|(_, v)| *v < trained[0] - slack || *v > trained[1] + slack)
                    .collect();
                let first = outside.first()?.1;
                let values = outside
                    .iter()
                    .fold([first, first], |[lo, hi], (_, v)| [lo.min(*v), hi.max(*v)]);
                Some(OutOfRange {
                    field,
                    objects: outside.into_iter().map(|(i, _)| i).collect(),
                    values,
                    trained,
                    relative: field == "mass" && self.mass_relative,
                })
            })
            .collect()
    }

    /// Checks that every bound is finite and `low <= high`.
    pub fn validate(&self) -> Result<(), String> {
        for (name, [lo, hi]) in [
            ("mass", self.mass),
            ("friction", self.friction),
            ("restitution", self.restitution),
        ] {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return Err(format!(
                    "trained_ranges.{name} must be finite with low <= high, got [{lo}, {hi}]"
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn object(mass: f32, friction: f32, restitution: f32) -> ObjectInput {
        ObjectInput {
            reference: vec![[0.0; 3]],
            mass,
            friction,
            restitution,
            kinematic: false,
        }
    }

    fn check(r: &TrainedRanges, objects: &[ObjectInput]) -> Vec<OutOfRange> {
        r.check(objects)
    }

    fn ranges() -> TrainedRanges {
        let scenes = [
            vec![([0.5, 0.1, 0.05], false), ([4.0, 1.0, 0.8], false)],
            vec![([1.0, 0.4, 0.3], true)],
        ];
        TrainedRanges::of(scenes, false).unwrap()
    }

    #[test]
    fn ranges_span_the_given_parameters() {
        let r = ranges();
        assert_eq!(r.mass, [0.5, 4.0]);
        assert_eq!(r.friction, [0.1, 1.0]);
        assert_eq!(r.restitution, [0.05, 0.8]);
        assert_eq!(TrainedRanges::of(Vec::<Vec<_>>::new(), false), None);
        let wider = r.union(&TrainedRanges::of([[([10.0, 0.0, 0.5], false)]], false).unwrap());
        assert_eq!(wider.mass, [0.5, 10.0]);
        assert_eq!(wider.friction, [0.0, 1.0]);
        assert_eq!(wider.restitution, [0.05, 0.8]);
    }

    #[test]
    fn objects_inside_pass_and_those_outside_are_named() {
        let r = ranges();
        assert!(check(&r, &[object(1.0, 0.5, 0.2), object(0.5, 1.0, 0.8)]).is_empty());
        // Written with fewer digits than the stored bound: still inside.
        assert!(check(&r, &[object(1.0, 0.1, 0.05)]).is_empty());
        let out = check(
            &r,
            &[
                object(1.0, 0.0, 0.2),
                object(1.0, 0.5, 0.2),
                object(20.0, 2.0, 0.2),
            ],
        );
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].field, "mass");
        assert_eq!(out[0].objects, vec![2]);
        assert_eq!(out[1].field, "friction");
        assert_eq!(out[1].objects, vec![0, 2]);
        assert_eq!(out[1].values, [0.0, 2.0]);
        let m = out[1].message("scene");
        assert_eq!(
            m,
            "scene.objects[0,2].friction: 0 to 2 is outside the range the model was trained \
             on (0.1 to 1); its forecast there is less accurate"
        );
        assert!(m.is_ascii());
        // Trained bounds read as a person writes them.
        let mut raw = ranges();
        raw.friction = [0.100_038_625, 0.999_993_5];
        let m = check(&raw, &[object(1.0, 2.0, 0.2)])[0].message("scene");
        assert!(m.contains("(0.1 to 1)"), "{m}");
        assert_eq!(
            (human(1234.5), human(0.012345), human(-2.5)),
            ("1230".into(), "0.0123".into(), "-2.5".into())
        );
    }

    #[test]
    fn long_lists_are_cut_and_bad_bounds_refused() {
        let objects: Vec<ObjectInput> = (0..9).map(|_| object(1.0, 0.5, 0.95)).collect();
        let out = check(&ranges(), &objects);
        assert_eq!(out.len(), 1);
        assert!(
            out[0]
                .message("variants[1]")
                .starts_with("variants[1].objects[0,1,2,3,4,5,3 more].restitution: 0.95 is")
        );
        let mut bad = ranges();
        bad.friction = [1.0, 0.5];
        assert!(bad.validate().is_err());
        bad.friction = [f32::NAN, 0.5];
        assert!(bad.validate().is_err());
        assert!(ranges().validate().is_ok());
    }

    #[test]
    fn relative_ranges_hold_mass_ratios_within_scenes() {
        // Scenes of 1 and 4 kg, and of 10 and 40 kg: ratios 0.5 and 2 either way; a kinematic
        // object's mass (here a 500 kg pusher) counts for nothing.
        let dynamic = |m: f32| ([m, 0.5, 0.3], false);
        let scenes = [
            vec![dynamic(1.0), dynamic(4.0), ([500.0, 0.9, 0.3], true)],
            vec![dynamic(10.0), dynamic(40.0)],
        ];
        let r = TrainedRanges::of(scenes, true).unwrap();
        assert_eq!(r.friction, [0.5, 0.9]);
        assert!(r.mass_relative);
        assert!((r.mass[0] - 0.5).abs() < 1e-5 && (r.mass[1] - 2.0).abs() < 1e-5);
        // Any scale passes; a ratio of 8 (masses 1 and 64) does not.
        assert!(check(&r, &[object(300.0, 0.5, 0.3), object(1200.0, 0.5, 0.3)]).is_empty());
        let mut pusher = object(1.0e4, 0.5, 0.3);
        pusher.kinematic = true;
        assert!(check(&r, &[object(1.0, 0.5, 0.3), object(2.0, 0.5, 0.3), pusher]).is_empty());
        let out = check(&r, &[object(1.0, 0.5, 0.3), object(64.0, 0.5, 0.3)]);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].objects, vec![0, 1]);
        assert!(out[0].relative);
        let m = out[0].message("scene");
        assert!(
            m.starts_with("scene.objects[0,1].mass: 0.125 to 8 times the scene's geometric mean mass is outside the ratios the model was trained on (0.5 to 2)"),
            "{m}"
        );
        // Absolute ranges inherited by a relative model keep friction and restitution only.
        let joined = TrainedRanges::seen(Some(ranges()), [r], true).unwrap();
        assert!(joined.mass_relative);
        assert_eq!(joined.mass, r.mass);
        assert_eq!(joined.friction, [0.1, 1.0]);
        // Without relative data, a relative model has no ranges of its kind; an absolute
        // model keeps its inherited ranges, and relative data do not join them.
        assert_eq!(TrainedRanges::seen(Some(ranges()), [], true), None);
        assert_eq!(
            TrainedRanges::seen(Some(ranges()), [], false),
            Some(ranges())
        );
        assert_eq!(TrainedRanges::seen(None, [r], false), None);
        assert_eq!(TrainedRanges::seen(None, [], true), None);
        // Stored without the flag, a config reads as absolute.
        let back: TrainedRanges = serde_json::from_str(
            r#"{"mass": [0.5, 4.0], "friction": [0.1, 1.0], "restitution": [0.05, 0.8]}"#,
        )
        .unwrap();
        assert_eq!(back, ranges());
    }
}
