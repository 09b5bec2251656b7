//! `dynaserve train compare` on the shipped release's own scorecard
//! (`models/rigidformer-small/eval`: the reports its card quotes) and on copies of it with
//! single figures moved, written to a temporary directory; the planner clause on the release's
//! own push planner record (`planner.json`) and on copies of it with the distances moved.

use std::path::{Path, PathBuf};

use dynaserve_train::train::compare::{
    Verdict, check_same_data, check_same_planner, compare, format_comparison, read_scorecard,
    seed_spread,
};
use serde_json::Value;

fn release() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rigidformer-small/eval")
}

/// A fresh directory under the system temporary directory, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        let dir = std::env::temp_dir().join(format!("dynaserve-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn read(file: &str) -> Value {
    serde_json::from_str(&std::fs::read_to_string(release().join(file)).unwrap()).unwrap()
}

/// The release's scorecard copied into `dir`, each report passed through `edit` first.
fn copy_with(dir: &Path, edit: impl Fn(&str, &mut Value)) {
    for file in ["eval.json", "fresh.json", "physics-suite.json"] {
        let mut v = read(file);
        edit(file, &mut v);
        std::fs::write(dir.join(file), serde_json::to_string(&v).unwrap()).unwrap();
    }
}

#[test]
fn the_release_against_itself_ties_on_every_figure_and_keeps_the_guard() {
    let card = read_scorecard(&release()).unwrap();
    assert_eq!(card.figures.len(), 14);
    assert!(
        card.figures
            .iter()
            .all(|f| f.value.is_finite() && f.value >= 0.0),
        "{:?}",
        card.figures
    );
    // The fresh split is scored on fewer, shorter-lived scenes than the test split, but both
    // grow with the horizon.
    assert!(
        card.fresh_m.windows(2).all(|w| w[0] < w[1]),
        "{:?}",
        card.fresh_m
    );
    let c = compare(&card, &card);
    assert!(c.verdicts.iter().all(|&v| v == Verdict::Tie));
    assert_eq!((c.better, c.worse), (0, 0));
    assert!(c.guard_holds && !c.ships());
}

#[test]
fn moved_figures_count_in_their_own_direction_and_the_guard_reads_the_fresh_split() {
    let tmp = TempDir::new("compare");
    // Object contact 10% further below ballistic (better), the test split 5% worse at 0.5 s,
    // the fresh split 2% worse at 4 s.
    copy_with(&tmp.0, |file, v| match file {
        "physics-suite.json" => {
            for row in v["regimes"].as_array_mut().unwrap() {
                if row["regime"] == "object_contact" && row["k"] == 1 {
                    let r = &mut row["ballistic_over_model"][0];
                    *r = Value::from(r.as_f64().unwrap() * 1.1);
                }
            }
        }
        "eval.json" | "fresh.json" => {
            let h = if file == "eval.json" { 0.5 } else { 4.0 };
            let scale = if file == "eval.json" { 1.05 } else { 1.02 };
            let sizes = v["entries"][0]["report"]["step_sizes"]
                .as_array_mut()
                .unwrap();
            for s in sizes.iter_mut().filter(|s| s["dt_steps"] == 1) {
                for hz in s["horizons"].as_array_mut().unwrap() {
                    if hz["horizon_s"].as_f64() == Some(h) {
                        let t = &mut hz["translation_rmse_m"];
                        *t = Value::from(t.as_f64().unwrap() * scale);
                    }
                }
            }
        }
        _ => {}
    });
    let reference = read_scorecard(&release()).unwrap();
    let candidate = read_scorecard(&tmp.0).unwrap();
    let c = compare(&reference, &candidate);
    let verdict_of = |name: &str| {
        let i = reference
            .figures
            .iter()
            .position(|f| f.name == name)
            .unwrap();
        c.verdicts[i]
    };
    assert_eq!(verdict_of("object contact (x)"), Verdict::Better);
    assert_eq!(verdict_of("MOVi-B 0.5 s (m)"), Verdict::Worse);
    assert_eq!((c.better, c.worse), (1, 1));
    assert!(
        (c.fresh_change[3] - 0.02).abs() < 1e-9,
        "{:?}",
        c.fresh_change
    );
    assert!(!c.guard_holds);

    // With the two as a seed spread, each moved figure's change is one deviation times
    // sqrt(2) (two samples: the deviation is the difference over sqrt(2)).
    let spread = seed_spread(&[reference.clone(), candidate.clone()]).unwrap();
    let text = format_comparison(&reference, &candidate, Some(&spread));
    assert!(text.contains("better on 1 of 14, worse on 1"), "{text}");
    assert!(text.contains("-> fails"), "{text}");
    assert!(text.contains("does not ship"), "{text}");
    let row = text
        .lines()
        .find(|l| l.starts_with("object contact (x)"))
        .unwrap();
    assert!(row.trim_end().ends_with("+1.4"), "{row}");
}

