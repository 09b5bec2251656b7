//! Generates a MOVi-like dataset split with the simulator's library API (the same function
//! `dynaserve sim` calls): `generate <movi-a|movi-b> <scenes> <out dir> <seed> <split>`.

use std::sync::atomic::{AtomicUsize, Ordering};

use dynaserve_sim::generators::generate_dataset;
use dynaserve_sim::{GenerateOptions, Generator};

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.len() != 5 {
        anyhow::bail!("usage: generate <movi-a|movi-b> <scenes> <out dir> <seed> <split>");
    }
    let generator = match a[0].as_str() {
        "movi-a" => Generator::movi_a(),
        "movi-b" => Generator::movi_b(),
        other => anyhow::bail!("unknown generator {other:?}"),
    };
    let scenes: usize = a[1].parse()?;
    let seed: u64 = a[3].parse()?;
    let opts = GenerateOptions::new(generator, seed, &a[4], scenes);
    let done = AtomicUsize::new(0);
    let t = std::time::Instant::now();
    let summary = generate_dataset(&opts, std::path::Path::new(&a[2]), false, &|| {
        let n = done.fetch_add(1, Ordering::Relaxed) + 1;
        if n % 100 == 0 {
            eprintln!("{n}/{scenes} scenes");
        }
    })?;
    println!(
        "{} scenes, {} objects, {} bytes in {:.1} s -> {}",
        summary.manifest.scenes,
        summary.manifest.objects,
        summary.bytes,
        t.elapsed().as_secs_f64(),
        summary.dir.display()
    );
    Ok(())
}
