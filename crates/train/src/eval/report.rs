//! Several predictors evaluated on the same scenes, side by side: [`SuiteReport`] (what
//! `dynaserve eval --json` writes), a plain-text summary ([`format_suite`]) and Markdown tables
//! for a model card ([`format_markdown`]).

use std::fmt::Write;

use serde::{Deserialize, Serialize};

use super::{DriftReport, EvalReport, Stat, write_missing_horizons};

/// One predictor of a suite.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SuiteEntry {
    /// Short column label (`model`, `model-768`, `static`, ...).
    pub label: String,
    /// What the predictor is given, for learned models (`512 points, 25% occluded`).
    pub input: Option<String>,
    /// Its report.
    pub report: EvalReport,
}

/// Every predictor of one `dynaserve eval` run, on the same scenes with the same options.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SuiteReport {
    /// The entries: learned-model variants first, then the baselines.
    pub entries: Vec<SuiteEntry>,
    /// Wall-clock time of the whole run, seconds.
    pub elapsed_s: f64,
}

fn num(v: Option<f64>, decimals: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.decimals$}"),
        Some(x) => format!("{x}"),
        None => "-".to_string(),
    }
}

/// A number with 3 significant digits (plain notation above 1e-3, scientific below).
fn sig(x: f64) -> String {
    if x == 0.0 {
        "0".into()
    } else if !x.is_finite() || x.abs() < 1e-3 {
        format!("{x:.2e}")
    } else {
        let d = (2 - x.abs().log10().floor() as i32).max(0) as usize;
        format!("{x:.d$}")
    }
}

/// The step-size column of a drift row: `-` for the ground truth (`dt_steps` 0).
fn step_label(d: &DriftReport) -> String {
    if d.dt_steps == 0 {
        "-".to_string()
    } else {
        d.dt_steps.to_string()
    }
}

fn stat_pair(s: Option<&Stat>) -> String {
    match s {
        Some(s) => format!("{} / {}", sig(s.mean), sig(s.max)),
        None => "-".into(),
    }
}

/// `mean / median / p90 / p99 / max` (the resting drift, where one object that falls over
/// moves the mean by metres).
fn stat_spread(s: Option<&Stat>) -> String {
    match s {
        Some(s) => format!(
            "{} / {} / {} / {} / {}",
            sig(s.mean),
            sig(s.median),
            sig(s.p90),
            sig(s.p99),
            sig(s.max)
        ),
        None => "-".into(),
    }
}