#[test]
fn a_scorecard_without_its_fresh_split_is_refused_by_name() {
    let tmp = TempDir::new("compare-missing");
    copy_with(&tmp.0, |_, _| {});
    std::fs::remove_file(tmp.0.join("fresh.json")).unwrap();
    let err = format!("{:#}", read_scorecard(&tmp.0).unwrap_err());
    assert!(err.contains("fresh.json"), "{err}");
}

#[test]
fn scorecards_of_different_data_are_refused() {
    let tmp = TempDir::new("compare-other-data");
    copy_with(&tmp.0, |file, v| {
        if file == "physics-suite.json" {
            v["source"] = Value::from("generated scenes (seed 8, split test)");
        }
    });
    let reference = read_scorecard(&release()).unwrap();
    check_same_data(&reference, &reference).unwrap();
    let other = read_scorecard(&tmp.0).unwrap();
    let err = format!("{:#}", check_same_data(&reference, &other).unwrap_err());
    assert!(
        err.contains("physics-suite.json") && err.contains("seed 8"),
        "{err}"
    );
}

#[test]
fn the_planner_clause_pairs_the_records_seed_by_seed_and_keeps_the_test_split() {
    let reference = read_scorecard(&release()).unwrap();
    let record = reference
        .planner
        .as_ref()
        .expect("the release has a planner.json");
    assert_eq!(record.seeds.len(), 200);
    // Against itself: no difference, so not better.
    let c = compare(&reference, &reference);
    let p = c.planner.as_ref().unwrap();
    assert_eq!((p.seeds, p.paired_mean, p.paired_se), (200, 0.0, 0.0));
    assert!(!p.planner_better() && !c.ships());

    // A candidate whose plans end 5 to 10 mm closer on every seed (never below zero) ships by
    // the clause alone: its fourteen figures tie.
    let tmp = TempDir::new("compare-planner");
    copy_with(&tmp.0, |_, _| {});
    let mut planner = read("planner.json");
    for (i, s) in planner["seeds"]
        .as_array_mut()
        .unwrap()
        .iter_mut()
        .enumerate()
    {
        let d = s["planned"].as_f64().unwrap();
        let closer = if i % 2 == 0 { 0.010 } else { 0.005 };
        s["planned"] = Value::from((d - closer).max(0.0));
    }
    let write = |v: &Value| {
        std::fs::write(tmp.0.join("planner.json"), v.to_string()).unwrap();
    };
    write(&planner);
    let candidate = read_scorecard(&tmp.0).unwrap();
    check_same_planner(&reference, &candidate).unwrap();
    let c = compare(&reference, &candidate);
    let p = c.planner.as_ref().unwrap();
    assert!((-0.0076..-0.004).contains(&p.paired_mean), "{p:?}");
    assert!(p.passes() && !c.ships_by_count() && c.ships(), "{p:?}");
    let text = format_comparison(&reference, &candidate, None);
    assert!(
        text.contains("push planner over 200 paired seeds"),
        "{text}"
    );
    assert!(
        text.contains("by the count (more than 9) and the guard: does not ship"),
        "{text}"
    );
    assert!(text.contains("outcome: ships"), "{text}");

    // The same planner with MOVi-B's test split 2% worse at 1 s does not ship.
    copy_with(&tmp.0, |file, v| {
        if file == "eval.json" {
            for s in v["entries"][0]["report"]["step_sizes"]
                .as_array_mut()
                .unwrap()
                .iter_mut()
                .filter(|s| s["dt_steps"] == 1)
            {
                for hz in s["horizons"].as_array_mut().unwrap() {
                    if hz["horizon_s"].as_f64() == Some(1.0) {
                        let t = &mut hz["translation_rmse_m"];
                        *t = Value::from(t.as_f64().unwrap() * 1.02);
                    }
                }
            }
        }
    });
    let c = compare(&reference, &read_scorecard(&tmp.0).unwrap());
    let p = c.planner.as_ref().unwrap();
    assert!(
        p.planner_better() && !p.test_guard_holds() && !c.ships(),
        "{p:?}"
    );

    // Another pusher speed, or fewer seeds, cannot be paired.
    planner["settings"]["speed"] = Value::from(0.4);
    write(&planner);
    let err = check_same_planner(&reference, &read_scorecard(&tmp.0).unwrap()).unwrap_err();
    assert!(err.to_string().contains("speed 0.8 against 0.4"), "{err}");
    planner["settings"]["speed"] = Value::from(0.8);
    planner["seeds"].as_array_mut().unwrap().truncate(40);
    write(&planner);
    let err = check_same_planner(&reference, &read_scorecard(&tmp.0).unwrap()).unwrap_err();
    assert!(err.to_string().contains("different seeds"), "{err}");

    // Without a record the clause is not judged, and says which file is missing.
    std::fs::remove_file(tmp.0.join("planner.json")).unwrap();
    let text = format_comparison(&reference, &read_scorecard(&tmp.0).unwrap(), None);
    assert!(
        text.contains("planner clause: not judged (no ") && text.contains("planner.json)"),
        "{text}"
    );
}
