//! The neural-network subcommands as a standalone binary, mounted exactly as `pi3det` mounts them
//! (useful before the main CLI wires them, and as the reference for that wiring):
//! `cargo run --release -p pi3det-nn --features cli --example pi3det_nn -- train --config …`.

use clap::{Parser, Subcommand};
use pi3det_nn::cli;

#[derive(Parser)]
#[command(name = "pi3det-nn")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Train a detector from a TOML config.
    Train(cli::TrainArgs),
    /// Run a trained detector over a dataset.
    Detect(cli::DetectArgs),
    /// Simulate, train on the vehicle, evaluate on all platforms.
    Demo(cli::DemoArgs),
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        what: BenchCommand,
    },
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Our training step and inference against PyTorch running the same network.
    Nn(cli::BenchNnArgs),
}

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .without_time()
        .init();
    let r = match Cli::parse().command {
        Command::Train(a) => cli::run_train(&a),
        Command::Detect(a) => cli::run_detect(&a),
        Command::Demo(a) => cli::run_demo(&a),
        Command::Bench { what: BenchCommand::Nn(a) } => cli::run_bench_nn(&a),
    };
    match r {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
