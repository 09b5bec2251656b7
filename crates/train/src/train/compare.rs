//! Candidates against a release on the model card's key figures: `dynaserve train compare`.
//!
//! A scorecard is a directory of three `dynaserve eval --json` reports of one model, named as
//! in a model's `eval/` directory: `eval.json` (the MOVi-B test split, step size 1 among
//! those scored), `fresh.json` (fresh MOVi-B scenes, step size 1) and `physics-suite.json`
//! (`--suite physics`). From them come the fourteen key figures the RigidFormer card ships by:
//! MOVi-B translation RMSE at 0.5, 1, 2 and 4 s and the mean resting drift (test split, k = 1);
//! the suite's towers, drop height, drop penetration, slide distance and the two collisions'
//! momentum (both as distance from rapier's), floor and object contact (ballistic over model,
//! k = 1) and free flight (k = 4). The count is head to head; the fresh-scene guard asks the
//! fresh split's translation RMSE to stay within 1% of the reference's at every horizon.
//! A scorecard may also hold a push planner's record (`planner.json`); when both do, the
//! rule's planner clause is judged too ([`crate::train::planner_record`]).
//! Scorecards of one recipe at several seeds give a seed spread: each figure's standard
//! deviation across them, against which a difference can be read (docs/training.md,
//! "Comparing a candidate with the release").

use std::fmt::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;

use crate::eval::SuiteReport;
use crate::eval::physics_suite::{FigureRow, PhysicsSuiteReport};
use crate::eval::regimes::Regime;
use crate::train::planner_record::{self, PlannerClause, PlannerRecord};

pub use super::horizon_guard::{
    FRESH_GUARD, HORIZONS_S, change_by_horizon, within_at_every_horizon,
};

/// Changes by horizon as text: `0.5 s +0.4%, 1 s -0.2%, ...`.
fn format_changes(changes: &[f64; 4]) -> String {
    changes
        .iter()
        .zip(&HORIZONS_S)
        .map(|(x, h)| format!("{h} s {:+.1}%", 100.0 * x))
        .collect::<Vec<_>>()
        .join(", ")
}

/// A candidate must be better on more than this many of the fourteen figures.
pub const COUNT_TO_SHIP: usize = 9;

/// Which way a figure improves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Better {
    /// Smaller is better (errors, distances).
    Lower,
    /// Larger is better (ratios of the ballistic baseline's error to the model's).
    Higher,
}

/// One key figure of one scorecard.
#[derive(Clone, Debug, PartialEq)]
pub struct KeyFigure {
    /// Short name with its unit (`MOVi-B 0.5 s (m)`).
    pub name: &'static str,
    /// Which way it improves.
    pub better: Better,
    /// Its value.
    pub value: f64,
}

/// The key figures of one model, read from a scorecard directory.
#[derive(Clone, Debug, PartialEq)]
pub struct Scorecard {
    /// The directory read.
    pub dir: PathBuf,
    /// The fourteen key figures, in the card's order.
    pub figures: Vec<KeyFigure>,
    /// Fresh-split translation RMSE at [`HORIZONS_S`], metres (the guard's figures).
    pub fresh_m: [f64; 4],
    /// What each report scored (test split, fresh split, suite): data, seed, scenes and
    /// protocol; scorecards are comparable only when these agree.
    pub data: [String; 3],
    /// The push planner's record (`planner.json`), when the directory has one.
    pub planner: Option<PlannerRecord>,
}

impl Scorecard {
    /// MOVi-B test-split translation RMSE at [`HORIZONS_S`] (k = 1), metres: the first four
    /// key figures.
    pub fn test_m(&self) -> [f64; 4] {
        let mut m = [0.0; 4];
        for (slot, f) in m.iter_mut().zip(&self.figures) {
            *slot = f.value;
        }
        m
    }
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> anyhow::Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))
}

/// What a `dynaserve eval --json` report scored: its data, seed, scenes and start frame.
fn movi_b_data(report: &SuiteReport) -> String {
    match report.entries.first().map(|e| &e.report) {
        Some(r) => {
            let data = r
                .dataset
                .as_ref()
                .map(|d| format!("{} (seed {}, split {})", d.dir, d.seed, d.split))
                .unwrap_or_else(|| "generated scenes".into());
            format!("{data}, {} scenes from frame {}", r.scenes, r.start_frame)
        }
        None => "no predictor".into(),
    }
}

