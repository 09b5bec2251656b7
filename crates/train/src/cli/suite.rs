//! `dynaserve eval --suite physics`: builds the predictors, generates (or reads) the physics
//! suite, scores it with progress on stderr, prints the summary and writes JSON and Markdown.

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};

use super::args::{BaselineKind, EvalArgs};
use crate::eval::physics_report::{format_physics_markdown, format_physics_text};
use crate::eval::physics_suite::{SuiteOptions, generate_suite, load_suite, run_suite, window_csv};
use crate::eval::{
    Ballistic, ModelPredictor, PointSelection, Predictor, RapierRestart, Static, driven,
};

/// Reference points per object of generated suite scenes (as in the datasets).
const SUITE_POINTS: usize = 1024;

/// Runs the physics suite for `dynaserve eval --suite physics`.
pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let (scenes, gravity, source) = if args.data.is_empty() {
        eprintln!(
            "generating the physics suite: {} scenes per group, seed {}, split test, {} materials",
            args.suite_scenes,
            args.seed,
            args.suite_materials.name()
        );
        let scenes = generate_suite(
            args.seed,
            "test",
            args.suite_scenes,
            SUITE_POINTS,
            args.suite_materials,
        )?;
        let gravity = dynaserve_sim::ScenarioParameters::new(vec![]).gravity;
        (
            scenes,
            gravity,
            format!(
                "generated scenes (seed {}, split test{})",
                args.seed,
                match args.suite_materials {
                    dynaserve_sim::Materials::Kubric => "",
                    dynaserve_sim::Materials::Uniform => ", uniform materials",
                }
            ),
        )
    } else {
        let (scenes, gravity) = load_suite(&args.data, args.max_scenes)?;
        let dirs: Vec<String> = args.data.iter().map(|d| d.display().to_string()).collect();
        (scenes, gravity, dirs.join(", "))
    };
    let ballistic = Ballistic {
        gravity,
        floor_z: Some(0.0),
    };
    let mut predictors: Vec<(String, Box<dyn Predictor>)> = Vec::new();
    match (args.baseline, &args.model) {
        (Some(BaselineKind::Static), None) => predictors.push(("static".into(), Box::new(Static))),
        (Some(BaselineKind::Ballistic), None) => {
            predictors.push(("ballistic".into(), Box::new(ballistic)))
        }
        (Some(BaselineKind::Rapier), None) => {
            let restart = rapier(args, gravity)?;
            predictors.push((restart.name(), Box::new(restart)))
        }
        (None, Some(dir)) => {
            let device = dynaserve_model::device_from_name(&args.device)?;
            let base = ModelPredictor::load_on(dir, &device)
                .with_context(|| format!("loading model {}", dir.display()))?;
            let model = match args.points_per_object {
                Some(n) => base.with_points_per_object(n),
                None => base.with_points(PointSelection::Nominal),
            };
            predictors.push(("model".into(), Box::new(model)));
            if !args.no_baselines {
                predictors.push(("ballistic".into(), Box::new(ballistic)));
                // With a pusher, the baseline of its push figures: pushed objects stay still.
                if scenes.iter().any(|s| driven::has_kinematic(&s.scene)) {
                    predictors.push(("static".into(), Box::new(Static)));
                }
            }
            if args.rapier {
                let restart = rapier(args, gravity)?;
                predictors.push((restart.name(), Box::new(restart)));
            }
        }
        _ => anyhow::bail!("give exactly one of --baseline and --model"),
    }
    let opts = SuiteOptions {
        start_frame: args.start_frame,
        step_sizes: args.step_sizes.clone(),
        window_stride: args.window_stride,
        gravity,
        two_frames: args.two_frames,
    };
    let bar = ProgressBar::new((scenes.len() * predictors.len()) as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} scene evaluations (eta {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message("physics suite");
    let refs: Vec<(&str, &dyn Predictor)> = predictors
        .iter()
        .map(|(l, p)| (l.as_str(), p.as_ref()))
        .collect();
    let per = scenes.len();
    let mut report = run_suite(&refs, &scenes, &opts, &source, &|pi, done| {
        bar.set_position((pi * per + done) as u64);
        bar.set_message(format!("physics suite: {}", refs[pi].0));
    })?;
    bar.finish_and_clear();
    report.elapsed_s = started.elapsed().as_secs_f64();
    print!("{}", format_physics_text(&report));
    println!(
        "\nscored {} scenes x {} predictors in {:.1} s",
        scenes.len(),
        predictors.len(),
        report.elapsed_s
    );
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&report)? + "\n")
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &args.markdown {
        std::fs::write(path, format_physics_markdown(&report))
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &args.windows {
        std::fs::write(path, window_csv(&report))
            .with_context(|| format!("writing {}", path.display()))?;
        println!(
            "wrote {} ({} windows)",
            path.display(),
            report.windows.len()
        );
    }
    Ok(())
}

/// The rapier restart for the suite's scenes: the conditions of the `--data` directories (which
/// must agree), or the generators' own for the generated suite.
fn rapier(args: &EvalArgs, gravity: [f32; 3]) -> anyhow::Result<RapierRestart> {
    let mut found: Option<RapierRestart> = None;
    for dir in &args.data {
        let reader = dynaserve_sim::DatasetReader::open(dir)
            .with_context(|| format!("opening dataset {}", dir.display()))?;
        let here = RapierRestart::from_manifest(reader.manifest())?;
        match &found {
            Some(first) if *first != here => anyhow::bail!(
                "{} was recorded under other conditions (shapes, floor or timing) than the first --data directory; the rapier restart needs one",
                dir.display()
            ),
            Some(_) => {}
            None => found = Some(here),
        }
    }
    Ok(found
        .unwrap_or_else(|| RapierRestart::movi(gravity))
        .with_cloud_points(args.rapier_cloud_points))
}
