//! `pi3det`: perspective-invariant LiDAR 3D object detection (Pi3DET) from the command line.
//!
//! This binary does not link libtorch: the detector commands ([`cmd::torch::FORWARDED`]) are
//! listed here but run in `pi3det-torch` (crates/cli-torch), see [`cmd::torch`].

mod cmd;

use clap::{Parser, Subcommand};
use cmd::torch::Forwarded;

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
    /// Write datasets (e.g. the full Pi3DET sequence release: Ouster packets in HDF5) in the released Pi3DET layout.
    Convert(cmd::convert::ConvertArgs),
    /// Simulate vehicle / drone / quadruped LiDAR sequences in the Pi3DET layout.
    Simulate(pi3det_sim::cli::SimulateArgs),
    /// KITTI-protocol AP (R11/R40; bbox, BEV, 3D, AOS) of detections against ground truth.
    Eval(pi3det_eval::cli::EvalArgs),
    /// Platform-discrepancy statistics, tables and figures (paper §3.3, Fig. 2), with pose-free attitude.
    Stats(pi3det_analysis::cli::StatsArgs),
    /// Fuse several detectors' boxes by kernel-density box fusion (MS3D++) into one label set.
    Fuse(pi3det_autolabel::cli::fuse::FuseArgs),
    /// Track labels over sequences (Kalman filter, GIoU + Hungarian), interpolating missed frames.
    Track(pi3det_autolabel::cli::track::TrackArgs),
    /// Draw 3-D boxes into the camera images through the calibration; flag boxes no camera sees.
    Project(pi3det_autolabel::cli::project::ProjectArgs),
    /// Write one self-contained HTML page (WebGL2) showing points, ground truth and detections.
    View(pi3det_viewer::cli::ViewArgs),
    /// Serve the viewer with box editing on loopback; saves write a new label set beside the data.
    Annotate(pi3det_viewer::cli::AnnotateArgs),
    /// Train a detector (PointPillars, anchor or center head) from a TOML config.
    Train(Forwarded),
    /// Run a trained detector over a dataset; write JSON lines and result.pkl, with latency.
    Detect(Forwarded),
    /// Pi3DET-Net: adapt a source-trained detector to a target platform without target labels.
    Adapt(Forwarded),
    /// Label frames with several detectors × test-time augmentation, box fusion and tracking.
    Autolabel(Forwarded),
    /// Run a detector on a live or recorded stream (Ouster UDP, ROS 2 bag, dataset) into JSON
    /// lines / Foxglove MCAP, with latency percentiles.
    Run(Forwarded),
    /// Export a checkpoint's network as TorchScript (model.pt [+ model.roi.pt] + model.json).
    Export(Forwarded),
    /// Simulate vehicle/drone/quadruped data, train on the vehicle, evaluate on all three.
    Demo(Forwarded),
    /// The old name of `bench suite`, still accepted.
    #[command(hide = true)]
    Benchmark(Forwarded),
    /// Measurements that print a table: speed (sim, sequence, nn, sparse, live) and accuracy
    /// (suite, real, autolabel).
    #[command(subcommand)]
    Bench(BenchCommand),
}

#[derive(Subcommand)]
enum BenchCommand {
    /// The cross-platform benchmark: methods × detectors × tasks as resumable, shardable cells → the paper's tables.
    Suite(Forwarded),
    /// Simulator throughput (frames/s, rays/s) for a 64×1024 scan.
    Sim(pi3det_sim::cli::BenchArgs),
    /// Box fusion and tracking against ground truth with simulated detectors, and their speed.
    Autolabel(pi3det_autolabel::cli::bench::BenchArgs),
    /// Decoding the full release's sequences (HDF5 + LZF + Ouster packets → points): frames/s.
    Sequence(cmd::convert::BenchSequenceArgs),
    /// Our detector's training step and inference against PyTorch running the same network.
    Nn(Forwarded),
    /// `pi3det run` end to end on loopback: latency per sweep (with and without VPP) and a soak.
    Live(Forwarded),
    /// The sparse 3-D backbone (forward + backward) against the same network as dense conv3d.
    Sparse(Forwarded),
    /// A checkpoint on every real labelled set (KITTI, Argoverse 1, nuScenes), no per-set flags: one table.
    Real(Forwarded),
}