/// Translation RMSE at [`HORIZONS_S`] (k = 1) and the k = 1 resting drift's mean of the first
/// entry of a `dynaserve eval --json` report.
fn movi_b(report: &SuiteReport, path: &Path) -> anyhow::Result<([f64; 4], Option<f64>)> {
    let entry = report
        .entries
        .first()
        .with_context(|| format!("{}: no predictor in the report", path.display()))?;
    let r = &entry.report;
    let mut rmse = [0.0; 4];
    for (slot, &h) in rmse.iter_mut().zip(&HORIZONS_S) {
        *slot = r
            .entry(1, h)
            .and_then(|e| e.translation_rmse_m)
            .with_context(|| {
                format!(
                    "{}: no step size 1 translation RMSE at {h} s (score with --step-sizes 1)",
                    path.display()
                )
            })?;
    }
    let drift = r.resting.as_ref().and_then(|rest| {
        rest.predicted
            .iter()
            .find(|d| d.dt_steps == 1)
            .and_then(|d| d.translation_m)
            .map(|s| s.mean)
    });
    Ok((rmse, drift))
}

fn figure<'a>(
    suite: &'a PhysicsSuiteReport,
    path: &Path,
    key: (&str, &str, &str),
) -> anyhow::Result<&'a FigureRow> {
    suite
        .figures
        .iter()
        .find(|f| (f.scenario.as_str(), f.group.as_str(), f.figure.as_str()) == key)
        .with_context(|| format!("{}: no figure {key:?}", path.display()))
}

/// The first predictor's mean of a suite figure.
fn model_mean(
    suite: &PhysicsSuiteReport,
    path: &Path,
    key: (&str, &str, &str),
) -> anyhow::Result<f64> {
    figure(suite, path, key)?
        .predictors
        .first()
        .map(|p| p.mean)
        .with_context(|| format!("{}: figure {key:?} has no predictor", path.display()))
}

/// How far the first predictor's mean of a suite figure is from rapier's, as a fraction.
fn off_rapier(
    suite: &PhysicsSuiteReport,
    path: &Path,
    key: (&str, &str, &str),
) -> anyhow::Result<f64> {
    let row = figure(suite, path, key)?;
    let rapier = row
        .rapier
        .as_ref()
        .with_context(|| format!("{}: figure {key:?} has no rapier value", path.display()))?;
    Ok((model_mean(suite, path, key)? / rapier.mean - 1.0).abs())
}

fn regime_row<'a>(
    suite: &'a PhysicsSuiteReport,
    path: &Path,
    regime: Regime,
    k: u32,
) -> anyhow::Result<&'a crate::eval::physics_suite::RegimeRow> {
    suite
        .regimes
        .iter()
        .find(|r| r.regime == regime && r.k == k)
        .with_context(|| format!("{}: no {regime:?} row at k = {k}", path.display()))
}

/// Ballistic-with-floor translation RMSE over the model's in a regime at k = 1.
fn contact_ratio(suite: &PhysicsSuiteReport, path: &Path, regime: Regime) -> anyhow::Result<f64> {
    regime_row(suite, path, regime, 1)?
        .ballistic_over_model
        .and_then(|[t, _]| t)
        .with_context(|| {
            format!(
                "{}: no ballistic-over-model ratio for {regime:?} at k = 1 (score with the ballistic baseline)",
                path.display()
            )
        })
}

/// The suite's scenario figures among the key figures: name, (scenario, group, figure), and
/// whether the figure is the distance of the model's mean from rapier's (else the mean itself).
#[rustfmt::skip]
const SUITE_FIGURES: [(&str, (&str, &str, &str), bool); 6] = [
    ("towers (m)",                ("rest", "tower", "max displacement"),     false),
    ("drop height (m)",           ("drop", "drop", "final height error"),    false),
    ("penetration (m)",           ("drop", "drop", "deepest penetration"),   false),
    ("slide, off rapier",         ("slide", "floor", "stopping distance"),   true),
    ("collide air, off rapier",   ("collide", "air", "momentum exchanged"),  true),
    ("collide floor, off rapier", ("collide", "floor", "momentum exchanged"), true),
];

