//! `pi3det adapt`: Pre-Adaptation on the source → pseudo-labels on the target's unlabelled
//! training frames → Knowledge-Adaptation, then the source-only (PA) model and the adapted one
//! evaluated on the target's validation frames; `adapt.json` and `adapt.md` in the output folder.
//!
//! Layout of `--out`: `adapt_config.toml`; `val_source_only[_vpp].jsonl` (the first missing when
//! the caller passed the source-only score in), `val_adapted.jsonl`
//! (the evaluated detections, for `pi3det eval --breakdown`); `pa/` (the training run of PA: checkpoints with stage
//! `pa`, `final.safetensors`); `pseudo_labels.jsonl` (the labels KA starts from, detection format);
//! `ka/` (epoch checkpoints with stage `ka` and optimiser moments, `labels_model.safetensors` —
//! the weights the current pseudo-labels came from — and `final.safetensors`). A run started again
//! with `resume` continues in the stage where it stopped: PA from its last epoch checkpoint, KA
//! from its last epoch checkpoint with the pseudo-labels regenerated from `labels_model`, which
//! reproduces the uninterrupted run.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use tch::Device;

use crate::guard::{self, Comparison, GuardConfig, PositiveStats};
use crate::ka::{DomainData, KaConfig, KaStep, KnowledgeAdaptation};
use crate::pseudo_labels::{self, LabelQuality, PseudoLabelConfig, PseudoLabeled};
use crate::thresholds::{self, AdaptiveThresholdConfig, Thresholds};
use pi3det_eval::bootstrap::{self, ClassComparison};
use pi3det_nn::augment::{AugmentConfig, RandomPlatformJitterConfig};
use pi3det_nn::checkpoint::{self, TrainState};
use pi3det_nn::config::{DetectorConfig, HeadConfig};
use pi3det_nn::config_override::{read_config, ConfigOverride};
use pi3det_nn::data_loader::Subset;
use pi3det_nn::detect::{self, FrameDetections};
use pi3det_nn::detector::Detector;
use pi3det_nn::error::{NnError, Result};
use pi3det_nn::eval::{self, ApSummary};
use pi3det_nn::losses::target_negatives::TargetNegativesConfig;
use pi3det_nn::necks::{GtdConfig, NeckConfig};
use pi3det_nn::preprocess::vpp::{median_sensor_height, VirtualPlatformPose, VppConfig, VppCounts};
use pi3det_nn::preprocess::{FrameTransform, Preprocessor, ShiftZ};
use pi3det_nn::roi_heads::pfa::PfaConfig;
use pi3det_nn::train::{self, build_augments, TrainOptions};

/// A Pi3DET-Net run's settings (`configs/pi3det_net_cpu.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdaptConfig {
    pub name: String,
    /// The detector PA trains (RPJ among its augmentations, the GTD neck, PFA) and KA adapts.
    pub detector: DetectorConfig,
    /// Virtual Platform Pose for target frames (absent: off).
    pub vpp: Option<VppConfig>,
    /// Without VPP, the z shift of the target's frames (absent: the detector's `shift_z`, as on the
    /// source) — e.g. one dataset-wide match of sensor heights, as the benchmark's baselines get.
    /// VPP levels each frame itself, so the two are refused together.
    pub target_shift_z: Option<f64>,
    pub pseudo_labels: PseudoLabelConfig,
    /// Per-class positive thresholds when `positive_score` gives too few positives.
    pub adaptive_thresholds: AdaptiveThresholdConfig,
    pub ka: KaConfig,
    /// KA's rules for the target's background (unsure outputs ignored, coverage weight).
    pub target_negatives: TargetNegativesConfig,
    /// Positives-per-frame warning and the adapted vs PA-through-VPP comparison.
    pub guard: GuardConfig,
}

impl Default for AdaptConfig {
    fn default() -> Self {
        let mut detector = DetectorConfig::default();
        detector.train.augment.push(AugmentConfig::RandomPlatformJitter(RandomPlatformJitterConfig::default()));
        detector.neck = Some(NeckConfig::Gtd(GtdConfig::default()));
        detector.roi_head = Some(Default::default());
        detector.pfa = Some(Default::default());
        Self {
            name: "pi3det_net".into(),
            detector,
            vpp: Some(VppConfig::default()),
            target_shift_z: None,
            pseudo_labels: PseudoLabelConfig::default(),
            adaptive_thresholds: AdaptiveThresholdConfig::default(),
            ka: KaConfig::default(),
            target_negatives: TargetNegativesConfig::default(),
            guard: GuardConfig::default(),
        }
    }
}

/// The components `--without` can switch off.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Component {
    Rpj,
    Vpp,
    Gtd,
    Pfa,
}

impl std::str::FromStr for Component {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "rpj" => Ok(Self::Rpj),
            "vpp" => Ok(Self::Vpp),
            "gtd" => Ok(Self::Gtd),
            "pfa" => Ok(Self::Pfa),
            o => Err(format!("unknown component {o:?} (rpj, vpp, gtd, pfa)")),
        }
    }
}

/// The paper's abbreviation (RPJ, VPP, GTD, PFA), as tables and logs name a component.
impl std::fmt::Display for Component {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Rpj => "RPJ",
            Self::Vpp => "VPP",
            Self::Gtd => "GTD",
            Self::Pfa => "PFA",
        })
    }
}

/// Components as reports and logs list them: `VPP, GTD, PFA`, or `none`.
pub fn component_names(c: &[Component]) -> String {
    if c.is_empty() {
        return "none".into();
    }
    c.iter().map(Component::to_string).collect::<Vec<_>>().join(", ")
}

impl AdaptConfig {
    pub fn from_file(path: &Path) -> Result<Self> {
        Self::from_file_with(path, &[])
    }

    /// The file with `--set` overrides applied before it is read.
    pub fn from_file_with(path: &Path, overrides: &[ConfigOverride]) -> Result<Self> {
        let cfg: Self = read_config(path, overrides)?;
        cfg.validate().map_err(|e| NnError::InvalidConfigFile { path: path.to_path_buf(), source: Box::new(e) })?;
        Ok(cfg)
    }

