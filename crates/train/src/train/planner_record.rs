//! A push planner's record and the ship rule's planner clause.
//!
//! `clients/python/examples/push_planner.py --json FILE` writes, per seed, the rapier-replayed
//! final distance of the box to the goal after the executed plan and after a random pusher path,
//! and how far the model's forecast of that final position was from rapier's on each (metres),
//! with the settings that shape a plan. A scorecard directory may hold one as `planner.json`.
//! The RigidFormer card's rule ships a candidate whose planner ends closer to the goal than the
//! release's by more than [`PLANNER_SE`] standard errors of the seed-by-seed difference, provided
//! its MOVi-B test-split translation RMSE stays within [`TEST_GUARD`] of the release's at every
//! horizon (the figure streaming clients live by).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use anyhow::Context;
use serde::Deserialize;

use super::horizon_guard::{FRESH_GUARD, change_by_horizon, within_at_every_horizon};

/// The planner clause asks the paired difference to exceed this many standard errors.
pub const PLANNER_SE: f64 = 2.0;

/// Under the planner clause the MOVi-B test split's translation RMSE may exceed the
/// reference's by at most this fraction at each horizon: the fresh-scene guard's bound.
pub const TEST_GUARD: f64 = FRESH_GUARD;

/// One seed of a planner run, distances in metres.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
pub struct PlannerSeed {
    /// The scene's and the sampler's seed.
    pub seed: u64,
    /// Rapier-replayed final distance to the goal after the executed plan, m.
    pub planned: f64,
    /// The same after a random pusher path, m.
    pub random: f64,
    /// How far the model's final box position was from rapier's on the executed plan, m.
    pub planned_off: f64,
    /// The same on the random path, m.
    pub random_off: f64,
}

/// A planner run as `push_planner.py --json` records it.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct PlannerRecord {
    /// The options that shape a plan (goal, rounds, horizon, samples, speed, ...): two records
    /// are paired only when these agree.
    pub settings: BTreeMap<String, serde_json::Value>,
    /// Every seed planned, in the order run.
    pub seeds: Vec<PlannerSeed>,
}

impl PlannerRecord {
    /// Mean rapier-replayed distance of the executed plans, m.
    pub fn mean_planned(&self) -> f64 {
        self.seeds.iter().map(|s| s.planned).sum::<f64>() / self.seeds.len() as f64
    }

    /// On how many seeds the plan ended closer to the goal than the random path.
    pub fn closer_than_random(&self) -> usize {
        self.seeds.iter().filter(|s| s.planned < s.random).count()
    }
}

/// Reads `dir/planner.json` when there is one; refuses an empty record, a seed listed twice
/// and distances that are not finite and non-negative.
pub fn read_planner(dir: &Path) -> anyhow::Result<Option<PlannerRecord>> {
    let path = dir.join("planner.json");
    if !path.exists() {
        return Ok(None);
    }
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let record: PlannerRecord =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    anyhow::ensure!(!record.seeds.is_empty(), "{}: no seeds", path.display());
    let mut seen = BTreeSet::new();
    for s in &record.seeds {
        anyhow::ensure!(
            seen.insert(s.seed),
            "{}: seed {} listed twice",
            path.display(),
            s.seed
        );
        let d = [s.planned, s.random, s.planned_off, s.random_off];
        anyhow::ensure!(
            d.iter().all(|x| x.is_finite() && *x >= 0.0),
            "{}: seed {} has a distance that is not a finite non-negative number: {d:?}",
            path.display(),
            s.seed
        );
    }
    Ok(Some(record))
}

/// Refuses two records that cannot be paired seed by seed: other settings or other seeds.
pub fn check_pairable(
    reference: &PlannerRecord,
    candidate: &PlannerRecord,
    what: (&Path, &Path),
) -> anyhow::Result<()> {
    let (a, b) = (what.0.display(), what.1.display());
    for key in reference.settings.keys().chain(candidate.settings.keys()) {
        let (x, y) = (reference.settings.get(key), candidate.settings.get(key));
        anyhow::ensure!(
            x == y,
            "planner.json of {a} and of {b} planned with different settings: {key} {} against {}",
            x.map_or("(absent)".into(), |v| v.to_string()),
            y.map_or("(absent)".into(), |v| v.to_string()),
        );
    }
    let seeds = |r: &PlannerRecord| r.seeds.iter().map(|s| s.seed).collect::<BTreeSet<_>>();
    let (x, y) = (seeds(reference), seeds(candidate));
    anyhow::ensure!(
        x == y,
        "planner.json of {a} and of {b} planned different seeds ({} and {}; {} in common): \
         run both over the same seeds",
        x.len(),
        y.len(),
        x.intersection(&y).count()
    );
    Ok(())
}

/// The planner clause for one candidate.
#[derive(Clone, Debug, PartialEq)]
pub struct PlannerClause {
    /// Seeds paired.
    pub seeds: usize,
    /// Mean rapier-replayed distance of the reference's executed plans, m.
    pub reference_mean: f64,
    /// The same of the candidate's, m.
    pub candidate_mean: f64,
    /// Mean over seeds of the candidate's distance minus the reference's, m (negative: closer).
    pub paired_mean: f64,
    /// Standard error of that mean (sample deviation over `sqrt(seeds)`), m.
    pub paired_se: f64,
    /// Seeds on which each ended closer than its random path: (reference, candidate).
    pub closer_than_random: (usize, usize),
    /// MOVi-B test-split translation RMSE change at each horizon, candidate over reference
    /// minus 1.
    pub test_change: [f64; 4],
}

