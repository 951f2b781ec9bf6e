//! `pi3det demo`: simulate vehicle / drone / quadruped data, train the CPU preset on the vehicle,
//! evaluate on every platform's validation split and print the table (Pi3DET's motivation: a
//! detector trained on a vehicle collapses on a drone or a quadruped).
//!
//! The validation split does not change with `--seed`: it is simulated with its own seed
//! (`--val-seed`) and its sequences take the platform's layouts in fixed proportions (stratified),
//! so a change of seed moves only what training does. (When it was drawn with the training seed,
//! the same vehicle model scored far apart on different 12-sequence splits, which held different
//! numbers of suburban sequences: results/2026-12-03-demo-point-features-seeds-0-1.md.)
//! `--seeds 0,1,2` measures what remains: simulation, training and evaluation once per seed, then
//! the mean ± sample standard deviation per platform and class. `demo.json` holds the settings,
//! every seed's rows and timings, and that summary.
//!
//! `--reuse` keeps data and a checkpoint already in the working folder, but only those made with
//! the same settings: the data folder's `.complete` marker records the simulation plans and seed,
//! the checkpoint's `.trained_on` marker the data it was trained on, and the checkpoint itself its
//! config (training seed and frame limits included; its post-processing may differ, the current
//! one is used).

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::{adapt_with_progress, open_subset, progress_style, train_with_progress, DeviceArgs, PI3DET_NET_CPU_PRESET};
use anyhow::{bail, Context, Result};
use indicatif::ProgressBar;
use pi3det_adapt::pipeline::{self, AdaptConfig, AdaptOptions};
use pi3det_data::Platform;
use pi3det_nn::detect::{self, Latency};
use pi3det_nn::eval::{self, ApSummary};
use pi3det_nn::train::TrainOptions;
use pi3det_nn::{checkpoint, DetectorConfig};
use pi3det_sim::PlatformPlan;
use serde::Serialize;

/// The validation data's seed unless `--val-seed` says otherwise.
pub const DEFAULT_VAL_SEED: u64 = 1000;

/// The platforms in table order.
pub const PLATFORMS: [Platform; 3] = [Platform::Vehicle, Platform::Drone, Platform::Quadruped];

