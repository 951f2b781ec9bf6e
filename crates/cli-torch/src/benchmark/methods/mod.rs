//! One benchmark cell: a method with a detector on a task, trained and evaluated on the task's
//! target validation split. Artifacts several cells share — simulated data, a source model, a
//! Pi3DET-Net Pre-Adaptation — are made once per output folder under `data/` and `shared/`,
//! each keyed by the full text of what made it, so a changed config never reuses a stale one.
//!
//! One file per method: [`reference`] (source-only, target-only, combined), [`sn`], [`st3d`]
//! (ST3D, ST3D++ and REDB, whose selection is [`redb`]), [`ms3d_pp`], [`pi3det_net`].

mod ms3d_pp;
mod pi3det_net;
mod redb;
mod reference;
mod sn;
mod st3d;

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::open_subset;
use anyhow::{bail, Context, Result};
use pi3det_adapt::baselines::memory::MemoryConfig;
use pi3det_adapt::baselines::redb::Candidate;
use pi3det_adapt::baselines::self_training::{SelfTraining, SelfTrainingConfig, SelfTrainingReport};
use pi3det_adapt::pipeline::{self as adapt, AdaptOptions};
use pi3det_adapt::pseudo_labels;
use pi3det_autolabel::fusion::FusionConfig;
use pi3det_autolabel::tracking::TrackingConfig;
use pi3det_data::{Dataset, FrameInfo, Object, Platform};
use pi3det_nn::augment::{AugmentConfig, RandomObjectScalingConfig, StatisticalNormalizationConfig};
use pi3det_nn::config::DetectorConfig;
use pi3det_nn::data_loader::Subset;
use pi3det_nn::detect::FrameDetections;
use pi3det_nn::eval::ApSummary;
use pi3det_nn::preprocess::vpp::median_sensor_height;
use pi3det_nn::preprocess::{FrameTransform, Level, Preprocessor};
use pi3det_nn::roi_heads::ScoreFusion;
use pi3det_nn::{checkpoint, train, Detector};

use super::suite::{Cell, DatasetSpec, DetectorEntry, MethodKind, MethodSpec, Suite, TaskSpec};
use crate::autolabel::{detect_in_view, ensemble, EnsembleOptions, View};

/// A cell's log: every line to `log.txt` and to stderr.
pub struct Log {
    file: std::fs::File,
    prefix: String,
}

impl Log {
    pub fn create(path: &Path, prefix: String) -> Result<Self> {
        let file = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        Ok(Self { file, prefix })
    }

    pub fn line(&mut self, s: impl AsRef<str>) {
        let s = s.as_ref();
        let _ = writeln!(self.file, "{s}");
        eprintln!("[{}] {s}", self.prefix);
    }
}

/// What a finished cell measured.
#[derive(Debug, Default)]
pub struct Outcome {
    pub ap: ApSummary,
    /// Pseudo-label rounds with their quality against the target's ground truth.
    pub pseudo_labels: Vec<serde_json::Value>,
}

pub struct Ctx<'a> {
    pub suite: &'a Suite,
    pub out: &'a Path,
    pub device: tch::Device,
}

/// FNV-1a, for folder names of shared artifacts (their full key is stored beside them).
pub fn fnv(s: &str) -> String {
    let mut h: u64 = 0xcbf29ce484222325;
    for b in s.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x100000001b3);
    }
    format!("{h:016x}")
}

