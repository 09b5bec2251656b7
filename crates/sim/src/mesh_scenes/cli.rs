//! `dynaserve sim mesh-d1` ... `mesh-d4`, and `sim inspect` / `sim preview` on mesh datasets.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;

use super::preview::write_mesh_preview;
use super::reader::MeshDatasetReader;
use super::sets::MeshSet;
use super::stats::inspect_mesh;
use super::writer::{MeshGenerateOptions, generate_mesh_dataset};
use crate::cli::split_args::{SplitArgs, scene_progress, worker_pool};

/// Options of the mesh set generators.
#[derive(Args, Debug, Clone)]
pub struct MeshGenerateArgs {
    /// What every split generator takes.
    #[command(flatten)]
    pub split_args: SplitArgs,
    /// Scenes per shard file.
    #[arg(long, default_value_t = 200)]
    pub scenes_per_shard: usize,
}

/// Generates a mesh split and prints what it wrote and how long it took.
pub fn run_generate(set: MeshSet, a: &MeshGenerateArgs) -> anyhow::Result<()> {
    let t = &a.split_args;
    t.check()?;
    if a.scenes_per_shard == 0 {
        bail!("--scenes-per-shard must be at least 1");
    }
    let mut opts = MeshGenerateOptions::new(set, t.seed, t.split.name(), t.scenes);
    opts.scenes_per_shard = a.scenes_per_shard;
    let pool = worker_pool(t.threads)?;
    let bar = scene_progress(t.scenes)?;
    let start = Instant::now();
    let cpu0 = cpu_seconds();
    let summary = pool
        .install(|| generate_mesh_dataset(&opts, &t.out, t.overwrite, &|| bar.inc(1)))
        .with_context(|| format!("generating {} into {}", set.name(), t.out.display()))?;
    bar.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    let m = &summary.manifest;
    let n = m.scenes.max(1) as f64;
    println!(
        "{} / {} (seed {}): {} scenes, {} objects ({:.2} per scene), {} vertices ({:.1} per \
         scene), {} faces, {} frames at {:.4} s",
        m.generator,
        m.split,
        m.seed,
        m.scenes,
        m.objects,
        m.objects as f64 / n,
        m.vertices,
        m.vertices as f64 / n,
        m.faces,
        m.frames,
        m.dt_frame
    );
    println!(
        "wrote {} shards, {:.2} MB ({:.1} kB per scene) to {}",
        m.shards.len(),
        summary.bytes as f64 / 1e6,
        summary.bytes as f64 / 1e3 / n,
        summary.dir.display()
    );
    let cpu = cpu_seconds().zip(cpu0).map(|(b, a)| b - a);
    println!(
        "took {:.1} s wall ({:.1} scenes/s, {:.0} ms per scene) on {} threads{}",
        secs,
        m.scenes as f64 / secs,
        1e3 * secs / n,
        pool.current_num_threads(),
        cpu.map(|c| format!(", {c:.1} s CPU ({:.0} ms per scene)", 1e3 * c / n))
            .unwrap_or_default()
    );
    Ok(())
}

/// CPU time of this process (user + system), seconds; `None` where /proc is unavailable.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let rest = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// `sim inspect` on a mesh split.
pub fn run_inspect(dir: &Path, limit: Option<usize>, json: bool) -> anyhow::Result<()> {
    let reader = MeshDatasetReader::open(dir)?;
    let stats = inspect_mesh(&reader, limit)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&stats)?);
    } else {
        print!("{stats}");
    }
    Ok(())
}

/// `sim preview` on a mesh split: scene `scene` and its most deformed object (or its first,
/// when nothing deforms).
pub fn run_preview(dir: &Path, scene: usize, out: &Path) -> anyhow::Result<()> {
    let reader = MeshDatasetReader::open(dir)?;
    if scene >= reader.len() {
        bail!(
            "--scene {scene} is out of range: the split has {} scenes",
            reader.len()
        );
    }
    let s = reader.get(scene)?;
    let m = reader.manifest();
    let title = format!("{} / {}: scene {scene}", m.generator, m.split);
    let (object, with_text) = write_mesh_preview(&s, m.bounds, &title, out)?;
    println!(
        "wrote {} (object {object}, {}){}",
        out.display(),
        s.objects[object].material.name(),
        if with_text {
            ""
        } else {
            " (without text: no usable font)"
        }
    );
    Ok(())
}
