//! `pi3det train`, `pi3det detect`, `pi3det demo` and `pi3det bench nn`: argument structs (clap)
//! and runners, for the `pi3det` binary to mount as subcommands.

use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use pi3det_data::Platform;

use crate::bench::Timing;
use crate::checkpoint;
use crate::config::DetectorConfig;
use crate::data_loader::{open_split, Subset};
use crate::detect::{self, Latency};
use crate::device::{self, DeviceChoice};
use crate::error::{NnError, Result};
use crate::eval::{self, ApSummary};
use crate::train::{self, Event, TrainOptions};

/// The CPU preset, built in (the same text as `configs/pointpillars_cpu.toml`).
pub const CPU_PRESET: &str = include_str!("../../../configs/pointpillars_cpu.toml");

/// Device and libtorch threads.
#[derive(clap::Args, Debug, Clone)]
pub struct DeviceArgs {
    /// cpu, cuda or auto (CUDA when libtorch finds a GPU).
    #[arg(long, default_value = "auto")]
    pub device: DeviceChoice,
    /// libtorch intra-op threads on the CPU [default: the config's `train.threads`, else
    /// $PI3DET_TORCH_THREADS, else every core; on a machine busy with other work 1 can be faster].
    #[arg(long, value_name = "N")]
    pub torch_threads: Option<usize>,
}

impl DeviceArgs {
    pub fn setup(&self, configured: usize) -> Result<tch::Device> {
        let n = self.torch_threads.unwrap_or_else(|| device::default_threads(configured));
        device::set_threads(n);
        let d = device::resolve(self.device)?;
        tracing::info!("device {d:?}, {n} libtorch thread(s)");
        Ok(d)
    }
}

fn parse_platform(s: &str) -> std::result::Result<Platform, String> {
    match Platform::parse(s) {
        Platform::Unknown => Err(format!("unknown platform {s:?} (vehicle, drone, quadruped)")),
        p => Ok(p),
    }
}

/// A dataset and the part of it to use.
#[derive(clap::Args, Debug, Clone)]
pub struct DataArgs {
    /// A Pi3DET folder (or info .pkl), a KITTI folder or an mmdet3d info .pkl.
    #[arg(long, value_name = "PATH")]
    pub data: PathBuf,
    /// When DATA is a Pi3DET folder with several info files, use pi3det_infos_<SPLIT>.pkl.
    #[arg(long)]
    pub split: Option<String>,
    /// Only frames of this platform.
    #[arg(long, value_parser = parse_platform)]
    pub platform: Option<Platform>,
    /// At most this many frames, spread evenly (0: all) [train: default the config's
    /// `train.max_train_frames`; detect: all].
    #[arg(long, value_name = "N")]
    pub max_frames: Option<usize>,
}

impl DataArgs {
    /// The frames to use: `--split` (else `default_split`), `--platform`, then at most
    /// `--max-frames` (else `default_max`; 0: all) spread evenly.
    pub fn subset(&self, default_split: &str, default_max: usize) -> Result<Subset> {
        open_subset(
            &self.data,
            Some(self.split.as_deref().unwrap_or(default_split)),
            self.platform,
            self.max_frames.unwrap_or(default_max),
        )
    }
}

pub fn open_subset(path: &Path, split: Option<&str>, platform: Option<Platform>, max: usize) -> Result<Subset> {
    let mut s = Subset::all(open_split(path, split)?);
    if let Some(p) = platform {
        s = s.platform(p)?;
    }
    Ok(s.take_spread(max))
}

