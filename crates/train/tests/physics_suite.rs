//! The physics scenario suite on real rapier scenes: regimes follow what the scenes do, the
//! scenario figures of a replay of the ground truth equal rapier's, the ballistic baseline is
//! exact in free flight and misses every contact effect, the shipped checkpoint runs through
//! the suite, and the reports render and round-trip.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use dynaserve_model::{Pose, SceneState};
use dynaserve_sim::writer::generate_dataset;
use dynaserve_sim::{GenerateOptions, Generator, Materials, SceneRecord};
use dynaserve_train::eval::physics_report::{format_physics_markdown, format_physics_text};
use dynaserve_train::eval::physics_suite::{
    PhysicsSuiteReport, SuiteOptions, SuiteScene, generate_suite, load_suite, run_suite,
};
use dynaserve_train::eval::regimes::{Regime, contact_flags, impact_subset, regime, windows};
use dynaserve_train::eval::{Ballistic, EvalError, ModelPredictor, Predictor};

const GRAVITY: [f32; 3] = [0.0, 0.0, -10.0];

/// One scene of each of the 7 suite groups (seed 7, split test, 256 points), generated once.
fn suite() -> &'static [SuiteScene] {
    static SUITE: OnceLock<Vec<SuiteScene>> = OnceLock::new();
    SUITE.get_or_init(|| generate_suite(7, "test", 1, 256, Materials::Kubric).unwrap())
}

fn ballistic() -> Ballistic {
    Ballistic {
        gravity: GRAVITY,
        floor_z: Some(0.0),
    }
}

fn options(stride: usize) -> SuiteOptions {
    SuiteOptions {
        window_stride: stride,
        gravity: GRAVITY,
        ..SuiteOptions::default()
    }
}

/// Test oracle: plays the recorded future back from whichever frame the observed poses are.
struct Replay;

impl Predictor for Replay {
    fn name(&self) -> String {
        "replay".into()
    }

    fn rollout(
        &self,
        scene: &SceneRecord,
        observed: &SceneState,
        dt_steps: u32,
        steps: usize,
    ) -> Result<Vec<Vec<Pose>>, EvalError> {
        let frames = scene.objects[0].positions.len();
        let s = (0..frames)
            .find(|&t| {
                scene
                    .objects
                    .iter()
                    .zip(&observed.current)
                    .all(|(o, p)| o.positions[t] == p.translation && o.rotations[t] == p.rotation)
            })
            .ok_or_else(|| EvalError::Invalid("observed poses are not a recorded frame".into()))?;
        Ok((1..=steps)
            .map(|i| {
                let t = (s + i * dt_steps as usize).min(frames - 1);
                scene
                    .objects
                    .iter()
                    .map(|o| Pose {
                        translation: o.positions[t],
                        rotation: o.rotations[t],
                    })
                    .collect()
            })
            .collect())
    }
}

fn scene_of<'a>(scenes: &'a [SuiteScene], scenario: &str, variant: &str) -> &'a SuiteScene {
    scenes
        .iter()
        .find(|s| {
            s.label.as_ref().is_some_and(|l| {
                l.scenario == scenario && (variant.is_empty() || l.variant == variant)
            })
        })
        .unwrap_or_else(|| panic!("no {scenario}/{variant} scene"))
}

fn regimes_of(s: &SuiteScene, k: usize) -> Vec<Regime> {
    let flags = contact_flags(&s.scene, GRAVITY).unwrap();
    let frames = s.scene.objects[0].positions.len();
    windows(frames, k, 1)
        .into_iter()
        .flat_map(|t| (0..s.scene.objects.len()).map(move |j| (t, j)))
        .map(|(t, j)| regime(&s.scene, &flags, j, t, k))
        .collect()
}

