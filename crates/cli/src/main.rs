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
    /// Train a detector (PointPillars, anchor or center head) from a TOML config.
    #[cfg(feature = "nn")]
    Train(pi3det_nn::cli::TrainArgs),
    /// Run a trained detector over a dataset; write JSON lines and result.pkl, with latency.
    #[cfg(feature = "nn")]
    Detect(pi3det_nn::cli::DetectArgs),
    /// Simulate vehicle/drone/quadruped data, train on the vehicle, evaluate on all three.
    #[cfg(feature = "nn")]
    Demo(pi3det_nn::cli::DemoArgs),
    /// Benchmarks that print a table.
    #[command(subcommand)]
    Bench(BenchCommand),
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Simulator throughput (frames/s, rays/s) for a 64×1024 scan.
    Sim(pi3det_sim::cli::BenchArgs),
    /// Our detector's training step and inference against PyTorch running the same network.
    #[cfg(feature = "nn")]
    Nn(pi3det_nn::cli::BenchNnArgs),
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
        #[cfg(feature = "nn")]
        Command::Train(args) => pi3det_nn::cli::run_train(args).map_err(anyhow::Error::from),
        #[cfg(feature = "nn")]
        Command::Detect(args) => pi3det_nn::cli::run_detect(args).map_err(anyhow::Error::from),
        #[cfg(feature = "nn")]
        Command::Demo(args) => pi3det_nn::cli::run_demo(args).map_err(anyhow::Error::from),
        #[cfg(feature = "nn")]
        Command::Bench(BenchCommand::Nn(args)) => pi3det_nn::cli::run_bench_nn(args).map_err(anyhow::Error::from),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