/// Train a detector (PointPillars with an anchor or center head) from a TOML config.
#[derive(clap::Args, Debug, Clone)]
pub struct TrainArgs {
    /// Detector config (e.g. configs/pointpillars_cpu.toml).
    #[arg(long)]
    pub config: PathBuf,
    #[command(flatten)]
    pub data: DataArgs,
    /// Validation data for periodic evaluation (its `val` split when it is a multi-split folder).
    #[arg(long, value_name = "PATH")]
    pub val: Option<PathBuf>,
    /// At most this many validation frames, spread evenly (0: all) [default: the config's
    /// `train.max_eval_frames`].
    #[arg(long, value_name = "N")]
    pub max_val_frames: Option<usize>,
    /// Output folder: checkpoints, config, evaluation reports.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue from a checkpoint of this config.
    #[arg(long, value_name = "CKPT")]
    pub resume: Option<PathBuf>,
    /// Replace the model an earlier run left in OUT.
    #[arg(long)]
    pub overwrite: bool,
    /// Override the config's epochs.
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Override the config's batch size.
    #[arg(long)]
    pub batch_size: Option<usize>,
    /// Override the config's seed.
    #[arg(long)]
    pub seed: Option<u64>,
    #[command(flatten)]
    pub device: DeviceArgs,
}

fn style(template: &str) -> ProgressStyle {
    ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar())
}

/// Trains with a progress bar; returns the report.
pub fn train_with_progress(opts: TrainOptions, quiet: bool) -> Result<train::TrainReport> {
    let bar = ProgressBar::hidden();
    let t0 = Instant::now();
    let mut on_event = |e: Event<'_>| match e {
        Event::Start { steps_per_epoch, total_steps, parameters, database } => {
            if !quiet {
                bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
            }
            bar.set_length(total_steps as u64);
            bar.set_style(style("{prefix} [{bar:25}] {pos}/{len} {elapsed}<{eta} {msg}"));
            eprintln!(
                "training: {parameters} parameters, {steps_per_epoch} steps per epoch, {total_steps} steps, ground-truth database of {database} objects"
            );
        }
        Event::Step(s) => {
            let terms: Vec<String> = s.terms.iter().map(|(k, v)| format!("{k} {v:.3}")).collect();
            bar.set_prefix(format!("epoch {}/{}", s.epoch + 1, s.epochs));
            bar.set_message(format!(
                "loss {:.3} ({}) lr {:.1e} |g| {:.1} {:.2} s/step{}",
                s.loss,
                terms.join(", "),
                s.lr,
                s.grad_norm,
                s.step_seconds,
                if s.wait_seconds > 0.05 {
                    format!(" (waited {:.2} s for data)", s.wait_seconds)
                } else {
                    String::new()
                }
            ));
            bar.set_position(s.step as u64);
        }
        Event::EpochEnd { epoch, mean_loss, mean_terms, seconds, data_wait_seconds } => {
            let terms: Vec<String> = mean_terms.iter().map(|(k, v)| format!("{k} {v:.3}")).collect();
            bar.suspend(|| {
                eprintln!(
                    "epoch {}: mean loss {mean_loss:.4} ({}), {seconds:.0} s ({data_wait_seconds:.0} s waiting for data)",
                    epoch + 1,
                    terms.join(", ")
                )
            });
        }
        Event::Eval { epoch, summary } => {
            bar.suspend(|| eprintln!("epoch {} val ({} frames): {}", epoch + 1, summary.frames, summary.one_line()));
        }
        Event::Checkpoint { path } => bar.suspend(|| tracing::info!("wrote {}", path.display())),
    };
    let r = train::train(opts, &mut on_event);
    bar.finish_and_clear();
    let r = r?;
    eprintln!("trained {} steps in {:.0} s ({:.0} s wall)", r.steps, r.train_seconds, t0.elapsed().as_secs_f64());
    Ok(r)
}

