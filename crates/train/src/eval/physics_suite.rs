//! The physics scenario suite: scenes that isolate one behaviour each (rest, drop, slide,
//! collide, stack-hit, roll; see `dynaserve_sim::scenarios`), generated deterministically in
//! memory or read from labelled dataset directories (also `push` data), and scored for any set of
//! predictors. Scenes with kinematic objects (a pusher) are rolled out with those objects
//! driven along their recorded poses ([`super::driven`]), and kinematic objects enter no
//! error:
//! - each scenario's own figures on a `k = 1` rollout from the start frame to the last frame,
//!   next to rapier's ([`super::scenario_figures`]);
//! - the one-step error of every window `t - k, t -> t + k` split by the ground truth's contact
//!   regime ([`super::regimes`]).

use std::path::PathBuf;

use dynaserve_geometry::geodesic_angle;
use dynaserve_sim::generators::{GenerateOptions, generate_scene};
use dynaserve_sim::scenarios::{Materials, RestVariant, Scenario, ScenarioParameters};
use dynaserve_sim::{DatasetReader, Generator, SceneLabel, SceneRecord};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::driven::{driven_rollout_batch, has_kinematic};
use super::regimes::{
    CONTACT_DISTANCE_M, ContactFlags, RESTING_ANGULAR_DEG_S, RESTING_SPEED_M_S, Regime,
    RegimeErrors, contact_flags, impact_subset, regime, windows,
};
use super::scenario_figures::{Sample, scene_samples};
use super::{DEFAULT_START_FRAME, EvalError, Predictor, RolloutRequest, observed_frames};

/// Seed of the generated suite (the training splits use seeds 0 to 2).
pub const DEFAULT_SUITE_SEED: u64 = 7;
/// Scenes per group of the generated suite.
pub const DEFAULT_SCENES_PER_GROUP: usize = 6;
/// Boxes of the suite's rest towers.
pub const SUITE_TOWER_BOXES: usize = 4;
/// One-step requests handed to a predictor at once.
const WINDOW_BATCH: usize = 256;
/// Scenes rolled out together.
const ROLLOUT_BATCH: usize = 16;

/// A suite scene: the recorded scene and, when known, what it isolates.
#[derive(Clone, Debug)]
pub struct SuiteScene {
    /// The scene.
    pub scene: SceneRecord,
    /// Scenario and variant (`None` for unlabelled data: it then only enters the regime
    /// table).
    pub label: Option<SceneLabel>,
}

/// The groups of the generated suite: (name, generator). `rest-tower` holds towers of
/// [`SUITE_TOWER_BOXES`] cubes, `rest-single` single objects, `collide-air` and
/// `collide-floor` one variant each; the others use the scenario generators' defaults. Every
/// object's material is drawn as `materials` says.
pub fn suite_groups(materials: Materials) -> Vec<(&'static str, Generator)> {
    let params = |s: Scenario| ScenarioParameters::new(vec![s]).with_materials(materials);
    let rest = |variant: RestVariant| {
        let mut p = params(Scenario::Rest);
        p.rest_variants = vec![variant];
        p.tower_boxes = [SUITE_TOWER_BOXES, SUITE_TOWER_BOXES];
        Generator::scenarios(p)
    };
    let collide = |air: f32| {
        let mut p = params(Scenario::Collide);
        p.collide_air_fraction = air;
        Generator::scenarios(p)
    };
    let plain = |s: Scenario| Generator::scenarios(params(s));
    vec![
        ("rest-tower", rest(RestVariant::Tower)),
        ("rest-single", rest(RestVariant::Single)),
        ("drop", plain(Scenario::Drop)),
        ("slide", plain(Scenario::Slide)),
        ("collide-air", collide(1.0)),
        ("collide-floor", collide(0.0)),
        ("stack-hit", plain(Scenario::StackHit)),
        ("roll", plain(Scenario::Roll)),
    ]
}