    pub fn from_toml_str(s: &str) -> Result<Self> {
        let cfg: Self = toml::from_str(s)?;
        cfg.validate()?;
        Ok(cfg)
    }

    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }

    pub fn validate(&self) -> Result<()> {
        self.detector.validate()?;
        if let Some(v) = &self.vpp {
            v.validate()?;
        }
        match self.target_shift_z {
            Some(_) if self.vpp.is_some() => {
                return Err(NnError::config(
                    "target_shift_z",
                    "target_shift_z is the target's shift without VPP; VPP levels each frame itself (drop one of them)",
                ))
            }
            Some(z) if !z.is_finite() => {
                return Err(NnError::config("target_shift_z", format!("target_shift_z must be finite, got {z}")))
            }
            _ => {}
        }
        self.pseudo_labels.validate()?;
        self.adaptive_thresholds.validate()?;
        self.target_negatives.validate()?;
        // Only the anchor head learns a teacher's scores; another head would pay for the
        // teacher's pass and change nothing.
        if self.target_negatives.teacher_scores && !matches!(self.detector.head, HeadConfig::Anchor(_)) {
            return Err(NnError::config(
                "target_negatives.teacher_scores",
                "target_negatives.teacher_scores needs the anchor head (detector.head); the center head has no teacher rule",
            ));
        }
        self.guard.validate()?;
        self.ka.validate()
    }

    /// The components that are on.
    pub fn components(&self) -> Vec<Component> {
        let d = &self.detector;
        let mut c = Vec::new();
        if d.train.augment.iter().any(|a| matches!(a, AugmentConfig::RandomPlatformJitter(_))) {
            c.push(Component::Rpj);
        }
        if self.vpp.is_some() {
            c.push(Component::Vpp);
        }
        if matches!(d.neck, Some(NeckConfig::Gtd(_))) {
            c.push(Component::Gtd);
        }
        if d.pfa.is_some() {
            c.push(Component::Pfa);
        }
        c
    }

    /// The same run with `off` switched off (an ablation row).
    pub fn without(&self, off: &[Component]) -> Self {
        let mut c = self.clone();
        for o in off {
            match o {
                Component::Rpj => {
                    c.detector.train.augment.retain(|a| !matches!(a, AugmentConfig::RandomPlatformJitter(_)))
                }
                Component::Vpp => c.vpp = None,
                Component::Gtd => c.detector.neck = None,
                Component::Pfa => c.detector.pfa = None,
            }
        }
        c
    }

    /// The same run with `on` switched on: a component the config lacks comes with its type's
    /// defaults (RPJ: the paper's U(−5°, 5°); VPP, GTD, PFA: their configs' defaults); one it has
    /// keeps the config's settings.
    pub fn with(&self, on: &[Component]) -> Self {
        let mut c = self.clone();
        let had = self.components();
        for o in on.iter().filter(|o| !had.contains(o)) {
            match o {
                Component::Rpj => c
                    .detector
                    .train
                    .augment
                    .push(AugmentConfig::RandomPlatformJitter(RandomPlatformJitterConfig::default())),
                Component::Vpp => c.vpp = Some(VppConfig::default()),
                Component::Gtd => c.detector.neck = Some(NeckConfig::Gtd(GtdConfig::default())),
                Component::Pfa => c.detector.pfa = Some(PfaConfig::default()),
            }
        }
        c
    }

    /// The same run with exactly the components `keep` (an ablation row): the others switched
    /// off, missing ones switched on as [`AdaptConfig::with`] does.
    pub fn exactly(&self, keep: &[Component]) -> Self {
        let off: Vec<Component> = self.components().into_iter().filter(|x| !keep.contains(x)).collect();
        self.without(&off).with(keep)
    }

    /// Target-frame augmentations in KA: the source's scene-level ones, without ground-truth
    /// sampling (no target database) and without platform jitter (VPP levelled the frame).
    fn target_detector_config(&self) -> DetectorConfig {
        let mut d = self.detector.clone();
        d.train.augment.retain(|a| !matches!(a, AugmentConfig::GtSampling(_) | AugmentConfig::RandomPlatformJitter(_)));
        d
    }
}

/// The stage a run stopped after (`stop_after`), for tests and for splitting work.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    Pa,
    Ka,
}

pub struct AdaptOptions {
    pub config: AdaptConfig,
    pub source: Subset,
    /// The target's training frames (their labels, if any, are never used for training).
    pub target: Subset,
    pub val: Option<Subset>,
    pub out_dir: PathBuf,
    pub device: Device,
    /// A finished PA checkpoint to start from instead of training one.
    pub pa_ckpt: Option<PathBuf>,
    /// Continue a run that stopped in `out_dir`.
    pub resume: bool,
    pub stop_after: Option<Stage>,
    /// The PA model's AP on `val`, when the caller has already measured it (the demo has): taken
    /// as the source-only row instead of evaluating the same model on the same frames again.
    pub source_only: Option<ApSummary>,
    /// Also run the two passes that only explain VPP: the PA model through VPP on `val`
    /// (`source_only_vpp`) and pseudo-labels without VPP (their quality row). Two inference passes
    /// over the target; the demo skips them.
    pub vpp_diagnostics: bool,
}