impl Ctx<'_> {
    /// `out/<kind>/<name>_<hash>`, made by `make` unless it was already made from `key`.
    /// Processes sharing `out` (Ray tasks on a shared filesystem) take turns through a file lock.
    fn shared(&self, kind: &str, name: &str, key: &str, make: impl FnOnce(&Path) -> Result<()>) -> Result<PathBuf> {
        let dir = self.out.join(kind).join(format!("{name}_{}", fnv(key)));
        std::fs::create_dir_all(self.out.join(kind))
            .with_context(|| format!("creating {}", self.out.join(kind).display()))?;
        let lock_path = self.out.join(kind).join(format!("{name}_{}.lock", fnv(key)));
        let lock = std::fs::File::create(&lock_path).with_context(|| format!("creating {}", lock_path.display()))?;
        lock.lock().with_context(|| format!("locking {}", lock_path.display()))?;
        let marker = dir.join(".complete");
        if std::fs::read_to_string(&marker).is_ok_and(|k| k == key) {
            return Ok(dir);
        }
        if dir.exists() {
            std::fs::remove_dir_all(&dir).with_context(|| format!("clearing {}", dir.display()))?;
        }
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        make(&dir)?;
        pi3det_data::io::write_atomic(&marker, key.as_bytes(), true)?;
        Ok(dir)
    }

    /// The folder holding `dataset`'s `train` (or `val`) split (simulated on first use; a
    /// validation split with its own seed is simulated, and shared, on its own).
    fn dataset_root(&self, name: &str, train: bool, log: &mut Log) -> Result<(PathBuf, DatasetSpec)> {
        let spec = self.suite.datasets[name].clone();
        if let Some(p) = &spec.path {
            return Ok((p.clone(), spec));
        }
        let sim = spec.sim.clone().expect("a checked suite's dataset is sim or path");
        let platform = Platform::parse(&sim.platform);
        // Both splits at once from one seed unless the validation split has a seed of its own.
        let (what, split, seed, stratify) = match (train, sim.val_seed) {
            (false, Some(v)) => (format!("{name}_val"), Some("val"), v, true),
            (true, Some(_)) => (format!("{name}_train"), Some("train"), sim.seed.unwrap_or(self.suite.seed), false),
            (_, None) => (name.to_string(), None, sim.seed.unwrap_or(self.suite.seed), false),
        };
        let mut key = sim.split_key(train, self.suite.seed);
        if let Some(p) = &sim.config {
            key += &format!("\n{}", std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?);
        }
        let dir = self.shared("data", &what, &key, |dir| {
            log.line(format!(
                "simulating {what}: {} {} sequences × {} frames ({} val), {}, seed {seed}{}",
                sim.sequences,
                platform,
                sim.frames,
                sim.val_sequences,
                sim.sensor,
                if stratify { ", stratified layouts" } else { "" }
            ));
            let base = match &sim.config {
                Some(p) => pi3det_sim::SimConfig::load(p)?,
                None => pi3det_sim::SimConfig::default(),
            };
            let cfg = pi3det_sim::SimConfig { sensor: pi3det_sim::SensorPreset::parse(&sim.sensor)?.config(), ..base };
            let plan = pi3det_sim::PlatformPlan {
                platform,
                sequences: sim.sequences,
                frames: sim.frames,
                val_sequences: sim.val_sequences,
            };
            let opts = pi3det_sim::ExportOptions {
                out: dir.to_path_buf(),
                seed,
                overwrite: true,
                per_platform_folders: true,
                layout: None,
                stratify_layouts: stratify,
            };
            match split {
                Some(split) => {
                    pi3det_sim::export_split(&cfg, &plan, split, &opts, &mut |_, _| {}).context("simulation")?;
                }
                None => {
                    pi3det_sim::export(&cfg, &[plan], &opts, &mut |_, _| {}).context("simulation")?;
                }
            }
            Ok(())
        })?;
        Ok((dir.join(platform.as_str()), spec))
    }

    pub(crate) fn split(&self, dataset: &str, train: bool, log: &mut Log) -> Result<Subset> {
        let (root, spec) = self.dataset_root(dataset, train, log)?;
        let (split, max) = if train {
            (&spec.train_split, self.suite.schedule.max_train_frames)
        } else {
            (&spec.val_split, self.suite.schedule.max_val_frames)
        };
        let dir = if spec.sim.is_some() { root.join(split) } else { root };
        let s =
            open_subset(&dir, Some(split), None, max).with_context(|| format!("dataset {dataset}, split {split}"))?;
        if s.is_empty() {
            bail!("dataset {dataset}: the {split} split has no frames");
        }
        Ok(s)
    }

    /// A detector config with the suite's schedule and seed.
    fn scheduled(&self, cfg: &DetectorConfig) -> DetectorConfig {
        let mut c = cfg.clone();
        if let Some(e) = self.suite.schedule.epochs {
            c.train.epochs = e;
        }
        c.train.seed = self.suite.seed;
        c.train.max_train_frames = 0;
        c
    }

    /// Trains `cfg` on `dataset`'s training split (once per output folder); its final checkpoint.
    /// `level_to_m`: every frame levelled from its own ground to this sensor height first (the
    /// pose-free Virtual Platform Pose), for a model trained in a platform's own frames.
    fn trained(
        &self,
        what: &str,
        cfg: &DetectorConfig,
        datasets: &[&str],
        stage: Option<&str>,
        level_to_m: Option<f64>,
        log: &mut Log,
    ) -> Result<PathBuf> {
        let specs: Vec<String> = datasets.iter().map(|d| format!("{d}: {:?}", self.suite.datasets[*d])).collect();
        let key = format!("{}\n{stage:?}\nlevel {level_to_m:?}\n{}", specs.join("\n"), cfg.to_toml());
        let frame_transform = match level_to_m {
            Some(h) => Level::Height(h).transform(cfg)?.map(|v| v as Arc<dyn FrameTransform>),
            None => None,
        };
        let mut train_sets = Vec::new();
        for d in datasets {
            train_sets.push(self.split(d, true, log)?);
        }
        let device = self.device;
        let dir = self.shared("shared", what, &key, |dir| {
            let train = concat(&train_sets);
            log.line(format!(
                "training {what} ({} frames, {} epochs, {} steps{})",
                train.len(),
                cfg.train.epochs,
                train.len() * cfg.train.epochs,
                match level_to_m {
                    Some(h) => format!(", every frame levelled to a {h:.2} m sensor height"),
                    None => String::new(),
                }
            ));
            let t = std::time::Instant::now();
            train::train(
                train::TrainOptions {
                    config: cfg.clone(),
                    train,
                    val: None,
                    out_dir: dir.to_path_buf(),
                    device,
                    resume: None,
                    stage: stage.map(str::to_string),
                    frame_transform,
                },
                &mut |e| {
                    if let train::Event::EpochEnd { epoch, mean_loss, seconds, .. } = e {
                        log.line(format!("  {what} epoch {} loss {mean_loss:.3} ({seconds:.0} s)", epoch + 1));
                    }
                },
            )?;
            log.line(format!("trained {what} in {:.0} s", t.elapsed().as_secs_f64()));
            Ok(())
        })?;
        Ok(dir.join("final.safetensors"))
    }
}