fn main() -> std::process::ExitCode {
    // The detector commands, and `help` for them, go to pi3det-torch with the arguments as given.
    let args: Vec<std::ffi::OsString> = std::env::args_os().skip(1).collect();
    if cmd::torch::is_help_for_forwarded(&args) || cmd::torch::forwarded(&args).is_some() {
        return finish(cmd::torch::run(&args));
    }
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .without_time()
        .init();
    if let Some(n) = cli.threads {
        // Ignored if rayon was already initialised, which cannot happen this early.
        let _ = rayon::ThreadPoolBuilder::new().num_threads(n).build_global();
    }
    let result = match &cli.command {
        Command::Info(args) => cmd::info::run(args),
        Command::Convert(args) => cmd::convert::run(args),
        Command::Bench(BenchCommand::Sequence(args)) => cmd::convert::run_bench(args),
        Command::Simulate(args) => pi3det_sim::cli::run(args).map_err(anyhow::Error::from),
        Command::Eval(args) => pi3det_eval::cli::run(args).map_err(anyhow::Error::from),
        Command::Stats(args) => pi3det_analysis::cli::run(args).map_err(anyhow::Error::from),
        Command::Fuse(args) => pi3det_autolabel::cli::fuse::run(args).map_err(anyhow::Error::from),
        Command::Track(args) => pi3det_autolabel::cli::track::run(args).map_err(anyhow::Error::from),
        Command::Bench(BenchCommand::Autolabel(args)) => {
            pi3det_autolabel::cli::bench::run(args).map_err(anyhow::Error::from)
        }
        Command::Project(args) => pi3det_autolabel::cli::project::run(args).map(|_| ()).map_err(anyhow::Error::from),
        Command::View(args) => pi3det_viewer::cli::run_view(args).map_err(anyhow::Error::from),
        Command::Annotate(args) => pi3det_viewer::cli::run_annotate(args).map_err(anyhow::Error::from),
        Command::Bench(BenchCommand::Sim(args)) => pi3det_sim::cli::run_bench(args).map_err(anyhow::Error::from),
        Command::Train(_)
        | Command::Detect(_)
        | Command::Adapt(_)
        | Command::Autolabel(_)
        | Command::Demo(_)
        | Command::Benchmark(_)
        | Command::Run(_)
        | Command::Export(_)
        | Command::Bench(
            BenchCommand::Suite(_)
            | BenchCommand::Nn(_)
            | BenchCommand::Live(_)
            | BenchCommand::Sparse(_)
            | BenchCommand::Real(_),
        ) => {
            unreachable!("handed to pi3det-torch above")
        }
    };
    finish(result.map(|()| std::process::ExitCode::SUCCESS))
}

fn finish(result: anyhow::Result<std::process::ExitCode>) -> std::process::ExitCode {
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", pi3det_data::error::report(e.as_ref()));
            std::process::ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    /// The subcommands declared with [`Forwarded`] arguments are exactly [`cmd::torch::FORWARDED`].
    #[test]
    fn forwarded_variants_match_the_list() {
        fn walk(c: &clap::Command, prefix: &str, out: &mut Vec<String>) {
            for s in c.get_subcommands() {
                let name = format!("{prefix}{}", s.get_name());
                if s.get_arguments().any(|a| a.get_id() == "args" && a.is_trailing_var_arg_set()) {
                    out.push(name);
                } else {
                    walk(s, &format!("{name} "), out);
                }
            }
        }
        let mut declared = Vec::new();
        walk(&Cli::command(), "", &mut declared);
        let mut listed: Vec<String> = cmd::torch::FORWARDED.iter().map(|s| s.to_string()).collect();
        declared.sort();
        listed.sort();
        assert_eq!(declared, listed);
    }
}