/// Progress events.
pub enum AdaptEvent<'a> {
    Stage(&'static str),
    Message(String),
    Pa(train::Event<'a>),
    Labels { done: usize, total: usize },
    KaStep(&'a KaStep),
    KaEpoch(KaEpochLoss),
}

/// A finished KA epoch (0-based) with its mean loss and the mean of each part: the source
/// batches' `L_det + λ_RoI L_RoI`, the target batches' `L_det`, and `λ_KL L_KL`.
#[derive(Debug, Clone, Copy, Serialize, Default)]
pub struct KaEpochLoss {
    pub epoch: usize,
    pub mean_loss: f64,
    pub mean_source: f64,
    pub mean_target: f64,
    pub mean_kl: f64,
    /// Mean over the target batches of their background weight (coverage rule; 1 without it).
    pub mean_background_weight: f64,
    pub seconds: f64,
}

/// Pseudo-label precision / recall of one way of making them.
#[derive(Debug, Clone, Serialize)]
pub struct QualityRow {
    pub labels: String,
    pub rows: Vec<LabelQuality>,
}

/// One set of pseudo-labels KA trained on: made before KA (epoch 0) or refreshed before `epoch`.
#[derive(Debug, Clone, Serialize)]
pub struct LabelRound {
    pub epoch: usize,
    /// The positive threshold of each class ([`thresholds`]).
    pub thresholds: Thresholds,
    /// Positives (at those thresholds) per target frame.
    pub positives: PositiveStats,
}

#[derive(Debug, Clone, Serialize, Default)]
pub struct AdaptReport {
    pub name: String,
    pub components: Vec<Component>,
    pub source_frames: usize,
    pub target_frames: usize,
    pub val_frames: usize,
    pub pa_checkpoint: PathBuf,
    pub final_checkpoint: Option<PathBuf>,
    /// The source sensor height VPP put target frames at.
    pub source_height_m: Option<f64>,
    pub vpp: Option<VppCounts>,
    /// Target validation: the PA model as it is, the PA model through VPP, the adapted model.
    pub source_only: Option<ApSummary>,
    pub source_only_vpp: Option<ApSummary>,
    pub adapted: Option<ApSummary>,
    /// The adapted model − the PA model through VPP on the validation frames, per class, with a
    /// 95 % interval from a paired bootstrap over the validation sequences (is the difference
    /// resolved or within noise).
    pub adapted_vs_pa_vpp: Vec<ClassComparison>,
    /// The validation sequences those intervals draw from.
    pub val_sequences: usize,
    pub pseudo_labels: usize,
    /// Each set of pseudo-labels: thresholds and positives per frame.
    pub label_rounds: Vec<LabelRound>,
    pub pseudo_label_quality: Vec<QualityRow>,
    /// What the run warns about (too few positives to adapt on, the guard's verdict).
    pub warnings: Vec<String>,
    /// The adapted model against the PA model through VPP on the target's training frames,
    /// and which of the two to ship.
    pub guard: Option<Comparison>,
    /// The KA epochs this run trained (a resumed run: the epochs after the resume).
    pub ka_epochs: Vec<KaEpochLoss>,
    pub pa_seconds: f64,
    pub ka_seconds: f64,
    pub total_seconds: f64,
}

/// Errors unless some of the target's annotated classes are the detector's (a target that names
/// its cars `car` or `vehicle.car` would silently train and score nothing).
pub fn check_classes(subset: &Subset, cfg: &DetectorConfig, what: &str) -> Result<()> {
    check_class_names(&subset.infos()?, cfg, what)
}

fn check_class_names(infos: &[pi3det_data::FrameInfo], cfg: &DetectorConfig, what: &str) -> Result<()> {
    let names: BTreeSet<&str> = infos.iter().flat_map(|i| &i.objects).map(|o| o.name.as_str()).collect();
    if names.is_empty() || names.iter().any(|n| cfg.class_index(n).is_some()) {
        return Ok(());
    }
    Err(NnError::Input(format!(
        "{what} labels use the classes {names:?}, none of which is among the detector's {:?} (class_aliases {:?}): map them with class_aliases",
        cfg.classes, cfg.class_aliases
    )))
}

/// The parts of a config that shape the network (everything but training, post-processing, loss
/// weights and how the network computes: memory layout, precision). A PA checkpoint may go on
/// under other loss weights (e.g. another λ_KL for Knowledge-Adaptation).
fn architecture(cfg: &DetectorConfig) -> toml::Table {
    let mut t: toml::Table = toml::from_str(&cfg.to_toml()).unwrap_or_default();
    for k in ["name", "train", "post", "loss_weights", "channels_last", "precision", "trained_on"] {
        t.remove(k);
    }
    let loss_settings = [
        ("pfa", &["roi_weight", "kl_weight", "kl_estimator", "kl_into_encoder"][..]),
        ("neck", &["rotation_weight"][..]),
    ];
    for (table, keys) in loss_settings {
        if let Some(toml::Value::Table(sub)) = t.get_mut(table) {
            keys.iter().for_each(|k| {
                sub.remove(*k);
            });
        }
    }
    t
}

/// Errors naming the differing sections when a checkpoint's network is not `cfg`'s.
pub fn check_architecture(path: &Path, ck_cfg: &DetectorConfig, cfg: &DetectorConfig) -> Result<()> {
    let (a, b) = (architecture(ck_cfg), architecture(cfg));
    let keys: BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    let differ: Vec<&str> = keys.into_iter().filter(|k| a.get(*k) != b.get(*k)).map(|k| k.as_str()).collect();
    if differ.is_empty() {
        return Ok(());
    }
    Err(NnError::Checkpoint {
        path: path.to_path_buf(),
        message: format!("was trained with another architecture than this config's detector (differs in {differ:?})"),
    })
}

fn latest_checkpoint(dir: &Path) -> Option<PathBuf> {
    let entries = std::fs::read_dir(dir).ok()?;
    entries
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().to_string();
            let n: usize = name.strip_prefix("checkpoint_epoch_")?.strip_suffix(".safetensors")?.parse().ok()?;
            Some((n, e.path()))
        })
        .max_by_key(|(n, _)| *n)
        .map(|(_, p)| p)
}

/// Draws of the paired bootstrap behind `adapted_vs_pa_vpp`.
const VAL_BOOTSTRAP_DRAWS: usize = 200;

/// AP on `val`; the detections go to `out` (JSON lines, for `pi3det eval --breakdown`).
pub fn evaluate(det: &Detector, prep: Arc<Preprocessor>, val: &Subset, out: &Path) -> Result<ApSummary> {
    Ok(evaluate_keeping(det, prep, val, out)?.0)
}

/// [`evaluate`], keeping the detections for a comparison.
fn evaluate_keeping(
    det: &Detector,
    prep: Arc<Preprocessor>,
    val: &Subset,
    out: &Path,
) -> Result<(ApSummary, Vec<FrameDetections>)> {
    let (frames, _) = detect::detect_with(det, prep, val, 4, true, &mut |_, _| {})?;
    detect::write_jsonl(out, &frames)?;
    let opts = val_options(det.cfg());
    Ok((eval::evaluate(&frames, &opts)?.1, frames))
}

