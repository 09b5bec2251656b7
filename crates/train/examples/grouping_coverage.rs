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

use dynaserve_model::{Device, ObjectInput, load_model};
use dynaserve_sim::DatasetReader;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 5 {
        eprintln!("usage: grouping_coverage SPLIT SCENES COUNTS MODEL_DIR [MODEL_DIR ...]");
        std::process::exit(2);
    }
    let reader = DatasetReader::open(&args[1]).unwrap();
    let scenes: usize = args[2].parse().unwrap();
    let counts: Vec<usize> = args[3].split(',').map(|s| s.parse().unwrap()).collect();
    println!(
        "model                              centres x neighbours  points  objects  grouped mean / min"
    );
    for dir in &args[4..] {
        let model = load_model(Path::new(dir), &Device::Cpu).unwrap();
        let c = model.config();
        for &n in &counts {
            let (mut sum, mut min, mut objects) = (0f64, f64::INFINITY, 0usize);
            for i in 0..scenes.min(reader.len()) {
                let rec = reader.get(i).unwrap();
                let inputs: Vec<ObjectInput> = rec
                    .objects
                    .iter()
                    .map(|o| ObjectInput {
                        reference: o.reference_points[..n.min(o.reference_points.len())].to_vec(),
                        mass: o.mass,
                        friction: o.friction,
                        restitution: o.restitution,
                        kinematic: o.kinematic,
                    })
                    .collect();
                let scene = model.prepare(inputs).unwrap();
                for j in 0..scene.len() {
                    let share = scene.grouped_points(j).unwrap() as f64
                        / scene.points_of(j).unwrap() as f64;
                    sum += share;
                    min = min.min(share);
                    objects += 1;
                }
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
}
