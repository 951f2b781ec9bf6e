//! `pi3det stats DATA... --out report/`: the argument struct and runner for the `pi3det` binary.

use std::io::Write;
use std::path::PathBuf;

use indicatif::{ProgressBar, ProgressStyle};

use crate::analyze::{analyze, Input, LevelChoice, Progress, StatsConfig};
use crate::error::AnalysisError;
use crate::ground::{AttitudePrior, GroundConfig};
use crate::report::{self, AttitudeCsv};

/// Platform-discrepancy statistics, tables and figures, with pose-free attitude from the ground.
#[derive(clap::Args, Debug, Clone)]
pub struct StatsArgs {
    /// Datasets: Pi3DET roots (pi3det_infos_*.pkl), KITTI split folders, mmdet3d info .pkl files;
    /// any mix, grouped by the platform each frame declares (KITTI and nuScenes: vehicle).
    #[arg(required = true, value_name = "DATA")]
    pub data: Vec<PathBuf>,
    /// Folder for report.md, the CSV tables, stats.json, attitude.csv and the figures.
    #[arg(long, default_value = "report")]
    pub out: PathBuf,
    /// Print the full JSON (as stats.json) to stdout instead of the markdown report.
    #[arg(long)]
    pub json: bool,
    /// At most this many frames of each dataset (the first ones by sequence and time).
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Bins of the 1-D distributions.
    #[arg(long, default_value_t = 100)]
    pub bins: usize,
    /// Bins per axis of the relative-pitch / distance histogram.
    #[arg(long, default_value_t = 60)]
    pub bins_2d: usize,
    /// Skip the ground-plane attitude fit.
    #[arg(long)]
    pub no_ground: bool,
    /// Skip temporal smoothing of the ground attitude along sequences.
    #[arg(long)]
    pub no_smoothing: bool,
    /// Inlier band of the ground plane fit (m).
    #[arg(long, default_value_t = 0.10)]
    pub ground_threshold_m: f64,
    /// Largest sensor tilt the ground fit considers (deg).
    #[arg(long, default_value_t = 35.0)]
    pub max_tilt_deg: f64,
    /// What levels the frames for elevation and levelled targets.
    #[arg(long, value_enum, default_value_t = LevelChoice::Auto)]
    pub level: LevelChoice,
    /// Tables only, no figures.
    #[arg(long)]
    pub no_plots: bool,
    /// Seed of the ground fit's RANSAC and of the scatter-plot sampling.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

impl StatsArgs {
    pub fn config(&self) -> StatsConfig {
        let ground = (!self.no_ground).then(|| GroundConfig {
            inlier_threshold_m: self.ground_threshold_m,
            prior: AttitudePrior { max_tilt_rad: self.max_tilt_deg.to_radians(), ..AttitudePrior::default() },
            seed: self.seed,
            ..GroundConfig::default()
        });
        StatsConfig {
            bins: self.bins,
            bins_2d: self.bins_2d,
            max_frames: self.max_frames,
            ground,
            smooth: !self.no_smoothing,
            level: self.level,
            seed: self.seed,
            ..StatsConfig::default()
        }
    }
}

struct Bar(ProgressBar);

impl Progress for Bar {
    fn total(&self, frames: u64) {
        self.0.set_length(frames);
    }
    fn frame_done(&self) {
        self.0.inc(1);
    }
}

/// Runs `pi3det stats`.
pub fn run(args: &StatsArgs) -> Result<(), AnalysisError> {
    let datasets = args.data.iter().map(|p| pi3det_data::open(p)).collect::<Result<Vec<_>, _>>()?;
    let inputs: Vec<Input> = args
        .data
        .iter()
        .zip(&datasets)
        .map(|(p, d)| Input { name: p.display().to_string(), dataset: d.as_ref() })
        .collect();
    std::fs::create_dir_all(&args.out).map_err(|e| AnalysisError::io(&args.out, e))?;
    let bar = ProgressBar::new(0)
        .with_style(
            ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} frames {per_sec} eta {eta}")
                .expect("valid template"),
        )
        .with_message("stats");
    let mut rows = AttitudeCsv::create(&args.out.join("attitude.csv"))?;
    let analysis = analyze(&inputs, &args.config(), &Bar(bar.clone()), &mut |f| rows.write(f))?;
    rows.finish()?;
    bar.finish_and_clear();
    let figures = if args.no_plots { Vec::new() } else { crate::plots::write_figures(&analysis, &args.out)? };
    let pngs: Vec<String> = figures
        .iter()
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect();
    report::write_tables(&analysis, &args.out, &pngs)?;
    let text = if args.json { report::json(&analysis)? } else { report::markdown(&analysis, &pngs) };
    let mut out = std::io::stdout().lock();
    writeln!(out, "{text}").map_err(|e| AnalysisError::io(std::path::Path::new("<stdout>"), e))?;
    tracing::info!("wrote the report, tables and {} figure files to {}", figures.len(), args.out.display());
    Ok(())
}
