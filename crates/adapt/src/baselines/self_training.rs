//! Self-training on a target's pseudo-labels, the loop ST3D, ST3D++, MS3D++ and REDB share:
//! labels from a labeller (the current detector, an ensemble, a selection), optionally merged
//! into ST3D's triplet [`memory`](super::memory) and refreshed every `refresh_every` epochs,
//! curriculum-widened augmentations, and per step one target batch (plus one source batch when
//! `source_assisted`, ST3D++), with domain-specific batch-norm statistics when `ds_norm`.
//! Steps run through [`crate::ka::KnowledgeAdaptation`] (its one-cycle schedule, seeding
//! and ignored band), so a self-trained baseline and Pi3DET-Net's KA differ only in what the
//! methods add. A finished run writes `final.safetensors` (the target's statistics in its batch
//! norms when `ds_norm`).

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use pi3det_data::FrameInfo;
use serde::{Deserialize, Serialize};
use tch::Device;

use super::curriculum::CurriculumConfig;
use super::ds_norm::DomainNorms;
use super::memory::{self, MemoryBox, MemoryConfig};
use crate::ka::{DomainData, KaConfig, KaStep, KnowledgeAdaptation};
use crate::pseudo_labels::{self, LabelQuality, PseudoLabelConfig, PseudoLabeled};
use pi3det_nn::augment::AugmentConfig;
use pi3det_nn::checkpoint::{self, TrainState};
use pi3det_nn::data_loader::Subset;
use pi3det_nn::detect::FrameDetections;
use pi3det_nn::detector::{Detector, Domain};
use pi3det_nn::error::{NnError, Result};
use pi3det_nn::preprocess::Preprocessor;
use pi3det_nn::train::build_augments;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SelfTrainingConfig {
    /// Passes over the target's training frames.
    pub epochs: usize,
    pub lr: f64,
    /// Positive score, ignored band and refresh period (0: the first labels stay fixed, MS3D++).
    pub labels: PseudoLabelConfig,
    pub memory: Option<MemoryConfig>,
    pub curriculum: Option<CurriculumConfig>,
    /// ST3D++: a source batch (with its labels) beside every target batch.
    pub source_assisted: bool,
    /// ST3D++: separate batch-norm statistics per domain (needs `source_assisted`).
    pub ds_norm: bool,
}

impl Default for SelfTrainingConfig {
    /// ST3D's recipe: memory, curriculum, labels refreshed every 2 epochs, thresholds 0.6 / 0.2.
    fn default() -> Self {
        Self {
            epochs: 4,
            lr: 0.0015,
            labels: PseudoLabelConfig { positive_score: 0.6, ignore_score: 0.2, refresh_every: 2 },
            memory: Some(MemoryConfig::default()),
            curriculum: Some(CurriculumConfig::default()),
            source_assisted: false,
            ds_norm: false,
        }
    }
}

/// The epochs of ST3D's published schedule, for which its refresh period (2) and curriculum
/// milestones (5, 10, 20, 25) are given.
pub const ST3D_EPOCHS: usize = 30;

impl SelfTrainingConfig {
    /// The same recipe over `epochs` epochs: the refresh period and the curriculum's milestones
    /// scaled from [`ST3D_EPOCHS`] (at least every epoch and from epoch 1), so a short run still
    /// relabels, merges its memory and widens its augmentations in the published proportions
    /// rather than stopping after its first labels. Fixed labels (`refresh_every = 0`) stay fixed.
    pub fn scaled_to(&self, epochs: usize) -> Self {
        let scale = |e: usize| ((e * epochs) as f64 / ST3D_EPOCHS as f64).round().max(1.0) as usize;
        let mut c = self.clone();
        c.epochs = epochs;
        if c.labels.refresh_every > 0 {
            c.labels.refresh_every = scale(c.labels.refresh_every);
        }
        if let Some(cur) = c.curriculum.as_mut() {
            cur.milestones = cur.milestones.iter().map(|&m| scale(m)).collect();
        }
        c
    }

    /// The (0-based) epochs that start with new pseudo-labels: the first, then every
    /// `refresh_every`.
    pub fn refresh_epochs(&self) -> Vec<usize> {
        let r = self.labels.refresh_every;
        (0..self.epochs).filter(|&e| e == 0 || (r > 0 && e % r == 0)).collect()
    }

