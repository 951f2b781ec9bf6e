//! Knowledge-Adaptation (Pi3DET-Net §4.3): starting from the pre-adapted weights, every step
//! takes one source batch (`L_det + λ_RoI L_RoI`; no `L_rot`) and one target batch (Virtual
//! Platform Pose, pseudo-labels with their ignored band, `L_det`), adds PFA's `λ_KL L_KL` between
//! the two batches' RoI latents, and makes one optimiser step on the sum. An epoch is one pass
//! over the target frames; the source loader cycles (reshuffled) as often as needed.
//!
//! Reproducible across interruptions: libtorch's generator (dropout, PFA's samples) is reseeded
//! at every epoch start from the run seed and the epoch, loaders and RoI sampling are seeded per
//! epoch and step, so resuming from an epoch's checkpoint continues exactly as an uninterrupted
//! run would.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use tch::Device;

use pi3det_nn::augment::Augment;
use pi3det_nn::config::TrainConfig;
use pi3det_nn::data_loader::{frame_seed, Batch, Loader, LoaderOptions, Subset};
use pi3det_nn::detector::{Detector, Domain};
use pi3det_nn::error::{NnError, Result};
use pi3det_nn::losses::target_negatives::{TargetNegatives, TargetNegativesConfig};
use pi3det_nn::optim::{OneCycle, Optimizer};
use pi3det_nn::preprocess::Preprocessor;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KaConfig {
    /// Passes over the target's training frames.
    pub epochs: usize,
    /// Peak learning rate of KA's own one-cycle schedule (the rest of the schedule is the
    /// detector's `train` section).
    pub lr: f64,
    /// Share of the pre-adapted weights in the shipped model: after the last epoch every weight
    /// becomes `(1 − pa_weight)·KA + pa_weight·PA` (WiSE-FT's weight-space ensemble; 0: the KA
    /// weights as trained). Self-training on a model's own pseudo-labels can take it below
    /// where it started on a target (the demo's quadruped); averaging with the model the labels
    /// came from keeps part of what KA adds without all of what it loses.
    pub pa_weight: f64,
    /// Parts of the detector KA leaves as Pre-Adaptation trained them: variable-name prefixes
    /// (`vfe`, `backbone_2d`, `neck`, `dense_head`, `roi_head`, …). Their batch-norm statistics
    /// still follow KA's batches.
    pub frozen: Vec<String>,
    /// Scales of the target batches' loss terms by name (`cls`, `loc`, `dir`, `hm`), on top of the
    /// detector's `loss_weights`: pseudo-labels' boxes are the labeller's own estimates, so a
    /// target can teach what is there at a different weight than where exactly it sits.
    pub target_loss_weights: BTreeMap<String, f64>,
}

impl Default for KaConfig {
    fn default() -> Self {
        // ST3D self-trains at half the source learning rate.
        Self { epochs: 2, lr: 0.0015, pa_weight: 0.0, frozen: Vec::new(), target_loss_weights: BTreeMap::new() }
    }
}

impl KaConfig {
    pub fn validate(&self) -> Result<()> {
        if self.epochs == 0 || !(self.lr.is_finite() && self.lr > 0.0) {
            return Err(NnError::config("ka", format!("ka: epochs must be positive and lr > 0 (got {self:?})")));
        }
        if !(0.0..1.0).contains(&self.pa_weight) {
            return Err(NnError::config(
                "ka.pa_weight",
                format!("ka.pa_weight must be in [0, 1) (got {})", self.pa_weight),
            ));
        }
        // A target batch's terms: the heads' classification and box terms (source-only terms
        // never reach a target batch).
        const TARGET_TERMS: [&str; 4] = ["cls", "loc", "dir", "hm"];
        if let Some(k) = self.target_loss_weights.keys().find(|k| !TARGET_TERMS.contains(&k.as_str())) {
            return Err(NnError::config(
                "ka.target_loss_weights",
                format!("ka.target_loss_weights: {k:?} is not a target loss term (one of {TARGET_TERMS:?})"),
            ));
        }
        if let Some((k, w)) = self.target_loss_weights.iter().find(|(_, w)| !(w.is_finite() && **w >= 0.0)) {
            return Err(NnError::config(
                "ka.target_loss_weights",
                format!("ka.target_loss_weights.{k} must be a finite weight ≥ 0 (got {w})"),
            ));
        }
        if let Some(p) = self.frozen.iter().find(|p| p.is_empty() || p.starts_with('.')) {
            return Err(NnError::config("ka.frozen", format!("ka.frozen: {p:?} is not a part of the detector")));
        }
        Ok(())
    }

