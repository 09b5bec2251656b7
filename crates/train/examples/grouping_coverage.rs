//! Share of each object's points that the encoder's set abstraction groups (and so passes to
//! the object token), by point count, for one or more models on a dataset's reference clouds.
//!
//! ```sh
//! cargo run --release -p dynaserve-train --example grouping_coverage -- \
//!     data/movi-b/test 50 96,256,512,1024 models/rigidformer-small runs/init-r72
//! ```
//!
//! Arguments: dataset split, number of scenes, point counts (a prefix of each stored cloud,
//! as `dynaserve eval --points-per-object` gives), then model directories. Prints, per model
//! and point count, the mean and smallest share of an object's points that fall in at least
//! one of its `sa_centres` groups of `sa_neighbours` nearest points.
use std::path::Path;

use anyhow::{Context, bail};
use dynaserve_sim::DatasetReader;
use dynaserve_train::eval::ModelPredictor;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 5 {
        bail!("usage: grouping_coverage SPLIT SCENES COUNTS MODEL_DIR [MODEL_DIR ...]");
    }
    let reader = DatasetReader::open(&args[1]).with_context(|| format!("opening {}", args[1]))?;
    let scenes: usize = args[2].parse().context("SCENES must be a count")?;
    let counts = args[3]
        .split(',')
        .map(|s| s.parse::<usize>())
        .collect::<Result<Vec<_>, _>>()
        .context("COUNTS must be comma-separated point counts")?;
    println!(
        "model                              centres x neighbours  points  objects  grouped mean / min"
    );
    for dir in &args[4..] {
        let base =
            ModelPredictor::load(Path::new(dir)).with_context(|| format!("loading {dir}"))?;
        let c = base.model().config();
        for &n in &counts {
            // The evaluation's own selection: the first `n` stored points of each object.
            let predictor = base.clone().with_points_per_object(n);
            let (mut sum, mut min, mut objects) = (0f64, f64::INFINITY, 0usize);
            for i in 0..scenes.min(reader.len()) {
                let scene = predictor
                    .model()
                    .prepare(predictor.inputs(&reader.get(i)?))?;
                for j in 0..scene.len() {
                    let grouped = scene.grouped_points(j).context("object index in range")?;
                    let points = scene.points_of(j).context("object index in range")?;
                    let share = grouped as f64 / points as f64;
                    sum += share;
                    min = min.min(share);
                    objects += 1;
                }
            }
            if objects == 0 {
                bail!("no objects in the first {scenes} scenes of {}", args[1]);
            }
            println!(
                "{dir:<34} {:>7} x {:<10}  {n:>6}  {objects:>7}  {:.3} / {:.3}",
                c.sa_centres,
                c.sa_neighbours,
                sum / objects as f64,
                min
            );
        }
    }
    Ok(())
}