/// Frames of several subsets as one (the `combined` method).
fn concat(sets: &[Subset]) -> Subset {
    if sets.len() == 1 {
        return sets[0].clone();
    }
    let parts: Vec<Subset> = sets.to_vec();
    let len = parts.iter().map(Subset::len).sum();
    Subset { dataset: Arc::new(Concat { parts, root: PathBuf::new() }), indices: (0..len).collect() }
}

struct Concat {
    parts: Vec<Subset>,
    root: PathBuf,
}

impl Concat {
    /// The part holding frame `i` of the concatenation and the frame's index in its dataset.
    fn locate(&self, mut i: usize) -> std::result::Result<(&Subset, usize), pi3det_data::DataError> {
        for p in &self.parts {
            if i < p.len() {
                return Ok((p, p.indices[i]));
            }
            i -= p.len();
        }
        Err(pi3det_data::DataError::invalid(
            &self.root,
            format!("frame {i} past the end of a concatenation of {} frames", self.len()),
        ))
    }
}

impl Dataset for Concat {
    fn format(&self) -> pi3det_data::Format {
        self.parts[0].dataset.format()
    }
    fn root(&self) -> &Path {
        &self.root
    }
    fn len(&self) -> usize {
        self.parts.iter().map(Subset::len).sum()
    }
    fn info(&self, index: usize) -> std::result::Result<FrameInfo, pi3det_data::DataError> {
        let (p, i) = self.locate(index)?;
        p.dataset.info(i)
    }
    fn load(&self, index: usize) -> std::result::Result<pi3det_data::Frame, pi3det_data::DataError> {
        let (p, i) = self.locate(index)?;
        p.dataset.load(i)
    }
}