/// The cross-platform demo: simulate vehicle / drone / quadruped data, train the CPU preset on
/// the vehicle, evaluate on all three platforms and print the table (Pi3DET's motivation).
#[derive(clap::Args, Debug, Clone)]
pub struct DemoArgs {
    /// Working folder: the demo (re)writes its data/, pointpillars_vehicle/ and reports there
    /// (with --seeds, one seed_S/ folder per seed S).
    #[arg(long, default_value = "runs/demo")]
    pub out: PathBuf,
    /// Detector config for the vehicle model [default: the detector of the built-in Pi3DET-Net
    /// preset, configs/pi3det_net_cpu.toml: the two-stage CPU PointPillars with GTD and PFA].
    /// Adaptation runs only when its network is the adaptation config's.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Pi3DET-Net config for adapting the vehicle model to the drone and the quadruped
    /// [default: the built-in configs/pi3det_net_cpu.toml].
    #[arg(long, value_name = "PATH")]
    pub adapt_config: Option<PathBuf>,
    /// Knowledge-Adaptation epochs over each target's training frames (0: no adaptation).
    #[arg(long, default_value_t = 2, value_name = "N")]
    pub ka_epochs: usize,
    /// Vehicle training sequences. More distinct frames at the same number of steps: 40 × 30
    /// frames for 3 epochs beat 12 × 30 for 10 epochs (results/2026-12-01-two-stage-preset-seeds.md).
    #[arg(long, default_value_t = 40, value_name = "N")]
    pub train_sequences: u32,
    /// Validation sequences per platform (vehicle, drone, quadruped).
    #[arg(long, default_value_t = 12, value_name = "N")]
    pub val_sequences: u32,
    /// Frames per sequence (10 Hz).
    #[arg(long, default_value_t = 30, value_name = "N")]
    pub frames: u32,
    /// Drone and quadruped training sequences: simulated for adaptation (which trains on
    /// unlabelled target frames); the vehicle detector never sees them.
    #[arg(long, default_value_t = 4, value_name = "N")]
    pub target_train_sequences: u32,
    /// Evaluate at most N frames per platform, spread evenly (0: all) [default: the config's
    /// `train.max_eval_frames`].
    #[arg(long, value_name = "N")]
    pub max_val_frames: Option<usize>,
    /// Training epochs over the vehicle training frames (3 × 1,200 frames = 3,600 steps at batch
    /// 1); the config's own schedule (`train.epochs`) is used with `--epochs 0`.
    #[arg(long, default_value_t = 3)]
    pub epochs: usize,
    /// Seed of the training data's simulation and of training (the config's `train.seed`).
    #[arg(long, default_value_t = 0, conflicts_with = "seeds")]
    pub seed: u64,
    /// Seed of the validation splits' simulation: fixed, so that --seed moves only training.
    #[arg(long, default_value_t = DEFAULT_VAL_SEED, value_name = "S")]
    pub val_seed: u64,
    /// Several seeds, comma-separated (instead of --seed): simulate, train and evaluate once per
    /// seed (in OUT/seed_S/), then print the per-seed table and the mean ± std.
    #[arg(long, value_delimiter = ',', value_name = "S,S,...")]
    pub seeds: Vec<u64>,
    /// Simulator settings for the training splits (TOML, `pi3det simulate --print-config`), e.g.
    /// `[randomise] sensors = [...]` to train on several beam layouts; the validation splits keep
    /// the default simulator, so their table stays comparable.
    #[arg(long, value_name = "TOML")]
    pub sim_config: Option<PathBuf>,
    /// Reuse data and checkpoint already in the working folder (only if made with these settings).
    #[arg(long)]
    pub reuse: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// One row of the demo table.
#[derive(Debug, Clone, Serialize)]
pub struct DemoRow {
    pub platform: String,
    pub frames: usize,
    pub summary: ApSummary,
    pub latency: Latency,
}

/// Wall-clock seconds of the stages (0 for a stage whose result was reused).
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Timings {
    pub simulate_s: f64,
    pub train_s: f64,
    pub evaluate_s: f64,
    /// Pi3DET-Net's adaptation to the drone and the quadruped (evaluations included).
    pub adapt_s: f64,
    pub total_s: f64,
}

impl Timings {
    fn add(&mut self, o: &Timings) {
        self.simulate_s += o.simulate_s;
        self.train_s += o.train_s;
        self.evaluate_s += o.evaluate_s;
        self.adapt_s += o.adapt_s;
    }

    pub fn line(&self) -> String {
        format!(
            "simulate {:.0} s, train {:.0} s, evaluate {:.0} s, adapt {:.0} s, total {:.0} s",
            self.simulate_s, self.train_s, self.evaluate_s, self.adapt_s, self.total_s
        )
    }
}

/// One seed's run.
#[derive(Debug, Clone, Serialize)]
pub struct SeedRun {
    pub seed: u64,
    /// Its working folder (data/, pointpillars_vehicle/, `eval_<platform>.json`).
    pub dir: PathBuf,
    pub reused_data: bool,
    pub reused_checkpoint: bool,
    pub rows: Vec<DemoRow>,
    pub timings: Timings,
}

/// Mean and sample standard deviation (n − 1; `None` below two values) of one number over seeds.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Spread {
    pub mean: f64,
    pub std: Option<f64>,
    pub values: Vec<f64>,
}

impl Spread {
    pub fn of(values: Vec<f64>) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let std =
            (values.len() > 1).then(|| (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt());
        Some(Self { mean, std, values })
    }

