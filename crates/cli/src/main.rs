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
}

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
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
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