fn load(path: &Path, cfg: Option<&DetectorConfig>, device: tch::Device) -> Result<Detector> {
    let ck = checkpoint::load(path)?;
    let cfg = cfg.unwrap_or(&ck.config);
    let mut det = Detector::new(cfg, device)?;
    ck.load_into(&mut det, path)?;
    Ok(det)
}

/// The method's self-training settings: the suite's, else the method's published recipe.
fn self_training_config(m: &MethodSpec, epochs: Option<usize>) -> SelfTrainingConfig {
    let mut c = m.self_training.clone().unwrap_or_else(|| {
        let st3d = SelfTrainingConfig::default();
        match m.kind {
            MethodKind::St3dPp => SelfTrainingConfig {
                memory: Some(MemoryConfig { per_class: true, ..Default::default() }),
                source_assisted: true,
                ds_norm: true,
                ..st3d
            },
            MethodKind::Redb => SelfTrainingConfig {
                memory: None,
                curriculum: None,
                labels: pseudo_labels::PseudoLabelConfig { positive_score: 0.5, ignore_score: 0.2, refresh_every: 0 },
                ..st3d
            },
            // MS3D's published thresholds on its fused, tracked labels (fixed within a round).
            MethodKind::Ms3dPp => SelfTrainingConfig {
                memory: None,
                curriculum: None,
                labels: pseudo_labels::PseudoLabelConfig { positive_score: 0.6, ignore_score: 0.2, refresh_every: 0 },
                ..st3d
            },
            _ => st3d,
        }
    });
    // The published recipe at the suite's length: refresh period and curriculum scaled with it.
    if m.self_training.is_none() {
        if let Some(e) = epochs {
            c = c.scaled_to(e);
        }
    }
    c
}

fn rounds_json(r: &SelfTrainingReport) -> Vec<serde_json::Value> {
    r.rounds.iter().map(|x| serde_json::to_value(x).unwrap_or_default()).collect()
}

fn log_rounds(log: &mut Log, r: &SelfTrainingReport) {
    for round in &r.rounds {
        let q: Vec<String> = round
            .quality
            .iter()
            .map(|q| format!("{}@{} P {:.1} R {:.1}", q.class, q.iou, q.precision, q.recall))
            .collect();
        log.line(format!(
            "  labels at epoch {}: {} positive, {} ignored; {}",
            round.epoch,
            round.positives,
            round.ignored,
            q.join(", ")
        ));
    }
    log.line(format!("  self-training: {} steps, {:.0} s", r.steps, r.seconds));
}

/// What every method's run gets: the cell, its task's data and the detector config it starts from.
pub(super) struct CellRun<'a> {
    ctx: &'a Ctx<'a>,
    cell: &'a Cell,
    task: &'a TaskSpec,
    method: &'a MethodSpec,
    entry: &'a DetectorEntry,
    /// The cell's detector with the suite's schedule.
    base: DetectorConfig,
    /// `base` with Random Object Scaling first when the method asks for it (ST3D's source model).
    with_ros: DetectorConfig,
    val: Subset,
    target: Subset,
    target_infos: Vec<FrameInfo>,
    /// The `shift_z` that puts the target's frames where the source's were (height matching).
    target_shift: f64,
    dir: &'a Path,
    device: tch::Device,
    adapt_epochs: Option<usize>,
}