    /// The KA loop's settings this self-training runs with (the trained weights as they are).
    fn ka(&self) -> KaConfig {
        KaConfig { epochs: self.epochs, lr: self.lr, ..KaConfig::default() }
    }

    pub fn validate(&self) -> Result<()> {
        self.labels.validate()?;
        self.ka().validate()?;
        if self.ds_norm && !self.source_assisted {
            return Err(NnError::config(
                "self_training",
                "self_training: ds_norm needs source_assisted (a source batch to keep apart)",
            ));
        }
        if let Some(c) = &self.curriculum {
            if !(c.factor.is_finite() && c.factor > 0.0) {
                return Err(NnError::config(
                    "self_training.curriculum",
                    format!("self_training.curriculum: factor must be positive (got {})", c.factor),
                ));
            }
        }
        Ok(())
    }
}

/// The pseudo-labels of one refresh and their quality against target ground truth.
#[derive(Debug, Clone, Serialize)]
pub struct LabelRound {
    pub epoch: usize,
    pub positives: usize,
    pub ignored: usize,
    pub quality: Vec<LabelQuality>,
}

#[derive(Debug, Clone, Serialize, Default)]
pub struct SelfTrainingReport {
    pub rounds: Vec<LabelRound>,
    pub steps: i64,
    pub seconds: f64,
}

/// Makes pseudo-labels with the detector as it is now: one entry per target frame, in the
/// target subset's order, boxes at or above the ignore score.
pub type Labeller<'a> = dyn FnMut(&Detector) -> Result<Vec<FrameDetections>> + 'a;

pub struct SelfTraining<'a> {
    pub config: SelfTrainingConfig,
    /// Source frames for source-assisted steps (prepared and augmented as in source training).
    pub source: Option<DomainData>,
    pub target: Subset,
    /// The target's ground truth (for the label quality rows), if it has any.
    pub target_gt: Option<&'a [FrameInfo]>,
    pub device: Device,
}

/// The target's augmentations: the source's scene-level ones (no database pasting, no platform
/// jitter, no object resizing, which are source-side methods), widened by the curriculum.
fn target_augments(
    det_cfg: &pi3det_nn::config::DetectorConfig,
    cfg: &SelfTrainingConfig,
    epoch: usize,
) -> Vec<AugmentConfig> {
    let base: Vec<AugmentConfig> = det_cfg
        .train
        .augment
        .iter()
        .filter(|a| {
            !matches!(
                a,
                AugmentConfig::GtSampling(_)
                    | AugmentConfig::RandomPlatformJitter(_)
                    | AugmentConfig::RandomObjectScaling(_)
                    | AugmentConfig::StatisticalNormalization(_)
            )
        })
        .cloned()
        .collect();
    match &cfg.curriculum {
        Some(c) => c.apply(&base, epoch),
        None => base,
    }
}

