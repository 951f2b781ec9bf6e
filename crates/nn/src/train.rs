//! Training: the loader thread prepares augmented batches with their targets while the network
//! trains on the previous one; AdamW (or Adam) with a one-cycle schedule and gradient clipping;
//! periodic evaluation with the project's evaluator; a checkpoint per `ckpt_every` epochs (atomic,
//! with the optimiser moments) and `final.safetensors` (weights only); `--resume` continues from
//! a checkpoint's epoch with its weights and moments; seeds fix the initial weights, the shuffling
//! and every augmentation draw.
//!
//! `pi3det train --config configs/pointpillars_cpu.toml --data DATA/vehicle/train --val
//! DATA/vehicle/val --out runs/pp_cpu`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use tch::Device;

use crate::augment::{Augment, AugmentConfig, GtDatabase, GtSamplingConfig};
use crate::checkpoint::{self, TrainState};
use crate::config::DetectorConfig;
use crate::data_loader::{Loader, LoaderOptions, Subset};
use crate::detect;
use crate::detector::{Detector, Domain};
use crate::error::{NnError, Result};
use crate::eval::{self, ApSummary};
use crate::optim::{OneCycle, Optimizer};
use crate::preprocess::Preprocessor;

/// What to train on and where to write.
pub struct TrainOptions {
    pub config: DetectorConfig,
    pub train: Subset,
    pub val: Option<Subset>,
    pub out_dir: PathBuf,
    pub device: Device,
    /// A checkpoint written by an earlier run of the same config to continue from.
    pub resume: Option<PathBuf>,
    /// Recorded in the checkpoints (`pa` for Pi3DET-Net's Pre-Adaptation; `None`: plain training).
    pub stage: Option<String>,
    /// Every frame's transform into the detector's frame instead of the config's `shift_z`
    /// (e.g. Virtual Platform Pose); training, the ground-truth database and evaluation use it.
    pub frame_transform: Option<Arc<dyn crate::preprocess::FrameTransform>>,
}