    /// `37.6 ± 1.2` (`37.6 (n=1)` for one value).
    pub fn show(&self) -> String {
        match self.std {
            Some(s) => format!("{:.1} ± {s:.1}", self.mean),
            None => format!("{:.1} (n={})", self.mean, self.values.len()),
        }
    }
}

/// A class on a platform over the seeds: BEV and 3D AP_R40 (seeds whose data held no ground truth
/// of the class are left out).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ClassSpread {
    pub class: String,
    pub iou: f64,
    pub bev: Option<Spread>,
    pub d3: Option<Spread>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlatformSpread {
    pub platform: String,
    pub classes: Vec<ClassSpread>,
}

/// What `demo.json` holds.
#[derive(Debug, Clone, Serialize)]
pub struct DemoReport {
    pub config: String,
    pub train_sequences: u32,
    pub val_sequences: u32,
    /// The validation splits' simulation seed (the same for every training seed).
    pub val_seed: u64,
    pub frames: u32,
    pub target_train_sequences: u32,
    pub max_val_frames: usize,
    pub epochs: usize,
    pub seeds: Vec<SeedRun>,
    /// Per platform and class over the seeds.
    pub summary: Vec<PlatformSpread>,
    pub timings: Timings,
}

impl DemoArgs {
    /// The seeds to run.
    pub fn seed_list(&self) -> Vec<u64> {
        if self.seeds.is_empty() {
            vec![self.seed]
        } else {
            self.seeds.clone()
        }
    }

    /// Vehicle, quadruped and drone plans: the last `val_sequences` of each go to `val`.
    pub fn plans(&self) -> Vec<PlatformPlan> {
        let plan = |platform, train| PlatformPlan {
            platform,
            sequences: train + self.val_sequences,
            frames: self.frames,
            val_sequences: self.val_sequences,
        };
        vec![
            plan(Platform::Vehicle, self.train_sequences),
            plan(Platform::Quadruped, self.target_train_sequences),
            plan(Platform::Drone, self.target_train_sequences),
        ]
    }

    fn check(&self) -> Result<()> {
        if self.train_sequences == 0 || self.val_sequences == 0 || self.frames == 0 {
            bail!("--train-sequences, --val-sequences and --frames must be positive");
        }
        let mut seeds = self.seed_list();
        seeds.sort_unstable();
        if seeds.windows(2).any(|w| w[0] == w[1]) {
            bail!("--seeds lists a seed twice");
        }
        Ok(())
    }
}

pub fn run_demo(args: &DemoArgs) -> Result<DemoReport> {
    let t0 = Instant::now();
    args.check()?;
    let mut adapt = match &args.adapt_config {
        Some(p) => AdaptConfig::from_file(p)?,
        None => AdaptConfig::from_toml_str(PI3DET_NET_CPU_PRESET).context("the built-in Pi3DET-Net preset")?,
    };
    adapt.ka.epochs = args.ka_epochs.max(1);
    let mut cfg = match &args.config {
        Some(p) => DetectorConfig::from_file(p)?,
        None => adapt.detector.clone(),
    };
    if args.epochs > 0 {
        cfg.train.epochs = args.epochs;
    }
    args.device.apply_precision(&mut cfg);
    args.device.apply_precision(&mut adapt.detector);
    cfg.validate()?;
    let max_val = args.max_val_frames.unwrap_or(cfg.train.max_eval_frames);
    let device = args.device.setup(cfg.train.threads)?;
    let seeds = args.seed_list();
    let multi = !args.seeds.is_empty();
    let mut runs = Vec::new();
    for (i, &seed) in seeds.iter().enumerate() {
        let dir = if multi { args.out.join(format!("seed_{seed}")) } else { args.out.clone() };
        if multi {
            eprintln!("seed {seed} ({}/{}) in {}", i + 1, seeds.len(), dir.display());
        }
        let run = run_seed(args, &cfg, &adapt, seed, max_val, &dir, device)?;
        println!(
            "{}{}",
            if multi { format!("seed {seed}:\n") } else { String::new() },
            demo_table(&run.rows, &cfg.classes)
        );
        println!("({})", run.timings.line());
        runs.push(run);
    }
    let mut timings = Timings::default();
    for r in &runs {
        timings.add(&r.timings);
    }
    timings.total_s = t0.elapsed().as_secs_f64();
    let summary = summarize(&runs, &cfg.classes);
    if multi {
        println!("per seed:\n{}", seeds_table(&runs, &cfg.classes));
        println!("over {} seeds (mean ± sample std):\n{}", runs.len(), spread_table(&summary));
    }
    let report = DemoReport {
        config: cfg.name.clone(),
        train_sequences: args.train_sequences,
        val_sequences: args.val_sequences,
        val_seed: args.val_seed,
        frames: args.frames,
        target_train_sequences: args.target_train_sequences,
        max_val_frames: max_val,
        epochs: cfg.train.epochs,
        seeds: runs,
        summary,
        timings,
    };
    let json = serde_json::to_vec_pretty(&report)?;
    std::fs::create_dir_all(&args.out).with_context(|| args.out.display().to_string())?;
    pi3det_data::io::write_atomic(&args.out.join("demo.json"), &json, true)?;
    println!(
        "(trained on the vehicle platform; KITTI-protocol AP_R40, moderate, within the detector's ±range; {})",
        timings.line()
    );
    Ok(report)
}