/// Generates the suite: `per_group` scenes of every group of [`suite_groups`] with objects of
/// `materials`, from `seed` and `split` (group `g` uses scene indices `g * 1_000_000 + i`, so
/// groups sharing a generator never share a scene), `points` reference points per object.
/// Deterministic and independent of the thread count.
pub fn generate_suite(
    seed: u64,
    split: &str,
    per_group: usize,
    points: usize,
    materials: Materials,
) -> Result<Vec<SuiteScene>, EvalError> {
    if per_group == 0 {
        return Err(EvalError::Invalid(
            "the suite needs at least one scene per group".into(),
        ));
    }
    let jobs: Vec<(GenerateOptions, u64)> = suite_groups(materials)
        .into_iter()
        .enumerate()
        .flat_map(|(g, (_, generator))| {
            let mut opts = GenerateOptions::new(generator, seed, split, per_group);
            opts.points = points;
            (0..per_group as u64).map(move |i| (opts.clone(), g as u64 * 1_000_000 + i))
        })
        .collect();
    jobs.par_iter()
        .map(|(opts, index)| {
            let g = generate_scene(opts, *index)?;
            Ok(SuiteScene {
                scene: g.record,
                label: g.label,
            })
        })
        .collect()
}

/// Reads the scenes of dataset directories (each scene labelled from its manifest's
/// `scenarios`, unlabelled if it has none), at most `max_scenes` per directory. Returns the
/// scenes and the gravity shared by all directories.
pub fn load_suite(
    dirs: &[PathBuf],
    max_scenes: Option<usize>,
) -> Result<(Vec<SuiteScene>, [f32; 3]), EvalError> {
    let mut scenes = Vec::new();
    let mut gravity = None;
    for dir in dirs {
        let reader = DatasetReader::open(dir)?;
        let m = reader.manifest();
        if let Some(g) = gravity
            && g != m.gravity
        {
            return Err(EvalError::Invalid(format!(
                "{} has gravity {:?}, the other directories {g:?}",
                dir.display(),
                m.gravity
            )));
        }
        gravity = Some(m.gravity);
        let labels = m.scenarios.clone();
        let limit = max_scenes.unwrap_or(usize::MAX);
        for (i, scene) in reader.iter().take(limit).enumerate() {
            scenes.push(SuiteScene {
                scene: scene?,
                label: labels.as_ref().and_then(|l| l.get(i).cloned()),
            });
        }
    }
    let gravity = gravity.ok_or_else(|| EvalError::Invalid("no dataset directory".into()))?;
    if scenes.is_empty() {
        return Err(EvalError::Invalid(
            "the dataset directories hold no scenes".into(),
        ));
    }
    Ok((scenes, gravity))
}

/// How the suite is scored.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SuiteOptions {
    /// Start frame `s` of the scenario rollouts (observed frames `s - 1` and `s`).
    pub start_frame: usize,
    /// Step sizes `k` of the regime table, frames.
    pub step_sizes: Vec<u32>,
    /// Every `n`-th window of a scene enters the regime table (1: all).
    pub window_stride: usize,
    /// Gravity of the data, m/s^2.
    pub gravity: [f32; 3],
    /// Observe only two frames per window, not the one before them (see
    /// [`super::EvalOptions::two_frames`]).
    #[serde(default)]
    pub two_frames: bool,
}

impl Default for SuiteOptions {
    fn default() -> Self {
        SuiteOptions {
            start_frame: DEFAULT_START_FRAME,
            step_sizes: vec![1, 2, 4],
            window_stride: 1,
            gravity: [0.0, 0.0, -10.0],
            two_frames: false,
        }
    }
}

/// Mean and maximum of a figure over its samples, and how many met the target.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FigureStat {
    /// Mean over the samples.
    pub mean: f64,
    /// Maximum over the samples.
    pub max: f64,
    /// Samples meeting the figure's target (`None` when it has none or for rapier).
    pub met: Option<u64>,
}