/// Progress of one step, for progress bars.
#[derive(Debug, Clone)]
pub struct StepInfo {
    pub epoch: usize,
    pub epochs: usize,
    pub batch: usize,
    pub batches: usize,
    pub step: i64,
    pub lr: f64,
    pub loss: f64,
    pub terms: Vec<(&'static str, f64)>,
    pub grad_norm: f64,
    pub step_seconds: f64,
    /// Seconds the training thread waited for the loader.
    pub wait_seconds: f64,
}

/// Events reported while training.
pub enum Event<'a> {
    Start {
        steps_per_epoch: usize,
        total_steps: usize,
        parameters: i64,
        database: usize,
    },
    Step(&'a StepInfo),
    /// `data_wait_seconds`: time the training thread waited for the loader in this epoch;
    /// `phase_seconds`: where the steps' time went (forward, loss, backward, optimiser).
    EpochEnd {
        epoch: usize,
        mean_loss: f64,
        mean_terms: Vec<(&'static str, f64)>,
        seconds: f64,
        data_wait_seconds: f64,
        phase_seconds: [(&'static str, f64); 4],
    },
    Eval {
        epoch: usize,
        summary: &'a ApSummary,
    },
    Checkpoint {
        path: &'a Path,
    },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochLog {
    pub epoch: usize,
    pub mean_loss: f64,
    pub seconds: f64,
    pub eval: Option<ApSummary>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainReport {
    pub final_checkpoint: PathBuf,
    pub epochs: Vec<EpochLog>,
    pub train_seconds: f64,
    pub steps: i64,
    pub final_eval: Option<ApSummary>,
}

/// Builds the augmentation pipeline (and the ground-truth database when it is used).
/// The database is built in the frame `prep` puts frames in (its per-frame transform), so pasted
/// objects share the detector's frame.
pub fn build_augments(prep: &Preprocessor, train: &Subset) -> Result<(Vec<Box<dyn Augment>>, usize)> {
    let cfg = &prep.cfg;
    let db = match cfg.train.augment.iter().find_map(|a| match a {
        AugmentConfig::GtSampling(c) => Some(c),
        _ => None,
    }) {
        Some(c) => Some(Arc::new(build_database(prep, train, c)?)),
        None => None,
    };
    let n = db.as_ref().map_or(0, |d| d.len());
    let augs = cfg.train.augment.iter().map(|a| a.build(db.as_ref(), &cfg.classes)).collect::<Result<_>>()?;
    Ok((augs, n))
}

/// The ground-truth database of a training subset (frames read in parallel).
pub fn build_database(prep: &Preprocessor, train: &Subset, gs: &GtSamplingConfig) -> Result<GtDatabase> {
    let cfg = &prep.cfg;
    let parts: Vec<GtDatabase> = train
        .indices
        .par_iter()
        .map(|&i| {
            let frame = train.dataset.load(i)?;
            let s = prep.sample(&frame, cfg.train.min_points_in_gt);
            Ok(GtDatabase::build([&s], &cfg.classes, gs))
        })
        .collect::<Result<_>>()?;
    let mut db = GtDatabase { by_class: vec![Vec::new(); cfg.classes.len()] };
    for p in parts {
        for (c, objs) in p.by_class.into_iter().enumerate() {
            db.by_class[c].extend(objs);
        }
    }
    Ok(db)
}

/// Evaluates a detector on a subset; ground truth restricted to the detector's BEV range.
pub fn evaluate_subset(
    det: &Detector,
    subset: &Subset,
    batch_size: usize,
) -> Result<(ApSummary, pi3det_eval::EvalReport)> {
    let (frames, _) = detect::detect(det, subset, batch_size, &mut |_, _| {})?;
    let r = det.cfg().pillars.point_cloud_range;
    let opts = eval::options(&det.cfg().classes, Some([r[0], r[1], r[3], r[4]]), None);
    let (report, summary) = eval::evaluate(&frames, &opts)?;
    Ok((summary, report))
}

/// Trains; `on_event` sees progress.
pub fn train(mut opts: TrainOptions, on_event: &mut dyn FnMut(Event<'_>)) -> Result<TrainReport> {
    opts.config.validate()?;
    if opts.train.is_empty() {
        return Err(NnError::Input("the training set has no frames".into()));
    }
    if opts.config.trained_on.is_none() {
        let resumed = match &opts.resume {
            Some(path) => checkpoint::load(path)?.config.trained_on,
            None => None,
        };
        opts.config.trained_on = Some(match resumed {
            Some(t) => t,
            None => trained_on(&opts.train, opts.frame_transform.is_some())?,
        });
    }
    let cfg = &opts.config;
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| NnError::io(&opts.out_dir, e))?;
    pi3det_data::io::write_atomic(&opts.out_dir.join("config.toml"), cfg.to_toml().as_bytes(), true)?;
    tch::manual_seed(cfg.train.seed as i64);
    let mut det = match &opts.frame_transform {
        Some(t) => Detector::with_preprocessor(Preprocessor::new(cfg)?.with_frame_transform(t.clone()), opts.device)?,
        None => Detector::new(cfg, opts.device)?,
    };
    let mut optim = Optimizer::new(det.named_trainables(), &cfg.train);
    let mut state = TrainState { stage: opts.stage.clone(), ..Default::default() };
    if let Some(path) = &opts.resume {
        let ck = checkpoint::load(path)?;
        // A checkpoint written before training recorded its frames resumes too.
        if ck.config.settings_toml() != cfg.settings_toml() {
            return Err(NnError::Input(format!(
                "{}: was written with another config; resume with the checkpoint's config",
                path.display()
            )));
        }
        ck.load_into(&mut det, path)?;
        optim.load_state(&ck.tensors, ck.state.step)?;
        state = ck.state;
    }
    let (augments, db_len) = build_augments(&det.prep, &opts.train)?;
    let augments = Arc::new(augments);
    let bs = cfg.train.batch_size;
    // The loader drops a last partial batch (unless it is the only one).
    let steps_per_epoch = (opts.train.len() / bs).max(1);
    let total_steps = steps_per_epoch * cfg.train.epochs;
    state.total_steps = total_steps;
    let schedule = OneCycle::new(&cfg.train, total_steps);
    on_event(Event::Start { steps_per_epoch, total_steps, parameters: det.num_parameters(), database: db_len });

    let mut report = TrainReport {
        final_checkpoint: PathBuf::new(),
        epochs: Vec::new(),
        train_seconds: 0.0,
        steps: 0,
        final_eval: None,
    };
    let mut saved: Vec<PathBuf> = Vec::new();
    let mut scales_checked = false;
    for epoch in state.epoch..cfg.train.epochs {
        let t_epoch = Instant::now();
        let loader = Loader::new(
            det.prep.clone(),
            augments.clone(),
            opts.train.clone(),
            LoaderOptions {
                batch_size: bs,
                train: true,
                seed: cfg.train.seed,
                epoch: epoch as u64,
                prefetch: cfg.train.prefetch,
                drop_last: true,
                views: Vec::new(),
            },
        );
        let batches = loader.num_batches;
        let mut sum = 0.0;
        let mut n = 0usize;
        let mut t_wait = Instant::now();
        let mut waited = 0.0;
        let mut term_sums: Vec<(&'static str, f64)> = Vec::new();
        let mut phases = [("forward", 0.0), ("loss", 0.0), ("backward", 0.0), ("optimiser", 0.0)];
        for (bi, batch) in loader.enumerate() {
            let batch = batch?;
            if batch.num_pillars < 2 {
                // Batch norm cannot train on (almost) nothing: frames without points in range.
                tracing::warn!("skipping a batch with {} pillars (frames without points in range?)", batch.num_pillars);
                t_wait = Instant::now();
                continue;
            }
            let wait = t_wait.elapsed().as_secs_f64();
            waited += wait;
            let t_step = Instant::now();
            let (lr, beta1) = schedule.at(optim.step as usize);
            let x = batch.inputs.to_device(opts.device);
            let targets = batch.targets.as_ref().ok_or_else(|| NnError::Loader("batch without targets".into()))?;
            let t = targets.to_device(opts.device);
            let mut rng = ChaCha8Rng::seed_from_u64(crate::data_loader::frame_seed(
                cfg.train.seed,
                epoch as u64,
                optim.step as u64 ^ 0x5eed,
            ));
            let out = det.forward_train(&x, &batch.gt, &mut rng)?;
            let t_loss = Instant::now();
            let losses = det.loss(&out, &t, &batch.gt, Domain::Source)?;
            let t_backward = Instant::now();
            // Once per run (also when resuming): a scale naming no term is a typo.
            if !scales_checked {
                scales_checked = true;
                let unused = losses.unused_scales();
                if !unused.is_empty() {
                    let names: Vec<&str> = losses.terms().iter().map(|(n, _)| *n).collect();
                    return Err(NnError::config(
                        "loss_weights",
                        format!(
                        "loss_weights names {unused:?}, which no stage of this detector computes (terms: {names:?})"
                    ),
                    ));
                }
            }
            let total = losses.total();
            optim.zero_grad();
            total.backward();
            let t_update = Instant::now();
            let grad_norm = optim.clip_grad_norm(cfg.train.grad_clip);
            let loss = total.double_value(&[]);
            if !loss.is_finite() || !grad_norm.is_finite() {
                return Err(NnError::Diverged(format!(
                    "loss {loss}, gradient norm {grad_norm} at epoch {epoch}, batch {bi}"
                )));
            }
            optim.update(lr, beta1);
            for (phase, (from, to)) in phases.iter_mut().zip([
                (t_step, t_loss),
                (t_loss, t_backward),
                (t_backward, t_update),
                (t_update, Instant::now()),
            ]) {
                phase.1 += (to - from).as_secs_f64();
            }
            sum += loss;
            n += 1;
            let info = StepInfo {
                epoch,
                epochs: cfg.train.epochs,
                batch: bi,
                batches,
                step: optim.step,
                lr,
                loss,
                terms: losses.terms().iter().map(|(k, v)| (*k, v.double_value(&[]))).collect(),
                grad_norm,
                step_seconds: t_step.elapsed().as_secs_f64(),
                wait_seconds: wait,
            };
            if term_sums.is_empty() {
                term_sums = info.terms.iter().map(|(k, _)| (*k, 0.0)).collect();
            }
            for (acc, (_, v)) in term_sums.iter_mut().zip(&info.terms) {
                acc.1 += v;
            }
            on_event(Event::Step(&info));
            t_wait = Instant::now();
        }
        let seconds = t_epoch.elapsed().as_secs_f64();
        let mean_loss = sum / n.max(1) as f64;
        state.epoch = epoch + 1;
        state.step = optim.step;
        state.train_seconds += seconds;
        state.last_loss = Some(mean_loss);
        let mean_terms = term_sums.iter().map(|(k, v)| (*k, v / n.max(1) as f64)).collect();
        on_event(Event::EpochEnd {
            epoch,
            mean_loss,
            mean_terms,
            seconds,
            data_wait_seconds: waited,
            phase_seconds: phases,
        });
        let last = epoch + 1 == cfg.train.epochs;
        let mut log = EpochLog { epoch: epoch + 1, mean_loss, seconds, eval: None };
        if let Some(val) = opts.val.as_ref().filter(|v| !v.is_empty()) {
            let every = cfg.train.eval_every;
            if last || (every > 0 && (epoch + 1) % every == 0) {
                let (summary, full) = evaluate_subset(&det, val, bs)?;
                let json = serde_json::to_vec_pretty(&full).unwrap_or_default();
                pi3det_data::io::write_atomic(
                    &opts.out_dir.join(format!("eval_epoch_{}.json", epoch + 1)),
                    &json,
                    true,
                )?;
                on_event(Event::Eval { epoch, summary: &summary });
                log.eval = Some(summary);
            }
        }
        let every = cfg.train.ckpt_every;
        if !last && every > 0 && (epoch + 1) % every == 0 {
            let path = opts.out_dir.join(format!("checkpoint_epoch_{}.safetensors", epoch + 1));
            checkpoint::save(&path, &det, Some(optim.state()), &state)?;
            on_event(Event::Checkpoint { path: &path });
            saved.push(path);
            while saved.len() > cfg.train.keep_checkpoints.max(1) {
                let old = saved.remove(0);
                let _ = std::fs::remove_file(old);
            }
        }
        report.epochs.push(log);
    }
    let final_path = opts.out_dir.join("final.safetensors");
    checkpoint::save(&final_path, &det, None, &state)?;
    on_event(Event::Checkpoint { path: &final_path });
    report.final_checkpoint = final_path;
    report.train_seconds = state.train_seconds;
    report.steps = state.step;
    report.final_eval = report.epochs.last().and_then(|e| e.eval.clone());
    let json = serde_json::to_vec_pretty(&report).unwrap_or_default();
    pi3det_data::io::write_atomic(&opts.out_dir.join("train_report.json"), &json, true)?;
    Ok(report)
}

/// The training frames' sensor height (median over up to 32 frames spread over the set; `None`
/// when training levels frames itself, e.g. `--vpp-height`, or no ground is found) and mean
/// intensity, recorded in the checkpoint's config ([`crate::config::TrainedOn`]).
pub fn trained_on(train: &Subset, levelled: bool) -> Result<crate::config::TrainedOn> {
    let part = train.clone().take_spread(32);
    let ground = pi3det_ground::GroundConfig::default();
    // One read per frame for both: (intensity sum, points with intensity, sensor height).
    let per_frame: Vec<(f64, usize, Option<f64>)> = part
        .indices
        .par_iter()
        .map(|&i| {
            let f = part.dataset.load(i)?;
            let n = f.points.len();
            let sum: f64 = (0..n).filter_map(|k| f.points.intensity(k)).map(f64::from).sum();
            let height = if levelled {
                None
            } else {
                pi3det_ground::estimate_ground(f.points.xyz_f64(), &ground).ok().map(|e| e.height_m)
            };
            Ok((sum, if f.points.stride() > 3 { n } else { 0 }, height))
        })
        .collect::<Result<_>>()?;
    let (sum, n) = per_frame.iter().fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    let mut heights: Vec<f64> = per_frame.iter().filter_map(|f| f.2).collect();
    heights.sort_by(f64::total_cmp);
    Ok(crate::config::TrainedOn {
        // The median, as VPP takes the source's height (`adapt::vpp::median_sensor_height`).
        sensor_height_m: heights.get(heights.len() / 2).copied(),
        intensity_mean: (n > 0).then(|| (sum / n as f64).clamp(0.0, 1.0)),
    })
}