/// Simulates (unless reusable), trains (unless reusable) and evaluates one seed in `dir`.
fn run_seed(
    args: &DemoArgs,
    cfg: &DetectorConfig,
    adapt: &AdaptConfig,
    seed: u64,
    max_val: usize,
    dir: &Path,
    device: tch::Device,
) -> Result<SeedRun> {
    let t0 = Instant::now();
    let mut timings = Timings::default();
    let data = dir.join("data");
    let plans = args.plans();
    // Each split's marker records what was simulated into it, so --reuse never mixes data of other
    // settings; the checkpoint's records the training split's.
    let train_sim = match &args.sim_config {
        Some(p) => pi3det_sim::SimConfig::load(p).with_context(|| format!("--sim-config {}", p.display()))?,
        None => pi3det_sim::SimConfig::default(),
    };
    let train_text = match &args.sim_config {
        Some(_) => format!("{plans:?} seed {seed}\n{}", train_sim.to_toml_string()),
        None => format!("{plans:?} seed {seed}\n"),
    };
    let val_text = format!("{plans:?} val seed {} stratified\n", args.val_seed);
    let (mut reused_data, mut reused_train_data) = (true, true);
    for (split, text, split_seed, stratify) in
        [("train", &train_text, seed, false), ("val", &val_text, args.val_seed, true)]
    {
        let marker = data.join(format!(".complete_{split}"));
        if args.reuse && std::fs::read_to_string(&marker).is_ok_and(|t| &t == text) {
            continue;
        }
        reused_data = false;
        reused_train_data &= split != "train";
        let t = Instant::now();
        // No marker while the data is being replaced: an interrupted run leaves none behind.
        let _ = std::fs::remove_file(&marker);
        let sim = if split == "train" { train_sim.clone() } else { pi3det_sim::SimConfig::default() };
        simulate_split(&sim, &data, &plans, split, split_seed, stratify)?;
        pi3det_data::io::write_atomic(&marker, text.as_bytes(), true)?;
        timings.simulate_s += t.elapsed().as_secs_f64();
    }
    let root = |p: Platform, split: &str| data.join(p.as_str()).join(split);
    let ckpt_dir = dir.join("pointpillars_vehicle");
    let final_ckpt = ckpt_dir.join("final.safetensors");
    let trained_marker = ckpt_dir.join(".trained_on");
    let cfg_train = cfg_train_of(cfg, seed);
    // Reuse a checkpoint only when it was trained on this data with this config; its `[post]`
    // may differ (post-processing leaves the weights alone: the current one is used).
    let same_training = |mut c: DetectorConfig| {
        c.post = cfg_train.post.clone();
        c.settings_toml() == cfg_train.settings_toml()
    };
    let reused_checkpoint = reused_train_data
        && std::fs::read_to_string(&trained_marker).is_ok_and(|t| t == train_text)
        && checkpoint::load(&final_ckpt).is_ok_and(|c| same_training(c.config));
    if !reused_checkpoint {
        let t = Instant::now();
        let _ = std::fs::remove_file(&trained_marker);
        let train = open_subset(&root(Platform::Vehicle, "train"), Some("train"), None, cfg.train.max_train_frames)?;
        eprintln!("training {} on {} vehicle frames (seed {seed})…", cfg.name, train.len());
        train_with_progress(
            TrainOptions {
                config: cfg_train.clone(),
                train,
                val: None,
                out_dir: ckpt_dir.clone(),
                device,
                resume: None,
                stage: None,
                frame_transform: None,
            },
            false,
        )?;
        pi3det_data::io::write_atomic(&trained_marker, train_text.as_bytes(), true)?;
        timings.train_s = t.elapsed().as_secs_f64();
    }
    let t = Instant::now();
    let (det, _) = checkpoint::load_detector_with_post(&final_ckpt, Some(&cfg_train.post), device)?;
    let mut rows = Vec::new();
    for p in PLATFORMS {
        let val = open_subset(&root(p, "val"), Some("val"), None, max_val)?;
        let bar =
            ProgressBar::new(val.len() as u64).with_style(progress_style("evaluate {prefix} [{bar:30}] {pos}/{len}"));
        bar.set_prefix(p.as_str());
        let (frames, latency) = detect::detect(&det, &val, 1, &mut |d, _| bar.set_position(d as u64))?;
        bar.finish_and_clear();
        let r = det.cfg().pillars.point_cloud_range;
        let opts = eval::options(&det.cfg().classes, Some([r[0], r[1], r[3], r[4]]), None);
        let (report, summary) = eval::evaluate(&frames, &opts)?;
        let json = serde_json::to_vec_pretty(&report)?;
        pi3det_data::io::write_atomic(&dir.join(format!("eval_{}.json", p.as_str())), &json, true)?;
        // AP and recall by distance and points per box, misplaced share, localisation errors.
        let b = eval::breakdown(&frames, &opts)?;
        pi3det_data::io::write_atomic(
            &dir.join(format!("breakdown_{}.json", p.as_str())),
            &serde_json::to_vec_pretty(&b)?,
            true,
        )?;
        if p == Platform::Vehicle {
            eprint!("{}", eval::format_breakdown(&b));
        }
        rows.push(DemoRow { platform: p.as_str().into(), frames: frames.len(), summary, latency });
    }
    timings.evaluate_s = t.elapsed().as_secs_f64();
    if args.ka_epochs > 0 {
        let t = Instant::now();
        let mut a = adapt.clone();
        // The vehicle model is the Pre-Adaptation: KA starts from it with the same schedule.
        a.detector = cfg_train_of(cfg, seed);
        if let Err(e) = pipeline::check_architecture(&final_ckpt, det.cfg(), &a.detector) {
            eprintln!("no adaptation: {e}");
        } else {
            let source =
                open_subset(&root(Platform::Vehicle, "train"), Some("train"), None, cfg.train.max_train_frames)?;
            for p in [Platform::Drone, Platform::Quadruped] {
                let out = dir.join(format!("pi3det_net_{}", p.as_str()));
                if out.exists() {
                    std::fs::remove_dir_all(&out).with_context(|| out.display().to_string())?;
                }
                eprintln!("Pi3DET-Net: vehicle → {} ({} KA epochs)…", p.as_str(), a.ka.epochs);
                // The same model on the same val frames was scored above: not evaluated again.
                let source_only = rows.iter().find(|r| r.platform == p.as_str()).map(|r| r.summary.clone());
                let r = adapt_with_progress(
                    AdaptOptions {
                        config: a.clone(),
                        source: source.clone(),
                        target: open_subset(&root(p, "train"), Some("train"), None, 0)?,
                        val: Some(open_subset(&root(p, "val"), Some("val"), None, max_val)?),
                        out_dir: out,
                        device,
                        pa_ckpt: Some(final_ckpt.clone()),
                        resume: false,
                        stop_after: None,
                        source_only,
                        // The demo's table shows source-only and adapted rows only.
                        vpp_diagnostics: false,
                    },
                    false,
                )?;
                if let Some(summary) = r.adapted {
                    let frames = r.val_frames;
                    let platform = format!("{} + Pi3DET-Net", p.as_str());
                    rows.push(DemoRow { platform, frames, summary, latency: Latency::default() });
                }
            }
        }
        timings.adapt_s = t.elapsed().as_secs_f64();
    }
    timings.total_s = t0.elapsed().as_secs_f64();
    Ok(SeedRun { seed, dir: dir.to_path_buf(), reused_data, reused_checkpoint, rows, timings })
}

