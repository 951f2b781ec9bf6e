//! `pi3det bench sparse`: forward + backward of the voxel detectors' sparse 3-D backbone
//! (`VoxelBackBone8x`, [`pi3det_nn::sparse`]) on real frames, against the same network as dense
//! `conv3d`s where that fits in memory — over the full range when it does, else on a crop
//! around the sensor, where both run — and points per second.

use std::path::PathBuf;
use std::time::Instant;

use pi3det_data::Frame;
use serde::Serialize;
use tch::{Device, Kind, Tensor};

use crate::args::{open_subset, DeviceArgs};
use pi3det_nn::backbones_3d::{Backbone3dConfig, VoxelBackbone8x};
use pi3det_nn::config::DetectorConfig;
use pi3det_nn::error::{NnError, Result};
use pi3det_nn::preprocess::Preprocessor;
use pi3det_nn::sparse::SparseTensor;

/// The SECOND CPU preset (`configs/second_cpu.toml`).
pub const SECOND_CPU_PRESET: &str = include_str!("../../../configs/second_cpu.toml");

/// Time the sparse 3-D backbone (forward + backward) against a dense `conv3d` network.
#[derive(clap::Args, Debug, Clone)]
pub struct BenchSparseArgs {
    /// Voxel detector config [default: configs/second_cpu.toml].
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Frames (train split); default: one simulated vehicle sequence.
    #[arg(long, value_name = "PATH")]
    pub data: Option<PathBuf>,
    #[arg(long, default_value_t = 4)]
    pub frames: usize,
    /// Timed passes over the frames (after one warm-up pass).
    #[arg(long, default_value_t = 2)]
    pub iters: usize,
    /// Half-width in metres of the square crop around the sensor where the dense network runs
    /// when the full range does not fit.
    #[arg(long, default_value_t = 12.8)]
    pub crop_m: f64,
    /// Memory the dense network may use (GiB, estimated from its activations).
    #[arg(long, default_value_t = 6.0)]
    pub dense_limit_gib: f64,
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

#[derive(Debug, Clone, Serialize)]
pub struct SparseBenchRow {
    pub net: String,
    pub region: String,
    /// `[D, H, W]`.
    pub grid: [i64; 3],
    pub voxels_per_frame: f64,
    pub points_per_frame: f64,
    /// Median over frames and passes; `None` when not run.
    pub forward_backward_ms: Option<f64>,
    pub points_per_s: Option<f64>,
    /// Estimated activation memory of the dense network.
    pub dense_gib: Option<f64>,
    pub note: String,
}

/// Voxel inputs of one frame on a grid: the backbone's sparse input and the points it holds.
struct Case {
    input: SparseTensor,
    points: usize,
}

fn cases(cfg: &DetectorConfig, frames: &[Frame], device: Device) -> Result<(Vec<Case>, [i64; 3])> {
    let prep = Preprocessor::new(cfg)?;
    let mut pz = prep.pillarizer()?;
    let g = prep.grid;
    let shape = cfg.sparse_shape();
    let mut out = Vec::new();
    for f in frames {
        let s = prep.sample(f, 0);
        let points = s.points.iter().filter(|p| g.cell(p[0], p[1], p[2]).is_some()).count();
        let v = pz.run(&s.points, cfg.pillars.max_pillars_train);
        let x = prep.collate_inputs(&[&v]);
        let feats = x.features.view([-1, 4]).to_device(device);
        let input =
            SparseTensor::from_flat_indices(feats, &x.cells, [g.nz as i64, g.ny as i64, g.nx as i64], shape, 1)?;
        out.push(Case { input, points });
    }
    Ok((out, shape))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Activation memory of the dense network on a grid (forward activations, masks and their
/// gradients, float32).
fn dense_gib(bb: &pi3det_nn::backbones_3d::VoxelBackbone8xConfig, shape: [i64; 3], c_in: i64) -> f64 {
    let mut s = shape;
    let mut total = (c_in + 1) as f64 * (s[0] * s[1] * s[2]) as f64;
    for (cfg, c) in bb.layer_specs() {
        s = cfg.output_shape(s);
        // Conv output, BN output, ReLU·mask output, each with a gradient; one mask.
        total += (6 * c + 1) as f64 * (s[0] * s[1] * s[2]) as f64;
    }
    total * 4.0 / (1u64 << 30) as f64
}

fn time_sparse(bb: &VoxelBackbone8x, cases: &[Case], iters: usize) -> Result<Vec<f64>> {
    use pi3det_nn::backbones_3d::Backbone3d;
    let mut ts = Vec::new();
    for pass in 0..=iters {
        for c in cases {
            let x = c.input.with_features(c.input.features.detach().set_requires_grad(true));
            let t = Instant::now();
            let y = bb.forward_t(&x, true)?;
            y.out.features.sum(Kind::Float).backward();
            if pass > 0 {
                ts.push(t.elapsed().as_secs_f64());
            }
        }
    }
    Ok(ts)
}

fn time_dense(bb: &VoxelBackbone8x, cases: &[Case], iters: usize) -> Vec<f64> {
    let mut ts = Vec::new();
    for pass in 0..=iters {
        for c in cases {
            let x = c.input.dense().detach().set_requires_grad(true);
            let ones = Tensor::ones([c.input.len() as i64, 1], (Kind::Float, c.input.features.device()));
            let mask = c.input.with_features(ones).dense();
            let t = Instant::now();
            let y = bb.forward_dense(&x, &mask);
            y.sum(Kind::Float).backward();
            if pass > 0 {
                ts.push(t.elapsed().as_secs_f64());
            }
        }
    }
    ts
}

/// Runs the benchmark: rows for the sparse network over the full range and on the crop, the
/// dense one where it fits.
pub fn bench_sparse(
    cfg: &DetectorConfig,
    frames: &[Frame],
    device: Device,
    iters: usize,
    crop_m: f64,
    dense_limit_gib: f64,
) -> Result<Vec<SparseBenchRow>> {
    let Some(Backbone3dConfig::VoxelBackbone8x(bb_cfg)) = &cfg.backbone_3d else {
        return Err(NnError::config(
            "backbone_3d",
            format!("{}: bench sparse needs a [backbone_3d] (a voxel detector)", cfg.name),
        ));
    };
    let vs = tch::nn::VarStore::new(device);
    let bb = bb_cfg.init(vs.root(), 4, &cfg.batch_norm);
    let r = cfg.pillars.point_cloud_range;
    let mut crop = cfg.clone();
    let v = cfg.pillars.pillar_size[0].max(cfg.pillars.pillar_size[1]) * 8.0;
    let half = ((crop_m / v).round().max(1.0)) * v;
    crop.pillars.point_cloud_range = [-half, -half, r[2], half, half, r[5]];
    let mut rows = Vec::new();
    for (region, c) in [("full range".to_string(), cfg), (format!("crop ±{half:.1} m"), &crop)] {
        let (cases, shape) = cases(c, frames, device)?;
        let n = cases.len().max(1) as f64;
        let voxels = cases.iter().map(|c| c.input.len()).sum::<usize>() as f64 / n;
        let points = cases.iter().map(|c| c.points).sum::<usize>() as f64 / n;
        let ms = 1e3 * median(time_sparse(&bb, &cases, iters)?);
        rows.push(SparseBenchRow {
            net: "sparse (ours)".into(),
            region: region.clone(),
            grid: shape,
            voxels_per_frame: voxels,
            points_per_frame: points,
            forward_backward_ms: Some(ms),
            points_per_s: Some(points / ms * 1e3),
            dense_gib: None,
            note: String::new(),
        });
        let gib = dense_gib(bb_cfg, shape, 4);
        let fits = gib <= dense_limit_gib;
        let dense_ms = fits.then(|| 1e3 * median(time_dense(&bb, &cases, iters)));
        rows.push(SparseBenchRow {
            net: "dense conv3d".into(),
            region,
            grid: shape,
            voxels_per_frame: voxels,
            points_per_frame: points,
            forward_backward_ms: dense_ms,
            points_per_s: dense_ms.map(|ms| points / ms * 1e3),
            dense_gib: Some(gib),
            note: if fits { String::new() } else { format!("not run: needs ~{gib:.1} GiB > {dense_limit_gib} GiB") },
        });
    }
    Ok(rows)
}

/// `pi3det bench sparse`; without `--data`, `default_frames(n)` supplies the frames.
pub fn run_bench_sparse(
    args: &BenchSparseArgs,
    default_frames: &mut dyn FnMut(usize) -> Result<Vec<Frame>>,
) -> Result<()> {
    let mut cfg = match &args.config {
        Some(p) => DetectorConfig::from_file(p)?,
        None => DetectorConfig::from_toml_str(SECOND_CPU_PRESET)?,
    };
    args.device.apply_precision(&mut cfg);
    let threads = args.device.threads(cfg.train.threads);
    let device = args.device.setup(cfg.train.threads)?;
    let n = args.frames.max(1);
    let frames: Vec<Frame> = match &args.data {
        Some(p) => {
            let s = open_subset(p, Some("train"), None, 0)?;
            s.indices.iter().take(n).map(|&i| s.dataset.load(i).map_err(NnError::from)).collect::<Result<_>>()?
        }
        None => default_frames(n)?,
    };
    let rows = bench_sparse(&cfg, &frames, device, args.iters.max(1), args.crop_m, args.dense_limit_gib)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&rows).unwrap_or_default());
        return Ok(());
    }
    println!(
        "{}: VoxelBackBone8x forward + backward, {} frame(s) × {} pass(es), {device:?}, {threads} libtorch thread(s)",
        cfg.name,
        frames.len(),
        args.iters.max(1)
    );
    println!(
        "| network | region | grid (z × y × x) | voxels/frame | points/frame | fwd+bwd ms (median) | points/s | note |"
    );
    println!("|---|---|---|---:|---:|---:|---:|---|");
    for r in &rows {
        let ms = r.forward_backward_ms.map_or("–".into(), |v| format!("{v:.0}"));
        let pps = r.points_per_s.map_or("–".into(), |v| format!("{:.0}k", v / 1e3));
        let note = match (r.dense_gib, r.note.is_empty()) {
            (Some(g), true) => format!("~{g:.1} GiB activations"),
            _ => r.note.clone(),
        };
        println!(
            "| {} | {} | {}×{}×{} | {:.0} | {:.0} | {ms} | {pps} | {note} |",
            r.net, r.region, r.grid[0], r.grid[1], r.grid[2], r.voxels_per_frame, r.points_per_frame
        );
    }
    Ok(())
}
