//! Writes a randomly initialised RigidFormer checkpoint, for trying the server (or measuring
//! it) before a trained checkpoint is available. Its predictions are meaningless; its cost per
//! step is that of a trained model of the same configuration.
//!
//! ```text
//! cargo run --release -p dynaserve-server --example random_checkpoint -- DIR [small|tiny|paper]
//! ```

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let dir = args
        .next()
        .ok_or_else(|| anyhow::anyhow!("usage: random_checkpoint DIR [small|tiny|paper]"))?;
    let config = match args.next().as_deref() {
        None | Some("small") => dynaserve_model::ModelConfig::small(),
        Some("tiny") => dynaserve_model::ModelConfig::tiny(),
        Some("paper") => dynaserve_model::ModelConfig::paper(),
        Some(other) => anyhow::bail!("unknown configuration {other:?} (small, tiny or paper)"),
    };
    dynaserve_model::RigidFormer::new(config, 1, &dynaserve_model::Device::Cpu)?
        .save(std::path::Path::new(&dir))?;
    println!("wrote a random-init checkpoint to {dir}");
    Ok(())
}
