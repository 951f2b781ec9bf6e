//! Runs a model exported by `pi3det export` from Rust: the TorchScript files with pi3det's own
//! pillarization before and decoding + NMS after (what `pi3det run --ckpt model.pt` does), on
//! the first frame of a dataset.
//!
//! `cargo run --release -p pi3det-cli-torch --example torchscript -- model.pt DATA_DIR`

use std::path::Path;

use anyhow::{bail, Context};
use pi3det_cli_torch::args::open_subset;
use pi3det_nn::data_loader::prepare_frame;
use pi3det_nn::detect::to_objects;
use pi3det_nn::export::TorchScriptModel;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [model, data] = args.as_slice() else { bail!("usage: torchscript MODEL.pt DATA_DIR") };
    let ts = TorchScriptModel::load(Path::new(model), tch::Device::Cpu, |_| {})?;
    let subset = open_subset(Path::new(data), None, None, 1)?;
    let frame = subset.dataset.load(*subset.indices.first().context("no frames")?)?;
    // Points → pillars in the detector's frame (the config saved with the model).
    let prep = ts.det.prep.clone();
    let p = prepare_frame(&prep, &[], &frame, false, 0)?;
    let x = prep.collate_inputs(&[&p.pillars]);
    let _guard = tch::no_grad_guard();
    let out = ts.forward(&x)?;
    let dets = ts.det.post_process(&out, 1)?;
    for o in to_objects(&ts.det, &dets[0], &p.detector_from_lidar) {
        let b = o.box3d;
        println!(
            "{:<10} {:.2}  x {:6.2} y {:6.2} z {:5.2}  {:.2}×{:.2}×{:.2}  heading {:+.2}",
            o.name,
            o.score.unwrap_or(1.0),
            b.x,
            b.y,
            b.z,
            b.dx,
            b.dy,
            b.dz,
            b.heading
        );
    }
    Ok(())
}
