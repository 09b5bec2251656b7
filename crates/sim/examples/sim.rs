//! The `dynaserve sim` subcommand on its own, for generating or inspecting ground truth without
//! building the model and server crates:
//!
//! ```sh
//! cargo run -p dynaserve-sim --example sim -- mesh-d1 --scenes 400 --out data/physi/d1/train
//! cargo run -p dynaserve-sim --example sim -- inspect data/physi/d1/train
//! ```

use clap::Parser;

/// Arguments: everything after `dynaserve sim`.
#[derive(Parser)]
#[command(
    name = "sim",
    about = "dynaserve sim: generate, inspect and preview datasets"
)]
struct Args {
    #[command(flatten)]
    sim: dynaserve_sim::cli::SimArgs,
}

fn main() -> anyhow::Result<()> {
    dynaserve_sim::cli::run(Args::parse().sim)
}
