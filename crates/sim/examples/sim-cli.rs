//! `simulate` and `bench` exactly as `pi3det simulate` / `pi3det bench sim` wire them.

use clap::{Parser, Subcommand};

#[derive(Parser)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    Simulate(pi3det_sim::cli::SimulateArgs),
    Bench(pi3det_sim::cli::BenchArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Simulate(a) => pi3det_sim::cli::run(a),
        Command::Bench(a) => pi3det_sim::cli::run_bench(a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
