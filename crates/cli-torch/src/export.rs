//! `pi3det export`: a checkpoint's network as TorchScript (see `pi3det_nn::export` for the
//! files and their contract), traced on one real or simulated frame.
//!
//! `pi3det export --ckpt runs/pp/final.safetensors --format torchscript --out model.pt`

use std::path::PathBuf;

use crate::args::{open_subset, DeviceArgs};
use anyhow::{bail, Context, Result};
use pi3det_nn::data_loader::prepare_frame;
use pi3det_nn::export::{config_path, example_path, export, roi_path};

/// Export a checkpoint's network as TorchScript (model.pt [+ model.roi.pt] + model.json).
#[derive(clap::Args, Debug, Clone)]
pub struct ExportArgs {
    /// Checkpoint (.safetensors) of `pi3det train` or `pi3det adapt`.
    #[arg(long)]
    pub ckpt: PathBuf,
    /// Only `torchscript`: ONNX needs an exporter that is not part of libtorch's C++ API.
    #[arg(long, default_value = "torchscript")]
    pub format: String,
    /// The model file (`.pt`); its description (`.json`: config, output shapes), the traced
    /// frame's inputs and output (`.example.npz`) and a two-stage model's second stage
    /// (`.roi.pt`) go beside it.
    #[arg(long)]
    pub out: PathBuf,
    /// Trace on the first frame of this dataset (default: a simulated vehicle frame).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Replace files an earlier export left.
    #[arg(long)]
    pub overwrite: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

pub fn run(args: &ExportArgs) -> Result<()> {
    match args.format.as_str() {
        "torchscript" => {}
        "onnx" => bail!(
            "--format onnx: libtorch's C++ API (what tch links) has no ONNX exporter — it lives in PyTorch's Python \
             package; export TorchScript and convert it in Python with torch.onnx if you need ONNX"
        ),
        other => bail!("--format {other}: unknown (torchscript)"),
    }
    if args.out.extension().is_none_or(|e| e != "pt") {
        bail!("--out {}: the model file must end in .pt", args.out.display());
    }
    let files = [args.out.clone(), roi_path(&args.out), config_path(&args.out), example_path(&args.out)];
    if !args.overwrite {
        if let Some(f) = files.iter().find(|f| f.exists()) {
            bail!("{} exists; pass --overwrite to replace it", f.display());
        }
    }
    let device = args.device.setup(0)?;
    let (mut det, _) = pi3det_nn::checkpoint::load_detector(&args.ckpt, device)?;
    let frame = match &args.data {
        Some(d) => {
            let s = open_subset(d, None, None, 1)?;
            let i = *s.indices.first().with_context(|| format!("{}: no frames", d.display()))?;
            s.dataset.load(i)?
        }
        None => crate::frames::vehicle_frames(1)?.into_iter().next().context("the simulator gave no frame")?,
    };
    let prep = det.prep.clone();
    let p = prepare_frame(&prep, &[], &frame, false, 0)?;
    let x = prep.collate_inputs(&[&p.pillars]);
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
    }
    let written = export(&mut det, &x, &args.out)?;
    println!("traced on frame {} ({} pillars)", frame.info.id, p.pillars.len());
    println!("{}", written.dense.display());
    if let Some(r) = &written.roi {
        println!("{}", r.display());
    }
    println!("{}", written.config.display());
    println!("{}", written.example.display());
    Ok(())
}