/// Simulates one split of every plan into `data/<platform>/<split>` (replacing what is there).
fn simulate_split(
    cfg: &pi3det_sim::SimConfig,
    data: &Path,
    plans: &[PlatformPlan],
    split: &str,
    seed: u64,
    stratify: bool,
) -> Result<()> {
    // Sequences of each plan that fall in this split.
    let in_split: Vec<u64> =
        plans.iter().map(|p| (0..p.sequences).filter(|&i| p.split_of(i) == split).count() as u64).collect();
    let counts: Vec<String> =
        plans.iter().zip(&in_split).map(|(p, n)| format!("{n} {}", p.platform.as_str())).collect();
    let frames = plans.first().map_or(0, |p| p.frames);
    eprintln!(
        "simulating {split}: {} sequences of {frames} frames (seed {seed}{})…",
        counts.join(", "),
        if stratify { ", stratified layouts" } else { "" }
    );
    let opts = pi3det_sim::ExportOptions {
        out: data.to_path_buf(),
        seed,
        overwrite: true,
        per_platform_folders: true,
        layout: None,
        stratify_layouts: stratify,
    };
    let total: u64 = plans.iter().zip(&in_split).map(|(p, n)| n * u64::from(p.frames)).sum();
    let bar = ProgressBar::new(total).with_style(progress_style(&format!(
        "simulate {split} [{{bar:30}}] {{pos}}/{{len}} frames {{elapsed}}<{{eta}}"
    )));
    for plan in plans {
        pi3det_sim::export_split(cfg, plan, split, &opts, &mut |_, _| bar.inc(1)).context("simulation")?;
    }
    bar.finish_and_clear();
    Ok(())
}

