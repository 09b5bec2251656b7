//! Spread calibration (`dynaserve eval --suite calibration`): how well a model's own per-object
//! spread ([`dynaserve_model::WorldModel::step_with_spread`], an ensemble's members'
//! disagreement) predicts its actual error against the recorded simulation.
//!
//! For each scene the model rolls out from the recorded start frame `s` in steps of one frame
//! (the kinematic objects driven along their recorded poses, as in [`super::driven`]). At each
//! reported horizon of `h` steps and for each dynamic object (kinematic pushers are excluded):
//! - the error: the distance of the predicted centre from the recorded one at frame `s + h`, m
//!   (and the geodesic orientation error, degrees);
//! - the spread: the model's position spread of that step's prediction, m (and its orientation
//!   spread, degrees);
//! - the baseline: the path length the object travelled in the model's own rollout from `s` to
//!   step `h`, m (the sum of its per-step displacements), available to a planner without the
//!   truth, like the spread.
//!
//! Per horizon, over all objects of all scenes: the Spearman rank correlation of the spread
//! with the error and of the baseline with the error (ties get average ranks), and the mean
//! error in each decile of the spread and of the baseline. A decile is chosen by average rank:
//! the item of 0-based average rank `r` among `n` goes to bin `floor(10 r / n)`, so tied values
//! share a bin (and a bin may be empty).

use std::path::Path;

use dynaserve_geometry::geodesic_angle;
use dynaserve_geometry::metrics::squared_distance;
use dynaserve_model::{Drive, PoseSpread, SceneState, StepItem};
use dynaserve_sim::{DatasetReader, SceneRecord};
use plotters::prelude::*;
use serde::{Deserialize, Serialize};

use super::driven::recorded_targets;
use super::{EvalError, ModelPredictor, observed_frames, poses_at};

/// Default horizons, steps of one frame (0.25, 0.5, 1 and 2 s at 24 fps).
pub const DEFAULT_CALIBRATION_STEPS: [usize; 4] = [6, 12, 24, 48];
/// Bins of the decile tables.
pub const BINS: usize = 10;

/// What the calibration suite scores.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationOptions {
    /// Start frame `s`: the model observes frames `s - 1` and `s` (and `s - 2` with history).
    pub start_frame: usize,
    /// Horizons in steps of one frame, each `>= 1`.
    pub horizons_steps: Vec<usize>,
    /// Observe only frames `s - 1` and `s`.
    pub two_frames: bool,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        CalibrationOptions {
            start_frame: super::DEFAULT_START_FRAME,
            horizons_steps: DEFAULT_CALIBRATION_STEPS.to_vec(),
            two_frames: false,
        }
    }
}

/// One bin of a decile table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DecileBin {
    /// Items in the bin.
    pub count: usize,
    /// Mean of the ranking value (spread or baseline) over the bin; `None` when empty.
    pub mean_key: Option<f64>,
    /// Mean error over the bin; `None` when empty.
    pub mean_error: Option<f64>,
}

/// One horizon of the report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationHorizon {
    /// Steps of one frame after the start frame.
    pub steps: usize,
    /// The same in seconds.
    pub time_s: f64,
    /// Scored (object, scene) pairs.
    pub objects: usize,
    /// Mean translation error, m.
    pub mean_error_m: f64,
    /// Mean position spread, m.
    pub mean_spread_m: f64,
    /// Mean baseline (path length in the rollout), m.
    pub mean_baseline_m: f64,
    /// Spearman correlation of the position spread with the translation error.
    pub spearman_spread: Option<f64>,
    /// Spearman correlation of the baseline with the translation error.
    pub spearman_baseline: Option<f64>,
    /// Spearman correlation of the accumulated spread (the per-step position spreads up to
    /// the horizon summed in quadrature) with the translation error.
    #[serde(default)]
    pub spearman_accumulated: Option<f64>,
    /// Spearman correlation of the orientation spread with the orientation error.
    pub spearman_orientation: Option<f64>,
    /// Mean translation error per decile of the position spread (lowest first).
    pub spread_deciles: Vec<DecileBin>,
    /// Mean translation error per decile of the baseline (lowest first).
    pub baseline_deciles: Vec<DecileBin>,
}