/// One figure of one scenario group: rapier's value and every predictor's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FigureRow {
    /// Scenario name.
    pub scenario: String,
    /// Variant.
    pub group: String,
    /// Figure name (definitions in `docs/evaluation.md`).
    pub figure: String,
    /// Unit.
    pub unit: String,
    /// The target each sample is judged by, if any.
    pub target: Option<String>,
    /// Samples (scenes, or objects for `slide` and `roll`).
    pub samples: u64,
    /// Rapier's figure on the same scenes, for figures that have one.
    pub rapier: Option<FigureStat>,
    /// One entry per predictor, in the report's predictor order.
    pub predictors: Vec<FigureStat>,
}

/// Pooled one-step errors of one predictor in one (regime, step size).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RegimeCell {
    /// Translation RMSE, m.
    pub translation_rmse_m: Option<f64>,
    /// Orientation RMSE, deg.
    pub orientation_rmse_deg: Option<f64>,
}

/// One row of the regime table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegimeRow {
    /// Regime.
    pub regime: Regime,
    /// Step size, frames.
    pub k: u32,
    /// Object-windows pooled.
    pub count: u64,
    /// One entry per predictor, in the report's predictor order.
    pub predictors: Vec<RegimeCell>,
    /// Ballistic RMSE over model RMSE (translation, orientation), when both ran.
    pub ballistic_over_model: Option<[Option<f64>; 2]>,
}

/// A predictor of the report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SuitePredictor {
    /// Column label (`model`, `ballistic`, ...).
    pub label: String,
    /// The predictor's own name.
    pub name: String,
}

/// Scenes of one scenario variant.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScenarioCount {
    /// Scenario (`unlabelled` for scenes without a label).
    pub scenario: String,
    /// Variant.
    pub variant: String,
    /// Scenes.
    pub scenes: u64,
}

/// The whole suite report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PhysicsSuiteReport {
    /// Where the scenes came from (generated seed and split, or directories).
    pub source: String,
    /// Scenes per scenario variant.
    pub scenes: Vec<ScenarioCount>,
    /// Scoring options.
    pub options: SuiteOptions,
    /// Base contact distance of the regimes, m.
    pub contact_distance_m: f64,
    /// Resting thresholds: centre speed (m/s) and angular speed (deg/s).
    pub resting_thresholds: [f64; 2],
    /// The predictors, in column order.
    pub predictors: Vec<SuitePredictor>,
    /// Scenario figures.
    pub figures: Vec<FigureRow>,
    /// One-step errors by regime and step size.
    pub regimes: Vec<RegimeRow>,
    /// Wall time, seconds.
    pub elapsed_s: f64,
    /// Every scored one-step window of every predictor (not in the JSON: written by
    /// [`window_csv`] when asked for).
    #[serde(skip)]
    pub windows: Vec<WindowRecord>,
}

/// One object-window of the regime table, for looking at individual errors.
#[derive(Clone, Debug, PartialEq)]
pub struct WindowRecord {
    /// Predictor label.
    pub predictor: String,
    /// Scene index in the suite.
    pub scene: usize,
    /// Object index in the scene.
    pub object: usize,
    /// Observed frame `t` (the window is `t - k, t -> t + k`).
    pub t: usize,
    /// Step size, frames.
    pub k: u32,
    /// Ground-truth regime.
    pub regime: Regime,
    /// A floor-contact window with a landing, bounce or lift-off ([`Regime::FloorImpact`]).
    pub impact: bool,
    /// An object-contact window in which a contact begins or ends ([`Regime::ObjectImpact`]).
    pub object_impact: bool,
    /// Floor-contact flags of frames `t - k ..= t + k`, `1` or `0` each.
    pub floor: String,
    /// Object-contact flags (distance test) of the same frames.
    pub object_contact: String,
    /// Impulse flags (acceleration off gravity) of the same frames.
    pub impulse: String,
    /// Translation error, m.
    pub translation_m: f64,
    /// Orientation error, degrees.
    pub orientation_deg: f64,
}

/// The windows of a report as CSV (header and one line per record).
pub fn window_csv(report: &PhysicsSuiteReport) -> String {
    let mut out = String::from(
        "predictor,scene,object,t,k,regime,impact,object_impact,floor,object_contact,impulse,\
         translation_m,orientation_deg\n",
    );
    for w in &report.windows {
        out.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{:.6},{:.4}\n",
            w.predictor,
            w.scene,
            w.object,
            w.t,
            w.k,
            w.regime.name(),
            w.impact,
            w.object_impact,
            w.floor,
            w.object_contact,
            w.impulse,
            w.translation_m,
            w.orientation_deg
        ));
    }
    out
}

