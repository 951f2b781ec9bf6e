//! `pi3det eval` before it is mounted in the binary: the same arguments and output.
//!
//! `cargo run --release -p pi3det-eval --features cli --example eval_files -- --gt DATASET --det DETECTIONS [--json]`

use clap::Parser;

#[derive(Parser)]
#[command(name = "eval_files")]
struct Cli {
    #[command(flatten)]
    eval: pi3det_eval::cli::EvalArgs,
}

fn main() {
    let cli = Cli::parse();
    if let Err(e) = pi3det_eval::cli::run(&cli.eval) {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}