impl SelfTraining<'_> {
    /// Self-trains `det` in place; the final weights go to `out_dir/final.safetensors`.
    pub fn run(
        &self,
        det: &mut Detector,
        labeller: &mut Labeller<'_>,
        out_dir: &Path,
        on_step: &mut dyn FnMut(&KaStep),
    ) -> Result<SelfTrainingReport> {
        let cfg = &self.config;
        cfg.validate()?;
        if self.target.is_empty() {
            return Err(NnError::Input("the target split has no frames".into()));
        }
        if cfg.source_assisted && self.source.is_none() {
            return Err(NnError::Input("source-assisted self-training needs source frames".into()));
        }
        if cfg.ds_norm && det.cfg().pfa.is_some() {
            return Err(NnError::config(
                "self_training",
                "self_training: ds_norm keeps each domain's pass apart, which PFA's source ↔ target KL term cannot",
            ));
        }
        std::fs::create_dir_all(out_dir).map_err(|e| NnError::io(out_dir, e))?;
        let t0 = Instant::now();
        let det_cfg = det.cfg().clone();
        let r = det_cfg.pillars.point_cloud_range;
        let bev = [r[0], r[1], r[3], r[4]];
        let pos = cfg.labels.positive_score;
        let mut norms = cfg.ds_norm.then(|| DomainNorms::new(&det.vs));
        let mut ka = KnowledgeAdaptation::new(det, &cfg.ka(), self.target.len())?;
        let mut report = SelfTrainingReport::default();
        let mut mem: Vec<Vec<MemoryBox>> = Vec::new();
        let mut labels: Vec<FrameDetections> = Vec::new();
        let refreshes = cfg.refresh_epochs();
        for epoch in 0..cfg.epochs {
            if refreshes.contains(&epoch) {
                if let Some(n) = norms.as_mut() {
                    n.enter(Domain::Target);
                }
                let new = labeller(det)?;
                if new.len() != self.target.len() {
                    return Err(NnError::Input(format!(
                        "the labeller gave {} frames for {} target frames",
                        new.len(),
                        self.target.len()
                    )));
                }
                labels = match &cfg.memory {
                    Some(m) => {
                        if mem.is_empty() {
                            mem = new.iter().map(|f| f.objects.iter().cloned().map(MemoryBox::new).collect()).collect();
                        } else {
                            mem = mem.iter().zip(&new).map(|(old, f)| memory::update(old, &f.objects, m)).collect();
                        }
                        new.iter()
                            .zip(&mem)
                            .map(|(f, m_)| FrameDetections {
                                info: f.info.clone(),
                                objects: memory::training_labels(m_, m, pos),
                            })
                            .collect()
                    }
                    None => new,
                };
                let positives =
                    labels.iter().flat_map(|f| &f.objects).filter(|o| o.score.unwrap_or(1.0) >= pos).count();
                let total: usize = labels.iter().map(|f| f.objects.len()).sum();
                let quality = match self.target_gt.filter(|g| g.iter().any(|i| !i.objects.is_empty())) {
                    Some(gt) => pseudo_labels::quality(&labels, gt, &det_cfg, pos, &[0.5, 0.7], bev),
                    None => Vec::new(),
                };
                report.rounds.push(LabelRound { epoch, positives, ignored: total - positives, quality });
            }
            let mut epoch_cfg = det_cfg.clone();
            epoch_cfg.train.augment = target_augments(&det_cfg, cfg, epoch);
            let prep = Arc::new(Preprocessor::new(&epoch_cfg)?.with_ignore_score_below(pos));
            let subset = PseudoLabeled::new(&self.target, &labels)?.subset(&self.target);
            let (augments, _) = build_augments(&prep, &subset)?;
            let target = DomainData { subset, prep, augments: Arc::new(augments) };
            let source = if cfg.source_assisted { self.source.as_ref() } else { None };
            ka.epoch(det, epoch, source, &target, norms.as_mut(), self.device, on_step)?;
        }
        if let Some(n) = norms.as_mut() {
            n.enter(Domain::Target);
        }
        report.steps = ka.optim.step;
        report.seconds = t0.elapsed().as_secs_f64();
        let state = TrainState {
            epoch: cfg.epochs,
            step: ka.optim.step,
            total_steps: ka.total_steps,
            train_seconds: report.seconds,
            last_loss: None,
            stage: Some("self_training".into()),
        };
        checkpoint::save(&out_dir.join("final.safetensors"), det, None, &state)?;
        Ok(report)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn st3d_scaled_to_a_short_run_still_refreshes_and_widens() {
        let st3d = SelfTrainingConfig::default();
        let full = st3d.scaled_to(ST3D_EPOCHS);
        assert_eq!(full.refresh_epochs(), (0..30).step_by(2).collect::<Vec<_>>());
        assert_eq!(full.curriculum.as_ref().unwrap().milestones, vec![5, 10, 20, 25]);
        let six = st3d.scaled_to(6);
        assert_eq!(six.refresh_epochs(), vec![0, 1, 2, 3, 4, 5]);
        assert_eq!(six.curriculum.as_ref().unwrap().milestones, vec![1, 2, 4, 5]);
        let two = st3d.scaled_to(2);
        assert_eq!(two.refresh_epochs(), vec![0, 1], "two label rounds, the memory merges once");
        // MS3D++'s fixed labels stay fixed.
        let fixed = SelfTrainingConfig {
            labels: PseudoLabelConfig { refresh_every: 0, ..st3d.labels.clone() },
            ..st3d.clone()
        };
        assert_eq!(fixed.scaled_to(6).refresh_epochs(), vec![0]);
    }
}
