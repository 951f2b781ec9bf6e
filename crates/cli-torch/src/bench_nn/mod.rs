//! `pi3det bench nn`: our training step and end-to-end inference against PyTorch running the same
//! network on the same inputs. The frames come from `--data`, else from the caller (the
//! `pi3det-torch` binary simulates one vehicle sequence), so this crate needs no simulator.

pub mod side_by_side;

use std::path::{Path, PathBuf};

use pi3det_data::Frame;

use crate::args::{open_subset, DeviceArgs};
use crate::presets::CPU_PRESET;
use pi3det_nn::config::DetectorConfig;
use pi3det_nn::error::{NnError, Result};
use side_by_side::Timing;

/// Time our training step and end-to-end inference against PyTorch running the same network on
/// the same inputs (the installed torch, through `crates/cli-torch/python/bench_pointpillars.py`).
#[derive(clap::Args, Debug, Clone)]
pub struct BenchNnArgs {
    /// Detector config with an anchor head [default: the built-in CPU preset].
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Frames to use (the first `batch size` frames); default: one simulated vehicle sequence.
    #[arg(long, value_name = "PATH")]
    pub data: Option<PathBuf>,
    #[arg(long, default_value_t = 20)]
    pub iters: usize,
    #[arg(long, default_value_t = 3)]
    pub warmup: usize,
    /// Python with torch [default: the repository's .venv/bin/python, else python3].
    #[arg(long)]
    pub python: Option<PathBuf>,
    /// Skip the PyTorch side.
    #[arg(long)]
    pub no_torch: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// The PyTorch side, `crates/cli-torch/python/bench_pointpillars.py`.
const TORCH_SCRIPT: &str = include_str!("../../python/bench_pointpillars.py");

fn repo_path(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

/// Runs the benchmark and prints its table (or JSON). Without `--data`, `default_frames(n)`
/// supplies the `n` frames (n = the config's batch size).
pub fn run_bench_nn(args: &BenchNnArgs, default_frames: &mut dyn FnMut(usize) -> Result<Vec<Frame>>) -> Result<()> {
    let mut cfg = match &args.config {
        Some(p) => DetectorConfig::from_file(p)?,
        None => DetectorConfig::from_toml_str(CPU_PRESET)?,
    };
    args.device.apply_precision(&mut cfg);
    let threads = args.device.threads(cfg.train.threads);
    let device = args.device.setup(cfg.train.threads)?;
    let n = cfg.train.batch_size.max(1);
    let frames: Vec<Frame> = match &args.data {
        Some(p) => {
            let s = open_subset(p, Some("train"), None, 0)?;
            s.indices.iter().take(n).map(|&i| s.dataset.load(i).map_err(NnError::from)).collect::<Result<_>>()?
        }
        None => default_frames(n)?,
    };
    let prep = pi3det_nn::preprocess::Preprocessor::new(&cfg)?;
    let samples = frames.iter().map(|f| prep.sample(f, 1)).collect();
    let exchange = std::env::temp_dir().join(format!("pi3det-bench-nn-{}", std::process::id()));
    let python = if args.no_torch {
        None
    } else {
        let py = args.python.clone().unwrap_or_else(|| {
            let venv = repo_path(".venv/bin/python");
            if venv.exists() {
                venv
            } else {
                PathBuf::from("python3")
            }
        });
        // The script travels inside the binary, so a binary run away from its checkout (on a
        // GPU machine, say) still has it.
        std::fs::create_dir_all(&exchange).map_err(|e| NnError::io(&exchange, e))?;
        let script = exchange.join("bench_pointpillars.py");
        std::fs::write(&script, TORCH_SCRIPT).map_err(|e| NnError::io(&script, e))?;
        Some((py, script))
    };
    let report = side_by_side::run(&side_by_side::BenchOptions {
        config: cfg,
        samples,
        device,
        threads,
        iters: args.iters,
        warmup: args.warmup,
        exchange: exchange.clone(),
        python,
    });
    let _ = std::fs::remove_dir_all(&exchange);
    let r = report?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&r).unwrap_or_default());
        return Ok(());
    }
    println!(
        "{} on {} ({} libtorch thread(s), backbone in {}); {} points/frame, {} pillars (inference), batch {} ({} pillars) for training",
        r.config, r.device, r.torch_threads, r.compute_kind, r.points_per_frame, r.infer_pillars, r.batch_size, r.train_pillars
    );
    println!("| | ours (median ms) | PyTorch (median ms) | ours / PyTorch |");
    println!("|---|---:|---:|---:|");
    let opt = |t: Option<Timing>| t.map(|t| format!("{:.1}", t.median_ms)).unwrap_or_else(|| "–".into());
    let ratio = |r: Option<f64>| r.map(|r| format!("{r:.2}")).unwrap_or_else(|| "–".into());
    let [f, l, b, u] = r.train_parts_ms;
    println!(
        "| training step (forward {f:.0} + loss {l:.0} + backward {b:.0} + clip/AdamW {u:.0}) | {:.1} | {} | {} |",
        r.train_step.median_ms,
        opt(r.torch_train_step),
        ratio(r.train_ratio)
    );
    println!(
        "| inference: pillarize {:.1} + network {:.1} + decode/NMS {:.1} vs network forward | {:.1} | {} | {} |",
        r.pillarize.median_ms,
        r.network.median_ms,
        r.post.median_ms,
        r.inference.median_ms,
        opt(r.torch_forward),
        ratio(r.inference_ratio)
    );
    if let Some(v) = &r.torch_version {
        println!("(PyTorch {v})");
    }
    Ok(())
}