/// One scored (scene, object, horizon).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationSample {
    /// Scene index in the split.
    pub scene: usize,
    /// Object index in the scene.
    pub object: usize,
    /// Horizon, steps.
    pub steps: usize,
    /// Translation error, m.
    pub error_m: f64,
    /// Orientation error, degrees.
    pub error_deg: f64,
    /// The model's spread at that step.
    pub spread: PoseSpread,
    /// Path length in the model's rollout from the start, m.
    pub baseline_m: f64,
    /// The position spreads of every step up to this one summed in quadrature, m: the error
    /// independent per-step errors of that size would add up to.
    #[serde(default)]
    pub accumulated_m: f64,
}

/// The calibration report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationReport {
    /// The model (name and input).
    pub model: String,
    /// The networks the model averages (an ensemble's members).
    pub members: Vec<String>,
    /// Where the scenes came from.
    pub source: String,
    /// Scenes scored.
    pub scenes: usize,
    /// Kinematic objects excluded (over all scenes).
    pub kinematic_excluded: usize,
    /// The options.
    pub options: CalibrationOptions,
    /// Horizons that could not be scored, with the reason.
    pub missing: Vec<String>,
    /// Per horizon.
    pub horizons: Vec<CalibrationHorizon>,
    /// Every scored item (not written to the JSON, which keeps the summaries only).
    #[serde(skip)]
    pub samples: Vec<CalibrationSample>,
    /// Wall time, seconds.
    pub elapsed_s: f64,
}

/// Average ranks (0-based) of `values`: tied values share the mean of their positions.
pub fn average_ranks(values: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let mut ranks = vec![0.0; values.len()];
    let mut i = 0;
    while i < order.len() {
        let mut j = i + 1;
        while j < order.len() && values[order[j]] == values[order[i]] {
            j += 1;
        }
        let mean = (i + j - 1) as f64 / 2.0;
        for &k in &order[i..j] {
            ranks[k] = mean;
        }
        i = j;
    }
    ranks
}

fn pearson(x: &[f64], y: &[f64]) -> Option<f64> {
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx) * (a - mx);
        syy += (b - my) * (b - my);
    }
    (sxx > 0.0 && syy > 0.0).then(|| sxy / (sxx * syy).sqrt())
}

/// Spearman rank correlation of `x` and `y` (the Pearson correlation of their average ranks);
/// `None` for fewer than two pairs, unequal lengths or a constant side.
pub fn spearman(x: &[f64], y: &[f64]) -> Option<f64> {
    if x.len() != y.len() || x.len() < 2 {
        return None;
    }
    pearson(&average_ranks(x), &average_ranks(y))
}

/// Mean `error` per decile of `key` (module docs: by average rank, ties in one bin).
pub fn deciles(key: &[f64], error: &[f64]) -> Vec<DecileBin> {
    let n = key.len().min(error.len());
    let ranks = average_ranks(&key[..n]);
    let mut sums = vec![(0usize, 0.0f64, 0.0f64); BINS];
    for i in 0..n {
        let bin = ((ranks[i] * BINS as f64 / n as f64).floor() as usize).min(BINS - 1);
        let s = &mut sums[bin];
        s.0 += 1;
        s.1 += key[i];
        s.2 += error[i];
    }
    sums.into_iter()
        .map(|(count, k, e)| DecileBin {
            count,
            mean_key: (count > 0).then(|| k / count as f64),
            mean_error: (count > 0).then(|| e / count as f64),
        })
        .collect()
}

/// The first `max` scenes of a dataset split (all without `max`).
pub fn load_scenes(dir: &Path, max: Option<usize>) -> Result<Vec<SceneRecord>, EvalError> {
    let reader = DatasetReader::open(dir)?;
    let n = max.unwrap_or(usize::MAX).min(reader.len());
    (0..n).map(|i| Ok(reader.get(i)?)).collect()
}

