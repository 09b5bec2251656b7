//! `dynaserve view`: a dataset scene's rapier trajectory beside a model's rollout from the same
//! start, in the browser viewer. It serves the model like `dynaserve serve` and offers the scene
//! first in the viewer (`GET /v1/examples`, with its ground truth); the page streams the model's
//! rollout, draws it over the ghosted ground truth and plots the error against time.

use std::path::PathBuf;

use anyhow::{Context, bail};
use dynaserve_client::json;
use dynaserve_server::ServeConfig;
use dynaserve_server::viewer::{Example, Viewer};
use dynaserve_sim::{DatasetReader, SceneRecord};

/// Flags of `dynaserve view`; the server's flags (`--model`, `--http-addr`, ...) apply too.
#[derive(clap::Args, Debug)]
pub struct ViewArgs {
    /// Dataset split directory (written by `dynaserve sim`).
    #[arg(long)]
    pub data: PathBuf,
    /// Index of the scene in the split.
    #[arg(long, default_value_t = 0)]
    pub scene: usize,
    /// Frames per model step.
    #[arg(long, default_value_t = 1)]
    pub dt_steps: u32,
    /// Frame the rollout starts from (it needs `dt_steps` frames before it); default
    /// `dt_steps`, the earliest possible.
    #[arg(long)]
    pub start: Option<usize>,
    /// Steps to compare; default: as many as the scene holds after `start`, up to
    /// `--max-steps`.
    #[arg(long)]
    pub steps: Option<u32>,
    /// The server (models, addresses, limits).
    #[command(flatten)]
    pub serve: ServeConfig,
}

fn pose(p: dynaserve_model::Pose) -> json::Pose {
    json::Pose {
        translation: p.translation,
        rotation: p.rotation,
    }
}

