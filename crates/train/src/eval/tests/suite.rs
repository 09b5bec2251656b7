//! The suite reports, printed and plotted.

use super::*;

#[test]
fn suite_reports_print_and_plot() {
    let s = scene(2, 101, |j, t| {
        pose(
            Vector3::new(j as f64 * 2.0, t, 0.5 + (1.0 - t).max(0.0)),
            UnitQuaternion::identity(),
        )
    });
    let opts = EvalOptions::default();
    let ballistic = Ballistic {
        gravity: [0.0, 0.0, -10.0],
        floor_z: Some(0.0),
    };
    let suite = SuiteReport {
        entries: vec![
            SuiteEntry {
                label: "static".into(),
                input: None,
                report: evaluate_scenes(&Static, std::slice::from_ref(&s), &opts).unwrap(),
            },
            SuiteEntry {
                label: "ballistic".into(),
                input: None,
                report: evaluate_scenes(&ballistic, std::slice::from_ref(&s), &opts).unwrap(),
            },
        ],
        elapsed_s: 0.0,
    };
    let text = format_suite(&suite);
    for want in [
        "translation RMSE (m)",
        "orientation RMSE (deg)",
        "stability: k = 1, 100 steps",
        "resting drift over frames 76..100",
        "ground truth",
        "0.5 s (12 fr)",
        "per-object error at k = 1",
    ] {
        assert!(text.contains(want), "{want:?} missing from\n{text}");
    }
    let md = format_markdown(&suite);
    // The per-object table: every horizon, each predictor in turn.
    assert!(md.contains("**Per-object error** at k = 1"), "{md}");
    // The corner clouds' spacing is 1 m, so the contact distance between objects (0.01 m
    // plus that spacing) spans the 1 m gap between the two cubes: both count as touching.
    assert!(
        md.contains("**Per-object error by contact** of `static`"),
        "{md}"
    );
    for h in ["0.5 s (12 fr)", "1 s (24 fr)", "2 s (48 fr)", "4 s (96 fr)"] {
        assert!(
            md.contains(&format!("| {h} | another object | 2 |")),
            "{md}"
        );
    }
    assert!(text.contains("by what the object touched"), "{text}");
    for label in ["static", "ballistic"] {
        assert_eq!(md.matches(&format!("fr) | {label} |")).count(), 4, "{md}");
    }
    assert!(md.contains("| horizon | k | static | ballistic |"), "{md}");
    assert!(md.contains("| 4 s (96 fr) | 4 |"), "{md}");
    assert!(md.contains("**Resting drift**"), "{md}");
    let json = serde_json::to_string(&suite).unwrap();
    let back: SuiteReport = serde_json::from_str(&json).unwrap();
    assert_eq!(back.entries.len(), 2);
    let png = std::env::temp_dir().join(format!("dynaserve-eval-plot-{}.png", std::process::id()));
    plot_errors(
        &png,
        "test",
        &[
            ("static", &suite.entries[0].report, PlotStyle::EveryStepSize),
            ("ballistic", &suite.entries[1].report, PlotStyle::Baseline),
        ],
    )
    .unwrap();
    let bytes = std::fs::read(&png).unwrap();
    std::fs::remove_file(&png).ok();
    assert_eq!(&bytes[1..4], b"PNG");
    assert!(bytes.len() > 5000);
}

#[test]
fn the_resting_drift_by_shape_is_printed_in_text_and_markdown() {
    // Two objects at rest, of shapes 5 (named) and 3 (no name in the manifest).
    let s = resting_pair_of_shapes_5_and_3();
    let mut report = evaluate_scenes(&Static, &[s], &EvalOptions::default()).unwrap();
    for d in &mut report.resting.as_mut().unwrap().predicted {
        for x in &mut d.by_shape {
            if x.shape_id == 5 {
                x.shape = "cube".into();
            }
        }
    }
    let suite = SuiteReport {
        entries: vec![SuiteEntry {
            label: "static".into(),
            input: None,
            report,
        }],
        elapsed_s: 0.0,
    };
    let text = format_suite(&suite);
    assert!(text.contains("resting drift by shape (static)"), "{text}");
    let rows: Vec<&str> = text
        .lines()
        .skip_while(|l| !l.starts_with("resting drift by shape"))
        .skip(2)
        .collect();
    // One row per (step size, shape), shapes by id: 3 (its id) before 5 (its name).
    assert_eq!(rows.len(), 2 * 3, "{text}");
    assert!(
        rows[0].contains(" 3 ") && rows[1].contains("cube"),
        "{text}"
    );
    let md = format_markdown(&suite);
    assert!(md.contains("**Resting drift by shape**"), "{md}");
    assert_eq!(md.matches("| static | 1 | cube | 1 |").count(), 1, "{md}");
}
