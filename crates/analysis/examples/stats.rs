//! `pi3det stats` without the `pi3det` binary:
//! `cargo run --release -p pi3det-analysis --features cli --example stats -- DATA... --out report/`

use clap::Parser;

#[derive(Parser)]
#[command(name = "stats", about = "Platform-discrepancy statistics and pose-free attitude")]
struct Cli {
    #[command(flatten)]
    args: pi3det_analysis::cli::StatsArgs,
}

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .without_time()
        .init();
    match pi3det_analysis::cli::run(&Cli::parse().args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