impl TrainArgs {
    /// The config file with the command line's overrides (epochs, batch size, seed, frame
    /// limits) written into it, so the checkpoint records what was run.
    pub fn config(&self) -> Result<DetectorConfig> {
        let mut cfg = DetectorConfig::from_file(&self.config)?;
        if let Some(e) = self.epochs {
            cfg.train.epochs = e;
        }
        if let Some(b) = self.batch_size {
            cfg.train.batch_size = b;
        }
        if let Some(s) = self.seed {
            cfg.train.seed = s;
        }
        if let Some(n) = self.data.max_frames {
            cfg.train.max_train_frames = n;
        }
        if let Some(n) = self.max_val_frames {
            cfg.train.max_eval_frames = n;
        }
        cfg.validate()?;
        Ok(cfg)
    }
}

pub fn run_train(args: &TrainArgs) -> Result<()> {
    let cfg = args.config()?;
    if args.resume.is_none() && !args.overwrite {
        // Any checkpoint: older epochs' files are deleted as training goes on.
        refuse_existing(&args.out, |name| name.ends_with(".safetensors"))?;
    }
    let device = args.device.setup(cfg.train.threads)?;
    let train = args.data.subset("train", cfg.train.max_train_frames)?;
    let val = match &args.val {
        Some(v) => Some(open_subset(v, Some("val"), args.data.platform, cfg.train.max_eval_frames)?),
        None => None,
    };
    eprintln!(
        "{}: {} training frames{}",
        cfg.name,
        train.len(),
        val.as_ref().map(|v| format!(", {} validation frames", v.len())).unwrap_or_default()
    );
    let report = train_with_progress(
        TrainOptions { config: cfg, train, val, out_dir: args.out.clone(), device, resume: args.resume.clone() },
        false,
    )?;
    println!("final checkpoint: {}", report.final_checkpoint.display());
    if let Some(s) = &report.final_eval {
        println!("validation: {}", s.one_line());
    }
    Ok(())
}

/// Run a trained detector over a dataset and write its detections (JSON lines and OpenPCDet's
/// result.pkl), with per-frame latency.
#[derive(clap::Args, Debug, Clone)]
pub struct DetectArgs {
    /// Checkpoint (.safetensors) written by `pi3det train`.
    #[arg(long)]
    pub ckpt: PathBuf,
    #[command(flatten)]
    pub data: DataArgs,
    /// Output folder: detections.jsonl, result.pkl, latency.json (and eval.json with --eval).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 1)]
    pub batch_size: usize,
    /// Override the checkpoint's score threshold.
    #[arg(long)]
    pub score_threshold: Option<f64>,
    /// Override the checkpoint's NMS IoU threshold.
    #[arg(long)]
    pub nms_iou: Option<f64>,
    /// Override the z shift applied to the points (e.g. to move a drone's ground to z ≈ 0).
    #[arg(long, allow_negative_numbers = true)]
    pub shift_z: Option<f64>,
    /// Also evaluate against the data's ground truth (within the detector's range) and print it.
    #[arg(long)]
    pub eval: bool,
    /// Replace detections an earlier run left in OUT.
    #[arg(long)]
    pub overwrite: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// Errors when `dir` already holds a file an earlier run wrote (`is_output` on its name); a
/// missing `dir` holds none.
fn refuse_existing(dir: &Path, is_output: impl Fn(&str) -> bool) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(()) };
    match entries.flatten().map(|e| e.path()).find(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(&is_output)) {
        Some(p) => Err(NnError::Input(format!(
            "{} already exists (an earlier run's output); pass --overwrite to replace it",
            p.display()
        ))),
        None => Ok(()),
    }
}