/// The config the vehicle model is trained with: no periodic evaluation, the run's seed.
fn cfg_train_of(cfg: &DetectorConfig, seed: u64) -> DetectorConfig {
    let mut c = cfg.clone();
    c.train.eval_every = 0;
    c.train.seed = seed;
    c
}

/// Mean ± std per platform and class over the runs.
pub fn summarize(runs: &[SeedRun], classes: &[String]) -> Vec<PlatformSpread> {
    let platforms: Vec<String> =
        runs.first().map(|r| r.rows.iter().map(|r| r.platform.clone()).collect()).unwrap_or_default();
    platforms
        .into_iter()
        .map(|platform| {
            let aps: Vec<_> = runs
                .iter()
                .filter_map(|r| r.rows.iter().find(|row| row.platform == platform))
                .map(|row| &row.summary)
                .collect();
            let classes = classes
                .iter()
                .map(|c| {
                    let found: Vec<_> = aps.iter().filter_map(|s| s.get(c)).filter(|a| a.num_gt > 0).collect();
                    ClassSpread {
                        class: c.clone(),
                        iou: aps.iter().find_map(|s| s.get(c)).map_or(0.0, |a| a.iou),
                        bev: Spread::of(found.iter().map(|a| a.bev_r40).collect()),
                        d3: Spread::of(found.iter().map(|a| a.d3_r40).collect()),
                    }
                })
                .collect();
            PlatformSpread { platform, classes }
        })
        .collect()
}