    /// The detector's variables KA trains: all but the [`frozen`](Self::frozen) parts. Refuses a
    /// prefix that names no variable (a typo would otherwise freeze nothing).
    pub fn trainables(&self, det: &Detector) -> Result<Vec<(String, tch::Tensor)>> {
        let all = det.named_trainables();
        let hits = |p: &str, n: &str| n == p || n.starts_with(&format!("{p}."));
        if let Some(p) = self.frozen.iter().find(|p| !all.iter().any(|(n, _)| hits(p, n))) {
            return Err(NnError::config(
                "ka.frozen",
                format!("ka.frozen: no trainable variable of the detector is under {p:?}"),
            ));
        }
        Ok(all.into_iter().filter(|(n, _)| !self.frozen.iter().any(|p| hits(p, n))).collect())
    }

    /// The detector's training settings with KA's schedule.
    pub fn train_config(&self, base: &TrainConfig) -> TrainConfig {
        TrainConfig { epochs: self.epochs, lr: self.lr, ..base.clone() }
    }
}

/// One domain's data: frames, how they are prepared and augmented.
#[derive(Clone)]
pub struct DomainData {
    pub subset: Subset,
    pub prep: Arc<Preprocessor>,
    pub augments: Arc<Vec<Box<dyn Augment>>>,
}

/// Progress of one KA step.
#[derive(Debug, Clone)]
pub struct KaStep {
    pub epoch: usize,
    pub step: i64,
    pub total_steps: usize,
    pub lr: f64,
    pub loss: f64,
    /// Source and target loss totals and λ_KL·L_KL (0 without PFA or without RoIs).
    pub source: f64,
    pub target: f64,
    pub kl: f64,
    /// The target batch's mean background weight under the coverage rule (1 without it;
    /// [`pi3det_nn::losses::target_negatives`]).
    pub target_background_weight: f64,
    pub grad_norm: f64,
    pub step_seconds: f64,
}

/// The KA loop's state: optimiser, schedule and the step counters.
pub struct KnowledgeAdaptation {
    pub optim: Optimizer,
    schedule: OneCycle,
    train: TrainConfig,
    pub steps_per_epoch: usize,
    pub total_steps: usize,
    /// The target batches' background rules and the band's floor they default to (none: every
    /// unlabelled target output is background, as in self-training baselines).
    negatives: Option<(TargetNegativesConfig, f64)>,
    /// The pre-adapted model whose scores the target's background learns
    /// (`target_negatives.teacher_scores`).
    teacher: Option<Detector>,
    target_loss_weights: BTreeMap<String, f64>,
}

impl KnowledgeAdaptation {
    /// The optimiser takes [`KaConfig::trainables`]; the frozen parts' variables stop requiring
    /// gradients, so backward neither computes nor accumulates any for them.
    pub fn new(det: &Detector, cfg: &KaConfig, target_frames: usize) -> Result<Self> {
        let train = cfg.train_config(&det.cfg().train);
        let steps_per_epoch = (target_frames / train.batch_size).max(1);
        let total_steps = steps_per_epoch * cfg.epochs;
        let trained = cfg.trainables(det)?;
        if trained.len() < det.named_trainables().len() {
            for (name, t) in det.named_trainables() {
                if !trained.iter().any(|(n, _)| *n == name) {
                    let _ = t.set_requires_grad(false);
                }
            }
        }
        Ok(Self {
            optim: Optimizer::new(trained, &train),
            schedule: OneCycle::new(&train, total_steps),
            train,
            steps_per_epoch,
            total_steps,
            negatives: None,
            teacher: None,
            target_loss_weights: cfg.target_loss_weights.clone(),
        })
    }

    /// Target batches' background under `cfg` ([`pi3det_nn::losses::target_negatives`]; when enabled), with
    /// `ignore_score` the pseudo-labels' band floor.
    pub fn with_target_negatives(mut self, cfg: &TargetNegativesConfig, ignore_score: f64) -> Self {
        self.negatives = cfg.enabled.then(|| (cfg.clone(), ignore_score));
        self
    }

    /// The pre-adapted model as the target background's teacher (`target_negatives.teacher_scores`;
    /// it takes part only where the background rules are enabled).
    pub fn with_teacher(mut self, teacher: Detector) -> Self {
        self.teacher = Some(teacher);
        self
    }