impl SuiteReport {
    /// Rows of the resting-drift table: the ground truth of `resting`, then every entry's
    /// predicted drift per step size.
    fn drift_rows<'a>(
        &'a self,
        resting: &'a super::RestingReport,
    ) -> impl Iterator<Item = (&'a str, &'a DriftReport)> {
        std::iter::once(("ground truth", &resting.truth)).chain(self.entries.iter().flat_map(|e| {
            e.report
                .resting
                .iter()
                .flat_map(|rr| rr.predicted.iter())
                .map(move |d| (e.label.as_str(), d))
        }))
    }

    fn first(&self) -> Option<&EvalReport> {
        self.entries.first().map(|e| &e.report)
    }

    /// The first predictor's label and its resting drift per (step size, shape) as cells: `k`,
    /// the shape's name (its id where the manifest gave none), the object count and the
    /// translation spread (m). The first predictor is the model evaluated (the baselines' rows
    /// say nothing per shape); the JSON report has every predictor's.
    fn first_shape_drift(&self) -> (&str, Vec<[String; 4]>) {
        let first = self.entries.first();
        let label = first.map_or("", |e| e.label.as_str());
        let rows = first
            .and_then(|e| e.report.resting.as_ref())
            .into_iter()
            .flat_map(|rr| &rr.predicted)
            .flat_map(|d| {
                d.by_shape.iter().map(move |x| {
                    [
                        step_label(d),
                        if x.shape.is_empty() {
                            x.shape_id.to_string()
                        } else {
                            x.shape.clone()
                        },
                        x.translation_m.count.to_string(),
                        stat_spread(Some(&x.translation_m)),
                    ]
                })
            })
            .collect();
        (label, rows)
    }

    /// The per-object error spread at step size 1 (or the first step size where 1 was not
    /// evaluated): that step size in frames, and per horizon and predictor in turn the cells
    /// horizon label, predictor label, translation spread (m), orientation spread (deg).
    fn spread_rows(&self) -> (u32, Vec<[String; 4]>) {
        let Some((k, dt)) = self.spread_step() else {
            return (1, Vec::new());
        };
        let horizons = self.first().map_or(0, |r| r.step_sizes[k].horizons.len());
        let rows = (0..horizons)
            .flat_map(|h| {
                self.entries.iter().filter_map(move |e| {
                    let x = e.report.step_sizes.get(k)?.horizons.get(h)?;
                    (x.translation_m.is_some() || x.orientation_deg.is_some()).then(|| {
                        [
                            self.horizon_label(h),
                            e.label.clone(),
                            stat_spread(x.translation_m.as_ref()),
                            stat_spread(x.orientation_deg.as_ref()),
                        ]
                    })
                })
            })
            .collect();
        (dt, rows)
    }

    /// The step size of the per-object tables: the index of step size 1 in the first report
    /// (or of its first step size where 1 was not evaluated), and that step size in frames.
    fn spread_step(&self) -> Option<(usize, u32)> {
        let r = self.first()?;
        let k = r
            .step_sizes
            .iter()
            .position(|x| x.dt_steps == 1)
            .or((!r.step_sizes.is_empty()).then_some(0))?;
        Some((k, r.step_sizes[k].dt_steps))
    }

    /// The first predictor's label and its per-object errors at the step size of
    /// [`SuiteReport::spread_step`] split by what the objects touched, as cells: horizon,
    /// contact class, objects, translation RMSE (m), orientation RMSE (deg), orientation
    /// spread (deg).
    fn contact_rows(&self) -> (&str, Vec<[String; 6]>) {
        let label = self.entries.first().map_or("", |e| e.label.as_str());
        let Some((k, _)) = self.spread_step() else {
            return (label, Vec::new());
        };
        let horizons = self
            .first()
            .map_or(&[][..], |r| &r.step_sizes[k].horizons[..]);
        let rows = horizons
            .iter()
            .enumerate()
            .flat_map(|(h, x)| {
                x.by_contact.iter().map(move |c| {
                    [
                        self.horizon_label(h),
                        c.contact.name().to_string(),
                        c.translation_m.count.to_string(),
                        sig(c.translation_rmse_m),
                        sig(c.orientation_rmse_deg),
                        stat_spread(Some(&c.orientation_deg)),
                    ]
                })
            })
            .collect();
        (label, rows)
    }

    /// Rows of the error tables: every (horizon index, step-size index) of the first report.
    fn rows(&self) -> Vec<(usize, usize)> {
        let Some(r) = self.first() else {
            return Vec::new();
        };
        let horizons = r.step_sizes.first().map(|k| k.horizons.len()).unwrap_or(0);
        (0..horizons)
            .flat_map(|h| (0..r.step_sizes.len()).map(move |k| (h, k)))
            .collect()
    }

    fn horizon_label(&self, h: usize) -> String {
        let Some(x) = self
            .first()
            .and_then(|r| r.step_sizes.first())
            .and_then(|k| k.horizons.get(h))
        else {
            return String::new();
        };
        match x.frames {
            Some(f) => format!("{} s ({f} fr)", x.horizon_s),
            None => format!("{} s", x.horizon_s),
        }
    }

    fn metric(&self, entry: usize, h: usize, k: usize, orientation: bool) -> Option<f64> {
        let e = self.entries[entry]
            .report
            .step_sizes
            .get(k)?
            .horizons
            .get(h)?;
        if orientation {
            e.orientation_rmse_deg
        } else {
            e.translation_rmse_m
        }
    }

    fn header_line(&self) -> String {
        let Some(r) = self.first() else {
            return "empty evaluation".into();
        };
        let source = match &r.dataset {
            Some(d) => format!(
                "{} ({} split, seed {}, {})",
                d.generator, d.split, d.seed, d.dir
            ),
            None => "in-memory scenes".to_string(),
        };
        format!(
            "data: {source}; {} scenes, {} objects, {} frames of {:.4} s; observed frames s-k \
             and s = {}; {}",
            r.scenes, r.objects, r.frames, r.dt_frame, r.start_frame, r.pooling
        )
    }
}

