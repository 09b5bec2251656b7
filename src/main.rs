//! `dynaserve`: the one binary. Each subcommand lives in the crate that owns the concern; this
//! file only dispatches.

use clap::{Parser, Subcommand};

mod import;
mod view;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Serve, train, evaluate and generate data for learned physics world models.
#[derive(Parser)]
#[command(name = "dynaserve", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the version and the crates this binary is built from.
    Version,
    /// Serve world models over gRPC (default :50051) and HTTP (default :8080). With no flags,
    /// serves every model directory under models/.
    Serve(dynaserve_server::ServeConfig),
    /// Serve a model and show a dataset scene's ground truth beside the model's rollout from
    /// the same start in the browser viewer, with the error against time.
    View(view::ViewArgs),
    /// Run a scene file on a server and print the frames (one JSON line each) or save them.
    Rollout(dynaserve_client::cli::RolloutArgs),
    /// Train a world model from a configuration file, or export a run's checkpoint.
    Train(dynaserve_train::train::TrainArgs),
    /// Score a baseline (static, ballistic, rapier) or a trained model on a dataset split:
    /// translation and orientation RMSE at 0.5, 1, 2 and 4 s, as a table and JSON.
    Eval(dynaserve_train::cli::EvalArgs),
    /// Generate, inspect and preview ground-truth datasets (rapier3d): movi-a, movi-b,
    /// wrecking-ball.
    Sim(dynaserve_sim::cli::SimArgs),
    /// Convert a checkpoint of another implementation into a model directory: `dynaserve
    /// import physiformer --checkpoint FILE --out DIR` for the official PhysiFormer code's.
    Import(import::ImportArgs),
    /// Check that a device (CUDA) computes what the CPU computes: one RigidFormer step and one
    /// PhysiFormer denoiser call on both, as relative errors.
    Parity(dynaserve_train::parity::ParityArgs),
    /// Time RigidFormer's step at several batch sizes on one device (scene-steps per second),
    /// without a server.
    Throughput(dynaserve_train::throughput::ThroughputArgs),
}

fn main() -> anyhow::Result<()> {
    // Parsing the arguments starts no thread, so the compute settings may follow it.
    let cli = Cli::parse();
    let elementwise = match &cli.command {
        Command::Train(args) => args.elementwise_threads(),
        _ => None,
    };
    // SAFETY: no other thread exists yet.
    unsafe { dynaserve_model::configure_compute_split(None, elementwise) };
    dynaserve_model::keep_freed_memory();
    if !matches!(cli.command, Command::Serve(_) | Command::View(_)) {
        default_sigpipe();
    }
    match cli.command {
        Command::Version => {
            println!("dynaserve {}", env!("CARGO_PKG_VERSION"));
            Ok(())
        }
        Command::Serve(config) => dynaserve_server::run(config),
        Command::View(args) => view::run(args),
        Command::Rollout(args) => dynaserve_client::cli::run(args),
        Command::Train(args) => dynaserve_train::train::run_cli(args),
        Command::Eval(args) => dynaserve_train::cli::run_eval(args),
        Command::Sim(args) => dynaserve_sim::cli::run(args),
        Command::Import(args) => import::run(args),
        Command::Parity(args) => dynaserve_train::parity::run(args),
        Command::Throughput(args) => dynaserve_train::throughput::run(args),
    }
}

/// Lets a printing subcommand end quietly when its reader goes away (`dynaserve sim inspect
/// DIR | head`), as Unix tools do, instead of panicking on a broken pipe. The servers keep
/// Rust's default (SIGPIPE ignored): a client closing its socket is an error they handle.
fn default_sigpipe() {
    #[cfg(unix)]
    // SAFETY: called on the main thread before any other thread is started by the command;
    // SIG_DFL is a valid disposition for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