fn class_iou(rows: &[DemoRow], c: &str) -> f64 {
    rows.iter().find_map(|r| r.summary.get(c)).map(|a| a.iou).unwrap_or(0.0)
}

fn ap_cell(s: &ApSummary, c: &str) -> String {
    match s.get(c) {
        Some(a) if a.num_gt > 0 => format!(" {:.1} / {:.1} |", a.bev_r40, a.d3_r40),
        _ => " – |".into(),
    }
}

/// Markdown table: per platform, BEV / 3D AP per class.
pub fn demo_table(rows: &[DemoRow], classes: &[String]) -> String {
    let mut s = String::from("| platform | frames |");
    let mut sep = String::from("|---|---:|");
    for c in classes {
        s += &format!(" {c} BEV / 3D @{:.1} |", class_iou(rows, c));
        sep += "---:|";
    }
    s += " ms/frame |\n";
    s += &sep;
    s += "---:|\n";
    for r in rows {
        s += &format!("| {} | {} |", r.platform, r.frames);
        for c in classes {
            s += &ap_cell(&r.summary, c);
        }
        if r.latency.frames > 0 {
            s += &format!(" {:.0} |\n", r.latency.total_ms());
        } else {
            s += " – |\n";
        }
    }
    s
}

/// Markdown table: one row per seed and platform.
pub fn seeds_table(runs: &[SeedRun], classes: &[String]) -> String {
    let all: Vec<DemoRow> = runs.iter().flat_map(|r| r.rows.iter().cloned()).collect();
    let mut s = String::from("| seed | platform | frames |");
    let mut sep = String::from("|---:|---|---:|");
    for c in classes {
        s += &format!(" {c} BEV / 3D @{:.1} |", class_iou(&all, c));
        sep += "---:|";
    }
    s += &format!("\n{sep}\n");
    for run in runs {
        for r in &run.rows {
            s += &format!("| {} | {} | {} |", run.seed, r.platform, r.frames);
            for c in classes {
                s += &ap_cell(&r.summary, c);
            }
            s += "\n";
        }
    }
    s
}