/// The suite as plain text: the inputs, translation and orientation RMSE per (horizon, step
/// size) with one column per predictor, the stability rollout, and the resting drift.
pub fn format_suite(suite: &SuiteReport) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}", suite.header_line());
    for e in &suite.entries {
        // A learned model's name already carries its input.
        let _ = writeln!(
            s,
            "  {:<16} {} ({:.1} s)",
            e.label, e.report.predictor, e.report.elapsed_s
        );
    }
    let width = suite
        .entries
        .iter()
        .map(|e| e.label.len())
        .max()
        .unwrap_or(0)
        .max(9);
    for (title, orientation, decimals) in [
        ("translation RMSE (m)", false, 4),
        ("orientation RMSE (deg)", true, 2),
    ] {
        let _ = writeln!(s, "\n{title}");
        let mut header = format!("{:<16} {:>3} |", "horizon", "k");
        for e in &suite.entries {
            let _ = write!(header, " {:>width$}", e.label);
        }
        let _ = writeln!(s, "{header}");
        let _ = writeln!(s, "{}", "-".repeat(header.len()));
        for (h, k) in suite.rows() {
            let label = if k == 0 {
                suite.horizon_label(h)
            } else {
                String::new()
            };
            let dt = suite
                .first()
                .and_then(|r| r.step_sizes.get(k))
                .map(|x| x.dt_steps)
                .unwrap_or(0);
            let mut line = format!("{label:<16} {dt:>3} |");
            for i in 0..suite.entries.len() {
                let _ = write!(
                    line,
                    " {:>width$}",
                    num(suite.metric(i, h, k, orientation), decimals)
                );
            }
            let _ = writeln!(s, "{line}");
        }
    }
    if let Some(r) = suite.first() {
        write_missing_horizons(&mut s, r);
    }
    let (spread_k, spread) = suite.spread_rows();
    if !spread.is_empty() {
        let _ = writeln!(
            s,
            "\nper-object error at k = {}: mean / median / p90 / p99 / max over the objects",
            spread_k
        );
        let _ = writeln!(
            s,
            "{:<16} {:<16} | {:>46} {:>46}",
            "horizon", "predictor", "translation m", "orientation deg"
        );
        for [h, label, t, r] in spread {
            let _ = writeln!(s, "{h:<16} {label:<16} | {t:>46} {r:>46}");
        }
    }
    let (label, contact) = suite.contact_rows();
    if !contact.is_empty() {
        let _ = writeln!(
            s,
            "\nper-object error at k = {spread_k} ({label}) by what the object touched in the \
             ground truth from frame s to the horizon"
        );
        let _ = writeln!(
            s,
            "{:<16} {:<16} {:>7} | {:>8} {:>8} | {:>46}",
            "horizon", "touched", "objects", "RMSE m", "RMSE deg", "orientation deg"
        );
        for [h, c, n, t, r, spread] in contact {
            let _ = writeln!(s, "{h:<16} {c:<16} {n:>7} | {t:>8} {r:>8} | {spread:>46}");
        }
    }
    if let Some(l) = suite.first().and_then(|r| r.long_rollout.as_ref()) {
        let _ = writeln!(
            s,
            "\nstability: k = 1, {} steps from frame s (past the data's end); failure = a \
             non-finite pose or | |q| - 1 | > 1e-4",
            l.steps
        );
        let _ = writeln!(
            s,
            "{:<16} | {:>15} {:>13} {:>12} {:>14} {:>22}",
            "predictor",
            "failed objects",
            "failed scenes",
            "max ||q|-1|",
            "max pair dev m",
            "pre-proj. mean/max m"
        );
        for e in &suite.entries {
            if let Some(l) = &e.report.long_rollout {
                let _ = writeln!(
                    s,
                    "{:<16} | {:>15} {:>13} {:>12} {:>14} {:>22}",
                    e.label,
                    format!("{} / {}", l.failed_objects, l.objects),
                    format!("{} / {}", l.failed_scenes, e.report.scenes),
                    format!("{:.1e}", l.max_quaternion_norm_error),
                    format!("{:.1e}", l.max_pairwise_deviation_m),
                    stat_pair(l.projection_residual_m.as_ref())
                );
            }
        }
    }
    if let Some(r) = suite.first().and_then(|r| r.resting.as_ref()) {
        let _ = writeln!(
            s,
            "\nresting drift over frames {}..{} ({} s): {} of {} objects at rest in the ground \
             truth (speed < {} m/s and < {} deg/s between consecutive frames); mean / median / \
             p90 / p99 / max",
            r.first_frame,
            r.last_frame,
            r.options.window_s,
            r.objects_at_rest,
            r.objects,
            r.options.max_speed_m_s,
            r.options.max_angular_speed_deg_s
        );
        let _ = writeln!(
            s,
            "{:<16} {:>3} | {:>46} {:>46}",
            "predictor", "k", "translation m", "rotation deg"
        );
        for (label, d) in suite.drift_rows(r) {
            let _ = writeln!(
                s,
                "{:<16} {:>3} | {:>46} {:>46}",
                label,
                step_label(d),
                stat_spread(d.translation_m.as_ref()),
                stat_spread(d.rotation_deg.as_ref())
            );
        }
        let (label, shapes) = suite.first_shape_drift();
        if !shapes.is_empty() {
            let _ = writeln!(
                s,
                "\nresting drift by shape ({label}), translation m: mean / median / p90 / p99 / max"
            );
            let _ = writeln!(
                s,
                "{:>3} | {:<16} {:>7} | {:>46}",
                "k", "shape", "objects", "translation m"
            );
            for [k, shape, count, spread] in shapes {
                let _ = writeln!(s, "{k:>3} | {shape:<16} {count:>7} | {spread:>46}");
            }
        }
    }
    s
}