/// Reads the scorecard in `dir` (`eval.json`, `fresh.json`, `physics-suite.json`, and
/// `planner.json` when there is one).
pub fn read_scorecard(dir: &Path) -> anyhow::Result<Scorecard> {
    let (test_path, fresh_path, suite_path) = (
        dir.join("eval.json"),
        dir.join("fresh.json"),
        dir.join("physics-suite.json"),
    );
    let test_report: SuiteReport = read_json(&test_path)?;
    let (test, drift) = movi_b(&test_report, &test_path)?;
    let drift =
        drift.with_context(|| format!("{}: no step size 1 resting drift", test_path.display()))?;
    let fresh_report: SuiteReport = read_json(&fresh_path)?;
    let (fresh_m, _) = movi_b(&fresh_report, &fresh_path)?;
    let suite: PhysicsSuiteReport = read_json(&suite_path)?;
    let suite_scenes: u64 = suite.scenes.iter().map(|c| c.scenes).sum();
    let data = [
        movi_b_data(&test_report),
        movi_b_data(&fresh_report),
        format!(
            "{}, {suite_scenes} scenes from frame {}, every {} window(s)",
            suite.source, suite.options.start_frame, suite.options.window_stride
        ),
    ];
    let p = suite_path.as_path();
    let free_flight = regime_row(&suite, p, Regime::FreeFlight, 4)?
        .predictors
        .first()
        .and_then(|c| c.translation_rmse_m)
        .with_context(|| format!("{}: no free-flight error at k = 4", p.display()))?;
    use Better::{Higher, Lower};
    let mut figures: Vec<KeyFigure> = [
        "MOVi-B 0.5 s (m)",
        "MOVi-B 1 s (m)",
        "MOVi-B 2 s (m)",
        "MOVi-B 4 s (m)",
    ]
    .into_iter()
    .zip(test)
    .chain([("resting drift (m)", drift)])
    .map(|(name, value)| KeyFigure {
        name,
        better: Lower,
        value,
    })
    .collect();
    for (name, key, off_rapier_figure) in SUITE_FIGURES {
        let value = if off_rapier_figure {
            off_rapier(&suite, p, key)?
        } else {
            model_mean(&suite, p, key)?
        };
        figures.push(KeyFigure {
            name,
            better: Lower,
            value,
        });
    }
    for (name, regime) in [
        ("floor contact (x)", Regime::FloorContact),
        ("object contact (x)", Regime::ObjectContact),
    ] {
        let value = contact_ratio(&suite, p, regime)?;
        figures.push(KeyFigure {
            name,
            better: Higher,
            value,
        });
    }
    figures.push(KeyFigure {
        name: "free flight k=4 (m)",
        better: Lower,
        value: free_flight,
    });
    Ok(Scorecard {
        dir: dir.to_path_buf(),
        figures,
        fresh_m,
        data,
        planner: planner_record::read_planner(dir)?,
    })
}

/// Refuses two scorecards whose reports scored different data (another split, seed, scene
/// count, start frame, suite materials or window stride): their figures are not comparable.
pub fn check_same_data(a: &Scorecard, b: &Scorecard) -> anyhow::Result<()> {
    for (what, (x, y)) in ["eval.json", "fresh.json", "physics-suite.json"]
        .iter()
        .zip(a.data.iter().zip(&b.data))
    {
        anyhow::ensure!(
            x == y,
            "{what} of {} and of {} scored different data: {x} against {y}",
            a.dir.display(),
            b.dir.display()
        );
    }
    Ok(())
}

/// Refuses a candidate whose planner record cannot be paired with the reference's (other
/// settings or seeds); passes when either has none.
pub fn check_same_planner(reference: &Scorecard, candidate: &Scorecard) -> anyhow::Result<()> {
    match (&reference.planner, &candidate.planner) {
        (Some(r), Some(c)) => {
            planner_record::check_pairable(r, c, (&reference.dir, &candidate.dir))
        }
        _ => Ok(()),
    }
}

/// How a candidate's figure stands against the reference's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Better (in the figure's direction).
    Better,
    /// Worse.
    Worse,
    /// Equal.
    Tie,
}