/// What one predictor produced.
struct PredictorResult {
    samples: Vec<Sample>,
    errors: RegimeErrors,
    windows: Vec<WindowRecord>,
}

fn check_scenes(scenes: &[SuiteScene], opts: &SuiteOptions) -> Result<usize, EvalError> {
    let first = scenes
        .first()
        .ok_or_else(|| EvalError::Invalid("no scenes in the suite".into()))?;
    let frames = first
        .scene
        .objects
        .first()
        .map(|o| o.positions.len())
        .ok_or_else(|| EvalError::Invalid("suite scene 0 has no objects".into()))?;
    for (i, s) in scenes.iter().enumerate() {
        if s.scene.objects.is_empty() || s.scene.objects.iter().any(|o| o.positions.len() != frames)
        {
            return Err(EvalError::Invalid(format!(
                "suite scene {i} has no objects or not {frames} frames"
            )));
        }
    }
    if opts.start_frame == 0 || opts.start_frame + 1 >= frames {
        return Err(EvalError::Invalid(format!(
            "start frame {} needs frames {} to {}, the scenes have {frames}",
            opts.start_frame,
            opts.start_frame.saturating_sub(1),
            opts.start_frame + 1
        )));
    }
    if opts.step_sizes.is_empty() || opts.step_sizes.contains(&0) {
        return Err(EvalError::Invalid("step sizes must be at least 1".into()));
    }
    Ok(frames)
}