/// Per scene: the poses and spreads of every step, `[steps][objects]`.
type Rollout = (
    Vec<Vec<dynaserve_model::Pose>>,
    Vec<Vec<dynaserve_model::PoseSpread>>,
);

/// Rolls every scene `steps` steps of one frame from `start` with spreads, all scenes in one
/// batched model step per step, kinematic objects driven along their recorded poses.
fn rollouts(
    predictor: &ModelPredictor,
    scenes: &[SceneRecord],
    opts: &CalibrationOptions,
    steps: usize,
) -> Result<Vec<Rollout>, EvalError> {
    let model = predictor.model();
    for scene in scenes {
        let (m, d) = (model.config().dt_frame, scene.dt_frame);
        if (m - d).abs() > 1e-6 * d {
            return Err(EvalError::Invalid(format!(
                "model {} steps in frames of {m} s but the data has frames of {d} s",
                model.name()
            )));
        }
    }
    let lead = model.config().dynamics.kinematic_lead;
    let prepared = scenes
        .iter()
        .map(|s| model.prepare(predictor.inputs(s)))
        .collect::<Result<Vec<_>, _>>()?;
    let mut states: Vec<SceneState> = scenes
        .iter()
        .map(|s| observed_frames(s, opts.start_frame, 1, opts.two_frames))
        .collect::<Result<_, _>>()?;
    let kinematic: Vec<Vec<bool>> = scenes
        .iter()
        .map(|s| s.objects.iter().map(|o| o.kinematic).collect())
        .collect();
    let mut out: Vec<Rollout> = scenes.iter().map(|_| (Vec::new(), Vec::new())).collect();
    for step in 0..steps {
        let frame = opts.start_frame + step + 1;
        let targets: Vec<_> = scenes
            .iter()
            .zip(&kinematic)
            .map(|(s, k)| recorded_targets(s, k, frame))
            .collect::<Result<_, EvalError>>()?;
        let drives: Vec<Drive<'_>> = kinematic
            .iter()
            .zip(&targets)
            .map(|(k, t)| Drive::new(k, t))
            .collect();
        let inputs: Vec<SceneState> = drives
            .iter()
            .zip(&states)
            .map(|(d, s)| d.input(s, lead))
            .collect();
        let items: Vec<StepItem<'_>> = prepared
            .iter()
            .zip(&inputs)
            .map(|(scene, state)| StepItem {
                scene,
                state,
                dt_steps: 1,
            })
            .collect();
        let next = model.step_with_spread(&items)?;
        if next.len() != scenes.len() {
            return Err(EvalError::Invalid(format!(
                "model {} answered {} of {} scenes in a step",
                model.name(),
                next.len(),
                scenes.len()
            )));
        }
        for (i, answer) in next.into_iter().enumerate() {
            let spread = answer.spread.ok_or_else(|| {
                EvalError::Invalid(format!(
                    "model {} estimates no spread (an ensemble does)",
                    model.name()
                ))
            })?;
            let poses = drives[i].finish(&mut states[i], answer.poses).to_vec();
            out[i].0.push(poses);
            out[i].1.push(spread);
        }
    }
    Ok(out)
}