impl PlannerClause {
    /// Whether the test split stays within [`TEST_GUARD`] at every horizon.
    pub fn test_guard_holds(&self) -> bool {
        within_at_every_horizon(&self.test_change, TEST_GUARD)
    }

    /// Whether the candidate's planner is closer by more than [`PLANNER_SE`] standard errors.
    pub fn planner_better(&self) -> bool {
        self.paired_mean < -PLANNER_SE * self.paired_se
    }

    /// Whether the clause ships the candidate: a better planner with the test split kept.
    pub fn passes(&self) -> bool {
        self.planner_better() && self.test_guard_holds()
    }
}

/// The clause from two records (paired on the seeds they share; `None` under two) and the
/// two models' MOVi-B test-split translation RMSE at the four horizons (m).
pub fn planner_clause(
    reference: &PlannerRecord,
    candidate: &PlannerRecord,
    reference_test_m: [f64; 4],
    candidate_test_m: [f64; 4],
) -> Option<PlannerClause> {
    let by_seed: BTreeMap<u64, f64> = reference
        .seeds
        .iter()
        .map(|s| (s.seed, s.planned))
        .collect();
    let pairs: Vec<(f64, f64)> = candidate
        .seeds
        .iter()
        .filter_map(|s| by_seed.get(&s.seed).map(|&r| (r, s.planned)))
        .collect();
    if pairs.len() < 2 {
        return None;
    }
    let n = pairs.len() as f64;
    let mean = |f: &dyn Fn(&(f64, f64)) -> f64| pairs.iter().map(f).sum::<f64>() / n;
    let paired_mean = mean(&|&(r, c)| c - r);
    let var = pairs
        .iter()
        .map(|&(r, c)| (c - r - paired_mean).powi(2))
        .sum::<f64>()
        / (n - 1.0);
    Some(PlannerClause {
        seeds: pairs.len(),
        reference_mean: mean(&|&(r, _)| r),
        candidate_mean: mean(&|&(_, c)| c),
        paired_mean,
        paired_se: (var / n).sqrt(),
        closer_than_random: (
            reference.closer_than_random(),
            candidate.closer_than_random(),
        ),
        test_change: change_by_horizon(&reference_test_m, &candidate_test_m),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(planned: &[f64]) -> PlannerRecord {
        PlannerRecord {
            settings: BTreeMap::from([("speed".into(), serde_json::json!(0.8))]),
            seeds: planned
                .iter()
                .enumerate()
                .map(|(i, &p)| PlannerSeed {
                    seed: i as u64,
                    planned: p,
                    random: 0.3,
                    planned_off: 0.0,
                    random_off: 0.0,
                })
                .collect(),
        }
    }

    #[test]
    fn the_clause_pairs_seeds_and_needs_two_standard_errors_and_the_test_split() {
        let reference = record(&[0.10, 0.20, 0.30, 0.40]);
        // Differences -0.02, -0.04, -0.02, -0.04: mean -0.03, sample sd 0.01155, SE 0.00577.
        let candidate = record(&[0.08, 0.16, 0.28, 0.36]);
        let same = [1.0; 4];
        let c = planner_clause(&reference, &candidate, same, same).unwrap();
        assert_eq!(c.seeds, 4);
        assert!((c.paired_mean + 0.03).abs() < 1e-12, "{c:?}");
        assert!(
            (c.paired_se - (4e-4f64 / 3.0).sqrt() / 2.0).abs() < 1e-12,
            "{c:?}"
        );
        assert!(c.planner_better() && c.passes());
        // MOVi-B 2% worse at 4 s: the planner is better, the clause does not pass.
        let c = planner_clause(&reference, &candidate, same, [1.0, 1.0, 1.0, 1.02]).unwrap();
        assert!(c.planner_better() && !c.test_guard_holds() && !c.passes());
        // The reverse pairing is worse, never better.
        let c = planner_clause(&candidate, &reference, same, same).unwrap();
        assert!(!c.planner_better());
        // One seed in common cannot give a standard error.
        assert!(planner_clause(&record(&[0.1]), &record(&[0.2]), same, same).is_none());
    }

    #[test]
    fn records_of_other_settings_or_seeds_are_not_paired() {
        let (a, b) = (Path::new("a"), Path::new("b"));
        let reference = record(&[0.1, 0.2]);
        check_pairable(&reference, &record(&[0.3, 0.4]), (a, b)).unwrap();
        let mut slow = record(&[0.1, 0.2]);
        slow.settings.insert("speed".into(), serde_json::json!(0.4));
        let err = check_pairable(&reference, &slow, (a, b)).unwrap_err();
        assert!(err.to_string().contains("speed 0.8 against 0.4"), "{err}");
        let err = check_pairable(&reference, &record(&[0.1, 0.2, 0.3]), (a, b)).unwrap_err();
        assert!(err.to_string().contains("different seeds"), "{err}");
    }
}