/// The verdict on `candidate` against `reference` for a figure that improves `better`.
pub fn verdict(better: Better, reference: f64, candidate: f64) -> Verdict {
    if candidate == reference {
        Verdict::Tie
    } else if (candidate < reference) == (better == Better::Lower) {
        Verdict::Better
    } else {
        Verdict::Worse
    }
}

/// One candidate judged against the reference by the count and the fresh-scene guard.
#[derive(Clone, Debug, PartialEq)]
pub struct Comparison {
    /// Per key figure: the verdict.
    pub verdicts: Vec<Verdict>,
    /// Figures the candidate is better on.
    pub better: usize,
    /// Figures it is worse on.
    pub worse: usize,
    /// Fresh-split change at each horizon, candidate over reference minus 1.
    pub fresh_change: [f64; 4],
    /// Whether the fresh-scene guard holds ([`FRESH_GUARD`] at every horizon).
    pub guard_holds: bool,
    /// The planner clause, when both scorecards hold a planner record.
    pub planner: Option<PlannerClause>,
}

impl Comparison {
    /// Whether the candidate ships by the count and the guard.
    pub fn ships_by_count(&self) -> bool {
        self.better > COUNT_TO_SHIP && self.guard_holds
    }

    /// Whether the candidate ships: by the count and the guard, or by the planner clause.
    pub fn ships(&self) -> bool {
        self.ships_by_count() || self.planner.as_ref().is_some_and(PlannerClause::passes)
    }
}

/// `candidate` judged against `reference`.
pub fn compare(reference: &Scorecard, candidate: &Scorecard) -> Comparison {
    let verdicts: Vec<Verdict> = reference
        .figures
        .iter()
        .zip(&candidate.figures)
        .map(|(r, c)| verdict(r.better, r.value, c.value))
        .collect();
    let count = |v: Verdict| verdicts.iter().filter(|&&x| x == v).count();
    let fresh_change = change_by_horizon(&reference.fresh_m, &candidate.fresh_m);
    let planner = match (&reference.planner, &candidate.planner) {
        (Some(r), Some(c)) => {
            planner_record::planner_clause(r, c, reference.test_m(), candidate.test_m())
        }
        _ => None,
    };
    Comparison {
        better: count(Verdict::Better),
        worse: count(Verdict::Worse),
        guard_holds: within_at_every_horizon(&fresh_change, FRESH_GUARD),
        fresh_change,
        verdicts,
        planner,
    }
}

/// Per key figure, the mean and sample standard deviation over scorecards of one recipe at
/// different seeds (at least two).
pub fn seed_spread(runs: &[Scorecard]) -> anyhow::Result<Vec<(f64, f64)>> {
    anyhow::ensure!(
        runs.len() >= 2,
        "a seed spread needs the scorecards of at least two runs, got {}",
        runs.len()
    );
    let n = runs.len() as f64;
    Ok((0..runs[0].figures.len())
        .map(|i| {
            let mean = runs.iter().map(|r| r.figures[i].value).sum::<f64>() / n;
            let var = runs
                .iter()
                .map(|r| (r.figures[i].value - mean).powi(2))
                .sum::<f64>()
                / (n - 1.0);
            (mean, var.sqrt())
        })
        .collect())
}