/// Scores the spread calibration of `predictor` (a model with a spread) on `scenes`.
pub fn run_calibration(
    predictor: &ModelPredictor,
    scenes: &[SceneRecord],
    opts: &CalibrationOptions,
    source: &str,
) -> Result<CalibrationReport, EvalError> {
    let started = std::time::Instant::now();
    if opts.start_frame < 1 {
        return Err(EvalError::Invalid(
            "the start frame must be at least 1".into(),
        ));
    }
    let frames = scenes
        .iter()
        .map(|s| {
            s.objects
                .iter()
                .map(|o| o.positions.len().min(o.rotations.len()))
                .min()
                .unwrap_or(0)
        })
        .min()
        .unwrap_or(0);
    let mut missing = Vec::new();
    let mut horizons: Vec<usize> = Vec::new();
    for &h in &opts.horizons_steps {
        if h == 0 {
            missing.push("0 steps: a horizon must be at least one step".into());
        } else if opts.start_frame + h >= frames {
            missing.push(format!(
                "{h} steps: frame {} is beyond the last frame {} of the shortest scene",
                opts.start_frame + h,
                frames.saturating_sub(1)
            ));
        } else {
            horizons.push(h);
        }
    }
    let longest = horizons.iter().copied().max().unwrap_or(0);
    let runs = rollouts(predictor, scenes, opts, longest)?;
    let mut samples = Vec::new();
    let mut kinematic_excluded = 0;
    for (si, (scene, (poses, spreads))) in scenes.iter().zip(&runs).enumerate() {
        let start = poses_at(scene, opts.start_frame)?;
        for (j, o) in scene.objects.iter().enumerate() {
            if o.kinematic {
                kinematic_excluded += 1;
                continue;
            }
            let mut path = 0.0f64;
            let mut squares = 0.0f64;
            let mut last = start[j].translation;
            let mut step = 0;
            for &h in &horizons {
                while step < h {
                    let p = poses[step][j].translation;
                    squares += f64::from(spreads[step][j].position_m).powi(2);
                    path += squared_distance(&last, &p).sqrt();
                    last = p;
                    step += 1;
                }
                let pred = poses[h - 1][j];
                let f = opts.start_frame + h;
                samples.push(CalibrationSample {
                    scene: si,
                    object: j,
                    steps: h,
                    error_m: squared_distance(&pred.translation, &o.positions[f]).sqrt(),
                    error_deg: geodesic_angle(pred.rotation, o.rotations[f]).to_degrees(),
                    spread: spreads[h - 1][j],
                    baseline_m: path,
                    accumulated_m: squares.sqrt(),
                });
            }
        }
    }
    let dt = scenes.first().map(|s| f64::from(s.dt_frame)).unwrap_or(0.0);
    let horizons = horizons
        .iter()
        .map(|&h| summarise(&samples, h, dt))
        .collect();
    let model = predictor.model();
    Ok(CalibrationReport {
        model: format!("{} ({})", model.name(), predictor.input_description()),
        members: model.member_names(),
        source: source.into(),
        scenes: scenes.len(),
        kinematic_excluded,
        options: opts.clone(),
        missing,
        horizons,
        samples,
        elapsed_s: started.elapsed().as_secs_f64(),
    })
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        0.0
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

fn summarise(samples: &[CalibrationSample], steps: usize, dt: f64) -> CalibrationHorizon {
    let at: Vec<&CalibrationSample> = samples.iter().filter(|s| s.steps == steps).collect();
    let col =
        |f: &dyn Fn(&CalibrationSample) -> f64| -> Vec<f64> { at.iter().map(|s| f(s)).collect() };
    let error = col(&|s| s.error_m);
    let error_deg = col(&|s| s.error_deg);
    let spread = col(&|s| f64::from(s.spread.position_m));
    let spread_deg = col(&|s| f64::from(s.spread.orientation_deg));
    let baseline = col(&|s| s.baseline_m);
    let accumulated = col(&|s| s.accumulated_m);
    CalibrationHorizon {
        steps,
        time_s: steps as f64 * dt,
        objects: at.len(),
        mean_error_m: mean(&error),
        mean_spread_m: mean(&spread),
        mean_baseline_m: mean(&baseline),
        spearman_spread: spearman(&spread, &error),
        spearman_baseline: spearman(&baseline, &error),
        spearman_accumulated: spearman(&accumulated, &error),
        spearman_orientation: spearman(&spread_deg, &error_deg),
        spread_deciles: deciles(&spread, &error),
        baseline_deciles: deciles(&baseline, &error),
    }
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |v| format!("{v:.digits$}"))
}