#[test]
fn generated_suite_is_labelled_and_deterministic() {
    let scenes = suite();
    assert_eq!(scenes.len(), 8);
    let again = generate_suite(7, "test", 1, 256, Materials::Kubric).unwrap();
    for (a, b) in scenes.iter().zip(&again) {
        assert_eq!(a.scene, b.scene);
        assert_eq!(a.label, b.label);
    }
    let tower = scene_of(scenes, "rest", "tower");
    assert_eq!(
        tower.scene.objects.len(),
        4,
        "the suite's towers have 4 boxes"
    );
    for (name, variant) in [
        ("drop", ""),
        ("slide", ""),
        ("collide", "air"),
        ("collide", "floor"),
        ("stack-hit", ""),
        ("roll", ""),
    ] {
        scene_of(scenes, name, variant);
    }
    assert!(generate_suite(7, "test", 0, 256, Materials::Kubric).is_err());
}

#[test]
fn regimes_follow_what_the_scenes_do() {
    let scenes = suite();
    for k in [1, 4] {
        let tower = regimes_of(scene_of(scenes, "rest", "tower"), k);
        assert!(
            tower.iter().all(|r| *r == Regime::Resting),
            "k {k}: {tower:?}"
        );
    }
    // A drop starts in free flight and ends on the floor.
    let drop = regimes_of(scene_of(scenes, "drop", ""), 1);
    assert_eq!(drop[0], Regime::FreeFlight);
    let last = *drop.last().unwrap();
    assert!(
        matches!(last, Regime::Resting | Regime::FloorContact),
        "{last:?}"
    );
    assert!(drop.contains(&Regime::FloorContact));
    // The drop lands within some floor-contact window; a slide touches the floor throughout.
    let impacts = |s: &SuiteScene| {
        let flags = contact_flags(&s.scene, GRAVITY).unwrap();
        let frames = s.scene.objects[0].positions.len();
        windows(frames, 1, 1)
            .into_iter()
            .filter(|&t| {
                let r = regime(&s.scene, &flags, 0, t, 1);
                r == Regime::FloorContact
                    && impact_subset(&flags, r, 0, t, 1) == Some(Regime::FloorImpact)
            })
            .count()
    };
    assert!(impacts(scene_of(scenes, "drop", "")) > 0);
    assert_eq!(impacts(scene_of(scenes, "slide", "")), 0);
    // Sliding objects touch the floor throughout and never another object.
    let slide = regimes_of(scene_of(scenes, "slide", ""), 1);
    assert!(!slide.contains(&Regime::FreeFlight) && !slide.contains(&Regime::ObjectContact));
    // Thrown objects meet; the stack is hit.
    for variant in ["air", "floor"] {
        let r = regimes_of(scene_of(scenes, "collide", variant), 1);
        assert!(r.contains(&Regime::ObjectContact), "{variant}");
    }
    assert!(regimes_of(scene_of(scenes, "stack-hit", ""), 1).contains(&Regime::ObjectContact));
}

