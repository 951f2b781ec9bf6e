//! `pi3det adapt`: Pi3DET-Net's PA → pseudo-labels → KA with a progress bar per stage
//! ([`pi3det_adapt::pipeline`]).

use std::path::PathBuf;

use indicatif::ProgressBar;

use crate::args::{open_subset, DeviceArgs};
use crate::common::progress_style;
use pi3det_adapt::pipeline::{self, AdaptConfig, AdaptEvent, AdaptOptions, AdaptReport, Component, Stage};
use pi3det_nn::config_override::ConfigOverride;
use pi3det_nn::error::Result;
use pi3det_nn::train::Event;

/// Adapt a detector trained on a source platform to a target platform without target labels
/// (Pi3DET-Net: RPJ, VPP, GTD, PFA; Pre-Adaptation → pseudo-labels → Knowledge-Adaptation).
#[derive(clap::Args, Debug, Clone)]
pub struct AdaptArgs {
    /// Adaptation config (e.g. configs/pi3det_net_cpu.toml).
    #[arg(long)]
    pub config: PathBuf,
    /// Labelled source training data (e.g. DATA/vehicle/train).
    #[arg(long, value_name = "PATH")]
    pub source: PathBuf,
    /// Target training data; its labels, if any, are only used to score the pseudo-labels.
    #[arg(long, value_name = "PATH")]
    pub target: PathBuf,
    /// Target validation data: the source-only and adapted models are evaluated on it.
    #[arg(long, value_name = "PATH")]
    pub val: Option<PathBuf>,
    /// Output folder (PA and KA checkpoints, pseudo-labels, adapt.json, adapt.md).
    #[arg(long)]
    pub out: PathBuf,
    /// Switch components off for an ablation row: any of rpj, vpp, gtd, pfa (comma-separated).
    #[arg(long, value_delimiter = ',', value_name = "C,C,...")]
    pub without: Vec<Component>,
    /// Start from this finished PA checkpoint instead of training one (same architecture).
    #[arg(long, value_name = "CKPT")]
    pub pa_ckpt: Option<PathBuf>,
    /// Continue a run that stopped in OUT, in the stage where it stopped.
    #[arg(long)]
    pub resume: bool,
    /// Stop after this stage (pa, ka).
    #[arg(long, value_parser = parse_stage)]
    pub stop_after: Option<Stage>,
    /// At most this many frames of each split, spread evenly (0: all).
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub max_frames: usize,
    /// Override PA's epochs (the detector's `train.epochs`).
    #[arg(long)]
    pub pa_epochs: Option<usize>,
    /// Override KA's epochs (`ka.epochs`).
    #[arg(long)]
    pub ka_epochs: Option<usize>,
    /// Leave out the VPP diagnostics: evaluating the PA model through VPP and scoring
    /// pseudo-labels made without VPP (two extra inference passes that show what VPP does).
    #[arg(long, overrides_with = "vpp_diagnostics")]
    pub no_vpp_diagnostics: bool,
    /// The diagnostics on (the default).
    #[arg(long, hide = true, overrides_with = "no_vpp_diagnostics")]
    pub vpp_diagnostics: bool,
    /// Override the seed of both stages.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Change one config key (dotted TOML path, e.g. `detector.pfa.kl_weight=0` or
    /// `pseudo_labels.positive_score=0.3`); repeatable. Applied before the flags above.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<ConfigOverride>,
    #[command(flatten)]
    pub device: DeviceArgs,
}

fn parse_stage(s: &str) -> std::result::Result<Stage, String> {
    match s {
        "pa" => Ok(Stage::Pa),
        "ka" => Ok(Stage::Ka),
        o => Err(format!("unknown stage {o:?} (pa, ka)")),
    }
}

impl AdaptArgs {
    /// The config file with the command line's overrides and `--without` applied.
    pub fn config(&self) -> Result<AdaptConfig> {
        let mut cfg = AdaptConfig::from_file_with(&self.config, &self.set)?.without(&self.without);
        if let Some(e) = self.pa_epochs {
            cfg.detector.train.epochs = e;
        }
        if let Some(e) = self.ka_epochs {
            cfg.ka.epochs = e;
        }
        if let Some(s) = self.seed {
            cfg.detector.train.seed = s;
        }
        self.device.apply_precision(&mut cfg.detector);
        cfg.validate()?;
        Ok(cfg)
    }
}