/// Markdown table: per platform, mean ± std of BEV and 3D AP per class.
pub fn spread_table(summary: &[PlatformSpread]) -> String {
    let Some(first) = summary.first() else { return String::new() };
    let mut s = String::from("| platform |");
    let mut sep = String::from("|---|");
    for c in &first.classes {
        s += &format!(" {0} BEV @{1:.1} | {0} 3D @{1:.1} |", c.class, c.iou);
        sep += "---:|---:|";
    }
    s += &format!("\n{sep}\n");
    let show = |x: &Option<Spread>| x.as_ref().map_or("–".to_string(), Spread::show);
    for p in summary {
        s += &format!("| {} |", p.platform);
        for c in &p.classes {
            s += &format!(" {} | {} |", show(&c.bev), show(&c.d3));
        }
        s += "\n";
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use pi3det_nn::eval::ClassAp;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        demo: DemoArgs,
    }

    fn parse(args: &[&str]) -> std::result::Result<DemoArgs, clap::Error> {
        Cli::try_parse_from([&["demo"], args].concat()).map(|c| c.demo)
    }

    #[test]
    fn defaults_split_and_seeds() {
        let a = parse(&[]).unwrap();
        assert_eq!((a.train_sequences, a.val_sequences, a.frames, a.target_train_sequences), (40, 12, 30, 4));
        assert_eq!((a.seed_list(), a.epochs, a.val_seed), (vec![0], 3, DEFAULT_VAL_SEED));
        let plans = a.plans();
        assert_eq!(plans[0].platform, Platform::Vehicle);
        assert_eq!((plans[0].sequences, plans[0].val_sequences), (52, 12));
        assert_eq!((plans[1].sequences, plans[1].val_sequences), (16, 12));
        assert_eq!((0..52).filter(|&i| plans[0].split_of(i) == "val").count(), 12);
        let a = parse(&["--seeds", "0,1,2"]).unwrap();
        assert_eq!(a.seed_list(), vec![0, 1, 2]);
        assert!(parse(&["--seeds", "1", "--seed", "2"]).is_err(), "--seed and --seeds conflict");
        assert!(parse(&["--seeds", "1,1"]).unwrap().check().is_err());
        assert!(parse(&["--val-sequences", "0"]).unwrap().check().is_err());
    }

    #[test]
    fn spread_is_the_sample_std() {
        let s = Spread::of(vec![1.0, 2.0, 3.0]).unwrap();
        assert_eq!(s.mean, 2.0);
        assert!((s.std.unwrap() - 1.0).abs() < 1e-12);
        assert_eq!(s.show(), "2.0 ± 1.0");
        assert_eq!(Spread::of(vec![5.0]).unwrap().std, None);
        assert!(Spread::of(vec![]).is_none());
    }

    fn run(seed: u64, car: f64) -> SeedRun {
        let ap = |class: &str, bev: f64, num_gt| ClassAp {
            class: class.into(),
            iou: if class == "Car" { 0.7 } else { 0.5 },
            bev_r40: bev,
            d3_r40: bev / 2.0,
            num_gt,
            num_det: 3,
            loose: None,
        };
        let row = |platform: &str, peds| DemoRow {
            platform: platform.into(),
            frames: 10,
            summary: ApSummary { frames: 10, classes: vec![ap("Car", car, 5), ap("Pedestrian", 10.0, peds)] },
            latency: Latency::default(),
        };
        SeedRun {
            seed,
            dir: PathBuf::new(),
            reused_data: false,
            reused_checkpoint: false,
            rows: vec![row("vehicle", 4), row("drone", 0)],
            timings: Timings::default(),
        }
    }

    #[test]
    fn summary_and_tables() {
        let classes = vec!["Car".to_string(), "Pedestrian".to_string()];
        let runs = vec![run(0, 40.0), run(1, 42.0)];
        let sum = summarize(&runs, &classes);
        assert_eq!(sum.len(), 2);
        let car = &sum[0].classes[0];
        assert_eq!(car.bev.as_ref().unwrap().values, vec![40.0, 42.0]);
        assert_eq!(car.d3.as_ref().unwrap().mean, 20.5);
        assert!((car.bev.as_ref().unwrap().std.unwrap() - 2f64.sqrt()).abs() < 1e-12);
        assert!(sum[1].classes[1].bev.is_none(), "no pedestrians on the drone: no number");
        let t = spread_table(&sum);
        assert!(t.contains("| vehicle | 41.0 ± 1.4 | 20.5 ± 0.7 | 10.0 ± 0.0 | 5.0 ± 0.0 |"), "{t}");
        assert!(t.contains("| drone | 41.0 ± 1.4 | 20.5 ± 0.7 | – | – |"), "{t}");
        let one = summarize(&runs[..1], &classes);
        assert!(spread_table(&one).contains("| vehicle | 40.0 (n=1) | 20.0 (n=1) |"), "{}", spread_table(&one));
        let t = seeds_table(&runs, &classes);
        assert!(t.contains("| 1 | vehicle | 10 | 42.0 / 21.0 | 10.0 / 5.0 |"), "{t}");
        let t = demo_table(&runs[0].rows, &classes);
        assert!(t.contains("| drone | 10 | 40.0 / 20.0 | – | – |"), "no latency measured: –");
    }
}