/// The horizon the plot shows: the one nearest 1 s.
pub fn plot_horizon(report: &CalibrationReport) -> Option<&CalibrationHorizon> {
    report
        .horizons
        .iter()
        .min_by(|a, b| (a.time_s - 1.0).abs().total_cmp(&(b.time_s - 1.0).abs()))
}

/// The report as Markdown: the summary per horizon, then the decile tables.
pub fn format_calibration_markdown(r: &CalibrationReport) -> String {
    let mut s = format!(
        "# Spread calibration: {}\n\nData: {}; {} scenes, start frame {}, steps of one frame; \
         {} kinematic objects excluded.\n\n",
        r.model, r.source, r.scenes, r.options.start_frame, r.kinematic_excluded
    );
    if !r.members.is_empty() {
        s += &format!("Members: {}.\n\n", r.members.join(", "));
    }
    s += "Error: distance of the predicted centre from the recorded one. Spread: the model's \
          position spread at that step; accumulated: the spreads of every step so far summed in \
          quadrature. Baseline: the path length the object travelled in the model's own \
          rollout so far. Spearman over objects x scenes.\n\n";
    s += "| horizon | objects | mean error (m) | mean spread (m) | Spearman spread | \
          Spearman accumulated | Spearman baseline | Spearman orient. spread | error, lowest \
          spread decile (m) | error, highest spread decile (m) |\n\
          |---|---|---|---|---|---|---|---|---|---|\n";
    for h in &r.horizons {
        s += &format!(
            "| {} steps ({:.2} s) | {} | {:.4} | {:.4} | {} | {} | {} | {} | {} | {} |\n",
            h.steps,
            h.time_s,
            h.objects,
            h.mean_error_m,
            h.mean_spread_m,
            opt(h.spearman_spread, 3),
            opt(h.spearman_accumulated, 3),
            opt(h.spearman_baseline, 3),
            opt(h.spearman_orientation, 3),
            opt(h.spread_deciles.first().and_then(|b| b.mean_error), 4),
            opt(h.spread_deciles.last().and_then(|b| b.mean_error), 4),
        );
    }
    for m in &r.missing {
        s += &format!("\nMissing horizon: {m}.\n");
    }
    for h in &r.horizons {
        s += &format!(
            "\n## {} steps ({:.2} s): mean error per decile\n\n| decile | n (spread) | spread (m) \
             | error (m) | n (baseline) | baseline (m) | error (m) |\n|---|---|---|---|---|---|---|\n",
            h.steps, h.time_s
        );
        for (i, (a, b)) in h.spread_deciles.iter().zip(&h.baseline_deciles).enumerate() {
            s += &format!(
                "| {} | {} | {} | {} | {} | {} | {} |\n",
                i + 1,
                a.count,
                opt(a.mean_key, 4),
                opt(a.mean_error, 4),
                b.count,
                opt(b.mean_key, 4),
                opt(b.mean_error, 4)
            );
        }
    }
    s
}

fn plot_err(e: impl std::fmt::Display) -> EvalError {
    EvalError::Invalid(format!("plot: {e}"))
}

