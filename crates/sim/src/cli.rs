//! `pi3det simulate` and `pi3det bench sim`: argument structs and runners for the `pi3det`
//! binary (feature `cli`).

use std::path::{Path, PathBuf};

use pi3det_data::Platform;

use crate::bench::{self, BenchOptions};
use crate::export::{default_val_sequences, export, pi3det_mini, stratified_layouts, ExportOptions, PlatformPlan};
use crate::preview::{render_bev, PreviewOptions};
use crate::scene::Layout;
use crate::sensor::SensorPreset;
use crate::sequence::{Sequence, SequenceSpec};
use crate::{SimConfig, SimError};

/// Ready-made dataset plans.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DatasetPreset {
    /// All three platforms at small scale with the paper's proportions (vehicle largest), split
    /// into train/val by sequence, one folder per platform and split.
    Pi3detMini,
}

fn parse_platform(s: &str) -> Result<Platform, String> {
    match Platform::parse(s) {
        Platform::Unknown => Err(format!("unknown platform {s:?} (vehicle, drone, quadruped)")),
        p => Ok(p),
    }
}

/// Sensor settings shared by both commands.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct SensorArgs {
    /// Sensor preset (default: the config's sensor, an Ouster OS1-64 as on all Pi3DET platforms).
    #[arg(long, value_enum)]
    pub sensor: Option<SensorPreset>,
    /// Domain randomisation: each sequence is recorded with one of these sensors, drawn from the
    /// seed and the sequence's index (e.g. `--sensors os1-64,hdl-64,vlp-32c,nuscenes-32`).
    #[arg(long, value_enum, value_delimiter = ',', conflicts_with = "sensor")]
    pub sensors: Vec<SensorPreset>,
    /// Override the number of beams.
    #[arg(long)]
    pub beams: Option<u32>,
    /// Override the columns per revolution (OS1: 512, 1024 or 2048).
    #[arg(long)]
    pub columns: Option<u32>,
    /// TOML file with settings to change (see --print-config for every key).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

impl SensorArgs {
    /// The configuration: the file (or defaults), then the preset, then beams/columns.
    pub fn config(&self) -> Result<SimConfig, SimError> {
        let mut cfg = match &self.config {
            Some(p) => SimConfig::load(p)?,
            None => SimConfig::default(),
        };
        if let Some(preset) = self.sensor {
            cfg.sensor = preset.config();
        }
        if !self.sensors.is_empty() {
            cfg.randomise.sensors = self.sensors.iter().map(|p| p.config().name).collect();
        }
        if let Some(b) = self.beams {
            cfg.sensor.beams = b;
        }
        if let Some(c) = self.columns {
            cfg.sensor.columns = c;
        }
        cfg.validate()?;
        Ok(cfg)
    }
}

/// Simulate LiDAR sequences from a vehicle, drone or quadruped and write them in the Pi3DET
/// layout (`<out>/<split>/`, or `<out>/<platform>/<split>/` with a preset).
#[derive(clap::Args, Debug, Clone)]
pub struct SimulateArgs {
    /// Platform to simulate: vehicle, drone or quadruped.
    #[arg(long, value_parser = parse_platform, required_unless_present_any = ["preset", "print_config"], conflicts_with = "preset")]
    pub platform: Option<Platform>,
    /// Number of sequences.
    #[arg(long, default_value_t = 4)]
    pub sequences: u32,
    /// Frames per sequence (10 Hz).
    #[arg(long, default_value_t = 200)]
    pub frames: u32,
    /// Sequences for the val split (default: a quarter, at least one from two sequences on).
    #[arg(long)]
    pub val_sequences: Option<u32>,
    /// Seed: the same seed gives byte-identical files.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder.
    #[arg(long, required_unless_present = "print_config")]
    pub out: Option<PathBuf>,
    /// A ready-made plan for all platforms instead of --platform/--sequences/--frames.
    #[arg(long, value_enum)]
    pub preset: Option<DatasetPreset>,
    /// Force one layout for every sequence (default: drawn per sequence by the platform's weights).
    #[arg(long, value_enum)]
    pub layout: Option<Layout>,
    /// Give each split's sequences layouts in the platform's proportions, in a fixed order,
    /// instead of drawing each (a small val split then holds the intended mix whatever the seed).
    #[arg(long, conflicts_with = "layout")]
    pub stratify_layouts: bool,
    /// Write a bird's-eye PNG of one frame of the first sequence (with a preset: one per platform,
    /// named `<stem>_<platform>.png`).
    #[arg(long)]
    pub preview: Option<PathBuf>,
    /// Which frame of the first sequence to preview.
    #[arg(long, default_value_t = 0)]
    pub preview_frame: usize,
    /// Metres from the sensor to the preview's edge.
    #[arg(long, default_value_t = 60.0)]
    pub preview_range: f64,
    /// Replace existing files.
    #[arg(long)]
    pub overwrite: bool,
    /// Keep only boxes with at least this many points (default 5, or the config's).
    #[arg(long)]
    pub min_points: Option<u32>,
    #[command(flatten)]
    pub sensor: SensorArgs,
    /// Print the full configuration as TOML and exit.
    #[arg(long)]
    pub print_config: bool,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
}