impl CellRun<'_> {
    /// `det` on the target's validation split (detections in the cell's folder).
    fn eval(&self, det: &Detector, log: &mut Log) -> Result<ApSummary> {
        self.eval_levelled(det, None, log)
    }

    /// [`CellRun::eval`] with every frame levelled to `level_to_m` first (as it was trained).
    fn eval_levelled(&self, det: &Detector, level_to_m: Option<f64>, log: &mut Log) -> Result<ApSummary> {
        let mut prep = Preprocessor::new(det.cfg())?;
        if let Some(h) = level_to_m {
            if let Some(v) = Level::Height(h).transform(det.cfg())? {
                prep = prep.with_frame_transform(v);
            }
        }
        let prep = Arc::new(prep);
        let ap = adapt::evaluate(det, prep, &self.val, &self.dir.join("val_detections.jsonl"))?;
        log.line(format!("target val ({} frames): {}", self.val.len(), ap.one_line()));
        Ok(ap)
    }

    /// The source model trained with `cfg` (shared between the cells that train the same).
    fn source_model(&self, cfg: &DetectorConfig, log: &mut Log) -> Result<PathBuf> {
        let what = if self.method.ros { "source_ros" } else { "source" };
        self.ctx.trained(
            &format!("{what}_{}_{}", self.task.source, self.cell.detector),
            cfg,
            &[&self.task.source],
            None,
            None,
            log,
        )
    }

    /// `cfg` for the target's frames.
    fn on_target(&self, cfg: &DetectorConfig) -> DetectorConfig {
        DetectorConfig { shift_z: self.target_shift, ..cfg.clone() }
    }
}

/// Runs one cell in `dir` (its folder, empty).
pub fn run_cell(ctx: &Ctx<'_>, cell: &Cell, dir: &Path, log: &mut Log) -> Result<Outcome> {
    let suite = ctx.suite;
    let task = suite.task(&cell.task);
    let method = &suite.methods[cell.method];
    let entry = &suite.detectors[&cell.detector];
    let base = ctx.scheduled(&entry.config);
    let val = ctx.split(&task.target, false, log)?;
    let target = ctx.split(&task.target, true, log)?;
    let mut with_ros = base.clone();
    if method.ros {
        with_ros.train.augment.insert(0, AugmentConfig::RandomObjectScaling(RandomObjectScalingConfig::default()));
    }
    let target_infos = target.infos()?;
    let target_shift = if suite.schedule.match_sensor_height {
        let source = ctx.split(&task.source, true, log)?;
        let (hs, _) = median_sensor_height(&source, 64)?;
        let (ht, _) = median_sensor_height(&target, 64)?;
        let z = base.shift_z + (ht - hs);
        log.line(format!("target frames: shift_z {z:.2} m (median sensor height: source {hs:.2} m, target {ht:.2} m)"));
        z
    } else {
        base.shift_z
    };
    let c = CellRun {
        ctx,
        cell,
        task,
        method,
        entry,
        base,
        with_ros,
        val,
        target,
        target_infos,
        target_shift,
        dir,
        device: ctx.device,
        adapt_epochs: suite.schedule.adapt_epochs,
    };
    match method.kind {
        MethodKind::SourceOnly => reference::source_only(&c, log),
        MethodKind::TargetOnly => reference::target_only(&c, log),
        MethodKind::Combined => reference::combined(&c, log),
        MethodKind::Sn => sn::run(&c, log),
        MethodKind::St3d | MethodKind::St3dPp | MethodKind::Redb => st3d::run(&c, log),
        MethodKind::Ms3dPp => ms3d_pp::run(&c, log),
        MethodKind::Pi3detNet => pi3det_net::run(&c, log),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv_is_stable() {
        assert_eq!(fnv(""), "cbf29ce484222325");
        assert_eq!(fnv("a"), "af63dc4c8601ec8c");
    }
}