/// The viewer example of scene `index` of `data`: a rollout request from frame `start` (with
/// the pose `dt_steps` frames earlier as the previous pose, the first `points` reference points
/// of each object) and the recorded poses of every later step as ground truth.
pub fn comparison(
    data: &DatasetReader,
    index: usize,
    points: usize,
    dt_steps: u32,
    start: usize,
    steps: Option<u32>,
    max_steps: u32,
) -> anyhow::Result<Example> {
    if index >= data.len() {
        bail!(
            "--scene {index}: the split has {} scenes (0 to {})",
            data.len(),
            data.len().saturating_sub(1)
        );
    }
    let scene: SceneRecord = data
        .get(index)
        .with_context(|| format!("reading scene {index}"))?;
    let k = dt_steps.max(1) as usize;
    if start < k {
        bail!("--start {start}: a step size of {k} frames needs frame {start} - {k}");
    }
    let frames = scene
        .objects
        .iter()
        .map(|o| o.positions.len().min(o.rotations.len()))
        .min()
        .unwrap_or(0);
    if start >= frames {
        bail!("--start {start}: the scene has {frames} frames");
    }
    let available = ((frames - 1 - start) / k) as u32;
    let steps = steps.unwrap_or(available).min(available).min(max_steps);
    if steps == 0 {
        bail!(
            "no step of {k} frames fits after frame {start} of this {frames}-frame scene (or --steps is 0)"
        );
    }
    let at = |t: usize| dynaserve_train::eval::poses_at(&scene, t).map_err(anyhow::Error::msg);
    let current = at(start)?;
    let previous = at(start - k)?;
    let objects = scene
        .objects
        .iter()
        .enumerate()
        .map(|(j, o)| json::ObjectSpec {
            points: Some(o.reference_points.iter().take(points).copied().collect()),
            mesh: None,
            pose: pose(current[j]),
            previous_pose: Some(pose(previous[j])),
            velocity: None,
            mass: o.mass,
            friction: o.friction,
            restitution: o.restitution,
        })
        .collect::<Vec<_>>();
    let dt = f64::from(scene.dt_frame) * k as f64;
    let ground_truth = (1..=steps)
        .map(|i| {
            Ok(json::StepFrame {
                step: i,
                time: f64::from(i) * dt,
                poses: at(start + i as usize * k)?.into_iter().map(pose).collect(),
                timing: None,
                spread: Vec::new(),
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let request = json::RolloutRequest {
        model: String::new(),
        scene: json::Scene { objects },
        steps,
        dt_steps: k as u32,
        timeout_ms: 0,
        stream: false,
    };
    let name = format!("scene-{index}");
    let mut example = Example::new(name, request);
    example.title = format!(
        "{} scene {index}: {} objects, {steps} steps from frame {start}",
        data.dir().display(),
        scene.objects.len()
    );
    example.ground_truth = ground_truth;
    Ok(example)
}

/// Runs `dynaserve view`: builds the comparison, then serves until SIGTERM or Ctrl-C.
pub fn run(args: ViewArgs) -> anyhow::Result<()> {
    let mut serve = args.serve;
    let dirs = dynaserve_server::model_dirs(&serve)?;
    // The comparison is a rigid rollout: the first RigidFormer directory sets its frame
    // interval and point count (PhysiFormer directories are served beside it).
    let rigid = dirs
        .iter()
        .find(|d| dynaserve_model::checkpoint::read_config(d).is_ok())
        .unwrap_or(&dirs[0]);
    let config = dynaserve_model::checkpoint::read_config(rigid)
        .with_context(|| format!("reading {}", rigid.display()))?;
    let data = DatasetReader::open(&args.data)
        .with_context(|| format!("opening the dataset {}", args.data.display()))?;
    let data_dt = data.manifest().dt_frame;
    if (data_dt - config.dt_frame).abs() > 1e-6 * data_dt.abs() {
        bail!(
            "the dataset's frame interval ({data_dt} s) is not the model's ({} s)",
            config.dt_frame
        );
    }
    let points = config
        .points_per_object
        .max(1)
        .min(serve.caps().max_points_per_object);
    let start = args.start.unwrap_or(args.dt_steps.max(1) as usize);
    let example = comparison(
        &data,
        args.scene,
        points,
        args.dt_steps,
        start,
        args.steps,
        serve.caps().max_steps,
    )?;
    eprintln!(
        "{}: open the HTTP address below in a browser",
        example.title
    );
    serve.models = dirs;
    dynaserve_server::server::run_with_viewer(serve, Viewer::builtin().with_first(example))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynaserve_sim::{GenerateOptions, Generator};

    #[test]
    fn a_dataset_scene_becomes_a_request_from_its_start_and_its_recorded_truth() {
        let dir = std::env::temp_dir().join(format!("dynaserve-view-{}", std::process::id()));
        let mut opts = GenerateOptions::new(Generator::movi_b(), 5, "test", 2);
        opts.points = 64;
        opts.sim.frames = 13;
        dynaserve_sim::writer::generate_dataset(&opts, &dir, true, &|| {}).unwrap();
        let data = DatasetReader::open(&dir).unwrap();
        let scene = data.get(1).unwrap();

        // Step size 2 from frame 2: (13 - 1 - 2) / 2 = 5 steps fit.
        let ex = comparison(&data, 1, 32, 2, 2, None, 10_000).unwrap();
        assert_eq!((ex.request.steps, ex.request.dt_steps), (5, 2));
        assert_eq!(ex.ground_truth.len(), 5);
        assert_eq!(ex.request.scene.objects.len(), scene.objects.len());
        for (j, o) in scene.objects.iter().enumerate() {
            let spec = &ex.request.scene.objects[j];
            assert_eq!(spec.points.as_ref().unwrap().len(), 32);
            assert_eq!(spec.pose.translation, o.positions[2]);
            assert_eq!(spec.previous_pose.unwrap().rotation, o.rotations[0]);
            assert_eq!(spec.mass, o.mass);
            let last = &ex.ground_truth[4];
            assert_eq!(last.step, 5);
            assert_eq!(last.poses[j].translation, o.positions[12]);
            assert!((last.time - 10.0 * f64::from(scene.dt_frame)).abs() < 1e-9);
        }

        assert_eq!(
            comparison(&data, 1, 32, 1, 1, Some(3), 10_000)
                .unwrap()
                .request
                .steps,
            3
        );
        let e = comparison(&data, 2, 32, 1, 1, None, 10_000).unwrap_err();
        assert!(e.to_string().contains("--scene 2"), "{e}");
        let e = comparison(&data, 0, 32, 2, 1, None, 10_000).unwrap_err();
        assert!(e.to_string().contains("--start 1"), "{e}");
        let e = comparison(&data, 0, 32, 1, 12, None, 10_000).unwrap_err();
        assert!(e.to_string().contains("no step"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
