//! `pi3det train`: a detector from a TOML config, with a progress bar, periodic evaluation and
//! checkpoints.

use std::path::PathBuf;
use std::time::Instant;

use indicatif::ProgressBar;

use crate::args::{open_subset, DataArgs, DeviceArgs};
use crate::common::{progress_style, refuse_existing};
use pi3det_nn::config::DetectorConfig;
use pi3det_nn::config_override::ConfigOverride;
use pi3det_nn::error::Result;
use pi3det_nn::train::{self, Event, TrainOptions};

/// Train a detector (PointPillars with an anchor or center head) from a TOML config.
#[derive(clap::Args, Debug, Clone)]
pub struct TrainArgs {
    /// Detector config (e.g. configs/pointpillars_cpu.toml).
    #[arg(long)]
    pub config: PathBuf,
    // `--max-frames` overrides the config's `train.max_train_frames`.
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
    /// Change one config key (dotted TOML path, e.g. `train.lr=0.002` or
    /// `head.anchors.0.matched_threshold=0.55`); repeatable. Applied before the flags above.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<ConfigOverride>,
    /// Level every training and validation frame through Virtual Platform Pose to a virtual
    /// sensor this many metres above the ground (e.g. a detector trained on drone labels in the
    /// frame Pi3DET-Net adapts in; `pi3det detect --vpp-height` for its inference).
    #[arg(long, value_name = "M")]
    pub vpp_height: Option<f64>,
    #[command(flatten)]
    pub device: DeviceArgs,
}

impl TrainArgs {
    /// The config file with the command line's overrides (epochs, batch size, seed, frame
    /// limits) written into it, so the checkpoint records what was run.
    pub fn config(&self) -> Result<DetectorConfig> {
        let mut cfg = DetectorConfig::from_file_with(&self.config, &self.set)?;
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
        self.device.apply_precision(&mut cfg);
        cfg.validate()?;
        Ok(cfg)
    }
}

/// Trains with a progress bar on stderr (none when `quiet`); returns the report.
pub fn train_with_progress(opts: TrainOptions, quiet: bool) -> Result<train::TrainReport> {
    let bar = ProgressBar::hidden();
    let t0 = Instant::now();
    let mut on_event = |e: Event<'_>| match e {
        Event::Start { steps_per_epoch, total_steps, parameters, database } => {
            if !quiet {
                bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
            }
            bar.set_length(total_steps as u64);
            bar.set_style(progress_style("{prefix} [{bar:25}] {pos}/{len} {elapsed}<{eta} {msg}"));
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
        Event::EpochEnd { epoch, mean_loss, mean_terms, seconds, data_wait_seconds, phase_seconds } => {
            let terms: Vec<String> = mean_terms.iter().map(|(k, v)| format!("{k} {v:.3}")).collect();
            let phases: Vec<String> = phase_seconds.iter().map(|(k, v)| format!("{k} {v:.0}")).collect();
            bar.suspend(|| {
                eprintln!(
                    "epoch {}: mean loss {mean_loss:.4} ({}), {seconds:.0} s ({}, {data_wait_seconds:.0} s waiting for data)",
                    epoch + 1,
                    terms.join(", "),
                    phases.join(", ")
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
    let frame_transform = match args.vpp_height {
        Some(h) => Some(crate::detect::vpp(&cfg, h)?),
        None => None,
    };
    let report = train_with_progress(
        TrainOptions {
            config: cfg,
            train,
            val,
            out_dir: args.out.clone(),
            device,
            resume: args.resume.clone(),
            stage: None,
            frame_transform,
        },
        false,
    )?;
    println!("final checkpoint: {}", report.final_checkpoint.display());
    if let Some(s) = &report.final_eval {
        println!("validation: {}", s.one_line());
    }
    Ok(())
}