fn preview_path(base: &Path, platform: Platform, several: bool) -> PathBuf {
    if !several {
        return base.to_path_buf();
    }
    let stem = base.file_stem().and_then(|s| s.to_str()).unwrap_or("preview");
    let ext = base.extension().and_then(|s| s.to_str()).unwrap_or("png");
    base.with_file_name(format!("{stem}_{}.{ext}", platform.as_str()))
}

pub fn run(args: &SimulateArgs) -> Result<(), SimError> {
    let mut cfg = args.sensor.config()?;
    if let Some(m) = args.min_points {
        cfg.labels.min_points = m;
    }
    if args.print_config {
        print!("{}", cfg.to_toml_string());
        return Ok(());
    }
    let out = args.out.clone().ok_or_else(|| SimError::invalid("--out is required"))?;
    let plans: Vec<PlatformPlan> = match (args.preset, args.platform) {
        (Some(DatasetPreset::Pi3detMini), _) => pi3det_mini(),
        (None, Some(platform)) => vec![PlatformPlan {
            platform,
            sequences: args.sequences,
            frames: args.frames,
            val_sequences: args.val_sequences.unwrap_or_else(|| default_val_sequences(args.sequences)),
        }],
        (None, None) => return Err(SimError::invalid("give --platform or --preset")),
    };
    let opts = ExportOptions {
        out: out.clone(),
        seed: args.seed,
        overwrite: args.overwrite,
        per_platform_folders: args.preset.is_some(),
        layout: args.layout,
        stratify_layouts: args.stratify_layouts,
    };
    let total: u64 = plans.iter().map(|p| u64::from(p.sequences) * u64::from(p.frames)).sum();
    let bar = if args.no_progress { indicatif::ProgressBar::hidden() } else { indicatif::ProgressBar::new(total) };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} frames ({per_sec}, eta {eta}) {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let t0 = std::time::Instant::now();
    let report = export(&cfg, &plans, &opts, &mut |seq, _| {
        bar.set_message(seq.name.clone());
        bar.inc(1);
    })?;
    bar.finish_and_clear();
    let secs = t0.elapsed().as_secs_f64();
    println!(
        "simulated {} frames in {:.1} s ({:.1} frames/s), seed {}",
        report.frames(),
        secs,
        report.frames() as f64 / secs.max(1e-9),
        args.seed
    );
    for s in &report.splits {
        println!(
            "  {:<9} {:<5} {:>5} frames {:>7} boxes {:>6.0} points/frame  {} ({})",
            s.platform.as_str(),
            s.split,
            s.frames,
            s.boxes,
            s.points as f64 / s.frames.max(1) as f64,
            s.info_file.display(),
            s.sequences.join(", ")
        );
    }
    if let Some(base) = &args.preview {
        for plan in &plans {
            let spec = SequenceSpec {
                platform: plan.platform,
                index: 0,
                frames: plan.frames,
                seed: args.seed,
                // Sequence 0 is first in its split: with stratified layouts it has the first one.
                layout: match (args.layout, args.stratify_layouts) {
                    (None, true) => Some(stratified_layouts(cfg.platform(plan.platform)?.layout_weights, 1)[0]),
                    (l, _) => l,
                },
            };
            let seq = Sequence::generate(&cfg, spec)?;
            let f = args.preview_frame.min(seq.len().saturating_sub(1));
            let sim = seq.render(f);
            let cars = sim.objects.iter().filter(|o| o.name == "Car").count();
            let caption = format!(
                "{} F{:04} PTS {} CAR {} PED {}",
                seq.name.replace('_', " "),
                f,
                sim.points.len(),
                cars,
                sim.objects.len() - cars
            );
            let path = preview_path(base, plan.platform, plans.len() > 1);
            let frame = sim.to_frame(&crate::export::frame_id(0, f), plan.platform, &seq.name);
            render_bev(
                &frame,
                &caption,
                &PreviewOptions { half_extent_m: args.preview_range, ..Default::default() },
                &path,
            )?;
            println!("  preview: {}", path.display());
        }
    }
    Ok(())
}

