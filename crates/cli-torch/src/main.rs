//! `pi3det-torch`: the detector commands of `pi3det` (`train`, `detect`, `adapt`, `autolabel`,
//! `run`, `export`, `demo`, `bench suite / real / nn / sparse / live`), the part that links libtorch. `pi3det` hands these commands over with their arguments verbatim, so
//! `pi3det train --help` is this binary's help; it can also be run directly.

use clap::{Parser, Subcommand};
use pi3det_cli_torch as cmd;
use pi3det_nn::NnError;

#[derive(Parser)]
#[command(
    name = "pi3det-torch",
    version,
    about = "pi3det's detector commands (libtorch); usually run through `pi3det`"
)]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Train a detector (PointPillars, anchor or center head) from a TOML config.
    Train(cmd::TrainArgs),
    /// Run a trained detector over a dataset; write JSON lines and result.pkl, with latency.
    Detect(cmd::DetectArgs),
    /// Pi3DET-Net: adapt a source-trained detector to a target platform without target labels.
    Adapt(cmd::AdaptArgs),
    /// Label frames with several detectors × test-time augmentation, box fusion and tracking.
    Autolabel(pi3det_cli_torch::autolabel::AutolabelArgs),
    /// Run a detector on a live or recorded stream (Ouster UDP, ROS 2 bag, dataset) into JSON
    /// lines / Foxglove MCAP, with latency percentiles.
    Run(pi3det_cli_torch::run::RunArgs),
    /// Export a checkpoint's network as TorchScript (model.pt [+ model.roi.pt] + model.json).
    Export(pi3det_cli_torch::export::ExportArgs),
    /// Simulate vehicle/drone/quadruped data, train on the vehicle, evaluate on all three.
    Demo(pi3det_cli_torch::demo::DemoArgs),
    /// The old name of `bench suite`, still accepted.
    #[command(hide = true)]
    Benchmark(pi3det_cli_torch::benchmark::BenchmarkArgs),
    /// Measurements that print a table: speed (nn, sparse, live) and accuracy (suite, real).
    #[command(subcommand)]
    Bench(BenchCommand),
}

#[derive(Subcommand)]
enum BenchCommand {
    /// The cross-platform benchmark: methods × detectors × tasks as resumable, shardable cells → the paper's tables.
    Suite(pi3det_cli_torch::benchmark::BenchmarkArgs),
    /// Our detector's training step and inference against PyTorch running the same network.
    Nn(cmd::BenchNnArgs),
    /// `pi3det run` end to end on loopback: latency per sweep (with and without VPP) and a soak.
    Live(pi3det_cli_torch::bench_live::BenchLiveArgs),
    /// The sparse 3-D backbone (forward + backward) against the same network as dense conv3d.
    Sparse(cmd::BenchSparseArgs),
    /// A checkpoint on every real labelled set (KITTI, Argoverse 1, nuScenes), no per-set flags: one table.
    Real(pi3det_cli_torch::bench_real::BenchRealArgs),
}

fn main() -> std::process::ExitCode {
    pi3det_nn::device::keep_freed_memory();
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .without_time()
        .init();
    let mut args = std::env::args_os();
    let program = args.next().unwrap_or_else(|| "pi3det".into());
    let cli = Cli::parse_from(std::iter::once(program).chain(cmd::rewrite_old_switches(args.collect())));
    if let Some(n) = cli.threads {
        // Ignored if rayon was already initialised, which cannot happen this early.
        let _ = rayon::ThreadPoolBuilder::new().num_threads(n).build_global();
    }
    let result = match &cli.command {
        Command::Train(args) => cmd::run_train(args).map_err(anyhow::Error::from),
        Command::Detect(args) => cmd::run_detect(args).map_err(anyhow::Error::from),
        Command::Adapt(args) => cmd::run_adapt(args).map(|_| ()).map_err(anyhow::Error::from),
        Command::Autolabel(args) => pi3det_cli_torch::autolabel::run_autolabel(args),
        Command::Run(args) => pi3det_cli_torch::run::run(args),
        Command::Export(args) => pi3det_cli_torch::export::run(args),
        Command::Demo(args) => pi3det_cli_torch::demo::run_demo(args).map(|_| ()),
        Command::Benchmark(args) | Command::Bench(BenchCommand::Suite(args)) => {
            pi3det_cli_torch::benchmark::run(args).map(|_| ())
        }
        Command::Bench(BenchCommand::Live(args)) => pi3det_cli_torch::bench_live::run(args),
        Command::Bench(BenchCommand::Real(args)) => pi3det_cli_torch::bench_real::run(args),
        Command::Bench(BenchCommand::Nn(args)) => cmd::run_bench_nn(args, &mut |n| {
            pi3det_cli_torch::frames::vehicle_frames(n).map_err(|e| NnError::Input(format!("simulation: {e}")))
        })
        .map_err(anyhow::Error::from),
        Command::Bench(BenchCommand::Sparse(args)) => cmd::run_bench_sparse(args, &mut |n| {
            pi3det_cli_torch::frames::vehicle_frames(n).map_err(|e| NnError::Input(format!("simulation: {e}")))
        })
        .map_err(anyhow::Error::from),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", pi3det_data::error::report(e.as_ref()));
            std::process::ExitCode::FAILURE
        }
    }
}