/// The suite as Markdown tables a model card can include: translation and orientation RMSE
/// per (horizon, step size) with one column per predictor, stability and resting drift.
pub fn format_markdown(suite: &SuiteReport) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}\n", suite.header_line());
    for e in &suite.entries {
        let _ = writeln!(s, "- `{}`: {}", e.label, e.report.predictor);
    }
    for (title, orientation, decimals) in [
        ("Translation RMSE (m)", false, 3),
        ("Orientation RMSE (deg)", true, 1),
    ] {
        let _ = writeln!(s, "\n**{title}**, pooled over all objects\n");
        let mut header = "| horizon | k |".to_string();
        let mut rule = "| --- | --- |".to_string();
        for e in &suite.entries {
            let _ = write!(header, " {} |", e.label);
            rule.push_str(" --- |");
        }
        let _ = writeln!(s, "{header}\n{rule}");
        for (h, k) in suite.rows() {
            let dt = suite
                .first()
                .and_then(|r| r.step_sizes.get(k))
                .map(|x| x.dt_steps)
                .unwrap_or(0);
            let mut line = format!("| {} | {dt} |", suite.horizon_label(h));
            for i in 0..suite.entries.len() {
                let _ = write!(
                    line,
                    " {} |",
                    num(suite.metric(i, h, k, orientation), decimals)
                );
            }
            let _ = writeln!(s, "{line}");
        }
    }
    let (spread_k, spread) = suite.spread_rows();
    if !spread.is_empty() {
        let _ = writeln!(
            s,
            "\n**Per-object error** at k = {}: mean / median / p90 / p99 / max over the objects \
             (the RMSE above pools their squares)\n\n| horizon | predictor | translation (m) | \
             orientation (deg) |\n| --- | --- | --- | --- |",
            spread_k
        );
        for [h, label, t, r] in spread {
            let _ = writeln!(s, "| {h} | {label} | {t} | {r} |");
        }
    }
    let (label, contact) = suite.contact_rows();
    if !contact.is_empty() {
        let _ = writeln!(
            s,
            "\n**Per-object error by contact** of `{label}` at k = {spread_k}: what \
             each object touched in the ground truth from frame s to the horizon (the regime \
             table's contact tests); orientation: mean / median / p90 / p99 / max\n\n| \
             horizon | touched | objects | translation RMSE (m) | orientation RMSE (deg) | \
             orientation (deg) |\n| --- | --- | --- | --- | --- | --- |"
        );
        for [h, c, n, t, r, spread] in contact {
            let _ = writeln!(s, "| {h} | {c} | {n} | {t} | {r} | {spread} |");
        }
    }
    if let Some(l) = suite.first().and_then(|r| r.long_rollout.as_ref()) {
        let _ = writeln!(
            s,
            "\n**Stability**: k = 1, {} steps from frame s; failure = a non-finite pose or \
             | \\|q\\| - 1 | > 1e-4\n",
            l.steps
        );
        let _ = writeln!(
            s,
            "| predictor | failed objects | failed scenes | max \\|\\|q\\| - 1\\| | max pairwise \
             distance deviation (m) | pre-projection residual mean / max (m) |\n| --- | --- | \
             --- | --- | --- | --- |"
        );
        for e in &suite.entries {
            if let Some(l) = &e.report.long_rollout {
                let _ = writeln!(
                    s,
                    "| {} | {} / {} | {} / {} | {:.1e} | {:.1e} | {} |",
                    e.label,
                    l.failed_objects,
                    l.objects,
                    l.failed_scenes,
                    e.report.scenes,
                    l.max_quaternion_norm_error,
                    l.max_pairwise_deviation_m,
                    stat_pair(l.projection_residual_m.as_ref())
                );
            }
        }
    }
    if let Some(r) = suite.first().and_then(|r| r.resting.as_ref()) {
        let _ = writeln!(
            s,
            "\n**Resting drift** over frames {}..{} ({} s) of the {} of {} objects at rest in \
             the ground truth (speed < {} m/s, < {} deg/s); mean / median / p90 / p99 / max\n",
            r.first_frame,
            r.last_frame,
            r.options.window_s,
            r.objects_at_rest,
            r.objects,
            r.options.max_speed_m_s,
            r.options.max_angular_speed_deg_s
        );
        let _ = writeln!(
            s,
            "| predictor | k | translation (m) | rotation (deg) |\n| --- | --- | --- | --- |"
        );
        for (label, d) in suite.drift_rows(r) {
            let _ = writeln!(
                s,
                "| {label} | {} | {} | {} |",
                step_label(d),
                stat_spread(d.translation_m.as_ref()),
                stat_spread(d.rotation_deg.as_ref())
            );
        }
        let (label, shapes) = suite.first_shape_drift();
        if !shapes.is_empty() {
            let _ = writeln!(
                s,
                "\n**Resting drift by shape** of the first predictor, translation (m): mean / \
                 median / p90 / p99 / max\n\n| predictor | k | shape | objects | translation (m) \
                 |\n| --- | --- | --- | --- | --- |"
            );
            for [k, shape, count, spread] in shapes {
                let _ = writeln!(s, "| {label} | {k} | {shape} | {count} | {spread} |");
            }
        }
    }
    s
}