pub fn run_detect(args: &DetectArgs) -> Result<()> {
    if !args.overwrite {
        refuse_existing(&args.out, |name| ["detections.jsonl", "result.pkl", "latency.json"].contains(&name))?;
    }
    let device = args.device.setup(0)?;
    let mut ck = checkpoint::load(&args.ckpt)?;
    if let Some(t) = args.score_threshold {
        ck.config.post.score_threshold = t;
    }
    if let Some(t) = args.nms_iou {
        ck.config.post.nms_iou = t;
    }
    if let Some(z) = args.shift_z {
        ck.config.shift_z = z;
    }
    let mut det = crate::Detector::new(&ck.config, device)?;
    ck.load_into(&mut det, &args.ckpt)?;
    let subset = args.data.subset("val", 0)?;
    let bar = ProgressBar::new(subset.len() as u64).with_style(style("detect [{bar:30}] {pos}/{len} {elapsed}<{eta}"));
    let (frames, lat) = detect::detect(&det, &subset, args.batch_size, &mut |done, _| bar.set_position(done as u64))?;
    bar.finish_and_clear();
    std::fs::create_dir_all(&args.out).map_err(|e| NnError::io(&args.out, e))?;
    detect::write_jsonl(&args.out.join("detections.jsonl"), &frames)?;
    detect::write_result_pkl(&args.out.join("result.pkl"), &frames, &det.cfg().classes)?;
    let lat_json = serde_json::to_vec_pretty(&serde_json::json!({
        "device": format!("{device:?}"), "batch_size": args.batch_size, "latency_ms": lat, "total_ms": lat.total_ms(),
    }))
    .unwrap_or_default();
    pi3det_data::io::write_atomic(&args.out.join("latency.json"), &lat_json, true)?;
    let n: usize = frames.iter().map(|f| f.objects.len()).sum();
    println!("{} frames, {n} detections → {}", frames.len(), args.out.display());
    println!("{}", format_latency(&lat));
    if args.eval {
        let r = det.cfg().pillars.point_cloud_range;
        let opts = eval::options(&det.cfg().classes, Some([r[0], r[1], r[3], r[4]]), None);
        let (report, _) = eval::evaluate(&frames, &opts)?;
        let json = serde_json::to_vec_pretty(&report).unwrap_or_default();
        pi3det_data::io::write_atomic(&args.out.join("eval.json"), &json, true)?;
        print!("{}", pi3det_eval::format_report(&report));
    }
    Ok(())
}

pub fn format_latency(l: &Latency) -> String {
    format!(
        "latency per frame: {:.1} ms (read + pillarize {:.1}, network {:.1}, decode + NMS {:.1})",
        l.total_ms(),
        l.prep_ms,
        l.network_ms,
        l.post_ms
    )
}

