//! `dynaserve train` without the rest of the binary (same arguments, same code path):
//! `cargo run --release -p dynaserve-train --example train -- --config FILE [--resume]`.

use clap::Parser;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    args: dynaserve_train::train::TrainArgs,
}

fn main() -> anyhow::Result<()> {
    let args = Cli::parse().args;
    // SAFETY: parsing starts no thread; no other thread exists yet.
    unsafe { dynaserve_model::configure_compute_split(None, args.elementwise_threads()) };
    dynaserve_train::train::run_cli(args)
}