/// Evaluation options of validation: the detector's classes inside its BEV range.
fn val_options(cfg: &DetectorConfig) -> pi3det_eval::EvalOptions {
    let r = cfg.pillars.point_cloud_range;
    eval::options(&cfg.classes, Some([r[0], r[1], r[3], r[4]]), None)
}

/// Runs PA → pseudo-labels → KA and the evaluations; `on_event` sees progress.
pub fn run(opts: AdaptOptions, on_event: &mut dyn FnMut(AdaptEvent<'_>)) -> Result<AdaptReport> {
    let t0 = Instant::now();
    let cfg = &opts.config;
    cfg.validate()?;
    let det_cfg = &cfg.detector;
    for (s, what) in [(&opts.source, "the source split"), (&opts.target, "the target split")] {
        if s.is_empty() {
            return Err(NnError::Input(format!("{what} has no frames")));
        }
    }
    check_classes(&opts.source, det_cfg, "the source")?;
    // `ka.frozen` names parts of this detector: a typo is refused now, not after PA.
    if !cfg.ka.frozen.is_empty() {
        cfg.ka.trainables(&Detector::new(det_cfg, Device::Cpu)?)?;
    }
    // The target's infos, read once: class check, pose check, pseudo-label quality.
    let target_infos = opts.target.infos()?;
    check_class_names(&target_infos, det_cfg, "the target")?;
    let val = opts.val.as_ref().filter(|v| !v.is_empty());
    if opts.val.is_some() && val.is_none() {
        return Err(NnError::Input("the validation split has no frames".into()));
    }
    if let Some(v) = val {
        check_classes(v, det_cfg, "the validation")?;
    }
    if let Some(p) = &opts.pa_ckpt {
        let ck = checkpoint::load(p)?;
        check_architecture(p, &ck.config, det_cfg)?;
    }
    let out = &opts.out_dir;
    if !opts.resume && ["pa", "ka", "adapt.json"].iter().any(|p| out.join(p).exists()) {
        return Err(NnError::Input(format!(
            "{} holds an earlier adaptation run: resume it or choose another folder",
            out.display()
        )));
    }
    std::fs::create_dir_all(out).map_err(|e| NnError::io(out, e))?;
    let cfg_path = out.join("adapt_config.toml");
    if opts.resume && cfg_path.exists() {
        let old = std::fs::read_to_string(&cfg_path).map_err(|e| NnError::io(&cfg_path, e))?;
        if old != cfg.to_toml() {
            return Err(NnError::Input(format!("{}: the run there used another config", cfg_path.display())));
        }
    }
    pi3det_data::io::write_atomic(&cfg_path, cfg.to_toml().as_bytes(), true)?;
    let mut report = AdaptReport {
        name: cfg.name.clone(),
        components: cfg.components(),
        source_frames: opts.source.len(),
        target_frames: opts.target.len(),
        val_frames: val.map_or(0, Subset::len),
        ..Default::default()
    };

    // Pre-Adaptation.
    on_event(AdaptEvent::Stage("pre-adaptation"));
    let pa_path = match &opts.pa_ckpt {
        Some(p) => p.clone(),
        None => {
            let dir = out.join("pa");
            let done = dir.join("final.safetensors");
            if done.exists() {
                let ck = checkpoint::load(&done)?;
                if ck.config.settings_toml() != det_cfg.settings_toml() {
                    return Err(NnError::Checkpoint {
                        path: done,
                        message: "was trained with another detector config".into(),
                    });
                }
                on_event(AdaptEvent::Message(format!("PA already finished: {}", done.display())));
            } else {
                let t = Instant::now();
                train::train(
                    TrainOptions {
                        config: det_cfg.clone(),
                        train: opts.source.clone(),
                        val: None,
                        out_dir: dir.clone(),
                        device: opts.device,
                        resume: latest_checkpoint(&dir),
                        stage: Some("pa".into()),
                        frame_transform: None,
                    },
                    &mut |e| on_event(AdaptEvent::Pa(e)),
                )?;
                report.pa_seconds = t.elapsed().as_secs_f64();
            }
            done
        }
    };
    report.pa_checkpoint = pa_path.clone();
    if opts.stop_after == Some(Stage::Pa) {
        return Ok(report);
    }
    let (mut det, _) = checkpoint::load_detector_with_post(&pa_path, Some(&det_cfg.post), opts.device)?;
    let pa_trained_on = det.cfg().trained_on;
    // The PA checkpoint's own config may differ in schedule and post-processing (`--pa-ckpt`);
    // adapt with ours.
    det.prep = Arc::new(Preprocessor::new(det_cfg)?);

    // The target's frame transform.
    let plain: Arc<dyn FrameTransform> = Arc::new(ShiftZ(det_cfg.shift_z));
    // Without VPP the target's frames take one shift: the source's unless the config gives theirs.
    let target_plain: Arc<dyn FrameTransform> = match cfg.target_shift_z {
        Some(z) => {
            on_event(AdaptEvent::Message(format!("target frames without VPP: shift_z {z:.2} m")));
            Arc::new(ShiftZ(z))
        }
        None => plain.clone(),
    };
    let vpp = match &cfg.vpp {
        Some(v) => {
            let h = match v.source_height_m {
                Some(h) => h,
                None => {
                    let (h, n) = median_sensor_height(&opts.source, v.source_frames)?;
                    on_event(AdaptEvent::Message(format!(
                        "VPP: source sensor height {h:.2} m (median ground fit of {n} source frames)"
                    )));
                    h
                }
            };
            report.source_height_m = Some(h);
            let has_pose = target_infos.iter().all(|i| i.world_from_lidar.is_some());
            on_event(AdaptEvent::Message(
                if has_pose && v.attitude == pi3det_nn::preprocess::vpp::AttitudeSource::Auto {
                    "VPP: target roll and pitch from the frames' poses, height from the ground fit".into()
                } else {
                    "VPP: the target has no poses: roll, pitch and height from the ground-plane estimate".into()
                },
            ));
            Some(Arc::new(VirtualPlatformPose::new(v, det_cfg.shift_z, h)))
        }
        None => None,
    };
    // The adapted model works in the frame KA trains it in: levelled to the source's height when
    // VPP is on, so inference levels to it by default ([`pi3det_nn::preprocess::Level::Trained`]).
    let recorded = pi3det_nn::config::TrainedOn {
        sensor_height_m: report.source_height_m.or(pa_trained_on.and_then(|t| t.sensor_height_m)),
        intensity_mean: pa_trained_on.and_then(|t| t.intensity_mean),
    };
    det.prep = Arc::new(Preprocessor::new(&DetectorConfig { trained_on: Some(recorded), ..det_cfg.clone() })?);
    let target_transform: Arc<dyn FrameTransform> = match &vpp {
        Some(v) => v.clone(),
        None => target_plain.clone(),
    };
    let target_cfg = cfg.target_detector_config();
    let target_prep = |ignore: bool| -> Result<Preprocessor> {
        let p = Preprocessor::new(&target_cfg)?.with_frame_transform(target_transform.clone());
        Ok(if ignore { p.with_ignore_score_below(cfg.pseudo_labels.positive_score) } else { p })
    };
    let plain_prep = Arc::new(Preprocessor::new(det_cfg)?);

    // The PA model's detections through VPP on `val`, kept for the comparison with the adapted model.
    let mut pa_vpp_val = None;
    if let Some(v) = val {
        on_event(AdaptEvent::Stage("evaluating the source-only model"));
        report.source_only = match &opts.source_only {
            Some(s) => Some(s.clone()),
            None => {
                let prep = match cfg.target_shift_z {
                    None => plain_prep.clone(),
                    Some(_) => Arc::new(Preprocessor::new(det_cfg)?.with_frame_transform(target_plain.clone())),
                };
                Some(evaluate(&det, prep, v, &out.join("val_source_only.jsonl"))?)
            }
        };
        if vpp.is_some() && opts.vpp_diagnostics {
            let o = out.join("val_source_only_vpp.jsonl");
            let (ap, frames) = evaluate_keeping(&det, Arc::new(target_prep(false)?), v, &o)?;
            report.source_only_vpp = Some(ap);
            pa_vpp_val = Some(frames);
        }
    }

    // Pseudo-labels and their quality (with and without VPP) where the target has ground truth.
    let ka_dir = out.join("ka");
    std::fs::create_dir_all(&ka_dir).map_err(|e| NnError::io(&ka_dir, e))?;
    let labels_model = ka_dir.join("labels_model.safetensors");
    let resume_ka = if opts.resume { latest_checkpoint(&ka_dir) } else { None };
    let final_path = ka_dir.join("final.safetensors");
    let make_labels = |det: &Detector, on_event: &mut dyn FnMut(AdaptEvent<'_>)| -> Result<Vec<FrameDetections>> {
        on_event(AdaptEvent::Stage("pseudo-labelling the target"));
        pseudo_labels::generate(det, Arc::new(target_prep(false)?), &opts.target, &cfg.pseudo_labels, &mut |d, t| {
            on_event(AdaptEvent::Labels { done: d, total: t })
        })
    };
    let gt = &target_infos;
    let has_gt = gt.iter().any(|i| !i.objects.is_empty());
    let r = det_cfg.pillars.point_cloud_range;
    let bev = [r[0], r[1], r[3], r[4]];
    let pos = cfg.pseudo_labels.positive_score;
    let from_labels_model = resume_ka.is_some() && labels_model.exists();
    let raw = if from_labels_model {
        let (m, _) = checkpoint::load_detector_with_post(&labels_model, Some(&det_cfg.post), opts.device)?;
        make_labels(&m, on_event)?
    } else {
        checkpoint::save(&labels_model, &det, None, &TrainState { stage: Some("ka".into()), ..Default::default() })?;
        make_labels(&det, on_event)?
    };
    // The PA model's boxes through VPP, which the guard compares the adapted model with (a
    // resumed run's labels may come from a refreshed model: the guard then runs PA again).
    let pa_detections = (!from_labels_model).then(|| raw.clone());
    let (mut labels, round) = label_round(&raw, cfg, if from_labels_model { usize::MAX } else { 0 });
    let lowered = round.thresholds.lowered;
    record_round(round, cfg, &mut report, on_event);
    if has_gt {
        let q = pseudo_labels::quality(&labels, gt, det_cfg, pos, &[0.5, 0.7], bev);
        let name = match (vpp.is_some(), lowered) {
            (true, false) => "PA model, through VPP",
            (false, false) => "PA model",
            (true, true) => "PA model, through VPP, adaptive thresholds",
            (false, true) => "PA model, adaptive thresholds",
        };
        if lowered {
            let q = pseudo_labels::quality(&raw, gt, det_cfg, pos, &[0.5, 0.7], bev);
            let fixed =
                if vpp.is_some() { "PA model, through VPP, positive_score" } else { "PA model, positive_score" };
            report.pseudo_label_quality.push(QualityRow { labels: fixed.into(), rows: q });
        }
        report.pseudo_label_quality.push(QualityRow { labels: name.into(), rows: q });
        if vpp.is_some() && opts.vpp_diagnostics {
            let (raw, _) = detect::detect_with(&det, plain_prep.clone(), &opts.target, 4, true, &mut |_, _| {})?;
            let q = pseudo_labels::quality(&raw, gt, det_cfg, pos, &[0.5, 0.7], bev);
            report
                .pseudo_label_quality
                .insert(0, QualityRow { labels: "PA model, sensor frame (no VPP)".into(), rows: q });
        }
    }
    detect::write_jsonl(&out.join("pseudo_labels.jsonl"), &raw)?;

    // Knowledge-Adaptation.
    on_event(AdaptEvent::Stage("knowledge-adaptation"));
    let t_ka = Instant::now();
    let (augments, _) = build_augments(&plain_prep, &opts.source)?;
    let source = DomainData { subset: opts.source.clone(), prep: plain_prep.clone(), augments: Arc::new(augments) };
    let target_augments = {
        let p = target_prep(true)?;
        Arc::new(build_augments(&p, &opts.target)?.0)
    };
    let target_data = |labels: &[FrameDetections]| -> Result<DomainData> {
        let subset = PseudoLabeled::new(&opts.target, labels)?.subset(&opts.target);
        Ok(DomainData { subset, prep: Arc::new(target_prep(true)?), augments: target_augments.clone() })
    };
    let mut ka = KnowledgeAdaptation::new(&det, &cfg.ka, opts.target.len())?
        .with_target_negatives(&cfg.target_negatives, cfg.pseudo_labels.ignore_score);
    if cfg.target_negatives.teacher_scores {
        let (teacher, _) = checkpoint::load_detector_with_post(&pa_path, Some(&det_cfg.post), opts.device)?;
        ka = ka.with_teacher(teacher);
    }
    let mut start = 0;
    if let Some(p) = &resume_ka {
        let ck = checkpoint::load(p)?;
        if ck.state.stage.as_deref() != Some("ka") {
            return Err(NnError::Checkpoint { path: p.clone(), message: "is not a KA checkpoint".into() });
        }
        ck.load_into(&mut det, p)?;
        start = ck.state.epoch;
        // The last epoch's checkpoint keeps no optimiser state (nothing is left to train; with a
        // PA share only the blend is).
        if start < cfg.ka.epochs {
            ka.optim.load_state(&ck.tensors, ck.state.step)?;
        }
        on_event(AdaptEvent::Message(format!("KA resumes after epoch {start} ({})", p.display())));
    }
    let mut target = target_data(&labels)?;
    report.pseudo_labels = labels.iter().map(|f| f.objects.iter().filter(|o| o.score >= Some(pos)).count()).sum();
    let refresh = cfg.pseudo_labels.refresh_every;
    // A KA checkpoint's training state after `epochs` epochs.
    let ka_state = |ka: &KnowledgeAdaptation, epochs: usize, last_loss: Option<f64>| TrainState {
        epoch: epochs,
        step: ka.optim.step,
        total_steps: ka.total_steps,
        train_seconds: t_ka.elapsed().as_secs_f64(),
        last_loss,
        stage: Some("ka".into()),
    };
    for epoch in start..cfg.ka.epochs {
        if refresh > 0 && epoch > 0 && epoch % refresh == 0 && epoch != start {
            checkpoint::save(
                &labels_model,
                &det,
                None,
                &TrainState { stage: Some("ka".into()), ..Default::default() },
            )?;
            let raw = make_labels(&det, on_event)?;
            let (l, round) = label_round(&raw, cfg, epoch);
            record_round(round, cfg, &mut report, on_event);
            labels = l;
            target = target_data(&labels)?;
            on_event(AdaptEvent::Stage("knowledge-adaptation"));
        }
        let t = Instant::now();
        // Sums of the source, target and λ_KL·KL parts over the epoch's steps.
        let (mut source_sum, mut target_sum, mut kl_sum, mut steps) = (0.0, 0.0, 0.0, 0usize);
        let mut weight_sum = 0.0;
        let mean_loss = ka.epoch(&det, epoch, Some(&source), &target, None, opts.device, &mut |s| {
            source_sum += s.source;
            target_sum += s.target;
            kl_sum += s.kl;
            weight_sum += s.target_background_weight;
            steps += 1;
            on_event(AdaptEvent::KaStep(s))
        })?;
        let n = steps.max(1) as f64;
        let summary = KaEpochLoss {
            epoch,
            mean_loss,
            mean_source: source_sum / n,
            mean_target: target_sum / n,
            mean_kl: kl_sum / n,
            mean_background_weight: weight_sum / n,
            seconds: t.elapsed().as_secs_f64(),
        };
        report.ka_epochs.push(summary);
        on_event(AdaptEvent::KaEpoch(summary));
        let state = ka_state(&ka, epoch + 1, Some(mean_loss));
        // With a PA share the last epoch is a checkpoint of its own and `final` the blend.
        let path = if epoch + 1 == cfg.ka.epochs && cfg.ka.pa_weight == 0.0 {
            final_path.clone()
        } else {
            ka_dir.join(format!("checkpoint_epoch_{}.safetensors", epoch + 1))
        };
        let moments = (epoch + 1 < cfg.ka.epochs).then(|| ka.optim.state());
        checkpoint::save(&path, &det, moments, &state)?;
    }
    if start >= cfg.ka.epochs && final_path.exists() {
        let ck = checkpoint::load(&final_path)?;
        ck.load_into(&mut det, &final_path)?;
    } else if cfg.ka.pa_weight > 0.0 {
        let pa = checkpoint::load(&pa_path)?;
        pa.blend_into(&mut det, &pa_path, cfg.ka.pa_weight)?;
        on_event(AdaptEvent::Message(format!(
            "KA: the shipped weights are {:.2} × KA + {:.2} × PA ({})",
            1.0 - cfg.ka.pa_weight,
            cfg.ka.pa_weight,
            final_path.display()
        )));
        let state = ka_state(&ka, cfg.ka.epochs, report.ka_epochs.last().map(|e| e.mean_loss));
        checkpoint::save(&final_path, &det, None, &state)?;
    }
    report.ka_seconds = t_ka.elapsed().as_secs_f64();
    report.final_checkpoint = Some(final_path.clone());
    // Counted again after the evaluation, which levels the validation frames too.
    report.vpp = vpp.as_ref().map(|v| v.counts());
    if opts.stop_after == Some(Stage::Ka) {
        return Ok(report);
    }
    if cfg.guard.compare {
        on_event(AdaptEvent::Stage("guard: adapted vs PA through VPP"));
        let c = compare_with_pa(
            &det,
            &opts,
            pa_detections.as_deref(),
            &pa_path,
            &final_path,
            Arc::new(target_prep(false)?),
        )?;
        let line = format!(
            "guard: ship {} — {} (on {} target frames: PA through VPP {:.2} confident boxes per frame, mean score {:.2}; adapted {:.2}, {:.2}; agreement F1 {:.2}); PA checkpoint {} (run it through VPP), adapted {}",
            c.ship,
            c.reason,
            c.frames,
            c.pa_vpp.per_frame,
            c.pa_vpp.mean_score,
            c.adapted.per_frame,
            c.adapted.mean_score,
            c.agreement_f1,
            c.pa_checkpoint.display(),
            c.adapted_checkpoint.display()
        );
        // Shown once, as an event (the command line prints them); the report keeps warnings.
        if c.ship == guard::Ship::PaVpp {
            report.warnings.push(line.clone());
            on_event(AdaptEvent::Message(format!("warning: {line}")));
        } else {
            on_event(AdaptEvent::Message(line));
        }
        report.guard = Some(c);
    }
    if let Some(v) = val {
        on_event(AdaptEvent::Stage("evaluating the adapted model"));
        let (ap, adapted) = evaluate_keeping(&det, Arc::new(target_prep(false)?), v, &out.join("val_adapted.jsonl"))?;
        report.adapted = Some(ap);
        if let Some(pa) = &pa_vpp_val {
            let infos: Vec<_> = adapted.iter().map(|f| f.info.clone()).collect();
            let (a, b) = (eval::detections(&adapted)?, eval::detections(pa)?);
            let c = bootstrap::compare(&infos, &a, &b, &val_options(det_cfg), VAL_BOOTSTRAP_DRAWS, 0)
                .map_err(NnError::from)?;
            report.val_sequences = c.sequences;
            report.adapted_vs_pa_vpp = c.classes;
        }
    }
    report.vpp = vpp.as_ref().map(|v| v.counts());
    report.total_seconds = t0.elapsed().as_secs_f64();
    let json = serde_json::to_vec_pretty(&report).unwrap_or_default();
    pi3det_data::io::write_atomic(&out.join("adapt.json"), &json, true)?;
    pi3det_data::io::write_atomic(&out.join("adapt.md"), markdown(&report, det_cfg).as_bytes(), true)?;
    Ok(report)
}

/// The labels KA trains on from the labeller's boxes `raw` (thresholds chosen for them), with
/// the round's thresholds and positives; `epoch`: the KA epoch they are made before
/// (`usize::MAX`: regenerated on resuming).
fn label_round(raw: &[FrameDetections], cfg: &AdaptConfig, epoch: usize) -> (Vec<FrameDetections>, LabelRound) {
    let pl = &cfg.pseudo_labels;
    let th = thresholds::choose(raw, &cfg.detector, pl, &cfg.adaptive_thresholds);
    let labels = thresholds::training_labels(raw, &th, &cfg.detector, pl.positive_score);
    let positives = PositiveStats::of(&labels, pl.positive_score);
    (labels, LabelRound { epoch, thresholds: th, positives })
}

/// Logs a label round (thresholds, positives per frame, the warning when they are too few) and
/// records it in the report.
fn record_round(
    round: LabelRound,
    cfg: &AdaptConfig,
    report: &mut AdaptReport,
    on_event: &mut dyn FnMut(AdaptEvent<'_>),
) {
    let p = &round.positives;
    on_event(AdaptEvent::Message(format!(
        "pseudo-labels: {} positives, {:.2} per target frame ({} of {} frames without any)",
        p.positives, p.per_frame, p.frames_without, p.frames
    )));
    if round.thresholds.lowered {
        let line = format!(
            "pseudo-labels: {:.2} positives per frame at positive_score {}: thresholds lowered to {}",
            round.thresholds.fixed_positives_per_frame,
            cfg.pseudo_labels.positive_score,
            round.thresholds.summary()
        );
        on_event(AdaptEvent::Message(line));
    }
    if let Some(w) = p.warning(cfg.guard.warn_positives_per_frame, cfg.target_negatives.enabled) {
        on_event(AdaptEvent::Message(format!("warning: {w}")));
        report.warnings.push(w);
    }
    report.label_rounds.push(round);
}

/// The guard's comparison on (up to `max_frames` of) the target's training frames: `det` (the
/// adapted model) and the PA model through VPP (`pa_detections`: its boxes on every target
/// frame when already made, else it runs again from `pa_path`).
fn compare_with_pa(
    det: &Detector,
    opts: &AdaptOptions,
    pa_detections: Option<&[FrameDetections]>,
    pa_path: &Path,
    adapted_path: &Path,
    prep: Arc<Preprocessor>,
) -> Result<Comparison> {
    let cfg = &opts.config;
    let n = opts.target.len();
    let m = if cfg.guard.max_frames == 0 { n } else { cfg.guard.max_frames.min(n) };
    let at: Vec<usize> = (0..m).map(|k| k * n / m).collect();
    let frames =
        Subset { dataset: opts.target.dataset.clone(), indices: at.iter().map(|&k| opts.target.indices[k]).collect() };
    // The pseudo-labels hold no box below the band's floor: confident starts there.
    let ignore = cfg.pseudo_labels.ignore_score;
    let score = cfg.guard.score.unwrap_or(ignore).max(ignore);
    let pa = match pa_detections {
        Some(d) => at.iter().map(|&k| d[k].clone()).collect(),
        None => {
            let (pa, _) = checkpoint::load_detector_with_post(pa_path, Some(&cfg.detector.post), opts.device)?;
            detect::detect_with(&pa, prep.clone(), &frames, 4, true, &mut |_, _| {})?.0
        }
    };
    let (adapted, _) = detect::detect_with(det, prep, &frames, 4, true, &mut |_, _| {})?;
    guard::compare(&pa, &adapted, &cfg.guard, score, pa_path.to_path_buf(), adapted_path.to_path_buf())
}

/// The report as markdown: AP of the source-only and adapted models, pseudo-label quality.
pub fn markdown(r: &AdaptReport, cfg: &DetectorConfig) -> String {
    let mut s = format!("# {} — components {}\n\n", r.name, component_names(&r.components));
    s += "| model on the target | ";
    s += &cfg.classes.iter().map(|c| format!("{c} BEV | {c} 3D")).collect::<Vec<_>>().join(" | ");
    s += " |\n| --- |";
    s += &" --- | --- |".repeat(cfg.classes.len());
    s += "\n";
    for (name, a) in [
        ("source-only (PA)", &r.source_only),
        ("source-only (PA) through VPP", &r.source_only_vpp),
        ("adapted (KA)", &r.adapted),
    ] {
        if let Some(a) = a {
            s += &format!("| {name} |");
            for c in &cfg.classes {
                match a.get(c) {
                    Some(x) => s += &format!(" {:.1} | {:.1} |", x.bev_r40, x.d3_r40),
                    None => s += " – | – |",
                }
            }
            s += "\n";
        }
    }
    if !r.adapted_vs_pa_vpp.is_empty() {
        s += "\n";
        s += &bootstrap::format_comparison(&r.adapted_vs_pa_vpp, "adapted", "PA through VPP", r.val_sequences);
    }
    if !r.pseudo_label_quality.is_empty() {
        s += "\nPseudo-labels (positives) against the target's ground truth:\n\n";
        let rows: Vec<(String, Vec<LabelQuality>)> =
            r.pseudo_label_quality.iter().map(|q| (q.labels.clone(), q.rows.clone())).collect();
        s += &pseudo_labels::quality_table(&rows);
    }
    if !r.label_rounds.is_empty() {
        s += "\nPositive pseudo-labels KA trained on:\n\n| before KA epoch | positives | per frame | frames without | thresholds |\n| --- | ---: | ---: | ---: | --- |\n";
        for l in &r.label_rounds {
            let epoch = if l.epoch == usize::MAX { "resumed".to_string() } else { (l.epoch + 1).to_string() };
            let th: Vec<String> =
                l.thresholds.classes.iter().map(|c| format!("{} {:.2}", c.class, c.threshold)).collect();
            s += &format!(
                "| {epoch} | {} | {:.2} | {} / {} | {} |\n",
                l.positives.positives,
                l.positives.per_frame,
                l.positives.frames_without,
                l.positives.frames,
                th.join(", ")
            );
        }
    }
    if let Some(g) = &r.guard {
        s += &format!(
            "\nGuard ({} target training frames, confident = score ≥ {:.2}): **ship {}** — {}.\n\n| model | confident boxes per frame | mean score |\n| --- | ---: | ---: |\n| PA through VPP (`{}`) | {:.2} | {:.3} |\n| adapted (`{}`) | {:.2} | {:.3} |\n\nThe adapted model finds {:.0} % of the PA model's confident boxes; agreement F1 {:.2}.\n",
            g.frames,
            g.score,
            g.ship,
            g.reason,
            g.pa_checkpoint.display(),
            g.pa_vpp.per_frame,
            g.pa_vpp.mean_score,
            g.adapted_checkpoint.display(),
            g.adapted.per_frame,
            g.adapted.mean_score,
            100.0 * g.retained,
            g.agreement_f1
        );
    }
    if !r.warnings.is_empty() {
        s += "\nWarnings:\n\n";
        for w in &r.warnings {
            s += &format!("- {w}\n");
        }
    }
    if let Some(v) = &r.vpp {
        s += &format!(
            "\nVPP: {} target frames levelled ({} from poses, {} from the ground fit, {} without ground kept the plain shift); source height {:.2} m.\n",
            v.frames,
            v.from_pose,
            v.from_ground,
            v.no_ground,
            r.source_height_m.unwrap_or(f64::NAN)
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Pi3DET-Net presets parse; the Voxel R-CNN one carries every component on the voxel
    /// detector (sparse backbone, voxel RoI pooling, GTD, PFA, RPJ). The CPU preset leaves RPJ
    /// out (its comment says why); the others keep the paper's four components.
    #[test]
    fn adapt_presets_parse() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        for name in ["pi3det_net_cpu.toml", "pi3det_net_paper.toml", "pi3det_net_voxel_rcnn_cpu.toml"] {
            let cfg = AdaptConfig::from_file(&dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
            let d = &cfg.detector;
            assert!(d.neck.is_some() && d.pfa.is_some() && d.roi_head.is_some(), "{name}");
            let voxel = name.contains("voxel");
            assert_eq!(d.backbone_3d.is_some(), voxel, "{name}");
            assert_eq!(d.roi_head.as_ref().is_some_and(|r| r.voxel_pool.is_some()), voxel, "{name}");
            let rpj = d.train.augment.iter().any(|a| matches!(a, AugmentConfig::RandomPlatformJitter(_)));
            assert_eq!(rpj, name != "pi3det_net_cpu.toml", "{name}: RPJ");
        }
    }

    /// An ablation row gets exactly its components: `without` drops, `with` adds a missing one with
    /// its defaults and keeps a present one's settings, and the two undo each other.
    #[test]
    fn exactly_switches_components_both_ways() {
        let all = AdaptConfig::default();
        assert_eq!(all.components(), vec![Component::Rpj, Component::Vpp, Component::Gtd, Component::Pfa]);
        let none = all.exactly(&[]);
        assert!(none.components().is_empty());
        let rpj = none.exactly(&[Component::Rpj]);
        assert_eq!(rpj.components(), vec![Component::Rpj]);
        let jitter = |c: &AdaptConfig| {
            c.detector
                .train
                .augment
                .iter()
                .filter_map(|a| match a {
                    AugmentConfig::RandomPlatformJitter(j) => Some(j.max_deg),
                    _ => None,
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(jitter(&rpj), vec![RandomPlatformJitterConfig::default().max_deg]);
        // A present component keeps its settings (and is not added twice).
        let mut mild = all.clone();
        for a in &mut mild.detector.train.augment {
            if let AugmentConfig::RandomPlatformJitter(j) = a {
                j.max_deg = 2.0;
            }
        }
        assert_eq!(jitter(&mild.exactly(&[Component::Rpj, Component::Vpp])), vec![2.0]);
        assert_eq!(none.with(&all.components()).components(), all.components());
        assert_eq!(all.exactly(&all.components()), all);
    }

    /// Loss weights and estimators, precision and layout do not make another network; widths and
    /// modules do.
    #[test]
    fn architecture_ignores_loss_weights() {
        let base = AdaptConfig::default().detector;
        let p = Path::new("pa.safetensors");
        let mut other = base.clone();
        other.pfa.as_mut().unwrap().kl_weight = 0.01;
        other.pfa.as_mut().unwrap().roi_weight = 0.5;
        other.pfa.as_mut().unwrap().kl_estimator = pi3det_nn::roi_heads::pfa::KlEstimator::Mixture;
        other.pfa.as_mut().unwrap().kl_into_encoder = false;
        other.precision = pi3det_nn::precision::Precision::Bf16;
        other.channels_last = !base.channels_last;
        if let Some(NeckConfig::Gtd(g)) = other.neck.as_mut() {
            g.rotation_weight = 1.0;
        }
        check_architecture(p, &base, &other).unwrap();
        other.pfa.as_mut().unwrap().latent_channels += 1;
        let err = check_architecture(p, &base, &other).unwrap_err().to_string();
        assert!(err.contains("pfa"), "{err}");
    }
}