/// Mean error per decile at the horizon nearest 1 s, of the spread and of the baseline, as an
/// 800 x 520 PNG.
pub fn plot_calibration(path: &Path, r: &CalibrationReport) -> Result<(), EvalError> {
    let h = plot_horizon(r).ok_or_else(|| EvalError::Invalid("plot: no horizon scored".into()))?;
    let line = |bins: &[DecileBin]| -> Vec<(f64, f64)> {
        bins.iter()
            .enumerate()
            .filter_map(|(i, b)| b.mean_error.map(|e| ((i + 1) as f64, e)))
            .collect()
    };
    let lines = [
        (
            "model spread",
            line(&h.spread_deciles),
            RGBColor(31, 119, 180),
        ),
        (
            "baseline: path length in the rollout",
            line(&h.baseline_deciles),
            RGBColor(127, 127, 127),
        ),
    ];
    let y_max = lines
        .iter()
        .flat_map(|l| l.1.iter().map(|p| p.1))
        .fold(1e-6f64, f64::max)
        * 1.1;
    let root = BitMapBackend::new(path, (800, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let title = format!(
        "Mean error per decile, {} steps ({:.2} s); Spearman spread {} / baseline {}",
        h.steps,
        h.time_s,
        opt(h.spearman_spread, 2),
        opt(h.spearman_baseline, 2)
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d(0.5..10.5f64, 0.0..y_max)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("decile of the predictor (1 = lowest)")
        .y_desc("mean translation error (m)")
        .draw()
        .map_err(plot_err)?;
    for (name, pts, color) in lines {
        chart
            .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
            .map_err(plot_err)?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color));
        chart
            .draw_series(pts.into_iter().map(|p| Circle::new(p, 4, color.filled())))
            .map_err(plot_err)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calibration_average_ranks_share_ties() {
        assert_eq!(
            average_ranks(&[3.0, 1.0, 3.0, 2.0, 3.0]),
            vec![3.0, 0.0, 3.0, 1.0, 3.0]
        );
    }

    #[test]
    fn calibration_spearman_on_hand_made_numbers() {
        // Monotone but not linear: exactly 1; reversed: -1.
        let x = [1.0, 2.0, 3.0, 4.0, 5.0];
        let y = [1.0, 4.0, 9.0, 16.0, 100.0];
        assert!((spearman(&x, &y).unwrap() - 1.0).abs() < 1e-12);
        let r: Vec<f64> = y.iter().rev().copied().collect();
        assert!((spearman(&x, &r).unwrap() + 1.0).abs() < 1e-12);
        // With ties: x ranks [0, 1.5, 1.5, 3], y ranks [0, 1, 2, 3]; by hand
        // cov = 1.5*... : dx = [-1.5, 0, 0, 1.5], dy = [-1.5, -0.5, 0.5, 1.5],
        // sxy = 4.5, sxx = 4.5, syy = 5 -> 4.5 / sqrt(22.5).
        let rho = spearman(&[1.0, 2.0, 2.0, 3.0], &[10.0, 20.0, 30.0, 40.0]).unwrap();
        assert!((rho - 4.5 / 22.5f64.sqrt()).abs() < 1e-12);
        // A constant side has no correlation.
        assert_eq!(spearman(&[1.0, 1.0, 1.0], &[1.0, 2.0, 3.0]), None);
        assert_eq!(spearman(&[1.0], &[1.0]), None);
    }

    #[test]
    fn calibration_deciles_on_hand_made_numbers() {
        // 20 distinct keys: two per bin, the errors 0..20 follow the key order.
        let key: Vec<f64> = (0..20).map(|i| (19 - i) as f64).collect();
        let error: Vec<f64> = key.iter().map(|k| k * 10.0).collect();
        let bins = deciles(&key, &error);
        assert_eq!(bins.len(), BINS);
        for (i, b) in bins.iter().enumerate() {
            assert_eq!(b.count, 2);
            assert_eq!(b.mean_key, Some(2.0 * i as f64 + 0.5));
            assert_eq!(b.mean_error, Some(20.0 * i as f64 + 5.0));
        }
        // Ties stay together: ten zeros (average rank 4.5 of 20 -> bin 2) and ten ones
        // (average rank 14.5 -> bin 7).
        let key: Vec<f64> = (0..20).map(|i| if i < 10 { 0.0 } else { 1.0 }).collect();
        let error: Vec<f64> = (0..20).map(|i| i as f64).collect();
        let bins = deciles(&key, &error);
        let counts: Vec<usize> = bins.iter().map(|b| b.count).collect();
        assert_eq!(counts, vec![0, 0, 10, 0, 0, 0, 0, 10, 0, 0]);
        assert_eq!(bins[2].mean_error, Some(4.5));
        assert_eq!(bins[7].mean_error, Some(14.5));
        assert_eq!(bins[0].mean_error, None);
    }
}