/// The cross-platform demo: simulate vehicle / drone / quadruped data, train the CPU preset on
/// the vehicle, evaluate on all three platforms and print the table (Pi3DET's motivation).
#[derive(clap::Args, Debug, Clone)]
pub struct DemoArgs {
    /// Working folder: the demo (re)writes its data/, pointpillars_vehicle/ and reports there.
    #[arg(long, default_value = "runs/demo")]
    pub out: PathBuf,
    /// Detector config [default: the built-in CPU preset, configs/pointpillars_cpu.toml].
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Vehicle sequences to simulate (a quarter go to validation) and frames per sequence.
    #[arg(long, default_value_t = 16)]
    pub vehicle_sequences: u32,
    #[arg(long, default_value_t = 30)]
    pub frames: u32,
    /// Drone and quadruped sequences (a quarter go to validation; the rest are there for
    /// adaptation, which trains on unlabelled target frames).
    #[arg(long, default_value_t = 4)]
    pub other_sequences: u32,
    /// Training epochs: 10 take about eleven minutes on two cores; the preset's own schedule
    /// (`train.epochs`) is used with `--epochs 0`.
    #[arg(long, default_value_t = 10)]
    pub epochs: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Reuse data and checkpoint already in the working folder.
    #[arg(long)]
    pub reuse: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// One row of the demo table.
#[derive(Debug, Clone, serde::Serialize)]
pub struct DemoRow {
    pub platform: String,
    pub frames: usize,
    pub summary: ApSummary,
    pub latency: Latency,
}

pub fn run_demo(args: &DemoArgs) -> Result<()> {
    let t0 = Instant::now();
    let mut cfg = match &args.config {
        Some(p) => DetectorConfig::from_file(p)?,
        None => DetectorConfig::from_toml_str(CPU_PRESET)?,
    };
    if args.epochs > 0 {
        cfg.train.epochs = args.epochs;
    }
    cfg.validate()?;
    let device = args.device.setup(cfg.train.threads)?;
    let data = args.out.join("data");
    let plans = vec![
        pi3det_sim::PlatformPlan::new(Platform::Vehicle, args.vehicle_sequences, args.frames),
        pi3det_sim::PlatformPlan::new(Platform::Quadruped, args.other_sequences, args.frames),
        pi3det_sim::PlatformPlan::new(Platform::Drone, args.other_sequences, args.frames),
    ];
    // The marker records what was simulated, so --reuse never mixes data of other settings.
    let done_marker = data.join(".complete");
    let plan_text = format!("{plans:?} seed {}\n", args.seed);
    let reuse_data = args.reuse && std::fs::read_to_string(&done_marker).is_ok_and(|t| t == plan_text);
    if !reuse_data {
        eprintln!(
            "simulating {} vehicle, {} quadruped and {} drone sequences of {} frames…",
            args.vehicle_sequences, args.other_sequences, args.other_sequences, args.frames
        );
        let opts = pi3det_sim::ExportOptions {
            out: data.clone(),
            seed: args.seed,
            overwrite: true,
            per_platform_folders: true,
            layout: None,
        };
        let total: u64 = plans.iter().map(|p| (p.sequences * p.frames) as u64).sum();
        let bar = ProgressBar::new(total).with_style(style("simulate [{bar:30}] {pos}/{len} frames {elapsed}<{eta}"));
        pi3det_sim::export(&pi3det_sim::SimConfig::default(), &plans, &opts, &mut |_, _| bar.inc(1))
            .map_err(|e| NnError::Input(format!("simulation: {e}")))?;
        bar.finish_and_clear();
        pi3det_data::io::write_atomic(&done_marker, plan_text.as_bytes(), true)?;
    }
    let root = |p: Platform, split: &str| data.join(p.as_str()).join(split);
    let ckpt_dir = args.out.join("pointpillars_vehicle");
    let final_ckpt = ckpt_dir.join("final.safetensors");
    let mut cfg_train = cfg.clone();
    cfg_train.train.eval_every = 0;
    // Reuse a checkpoint only when it was trained on this data with this config.
    let reuse_ckpt = reuse_data
        && final_ckpt.exists()
        && checkpoint::load(&final_ckpt).is_ok_and(|c| c.config.to_toml() == cfg_train.to_toml());
    if !reuse_ckpt {
        let train = open_subset(&root(Platform::Vehicle, "train"), Some("train"), None, cfg.train.max_train_frames)?;
        eprintln!("training {} on {} vehicle frames…", cfg.name, train.len());
        train_with_progress(
            TrainOptions { config: cfg_train, train, val: None, out_dir: ckpt_dir.clone(), device, resume: None },
            false,
        )?;
    }
    let (det, _) = checkpoint::load_detector(&final_ckpt, device)?;
    let mut rows = Vec::new();
    for p in [Platform::Vehicle, Platform::Drone, Platform::Quadruped] {
        let val = open_subset(&root(p, "val"), Some("val"), None, cfg.train.max_eval_frames)?;
        let bar = ProgressBar::new(val.len() as u64).with_style(style("evaluate {prefix} [{bar:30}] {pos}/{len}"));
        bar.set_prefix(p.as_str());
        let (frames, latency) = detect::detect(&det, &val, 1, &mut |d, _| bar.set_position(d as u64))?;
        bar.finish_and_clear();
        let r = det.cfg().pillars.point_cloud_range;
        let opts = eval::options(&det.cfg().classes, Some([r[0], r[1], r[3], r[4]]), None);
        let (report, summary) = eval::evaluate(&frames, &opts)?;
        let json = serde_json::to_vec_pretty(&report).unwrap_or_default();
        pi3det_data::io::write_atomic(&args.out.join(format!("eval_{}.json", p.as_str())), &json, true)?;
        rows.push(DemoRow { platform: p.as_str().into(), frames: frames.len(), summary, latency });
    }
    println!("{}", demo_table(&rows, &det.cfg().classes));
    let json = serde_json::to_vec_pretty(&rows).unwrap_or_default();
    pi3det_data::io::write_atomic(&args.out.join("demo.json"), &json, true)?;
    println!("(trained on the vehicle platform; KITTI-protocol AP_R40, moderate, within the detector's ±range; {:.0} s in all)", t0.elapsed().as_secs_f64());
    Ok(())
}

/// Markdown table: per platform, BEV / 3D AP per class.
pub fn demo_table(rows: &[DemoRow], classes: &[String]) -> String {
    let mut s = String::from("| platform | frames |");
    let mut sep = String::from("|---|---:|");
    for c in classes {
        let iou = rows.iter().find_map(|r| r.summary.get(c)).map(|a| a.iou).unwrap_or(0.0);
        s += &format!(" {c} BEV / 3D @{iou:.1} |");
        sep += "---:|";
    }
    s += " ms/frame |\n";
    s += &sep;
    s += "---:|\n";
    for r in rows {
        s += &format!("| {} | {} |", r.platform, r.frames);
        for c in classes {
            match r.summary.get(c) {
                Some(a) if a.num_gt > 0 => s += &format!(" {:.1} / {:.1} |", a.bev_r40, a.d3_r40),
                _ => s += " – |",
            }
        }
        s += &format!(" {:.0} |\n", r.latency.total_ms());
    }
    s
}

/// Time our training step and end-to-end inference against PyTorch running the same network on
/// the same inputs (the installed torch, through `crates/nn/python/bench_pointpillars.py`).
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

fn repo_path(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

pub fn run_bench_nn(args: &BenchNnArgs) -> Result<()> {
    let cfg = match &args.config {
        Some(p) => DetectorConfig::from_file(p)?,
        None => DetectorConfig::from_toml_str(CPU_PRESET)?,
    };
    let threads = args.device.torch_threads.unwrap_or_else(|| device::default_threads(cfg.train.threads));
    let device = args.device.setup(cfg.train.threads)?;
    let n = cfg.train.batch_size.max(1);
    let frames: Vec<pi3det_data::Frame> = match &args.data {
        Some(p) => {
            let s = open_subset(p, Some("train"), None, 0)?;
            s.indices.iter().take(n).map(|&i| s.dataset.load(i).map_err(NnError::from)).collect::<Result<_>>()?
        }
        None => {
            let spec = pi3det_sim::SequenceSpec {
                platform: Platform::Vehicle,
                index: 0,
                frames: n as u32,
                seed: 0,
                layout: None,
            };
            let seq = pi3det_sim::Sequence::generate(&pi3det_sim::SimConfig::default(), spec)
                .map_err(|e| NnError::Input(format!("simulation: {e}")))?;
            (0..seq.len()).map(|f| seq.render(f).to_frame(&format!("{f:07}"), Platform::Vehicle, &seq.name)).collect()
        }
    };
    let samples = frames.iter().map(|f| crate::data_loader::frame_to_sample(f, &cfg, 1)).collect();
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
        Some((py, repo_path("crates/nn/python/bench_pointpillars.py")))
    };
    let exchange = std::env::temp_dir().join(format!("pi3det-bench-nn-{}", std::process::id()));
    let report = crate::bench::run(&crate::bench::BenchOptions {
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
        "{} on {} ({} libtorch thread(s)); {} points/frame, {} pillars (inference), batch {} ({} pillars) for training",
        r.config, r.device, r.torch_threads, r.points_per_frame, r.infer_pillars, r.batch_size, r.train_pillars
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