    fn loader(&self, d: &DomainData, epoch: u64) -> Loader {
        Loader::new(
            d.prep.clone(),
            d.augments.clone(),
            d.subset.clone(),
            LoaderOptions {
                batch_size: self.train.batch_size,
                train: true,
                seed: self.train.seed,
                epoch,
                prefetch: self.train.prefetch,
                drop_last: true,
                views: Vec::new(),
            },
        )
    }

    /// One epoch over `target` with batches of `source` alongside (none: target batches only,
    /// as ST3D self-trains); returns the mean loss. With `norms`, each domain's batches run on
    /// its own batch-norm statistics (ST3D++'s DSNorm) and the target's are left in the network;
    /// PFA's KL term, which couples the two passes, is then not computed.
    #[allow(clippy::too_many_arguments)]
    pub fn epoch(
        &mut self,
        det: &Detector,
        epoch: usize,
        source: Option<&DomainData>,
        target: &DomainData,
        mut norms: Option<&mut crate::baselines::DomainNorms>,
        device: Device,
        on_step: &mut dyn FnMut(&KaStep),
    ) -> Result<f64> {
        let seed = self.train.seed;
        tch::manual_seed(frame_seed(seed, 0x4b41 + epoch as u64, 0) as i64 & i64::MAX);
        // Source passes are numbered apart from the PA epochs (fresh shuffles) and restart with
        // every KA epoch, so an epoch depends on nothing but its number.
        let source_pass = |k: u64| 1_000_000 + 1_000 * epoch as u64 + k;
        let mut passes = 0;
        let mut src = source.map(|s| self.loader(s, source_pass(passes)));
        let tgt = self.loader(target, 2_000_000 + epoch as u64);
        let (mut sum, mut n) = (0.0, 0usize);
        for (bi, tb) in tgt.enumerate() {
            let tb = tb?;
            let sb = match (&mut src, source) {
                (Some(l), Some(s)) => Some(match l.next() {
                    Some(b) => b?,
                    None => {
                        passes += 1;
                        *l = self.loader(s, source_pass(passes));
                        l.next().ok_or_else(|| NnError::Loader("the source set gave no batch".into()))??
                    }
                }),
                _ => None,
            };
            if sb.as_ref().is_some_and(|b| b.num_pillars < 2) || tb.num_pillars < 2 {
                tracing::warn!("KA: skipping a step with a batch of (almost) no pillars");
                continue;
            }
            let t0 = Instant::now();
            let (lr, beta1) = self.schedule.at(self.optim.step as usize);
            let mut rng = ChaCha8Rng::seed_from_u64(frame_seed(seed, epoch as u64, self.optim.step as u64 ^ 0x6b61));
            self.optim.zero_grad();
            // With per-domain statistics, each domain's pass is differentiated before the other's
            // statistics are swapped in: batch norm's backward checks the buffers it saw are
            // unchanged. The gradients add up to those of the summed loss.
            let split_backward = norms.is_some();
            let (ls, zs) = match &sb {
                Some(sb) => {
                    if let Some(nm) = norms.as_deref_mut() {
                        nm.enter(Domain::Source);
                    }
                    let (l, z) = domain_pass(det, sb, Domain::Source, None, &BTreeMap::new(), device, &mut rng)?;
                    if split_backward {
                        l.backward();
                    }
                    (Some(l), z)
                }
                None => (None, None),
            };
            if let Some(nm) = norms.as_deref_mut() {
                nm.enter(Domain::Target);
            }
            let neg = self.negatives.as_ref().map(|(c, ignore)| c.for_batch(*ignore, &tb.gt));
            let target_neg = neg.as_ref().map(|n| (n, self.teacher.as_ref()));
            let (lt, zt) =
                domain_pass(det, &tb, Domain::Target, target_neg, &self.target_loss_weights, device, &mut rng)?;
            let kl = match (zs, zt) {
                (Some(s), Some(t)) if !split_backward => det.kl_loss(&s, &t),
                _ => None,
            };
            let mut total = match &ls {
                Some(ls) if !split_backward => ls + &lt,
                _ => lt.shallow_clone(),
            };
            if let Some(k) = &kl {
                total = &total + k;
            }
            total.backward();
            let total = match &ls {
                Some(ls) if split_backward => ls.detach() + total.detach(),
                _ => total,
            };
            let grad_norm = self.optim.clip_grad_norm(self.train.grad_clip);
            let loss = total.double_value(&[]);
            if !loss.is_finite() || !grad_norm.is_finite() {
                return Err(NnError::Diverged(format!(
                    "KA: loss {loss}, gradient norm {grad_norm} at epoch {epoch}, batch {bi}"
                )));
            }
            self.optim.update(lr, beta1);
            sum += loss;
            n += 1;
            on_step(&KaStep {
                epoch,
                step: self.optim.step,
                total_steps: self.total_steps,
                lr,
                loss,
                source: ls.as_ref().map_or(0.0, |l| l.double_value(&[])),
                target: lt.double_value(&[]),
                kl: kl.map_or(0.0, |k| k.double_value(&[])),
                target_background_weight: neg.as_ref().map_or(1.0, TargetNegatives::mean_weight),
                grad_norm,
                step_seconds: t0.elapsed().as_secs_f64(),
            });
        }
        Ok(sum / n.max(1) as f64)
    }
}

