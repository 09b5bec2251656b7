//! `dynaserve eval --suite calibration`: loads the model and one dataset split, scores the
//! spread calibration, prints the summary and writes JSON, Markdown and the PNG.

use anyhow::Context;

use super::args::EvalArgs;
use crate::eval::calibration::{
    CalibrationOptions, format_calibration_markdown, load_scenes, plot_calibration, run_calibration,
};
use crate::eval::{ModelPredictor, PointSelection};

/// Runs the calibration suite for `dynaserve eval --suite calibration`.
pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let Some(dir) = &args.model else {
        anyhow::bail!("--suite calibration scores a --model with a spread (an ensemble)");
    };
    let data = match args.data.as_slice() {
        [one] => one,
        _ => anyhow::bail!("--suite calibration needs one --data directory"),
    };
    let device = dynaserve_model::device_from_name(&args.device)?;
    let base = ModelPredictor::load_on(dir, &device)
        .with_context(|| format!("loading model {}", dir.display()))?;
    let model = match args.points_per_object {
        Some(n) => base.with_points_per_object(n),
        None => base.with_points(PointSelection::Nominal),
    };
    let scenes = load_scenes(data, args.max_scenes)
        .with_context(|| format!("reading dataset {}", data.display()))?;
    let opts = CalibrationOptions {
        start_frame: args.start_frame,
        horizons_steps: args.calibration_steps.clone(),
        two_frames: args.two_frames,
    };
    eprintln!(
        "calibration: {} scenes of {}, horizons {:?} steps",
        scenes.len(),
        data.display(),
        opts.horizons_steps
    );
    let mut report = run_calibration(&model, &scenes, &opts, &data.display().to_string())?;
    report.elapsed_s = started.elapsed().as_secs_f64();
    let markdown = format_calibration_markdown(&report);
    print!("{markdown}");
    println!(
        "\nscored {} scenes in {:.1} s",
        report.scenes, report.elapsed_s
    );
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&report)? + "\n")
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &args.markdown {
        std::fs::write(path, &markdown).with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &args.plot {
        plot_calibration(path, &report)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