/// Measure simulation throughput: frames/s and rays/s of full frame rendering (scene build, ray
/// casting, labels) on one sequence.
#[derive(clap::Args, Debug, Clone)]
pub struct BenchArgs {
    /// Frames to time (after 3 warm-up frames).
    #[arg(long, default_value_t = 100)]
    pub frames: usize,
    #[arg(long, value_parser = parse_platform, default_value = "vehicle")]
    pub platform: Platform,
    #[arg(long, value_enum, default_value = "urban")]
    pub layout: Layout,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[command(flatten)]
    pub sensor: SensorArgs,
}

pub fn run_bench(args: &BenchArgs) -> Result<(), SimError> {
    let cfg = args.sensor.config()?;
    let opts = BenchOptions {
        platform: args.platform,
        layout: args.layout,
        frames: args.frames.max(1),
        seed: args.seed,
        ..Default::default()
    };
    let report = bench::run(&cfg, &opts)?;
    println!("{report}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(subcommand)]
        cmd: Cmd,
    }

    #[derive(clap::Subcommand)]
    enum Cmd {
        Simulate(SimulateArgs),
        Bench(BenchArgs),
    }

    #[test]
    fn arguments_parse() {
        let cli = Cli::try_parse_from([
            "x",
            "simulate",
            "--platform",
            "drone",
            "--sequences",
            "4",
            "--frames",
            "200",
            "--seed",
            "7",
            "--out",
            "d",
        ])
        .unwrap();
        let Cmd::Simulate(a) = cli.cmd else { panic!() };
        assert_eq!(a.platform, Some(Platform::Drone));
        assert_eq!((a.sequences, a.frames, a.seed), (4, 200, 7));
        let cli = Cli::try_parse_from([
            "x",
            "simulate",
            "--preset",
            "pi3det-mini",
            "--out",
            "d",
            "--sensor",
            "hdl-64",
            "--columns",
            "512",
        ])
        .unwrap();
        let Cmd::Simulate(a) = cli.cmd else { panic!() };
        assert_eq!(a.preset, Some(DatasetPreset::Pi3detMini));
        assert_eq!(a.sensor.config().unwrap().sensor.columns, 512);
        assert_eq!(a.sensor.config().unwrap().sensor.elevation_max_deg, 2.0);
        assert!(Cli::try_parse_from(["x", "simulate", "--out", "d"]).is_err());
        assert!(Cli::try_parse_from(["x", "simulate", "--platform", "boat", "--out", "d"]).is_err());
        assert!(Cli::try_parse_from(["x", "bench", "--frames", "5", "--sensor", "nuscenes-32"]).is_ok());
    }

    #[test]
    fn preview_names_per_platform() {
        assert_eq!(preview_path(Path::new("a/p.png"), Platform::Drone, true), PathBuf::from("a/p_drone.png"));
        assert_eq!(preview_path(Path::new("a/p.png"), Platform::Drone, false), PathBuf::from("a/p.png"));
    }
}