/// Forward and loss of one domain's batch (a target batch's background under `neg` when given,
/// with the teacher whose scores it learns): the loss total and PFA's latents.
fn domain_pass(
    det: &Detector,
    b: &Batch,
    domain: Domain,
    neg: Option<(&TargetNegatives, Option<&Detector>)>,
    scales: &BTreeMap<String, f64>,
    device: Device,
    rng: &mut ChaCha8Rng,
) -> Result<(tch::Tensor, Option<pi3det_nn::roi_heads::pfa::Latent>)> {
    let x = b.inputs.to_device(device);
    let targets = b.targets.as_ref().ok_or_else(|| NnError::Loader("batch without targets".into()))?;
    let out = det.forward_train(&x, &b.gt, rng)?;
    let targets = targets.to_device(device);
    let losses = match neg {
        Some((n, teacher)) => {
            let teacher = teacher.map(|t| t.dense_eval(&x)).transpose()?;
            det.loss_target(&out, &targets, &b.gt, n, teacher.as_ref())?
        }
        None => det.loss(&out, &targets, &b.gt, domain)?,
    };
    let z = det.latent(&out, domain).transpose()?;
    Ok((losses.total_scaled(scales), z))
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_nn::testing::tiny_detector;

    #[test]
    fn frozen_parts_leave_the_optimiser_and_a_wrong_name_is_refused() {
        let det = Detector::new(&tiny_detector(12.8, 0.8), Device::Cpu).unwrap();
        let all = KaConfig::default().trainables(&det).unwrap();
        assert_eq!(all.len(), det.named_trainables().len(), "nothing frozen by default");
        let cfg = KaConfig { frozen: vec!["vfe".into(), "backbone_2d".into()], ..Default::default() };
        let kept = cfg.trainables(&det).unwrap();
        assert!(!kept.is_empty() && kept.len() < all.len());
        assert!(kept.iter().all(|(n, _)| !n.starts_with("vfe.") && !n.starts_with("backbone_2d.")), "{kept:?}");
        assert!(kept.iter().any(|(n, _)| n.starts_with("dense_head.")));
        KnowledgeAdaptation::new(&det, &cfg, 4).unwrap();
        for (n, t) in det.named_trainables() {
            let frozen = n.starts_with("vfe.") || n.starts_with("backbone_2d.");
            assert_eq!(t.requires_grad(), !frozen, "{n}: gradients only for what KA trains");
        }
        // A prefix must name a whole part: `backbone` is not `backbone_2d`.
        let typo = KaConfig { frozen: vec!["backbone".into()], ..Default::default() };
        let e = typo.trainables(&det).unwrap_err().to_string();
        assert!(e.contains("ka.frozen") && e.contains("\"backbone\""), "{e}");
        assert!(KaConfig { frozen: vec![String::new()], ..Default::default() }.validate().is_err());
    }

    #[test]
    fn target_loss_weights_name_real_terms_and_finite_weights() {
        let with =
            |k: &str, w: f64| KaConfig { target_loss_weights: [(k.to_string(), w)].into(), ..Default::default() };
        with("loc", 0.0).validate().unwrap();
        with("cls", 0.5).validate().unwrap();
        let e = with("lco", 0.0).validate().unwrap_err().to_string();
        assert!(e.contains("\"lco\"") && e.contains("target_loss_weights"), "{e}");
        assert!(with("loc", -1.0).validate().is_err());
        assert!(with("loc", f64::NAN).validate().is_err());
    }
}