/// Runs an adaptation with progress bars on stderr (none when `quiet`).
pub fn adapt_with_progress(opts: AdaptOptions, quiet: bool) -> Result<AdaptReport> {
    let bar = ProgressBar::hidden();
    if !quiet {
        bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
    }
    bar.set_style(progress_style("{prefix} [{bar:25}] {pos}/{len} {elapsed}<{eta} {msg}"));
    let mut on_event = |e: AdaptEvent<'_>| match e {
        AdaptEvent::Stage(s) => {
            bar.set_prefix(s);
            bar.set_position(0);
            bar.set_message("");
        }
        AdaptEvent::Message(m) => bar.suspend(|| eprintln!("{m}")),
        AdaptEvent::Pa(Event::Start { total_steps, parameters, database, .. }) => {
            bar.set_length(total_steps as u64);
            bar.suspend(|| {
                eprintln!("PA: {parameters} parameters, {total_steps} steps, database of {database} objects")
            });
        }
        AdaptEvent::Pa(Event::Step(s)) => {
            let terms: Vec<String> = s.terms.iter().map(|(k, v)| format!("{k} {v:.3}")).collect();
            bar.set_prefix(format!("PA epoch {}/{}", s.epoch + 1, s.epochs));
            bar.set_message(format!("loss {:.3} ({})", s.loss, terms.join(", ")));
            bar.set_position(s.step as u64);
        }
        AdaptEvent::Pa(Event::EpochEnd { epoch, mean_loss, mean_terms, seconds, .. }) => {
            let terms: Vec<String> = mean_terms.iter().map(|(k, v)| format!("{k} {v:.3}")).collect();
            bar.suspend(|| {
                eprintln!("PA epoch {}: mean loss {mean_loss:.4} ({}), {seconds:.0} s", epoch + 1, terms.join(", "))
            })
        }
        AdaptEvent::Pa(_) => {}
        AdaptEvent::Labels { done, total } => {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        }
        AdaptEvent::KaStep(s) => {
            bar.set_length(s.total_steps as u64);
            bar.set_prefix(format!("KA epoch {}", s.epoch + 1));
            bar.set_message(format!(
                "loss {:.3} (source {:.3}, target {:.3}, λ_KL·KL {:.4}) lr {:.1e}",
                s.loss, s.source, s.target, s.kl, s.lr
            ));
            bar.set_position(s.step as u64);
        }
        AdaptEvent::KaEpoch(e) => {
            let parts = format!("source {:.3}, target {:.3}, λ_KL·KL {:.4}", e.mean_source, e.mean_target, e.mean_kl);
            let line = format!("KA epoch {}: mean loss {:.4} ({parts}), {:.0} s", e.epoch + 1, e.mean_loss, e.seconds);
            bar.suspend(|| eprintln!("{line}"))
        }
    };
    let r = pipeline::run(opts, &mut on_event);
    bar.finish_and_clear();
    r
}

pub fn run_adapt(args: &AdaptArgs) -> Result<AdaptReport> {
    let cfg = args.config()?;
    let device = args.device.setup(cfg.detector.train.threads)?;
    let source = open_subset(&args.source, Some("train"), None, args.max_frames)?;
    let target = open_subset(&args.target, Some("train"), None, args.max_frames)?;
    let val = match &args.val {
        Some(v) => Some(open_subset(v, Some("val"), None, args.max_frames)?),
        None => None,
    };
    eprintln!(
        "{}: components {}; {} source, {} target{} frames",
        cfg.name,
        pipeline::component_names(&cfg.components()),
        source.len(),
        target.len(),
        val.as_ref().map(|v| format!(", {} validation", v.len())).unwrap_or_default()
    );
    let det_cfg = cfg.detector.clone();
    let opts = AdaptOptions {
        config: cfg,
        source,
        target,
        val,
        out_dir: args.out.clone(),
        device,
        pa_ckpt: args.pa_ckpt.clone(),
        resume: args.resume,
        stop_after: args.stop_after,
        source_only: None,
        vpp_diagnostics: !args.no_vpp_diagnostics,
    };
    let report = adapt_with_progress(opts, false)?;
    println!("{}", pipeline::markdown(&report, &det_cfg));
    println!("report: {}", args.out.join("adapt.json").display());
    Ok(report)
}