/// The comparison as a plain-text table: every figure of the reference and the candidate, the
/// change, the verdict and, with a `spread`, the change in seed standard deviations; then the
/// count, the guard and the outcome.
pub fn format_comparison(
    reference: &Scorecard,
    candidate: &Scorecard,
    spread: Option<&[(f64, f64)]>,
) -> String {
    let c = compare(reference, candidate);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{} against {}",
        candidate.dir.display(),
        reference.dir.display()
    );
    let _ = write!(
        out,
        "{:<27} {:>10} {:>10} {:>8}  {:<7}",
        "figure", "reference", "candidate", "change", "verdict"
    );
    if spread.is_some() {
        let _ = write!(out, " {:>10} {:>9}", "seed sd", "change/sd");
    }
    out.push('\n');
    for (i, (r, k)) in reference.figures.iter().zip(&candidate.figures).enumerate() {
        let change = 100.0 * (k.value / r.value - 1.0);
        let v = match c.verdicts[i] {
            Verdict::Better => "better",
            Verdict::Worse => "worse",
            Verdict::Tie => "tie",
        };
        let _ = write!(
            out,
            "{:<27} {:>10.4} {:>10.4} {:>+7.1}%  {:<7}",
            r.name, r.value, k.value, change, v
        );
        if let Some(s) = spread {
            let (_, sd) = s[i];
            if sd > 0.0 {
                let z = (k.value - r.value) / sd;
                let _ = write!(out, " {sd:>10.4} {z:>+9.1}");
            } else {
                let _ = write!(out, " {sd:>10.4} {:>9}", "-");
            }
        }
        out.push('\n');
    }
    let _ = writeln!(
        out,
        "better on {} of {}, worse on {}; fresh-scene guard (within {:.0}% at every horizon): {} -> {}",
        c.better,
        c.verdicts.len(),
        c.worse,
        100.0 * FRESH_GUARD,
        format_changes(&c.fresh_change),
        if c.guard_holds { "holds" } else { "fails" }
    );
    let _ = writeln!(
        out,
        "by the count (more than {COUNT_TO_SHIP}) and the guard: {}",
        if c.ships_by_count() {
            "ships"
        } else {
            "does not ship"
        }
    );
    match &c.planner {
        Some(p) => {
            let in_se = if p.paired_se > 0.0 {
                format!("{:+.1}", p.paired_mean / p.paired_se)
            } else {
                "-".into()
            };
            let _ = writeln!(
                out,
                "push planner over {} paired seeds: reference {:.3} m, candidate {:.3} m \
                 (closer than random on {} and {}); paired difference {:+.4} m, standard error \
                 {:.4} m ({in_se} SE; better needs below -{:.0})",
                p.seeds,
                p.reference_mean,
                p.candidate_mean,
                p.closer_than_random.0,
                p.closer_than_random.1,
                p.paired_mean,
                p.paired_se,
                planner_record::PLANNER_SE
            );
            let _ = writeln!(
                out,
                "by the planner clause (planner better, MOVi-B test split within {:.0}% at every \
                 horizon: {}): {}",
                100.0 * planner_record::TEST_GUARD,
                format_changes(&p.test_change),
                match (p.planner_better(), p.test_guard_holds()) {
                    (true, true) => "ships",
                    (true, false) => "does not ship (the test split fails)",
                    (false, _) => "does not ship (the planner is not better)",
                }
            );
        }
        None => {
            let missing: Vec<String> = [reference, candidate]
                .iter()
                .filter(|s| s.planner.is_none())
                .map(|s| s.dir.join("planner.json").display().to_string())
                .collect();
            let why = if missing.is_empty() {
                "fewer than two seeds in common".to_string()
            } else {
                format!("no {}", missing.join(" or "))
            };
            let _ = writeln!(out, "planner clause: not judged ({why})");
        }
    }
    let _ = writeln!(
        out,
        "outcome: {}",
        if c.ships() { "ships" } else { "does not ship" }
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn verdicts_follow_each_figures_direction() {
        assert_eq!(verdict(Better::Lower, 1.0, 0.9), Verdict::Better);
        assert_eq!(verdict(Better::Lower, 1.0, 1.1), Verdict::Worse);
        assert_eq!(verdict(Better::Higher, 2.0, 2.1), Verdict::Better);
        assert_eq!(verdict(Better::Higher, 2.0, 1.9), Verdict::Worse);
        assert_eq!(verdict(Better::Higher, 2.0, 2.0), Verdict::Tie);
    }

    #[test]
    fn a_spread_needs_two_runs_and_uses_the_sample_deviation() {
        let card = |v: f64| Scorecard {
            dir: PathBuf::from("x"),
            figures: vec![KeyFigure {
                name: "f",
                better: Better::Lower,
                value: v,
            }],
            fresh_m: [1.0; 4],
            data: Default::default(),
            planner: None,
        };
        assert!(seed_spread(&[card(1.0)]).is_err());
        let s = seed_spread(&[card(1.0), card(2.0), card(3.0)]).unwrap();
        assert_eq!(s, vec![(2.0, 1.0)]);
    }
}