fn run_predictor(
    label: &str,
    predictor: &dyn Predictor,
    scenes: &[SuiteScene],
    flags: &[ContactFlags],
    frames: usize,
    opts: &SuiteOptions,
    progress: &dyn Fn(usize),
) -> Result<PredictorResult, EvalError> {
    let s = opts.start_frame;
    let steps = frames - 1 - s;
    let mut samples = Vec::new();
    let labelled: Vec<usize> = (0..scenes.len())
        .filter(|&i| scenes[i].label.is_some())
        .collect();
    for chunk in labelled.chunks(ROLLOUT_BATCH) {
        let requests = chunk
            .iter()
            .map(|&i| {
                Ok(RolloutRequest {
                    scene: &scenes[i].scene,
                    observed: observed_frames(&scenes[i].scene, s, 1, opts.two_frames)?,
                    dt_steps: 1,
                    steps,
                })
            })
            .collect::<Result<Vec<_>, EvalError>>()?;
        let rollouts = if chunk.iter().any(|&i| has_kinematic(&scenes[i].scene)) {
            driven_rollout_batch(predictor, &requests, &vec![s; requests.len()])?
        } else {
            predictor.rollout_batch(&requests)?
        };
        for (&i, rollout) in chunk.iter().zip(&rollouts) {
            let sc = &scenes[i];
            if let Some(label) = &sc.label {
                samples.extend(scene_samples(
                    &sc.scene,
                    label,
                    &flags[i],
                    s,
                    rollout,
                    opts.gravity,
                )?);
            }
        }
    }
    let mut errors = RegimeErrors::new(&opts.step_sizes);
    let mut records = Vec::new();
    for (i, sc) in scenes.iter().enumerate() {
        let mut jobs = Vec::new();
        for (ki, &k) in opts.step_sizes.iter().enumerate() {
            for t in windows(frames, k as usize, opts.window_stride) {
                jobs.push((ki, k, t));
            }
        }
        for chunk in jobs.chunks(WINDOW_BATCH) {
            let requests = chunk
                .iter()
                .map(|&(_, k, t)| {
                    Ok(RolloutRequest {
                        scene: &sc.scene,
                        observed: observed_frames(&sc.scene, t, k, opts.two_frames)?,
                        dt_steps: k,
                        steps: 1,
                    })
                })
                .collect::<Result<Vec<_>, EvalError>>()?;
            let out = predictor.rollout_batch(&requests)?;
            for (&(ki, k, t), rollout) in chunk.iter().zip(&out) {
                let poses = rollout.first().ok_or_else(|| EvalError::Predictor {
                    predictor: predictor.name(),
                    scene: i,
                    message: "returned no step".into(),
                })?;
                let target = t + k as usize;
                for (j, (pose, o)) in poses.iter().zip(&sc.scene.objects).enumerate() {
                    if o.kinematic {
                        continue;
                    }
                    let p = o.positions[target];
                    let dt = (0..3)
                        .map(|c| (f64::from(pose.translation[c]) - f64::from(p[c])).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    let da = geodesic_angle(pose.rotation, o.rotations[target]).to_degrees();
                    if !(dt.is_finite() && da.is_finite()) {
                        return Err(EvalError::Predictor {
                            predictor: predictor.name(),
                            scene: i,
                            message: format!("non-finite pose of object {j} at frame {target}"),
                        });
                    }
                    let r = regime(&sc.scene, &flags[i], j, t, k as usize);
                    errors.add(ki, r, dt, da);
                    let subset = impact_subset(&flags[i], r, j, t, k as usize);
                    if let Some(subset) = subset {
                        errors.add(ki, subset, dt, da);
                    }
                    let f = &flags[i];
                    let bits = |v: &Vec<Vec<bool>>| -> String {
                        (t - k as usize..=target)
                            .map(|x| if v[x][j] { '1' } else { '0' })
                            .collect()
                    };
                    records.push(WindowRecord {
                        predictor: label.to_string(),
                        scene: i,
                        object: j,
                        t,
                        k,
                        regime: r,
                        impact: subset == Some(Regime::FloorImpact),
                        object_impact: subset == Some(Regime::ObjectImpact),
                        floor: bits(&f.floor),
                        object_contact: bits(&f.object),
                        impulse: bits(&f.impulse),
                        translation_m: dt,
                        orientation_deg: da,
                    });
                }
            }
        }
        progress(i + 1);
    }
    Ok(PredictorResult {
        samples,
        errors,
        windows: records,
    })
}

fn stat(values: impl Iterator<Item = f64>, met: Option<u64>) -> FigureStat {
    let (mut sum, mut max, mut n) = (0.0, f64::NEG_INFINITY, 0u64);
    for v in values {
        sum += v;
        max = max.max(v);
        n += 1;
    }
    FigureStat {
        mean: if n > 0 { sum / n as f64 } else { 0.0 },
        max: if n > 0 { max } else { 0.0 },
        met,
    }
}

fn figure_rows(results: &[PredictorResult]) -> Vec<FigureRow> {
    let Some(first) = results.first() else {
        return Vec::new();
    };
    let mut keys: Vec<(String, String, &'static str)> = Vec::new();
    for s in &first.samples {
        let key = (s.scenario.clone(), s.group.clone(), s.figure);
        if !keys.contains(&key) {
            keys.push(key);
        }
    }
    keys.into_iter()
        .map(|(scenario, group, figure)| {
            let pick = |r: &PredictorResult| -> Vec<Sample> {
                r.samples
                    .iter()
                    .filter(|s| s.scenario == scenario && s.group == group && s.figure == figure)
                    .cloned()
                    .collect()
            };
            let base = pick(first);
            let head = &base[0];
            let rapier = head
                .rapier
                .is_some()
                .then(|| stat(base.iter().filter_map(|s| s.rapier), None));
            let predictors = results
                .iter()
                .map(|r| {
                    let own = pick(r);
                    let met = head.target.map(|t| {
                        own.iter()
                            .filter(|s| t.met(s.value, s.rapier.unwrap_or(0.0)))
                            .count() as u64
                    });
                    stat(own.iter().map(|s| s.value), met)
                })
                .collect();
            FigureRow {
                target: head.target.map(|t| t.describe(head.unit)),
                unit: head.unit.to_string(),
                samples: base.len() as u64,
                scenario,
                group,
                figure: figure.to_string(),
                rapier,
                predictors,
            }
        })
        .collect()
}

fn regime_rows(
    results: &[PredictorResult],
    labels: &[String],
    step_sizes: &[u32],
) -> Vec<RegimeRow> {
    let model = labels.iter().position(|l| l == "model");
    let ballistic = labels.iter().position(|l| l == "ballistic");
    let mut rows = Vec::new();
    for regime in Regime::REPORTED {
        for (ki, &k) in step_sizes.iter().enumerate() {
            let cells: Vec<RegimeCell> = results
                .iter()
                .map(|r| {
                    let e = r.errors.get(ki, regime);
                    RegimeCell {
                        translation_rmse_m: e.translation_rmse_m(),
                        orientation_rmse_deg: e.orientation_rmse_deg(),
                    }
                })
                .collect();
            let ratio = |b: Option<f64>, m: Option<f64>| match (b, m) {
                (Some(b), Some(m)) if m > 0.0 => Some(b / m),
                _ => None,
            };
            let ballistic_over_model = match (ballistic, model) {
                (Some(b), Some(m)) => Some([
                    ratio(cells[b].translation_rmse_m, cells[m].translation_rmse_m),
                    ratio(cells[b].orientation_rmse_deg, cells[m].orientation_rmse_deg),
                ]),
                _ => None,
            };
            rows.push(RegimeRow {
                regime,
                k,
                count: results
                    .first()
                    .map(|r| r.errors.get(ki, regime).count)
                    .unwrap_or(0),
                predictors: cells,
                ballistic_over_model,
            });
        }
    }
    rows
}

fn scene_counts(scenes: &[SuiteScene]) -> Vec<ScenarioCount> {
    let mut counts: Vec<ScenarioCount> = Vec::new();
    for s in scenes {
        let (scenario, variant) = match &s.label {
            Some(l) => (l.scenario.clone(), l.variant.clone()),
            None => ("unlabelled".to_string(), String::new()),
        };
        match counts
            .iter_mut()
            .find(|c| c.scenario == scenario && c.variant == variant)
        {
            Some(c) => c.scenes += 1,
            None => counts.push(ScenarioCount {
                scenario,
                variant,
                scenes: 1,
            }),
        }
    }
    counts
}

/// Scores `predictors` (column label, predictor) on the suite's scenes. `progress(predictor
/// index, scenes done)` is called as each predictor advances. `source` describes where the
/// scenes came from.
pub fn run_suite(
    predictors: &[(&str, &dyn Predictor)],
    scenes: &[SuiteScene],
    opts: &SuiteOptions,
    source: &str,
    progress: &dyn Fn(usize, usize),
) -> Result<PhysicsSuiteReport, EvalError> {
    let started = std::time::Instant::now();
    if predictors.is_empty() {
        return Err(EvalError::Invalid("no predictor to score".into()));
    }
    let frames = check_scenes(scenes, opts)?;
    let flags = scenes
        .par_iter()
        .map(|s| contact_flags(&s.scene, opts.gravity))
        .collect::<Result<Vec<_>, _>>()?;
    let results = predictors
        .iter()
        .enumerate()
        .map(|(pi, (l, p))| {
            run_predictor(l, *p, scenes, &flags, frames, opts, &|n| progress(pi, n))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let labels: Vec<String> = predictors.iter().map(|(l, _)| l.to_string()).collect();
    Ok(PhysicsSuiteReport {
        source: source.to_string(),
        scenes: scene_counts(scenes),
        options: opts.clone(),
        contact_distance_m: f64::from(CONTACT_DISTANCE_M),
        resting_thresholds: [RESTING_SPEED_M_S, RESTING_ANGULAR_DEG_S],
        predictors: predictors
            .iter()
            .map(|(l, p)| SuitePredictor {
                label: l.to_string(),
                name: p.name(),
            })
            .collect(),
        figures: figure_rows(&results),
        regimes: regime_rows(&results, &labels, &opts.step_sizes),
        elapsed_s: started.elapsed().as_secs_f64(),
        windows: results.into_iter().flat_map(|r| r.windows).collect(),
    })
}
