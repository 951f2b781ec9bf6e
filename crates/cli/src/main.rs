//! `pi3det`: perspective-invariant LiDAR 3D object detection (Pi3DET) from the command line.

mod cmd;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "pi3det", version, about = "Perspective-invariant LiDAR 3D object detection toolkit")]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Detect a dataset's format and print its statistics (paper appendix Table 6).
    Info(cmd::info::InfoArgs),
    /// Simulate vehicle / drone / quadruped LiDAR sequences in the Pi3DET layout.
    Simulate(pi3det_sim::cli::SimulateArgs),
    /// KITTI-protocol AP (R11/R40; bbox, BEV, 3D, AOS) of detections against ground truth.
    Eval(pi3det_eval::cli::EvalArgs),
    /// Platform-discrepancy statistics, tables and figures (paper §3.3, Fig. 2), with pose-free attitude.
    Stats(pi3det_analysis::cli::StatsArgs),
    /// Benchmarks that print a table.
    #[command(subcommand)]
    Bench(BenchCommand),
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Simulator throughput (frames/s, rays/s) for a 64×1024 scan.
    Sim(pi3det_sim::cli::BenchArgs),
}

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .without_time()
        .init();
    let cli = Cli::parse();
    if let Some(n) = cli.threads {
        // Ignored if rayon was already initialised, which cannot happen this early.
        let _ = rayon::ThreadPoolBuilder::new().num_threads(n).build_global();
    }
    let result = match &cli.command {
        Command::Info(args) => cmd::info::run(args),
        Command::Simulate(args) => pi3det_sim::cli::run(args).map_err(anyhow::Error::from),
        Command::Eval(args) => pi3det_eval::cli::run(args).map_err(anyhow::Error::from),
        Command::Stats(args) => pi3det_analysis::cli::run(args).map_err(anyhow::Error::from),
        Command::Bench(BenchCommand::Sim(args)) => pi3det_sim::cli::run_bench(args).map_err(anyhow::Error::from),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