#[test]
fn replaying_the_ground_truth_reproduces_rapier_figures_with_zero_error() {
    let report = run_suite(
        &[("replay", &Replay)],
        suite(),
        &options(3),
        "test",
        &|_, _| {},
    )
    .unwrap();
    assert!(!report.figures.is_empty());
    for f in &report.figures {
        let own = &f.predictors[0];
        if let Some(r) = &f.rapier {
            assert!(
                (own.mean - r.mean).abs() < 1e-9,
                "{}: {own:?} vs {r:?}",
                f.figure
            );
            assert!((own.max - r.max).abs() < 1e-9, "{}", f.figure);
        } else {
            // Errors against rapier.
            assert!(own.max < 1e-9, "{}: {own:?}", f.figure);
        }
    }
    for row in &report.regimes {
        let c = &row.predictors[0];
        if row.count > 0 {
            assert!(c.translation_rmse_m.unwrap() < 1e-9, "{row:?}");
            assert!(c.orientation_rmse_deg.unwrap() < 1e-6, "{row:?}");
        } else {
            assert_eq!(c.translation_rmse_m, None);
        }
    }
    let counted: u64 = report
        .regimes
        .iter()
        .filter(|r| r.k == 1 && Regime::ALL.contains(&r.regime))
        .map(|r| r.count)
        .sum();
    let expected: usize = suite()
        .iter()
        .map(|s| s.scene.objects.len() * windows(101, 1, 3).len())
        .sum();
    assert_eq!(counted, expected as u64);
    // Every window is listed once, with its regime; the impacts agree with the table's row.
    let k1: Vec<_> = report.windows.iter().filter(|w| w.k == 1).collect();
    assert_eq!(k1.len(), expected);
    let impact_row = report
        .regimes
        .iter()
        .find(|r| r.k == 1 && r.regime == Regime::FloorImpact)
        .unwrap();
    assert_eq!(
        k1.iter().filter(|w| w.impact).count() as u64,
        impact_row.count
    );
    // The object impacts likewise: object-contact windows whose flags are off at t or t + k.
    let object_impact_row = report
        .regimes
        .iter()
        .find(|r| r.k == 1 && r.regime == Regime::ObjectImpact)
        .unwrap();
    let object_impacts: Vec<_> = k1.iter().filter(|w| w.object_impact).collect();
    assert_eq!(object_impacts.len() as u64, object_impact_row.count);
    assert!(
        object_impact_row.count > 0,
        "the suite's collisions have onsets"
    );
    assert!(object_impacts.iter().all(|w| {
        let b = w.object_contact.as_bytes();
        w.regime == Regime::ObjectContact && (b[1] == b'0' || b[2] == b'0')
    }));
    assert!(
        k1.iter()
            .all(|w| w.translation_m < 1e-9 && w.floor.len() == 3 && w.object_contact.len() == 3)
    );
    let csv = dynaserve_train::eval::physics_suite::window_csv(&report);
    assert_eq!(csv.lines().count(), report.windows.len() + 1);
    assert!(csv.starts_with("predictor,scene,object,t,k,regime,impact"));
}

#[test]
fn ballistic_is_exact_in_free_flight_and_blind_to_contact() {
    let b = ballistic();
    let report = run_suite(
        &[("ballistic", &b)],
        suite(),
        &options(1),
        "test",
        &|_, _| {},
    )
    .unwrap();
    let row = |regime: Regime, k: u32| {
        report
            .regimes
            .iter()
            .find(|r| r.regime == regime && r.k == k)
            .unwrap()
    };
    for k in [1, 2, 4] {
        let free = row(Regime::FreeFlight, k);
        assert!(free.count > 0, "no free flight at k {k}");
        let t = free.predictors[0].translation_rmse_m.unwrap();
        assert!(t < 1e-4, "ballistic free flight k {k}: {t} m");
        let contact = row(Regime::ObjectContact, k).predictors[0]
            .translation_rmse_m
            .unwrap();
        assert!(
            contact > 100.0 * t.max(1e-6),
            "object contact k {k}: {contact} m"
        );
    }
    let figure = |scenario: &str, name: &str| {
        report
            .figures
            .iter()
            .find(|f| f.scenario == scenario && f.figure == name)
            .unwrap_or_else(|| panic!("no {scenario} {name}"))
    };
    // No friction: slides much farther than rapier. No collision: no momentum exchanged.
    let slide = figure("slide", "stopping distance");
    assert!(slide.predictors[0].mean > 1.5 * slide.rapier.as_ref().unwrap().mean);
    assert_eq!(slide.predictors[0].met, Some(0));
    let collide = figure("collide", "momentum exchanged");
    assert!(collide.predictors[0].max < 1e-3);
    assert!(collide.rapier.as_ref().unwrap().mean > 0.5);
    // Its floor lifts objects out: never below it.
    assert!(figure("drop", "deepest penetration").predictors[0].max < 1e-6);
    // Stacked boxes fall through each other (the floor is its only support).
    assert!(figure("rest", "max displacement").predictors[0].max > 0.5);
}

