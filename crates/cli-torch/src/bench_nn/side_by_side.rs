//! `pi3det bench nn`: our training step and end-to-end inference against PyTorch running the same
//! network (`crates/cli-torch/python/bench_pointpillars.py`) on the very same inputs, which we export.
//!
//! - Training step: forward + loss + backward + gradient clipping + AdamW update on a prepared
//!   batch (in training the batch is prepared on the loader thread, in parallel).
//! - Inference, ours: from the frame's points in memory — pillarization (Rust) + network
//!   (libtorch) + decoding + rotated NMS (Rust); PyTorch's: the network forward alone on the same
//!   pillars.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};
use tch::Device;

use pi3det_nn::augment::Sample;
use pi3det_nn::config::{DetectorConfig, HeadConfig};
use pi3det_nn::dense_heads::anchor_head::AnchorBatchTargets;
use pi3det_nn::dense_heads::FrameTargets;
use pi3det_nn::detector::Detector;
use pi3det_nn::error::{NnError, Result};
use pi3det_nn::optim::Optimizer;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct Timing {
    pub mean_ms: f64,
    pub median_ms: f64,
    pub min_ms: f64,
}

impl Timing {
    fn of(mut ts: Vec<f64>) -> Self {
        if ts.is_empty() {
            return Self::default();
        }
        ts.sort_by(f64::total_cmp);
        Self {
            mean_ms: 1e3 * ts.iter().sum::<f64>() / ts.len() as f64,
            median_ms: 1e3 * ts[ts.len() / 2],
            min_ms: 1e3 * ts[0],
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct BenchReport {
    pub config: String,
    pub device: String,
    pub torch_threads: usize,
    /// The BEV network's compute kinds in training and at inference (`train.precision`,
    /// `precision`).
    pub compute_kind: String,
    pub batch_size: usize,
    pub train_pillars: usize,
    pub infer_pillars: usize,
    pub points_per_frame: usize,
    /// Ours: the whole step and its parts (forward, loss, backward, clip + AdamW).
    pub train_step: Timing,
    pub train_parts_ms: [f64; 4],
    pub pillarize: Timing,
    pub network: Timing,
    pub post: Timing,
    pub inference: Timing,
    /// PyTorch's (when the script ran).
    pub torch_train_step: Option<Timing>,
    pub torch_forward: Option<Timing>,
    pub torch_version: Option<String>,
    /// Ours / PyTorch's, medians.
    pub train_ratio: Option<f64>,
    pub inference_ratio: Option<f64>,
}

pub struct BenchOptions {
    pub config: DetectorConfig,
    /// Frames in the detector's frame (z shifted), with boxes for the targets.
    pub samples: Vec<Sample>,
    pub device: Device,
    pub threads: usize,
    pub iters: usize,
    pub warmup: usize,
    /// Exchange folder for the PyTorch script.
    pub exchange: PathBuf,
    /// Python interpreter and script; `None` skips the PyTorch side.
    pub python: Option<(PathBuf, PathBuf)>,
}

fn write_bin<T: Copy>(dir: &Path, name: &str, data: &[T], to_bytes: impl Fn(T) -> Vec<u8>) -> Result<()> {
    let bytes: Vec<u8> = data.iter().flat_map(|&v| to_bytes(v)).collect();
    let path = dir.join(format!("{name}.bin"));
    std::fs::write(&path, bytes).map_err(|e| NnError::io(&path, e))
}

fn tensor_f32(t: &tch::Tensor) -> Result<Vec<f32>> {
    Ok(Vec::try_from(t.to_device(Device::Cpu).contiguous().view([-1]))?)
}

fn tensor_i64(t: &tch::Tensor) -> Result<Vec<i64>> {
    Ok(Vec::try_from(t.to_device(Device::Cpu).contiguous().view([-1]))?)
}

pub fn run(opts: &BenchOptions) -> Result<BenchReport> {
    let cfg = &opts.config;
    let HeadConfig::Anchor(anchor_cfg) = &cfg.head else {
        return Err(NnError::config(
            "bench_nn",
            "bench nn compares the anchor-head PointPillars; use an anchor-head config",
        ));
    };
    if opts.samples.is_empty() {
        return Err(NnError::Input("bench needs at least one frame".into()));
    }
    tch::manual_seed(0);
    let det = Detector::new(cfg, opts.device)?;
    let prep = det.prep.clone();
    let bs = cfg.train.batch_size.max(1);
    let batch: Vec<&Sample> = (0..bs).map(|i| &opts.samples[i % opts.samples.len()]).collect();
    let mut pz = prep.pillarizer()?;
    let pillars: Vec<_> = batch.iter().map(|s| pz.run(&s.points, cfg.pillars.max_pillars_train)).collect();
    let targets: Vec<FrameTargets> = batch.iter().map(|s| prep.targets(s)).collect();
    let x = prep.collate_inputs(&pillars.iter().collect::<Vec<_>>());
    let t = prep.collate_targets(&targets.iter().collect::<Vec<_>>())?;
    let (xd, td) = (x.to_device(opts.device), t.to_device(opts.device));
    let gt: Vec<pi3det_nn::data_loader::FrameGt> = batch
        .iter()
        .map(|s| pi3det_nn::data_loader::FrameGt {
            boxes: s.boxes.clone(),
            classes: s.classes.clone(),
            ignored: s.ignored.clone(),
            ignored_classes: s.ignored_classes.clone(),
            ..Default::default()
        })
        .collect();
    let mut optim = Optimizer::new(det.named_trainables(), &cfg.train);
    let sync = || {
        if opts.device.is_cuda() {
            tch::Cuda::synchronize(0);
        }
    };
    let mut step_times = Vec::new();
    let mut parts = [0f64; 4];
    for i in 0..opts.warmup + opts.iters {
        let t0 = Instant::now();
        let out = det.forward_train(&xd, &gt, &mut rand::SeedableRng::seed_from_u64(i as u64))?;
        sync();
        let t1 = Instant::now();
        let l = det.loss(&out, &td, &gt, pi3det_nn::detector::Domain::Source)?;
        sync();
        let t2 = Instant::now();
        optim.zero_grad();
        l.total().backward();
        sync();
        let t3 = Instant::now();
        optim.clip_grad_norm(cfg.train.grad_clip);
        optim.update(1e-3, 0.9);
        sync();
        let t4 = Instant::now();
        if i >= opts.warmup {
            step_times.push((t4 - t0).as_secs_f64());
            for (p, d) in parts.iter_mut().zip([t1 - t0, t2 - t1, t3 - t2, t4 - t3]) {
                *p += d.as_secs_f64() * 1e3 / opts.iters as f64;
            }
        }
    }
    // Inference from points: frame 0.
    let points = &opts.samples[0].points;
    let (mut tp, mut tn, mut tpost, mut tall) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut infer_pillars = 0;
    {
        let _g = tch::no_grad_guard();
        for i in 0..opts.warmup + opts.iters {
            let t0 = Instant::now();
            let p = pz.run(points, cfg.pillars.max_pillars_test);
            let xi = prep.collate_inputs(&[&p]).to_device(opts.device);
            let t1 = Instant::now();
            let out = det.forward_t(&xi, false)?;
            sync();
            let t2 = Instant::now();
            let dets = det.post_process(&out, 1)?;
            let t3 = Instant::now();
            std::hint::black_box(dets);
            infer_pillars = p.len();
            if i >= opts.warmup {
                tp.push((t1 - t0).as_secs_f64());
                tn.push((t2 - t1).as_secs_f64());
                tpost.push((t3 - t2).as_secs_f64());
                tall.push((t3 - t0).as_secs_f64());
            }
        }
    }
    let mut report = BenchReport {
        config: cfg.name.clone(),
        device: format!("{:?}", opts.device),
        torch_threads: opts.threads,
        compute_kind: format!(
            "{:?} (training) / {:?} (inference)",
            cfg.train.precision.compute_kind(opts.device),
            cfg.precision.compute_kind(opts.device)
        ),
        batch_size: bs,
        train_pillars: pillars.iter().map(|p| p.len()).sum(),
        infer_pillars,
        points_per_frame: points.len(),
        train_step: Timing::of(step_times),
        train_parts_ms: parts,
        pillarize: Timing::of(tp),
        network: Timing::of(tn),
        post: Timing::of(tpost),
        inference: Timing::of(tall),
        ..Default::default()
    };
    let Some((python, script)) = &opts.python else { return Ok(report) };
    if cfg.backbone_3d.is_some() {
        return Err(NnError::config(
            "bench_nn",
            "the PyTorch side of bench nn is PointPillars; run voxel detectors with --no-torch",
        ));
    }
    // Export the inputs for PyTorch.
    let dir = &opts.exchange;
    std::fs::create_dir_all(dir).map_err(|e| NnError::io(dir, e))?;
    let f32b = |v: f32| v.to_le_bytes().to_vec();
    let i64b = |v: i64| v.to_le_bytes().to_vec();
    write_bin(dir, "train_features", &tensor_f32(&x.features)?, f32b)?;
    write_bin(dir, "train_cells", &tensor_i64(&x.cells)?, i64b)?;
    let at = t
        .downcast_ref::<AnchorBatchTargets>()
        .ok_or_else(|| NnError::config("bench_nn", "bench nn needs an anchor-head config"))?;
    write_bin(dir, "train_labels", &tensor_i64(&at.labels)?, i64b)?;
    write_bin(dir, "train_pos_index", &tensor_i64(&at.pos_index)?, i64b)?;
    write_bin(dir, "train_pos_codes", &tensor_f32(&at.pos_codes)?, f32b)?;
    write_bin(dir, "train_pos_dir", &tensor_i64(&at.pos_dir)?, i64b)?;
    write_bin(dir, "train_pos_weight", &tensor_f32(&at.pos_weight)?, f32b)?;
    let p = pz.run(points, cfg.pillars.max_pillars_test);
    let xi = prep.collate_inputs(&[&p]);
    write_bin(dir, "infer_features", &tensor_f32(&xi.features)?, f32b)?;
    write_bin(dir, "infer_cells", &tensor_i64(&xi.cells)?, i64b)?;
    let meta = serde_json::json!({
        "batch_norm": cfg.batch_norm,
        "vfe_filters": cfg.vfe.num_filters,
        "backbone": cfg.backbone,
        "anchors_per_location": anchor_cfg.anchors_per_location(),
        "num_classes": cfg.classes.len(),
        "num_anchors": at.labels.size()[1],
        "nx": prep.grid.nx, "ny": prep.grid.ny,
        "max_points": cfg.pillars.max_points_per_pillar,
        "channels_last": cfg.channels_last && opts.device == Device::Cpu,
        "bf16_train": cfg.train.precision.compute_kind(opts.device) == tch::Kind::BFloat16,
        "bf16_infer": cfg.precision.compute_kind(opts.device) == tch::Kind::BFloat16,
        "loss_weights": {"cls": anchor_cfg.cls_weight, "loc": anchor_cfg.loc_weight, "dir": anchor_cfg.dir_weight},
        "train": {"batch_size": bs, "pillars": x.features.size()[0], "positives": at.pos_index.size()[0]},
        "infer": {"pillars": p.len()},
    });
    let meta_path = dir.join("meta.json");
    std::fs::write(&meta_path, serde_json::to_vec_pretty(&meta).unwrap_or_default())
        .map_err(|e| NnError::io(&meta_path, e))?;
    let out = std::process::Command::new(python)
        .arg(script)
        .arg(dir)
        .args([
            "--iters",
            &opts.iters.to_string(),
            "--warmup",
            &opts.warmup.to_string(),
            "--threads",
            &opts.threads.to_string(),
            "--device",
            if opts.device.is_cuda() { "cuda" } else { "cpu" },
        ])
        .env("OMP_NUM_THREADS", opts.threads.to_string())
        .output()
        .map_err(|e| NnError::io(python, e))?;
    if !out.status.success() {
        return Err(NnError::Input(format!("{} failed: {}", script.display(), String::from_utf8_lossy(&out.stderr))));
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout.lines().rev().find(|l| l.trim_start().starts_with('{')).unwrap_or("");
    let v: serde_json::Value =
        serde_json::from_str(line).map_err(|e| NnError::Input(format!("PyTorch output {line:?}: {e}")))?;
    let timing = |k: &str| -> Option<Timing> { serde_json::from_value(v.get(k)?.clone()).ok() };
    report.torch_train_step = timing("train_step");
    report.torch_forward = timing("forward");
    report.torch_version = v.get("torch").and_then(|s| s.as_str()).map(String::from);
    report.train_ratio = report.torch_train_step.map(|t| report.train_step.median_ms / t.median_ms);
    report.inference_ratio = report.torch_forward.map(|t| report.inference.median_ms / t.median_ms);
    Ok(report)
}