#[test]
fn shipped_model_runs_through_the_suite_next_to_ballistic() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rigidformer-small");
    let model =
        dynaserve_model::load_rigidformer(&dir, &dynaserve_model::Device::Cpu, false).unwrap();
    let model = ModelPredictor::from_rigidformer(Arc::new(model));
    let b = ballistic();
    let report = run_suite(
        &[("model", &model), ("ballistic", &b)],
        suite(),
        &SuiteOptions {
            step_sizes: vec![1],
            ..options(8)
        },
        "test",
        &|_, _| {},
    )
    .unwrap();
    for f in &report.figures {
        assert_eq!(f.predictors.len(), 2);
        assert!(
            f.predictors
                .iter()
                .all(|s| s.mean.is_finite() && s.max.is_finite())
        );
    }
    for row in &report.regimes {
        if row.count > 0 {
            let [t, _] = row.ballistic_over_model.expect("both predictors ran");
            assert!(t.is_some_and(f64::is_finite), "{row:?}");
        }
    }
}

#[test]
fn labelled_directories_are_read_and_reports_render() {
    let root = std::env::temp_dir().join(format!("dynaserve-physics-suite-{}", std::process::id()));
    let mix = root.join("mix");
    let movi = root.join("movi");
    let mut opts = GenerateOptions::new(Generator::physics_mix(), 3, "test", 3);
    opts.points = 128;
    generate_dataset(&opts, &mix, true, &|| {}).unwrap();
    let mut opts = GenerateOptions::new(Generator::movi_b(), 3, "test", 1);
    opts.points = 128;
    generate_dataset(&opts, &movi, true, &|| {}).unwrap();
    let (scenes, gravity) = load_suite(&[mix.clone(), movi], None).unwrap();
    assert_eq!(gravity, GRAVITY);
    assert_eq!(scenes.len(), 4);
    assert!(scenes[..3].iter().all(|s| s.label.is_some()));
    assert!(scenes[3].label.is_none(), "MOVi-B scenes carry no label");
    let (capped, _) = load_suite(std::slice::from_ref(&mix), Some(2)).unwrap();
    assert_eq!(capped.len(), 2);
    assert!(load_suite(&[root.join("missing")], None).is_err());

    let b = ballistic();
    let report = run_suite(
        &[("ballistic", &b)],
        &scenes,
        &options(4),
        "dirs",
        &|_, _| {},
    )
    .unwrap();
    assert!(report.scenes.iter().any(|c| c.scenario == "unlabelled"));
    let text = format_physics_text(&report);
    let md = format_physics_markdown(&report);
    for regime in Regime::ALL {
        assert!(text.contains(regime.name()) && md.contains(regime.name()));
    }
    for f in &report.figures {
        assert!(text.contains(&f.figure) && md.contains(&f.figure));
    }
    assert!(md.contains("| regime | k | count |"));
    let json = serde_json::to_string(&report).unwrap();
    let back: PhysicsSuiteReport = serde_json::from_str(&json).unwrap();
    assert_eq!(back.scenes, report.scenes);
    assert_eq!(back.predictors, report.predictors);
    assert_eq!(back.figures.len(), report.figures.len());
    for (a, b) in back.regimes.iter().zip(&report.regimes) {
        assert_eq!((a.regime, a.k, a.count), (b.regime, b.k, b.count));
        let (x, y) = (
            a.predictors[0].translation_rmse_m,
            b.predictors[0].translation_rmse_m,
        );
        assert!(
            x.zip(y)
                .is_none_or(|(x, y)| (x - y).abs() <= 1e-12 * y.abs())
        );
    }
    // Bad options are errors.
    let bad = SuiteOptions {
        start_frame: 0,
        ..options(1)
    };
    assert!(run_suite(&[("ballistic", &b)], &scenes, &bad, "dirs", &|_, _| {}).is_err());
    assert!(run_suite(&[], &scenes, &options(1), "dirs", &|_, _| {}).is_err());
    let _ = std::fs::remove_dir_all(&root);
}
