//! The detector as OpenPCDet users know it: a chain of named slots
//! `vfe → [backbone_3d] → map_to_bev → backbone_2d → [neck] → dense_head → [roi_head]`, each
//! built from its config. PointPillars (Lang et al., CVPR 2019) fills it with the pillar feature
//! net, the pillar scatter and the BEV backbone; the dense head is the SECOND-style anchor head
//! or the CenterPoint center head (Yin et al., CVPR 2021). Voxel detectors (SECOND, Yan et al.
//! 2018) fill `vfe` with the voxels' point means, `backbone_3d` with a sparse 3-D backbone
//! ([`crate::backbones_3d`]) and `map_to_bev` with its height compression; for pillars
//! `backbone_3d` is empty and `map_to_bev` is the pillar scatter.
//!
//! Train: `pi3det train --config configs/pointpillars_cpu.toml --data DIR --out runs/pp`;
//! detect: `pi3det detect --ckpt runs/pp/final.safetensors --data DIR --out det/`.
//!
//! The network runs on libtorch (tch); everything around it — pillarization, augmentation, target
//! assignment (on the loader thread, [`crate::preprocess`]), NMS — is Rust.

use std::sync::Arc;

use rand_chacha::ChaCha8Rng;
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

use crate::backbone_2d::Backbone2d;
use crate::backbones_3d::Backbone3d;
use crate::config::DetectorConfig;
use crate::data_loader::FrameGt;
use crate::dense_heads::{AnyDenseHead, BatchTargets, DenseOutput};
use crate::error::{NnError, Result};
use crate::losses::LossTerms;
use crate::map_to_bev::height_compression;
use crate::map_to_bev::scatter;
use crate::necks::gtd::rotation_loss;
use crate::necks::{Neck, NeckOutput};
pub use crate::post_process::Detection;
use crate::post_process::{nms_detections, to_detections};
pub use crate::preprocess::{Inputs, Preprocessor};
use crate::roi_heads::pfa::{Latent, Pfa};
use crate::roi_heads::roi_head::refined_frames;
use crate::roi_heads::{
    PillarPoints, ProposalBatch, Proposals, RoiBatchTargets, RoiOutput, RoiSource, SecondStage, StageGeometry,
};
use crate::sparse::SparseTensor;
use crate::vfe::{MeanVfe, Vfe};

/// A sparse 3-D backbone's stages (stage `s` at index `s − 1`) with where their voxels lie.
type VoxelStages = Vec<(SparseTensor, StageGeometry)>;

/// What one forward pass produced: the BEV map the heads saw and their outputs.
pub struct Forward {
    /// `[B, C, H, W]` BEV features after the backbone (and neck).
    pub bev: Tensor,
    pub dense: DenseOutput,
    /// The second stage, when the detector has one.
    pub roi: Option<RoiStage>,
    /// `[B, 2]` the neck's predicted (roll, pitch) in degrees (GTD).
    pub rotation_deg: Option<Tensor>,
}

/// Which domain a training batch comes from: source-only losses (the GTD rotation loss, PFA's
/// RoI classification) are not computed on target batches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Domain {
    Source,
    Target,
}

/// The second stage's part of a forward pass.
pub struct RoiStage {
    /// Per-RoI features, score logits and box codes; `out.rois` are the RoIs (detector frame).
    pub out: RoiOutput,
    /// Training: the sampled RoIs' targets.
    pub targets: Option<RoiBatchTargets>,
    /// Inference: the proposals the RoIs came from (scores, labels, padding mask).
    pub proposals: Option<ProposalBatch>,
}

/// The network with its weights.
pub struct Detector {
    pub vs: VarStore,
    pub prep: Arc<Preprocessor>,
    vfe: Vfe,
    backbone_3d: Option<Box<dyn Backbone3d>>,
    /// Where each of the 3-D backbone's stages lies (for a second stage pooling voxels).
    stage_geometry: Vec<StageGeometry>,
    backbone_2d: Backbone2d,
    neck: Option<Box<dyn Neck>>,
    dense_head: Box<dyn AnyDenseHead>,
    roi_head: Option<Box<dyn SecondStage>>,
    pfa: Option<Pfa>,
}

impl Detector {
    pub fn new(cfg: &DetectorConfig, device: Device) -> Result<Self> {
        Self::with_preprocessor(Preprocessor::new(cfg)?, device)
    }

    /// A detector whose frames go through `prep` (e.g. one with a per-frame transform).
    pub fn with_preprocessor(prep: Preprocessor, device: Device) -> Result<Self> {
        let prep = Arc::new(prep);
        let cfg = &prep.cfg;
        if device == Device::Cpu
            && [cfg.precision, cfg.train.precision].contains(&crate::precision::Precision::Bf16)
            && !crate::precision::cpu_has_bf16()
        {
            tracing::warn!(
                "precision bf16 on a CPU without native bfloat16: emulated, slower than f32 (`auto` picks f32 here)"
            );
        }
        let vs = VarStore::new(device);
        let root = vs.root();
        let bn = &cfg.batch_norm;
        let (vfe, backbone_3d) = match &cfg.backbone_3d {
            Some(b) => {
                let mean = MeanVfe;
                (Vfe::Mean(mean), Some(b.init(&root / "backbone_3d", mean.out_channels(), bn)))
            }
            None => (Vfe::Pillar(cfg.vfe.init(&root / "vfe", bn)), None),
        };
        let backbone_2d = cfg.backbone.init(&root / "backbone_2d", cfg.bev_input_channels(), bn);
        let mut c = cfg.backbone.out_channels();
        let neck = cfg.neck.as_ref().map(|n| n.init(&root / "neck", c, bn));
        if let Some(n) = &neck {
            c = n.out_channels();
        }
        let dense_head = cfg.head.init(&root / "dense_head", c, cfg.classes.len(), bn, &prep.map);
        let stage_channels = cfg.backbone_3d.as_ref().map(|b| b.stage_channels()).unwrap_or_default();
        let roi_head = match &cfg.roi_head {
            Some(r) => {
                Some(Box::new(r.init_with_stages(&root / "roi_head", c, &stage_channels, bn)?) as Box<dyn SecondStage>)
            }
            None => None,
        };
        let stage_geometry = cfg.backbone_3d.as_ref().map(|b| StageGeometry::of(b, &prep.grid)).unwrap_or_default();
        let pfa = match (&cfg.pfa, &roi_head) {
            (Some(p), Some(r)) => Some(p.init(&root / "pfa", r.feature_channels())),
            (Some(_), None) => return Err(NnError::config("pfa", "pfa needs a second stage (roi_head)")),
            (None, _) => None,
        };
        Ok(Self { vs, prep, vfe, backbone_3d, stage_geometry, backbone_2d, neck, dense_head, roi_head, pfa })
    }

    pub fn cfg(&self) -> &DetectorConfig {
        &self.prep.cfg
    }

    /// Infers in `precision` from now on (the weights are f32 either way).
    pub fn set_precision(&mut self, precision: crate::precision::Precision) -> Result<()> {
        self.prep = Arc::new(self.prep.with_precision(precision)?);
        Ok(())
    }

    pub fn device(&self) -> Device {
        self.vs.device()
    }

    /// Number of trainable parameters.
    pub fn num_parameters(&self) -> i64 {
        self.vs.trainable_variables().iter().map(|t| t.numel() as i64).sum()
    }

    /// The trainable variables by name (batch-norm running statistics are not among them), for
    /// an optimiser that keeps its moments under the same names in checkpoints.
    pub fn named_trainables(&self) -> Vec<(String, Tensor)> {
        let ptrs: Vec<usize> = self.vs.trainable_variables().iter().map(|t| t.data_ptr() as usize).collect();
        self.vs.variables().into_iter().filter(|(_, t)| ptrs.contains(&(t.data_ptr() as usize))).collect()
    }

    /// `vfe → [backbone_3d] → map_to_bev → backbone_2d → [neck]`: BEV features `[B, C, H, W]`
    /// of a batch, with the neck's rotation prediction when it makes one.
    pub fn bev_features(&self, x: &Inputs, train: bool) -> Result<NeckOutput> {
        Ok(self.features(x, train)?.0)
    }

    /// [`bev_features`](Self::bev_features) and, for voxel detectors, the 3-D backbone's stages
    /// with their geometry.
    fn features(&self, x: &Inputs, train: bool) -> Result<(NeckOutput, Option<VoxelStages>)> {
        let cell_features = self.vfe.forward_t(&x.features, train);
        let channels_last = self.cfg().channels_last && self.device() == Device::Cpu;
        let g = &self.prep.grid;
        let mut stages = None;
        let bev = match &self.backbone_3d {
            Some(b3) => {
                let index_shape = [g.nz as i64, g.ny as i64, g.nx as i64];
                let sparse = SparseTensor::from_flat_indices(
                    cell_features,
                    &x.cells,
                    index_shape,
                    self.cfg().sparse_shape(),
                    x.batch_size,
                )?;
                let out = b3.forward_t(&sparse, train)?;
                stages =
                    Some(out.stages.into_iter().map(|(s, _)| s).zip(self.stage_geometry.iter().copied()).collect());
                height_compression(&out.out, channels_last)
            }
            None => scatter(&cell_features, &x.cells, x.batch_size, g.ny as i64, g.nx as i64, channels_last),
        };
        // Mixed precision: the backbone and the neck in the compute kind, the heads in f32.
        let precision = if train { self.cfg().train.precision } else { self.cfg().precision };
        let kind = precision.compute_kind(self.device());
        let bev = self.backbone_2d.forward_t(&bev.to_kind(kind), train);
        let mut neck = match &self.neck {
            Some(n) => n.forward_t(&bev, train),
            None => NeckOutput { bev, rotation_deg: None },
        };
        neck.bev = neck.bev.to_kind(Kind::Float);
        Ok((neck, stages))
    }

    /// The batch's pillars for a second stage that reads points (pillar grids only).
    fn pillar_points<'a>(&self, x: &'a Inputs) -> Option<PillarPoints<'a>> {
        let grid = self.prep.grid;
        (!grid.voxels).then_some(PillarPoints {
            features: &x.features,
            cells: &x.cells,
            batch_size: x.batch_size,
            grid,
        })
    }

    /// Whether the chain has a sparse 3-D backbone (a voxel detector).
    pub fn has_backbone_3d(&self) -> bool {
        self.backbone_3d.is_some()
    }

    pub fn has_roi_head(&self) -> bool {
        self.roi_head.is_some()
    }

    /// The chain on a batch for inference (eval-mode when `train` is false). With a second
    /// stage, the RoIs are the dense head's proposals (test limits).
    pub fn forward_t(&self, x: &Inputs, train: bool) -> Result<Forward> {
        let (NeckOutput { bev, rotation_deg }, voxels) = self.features(x, train)?;
        let dense = self.dense_head.forward_t(&bev, train);
        let roi = match &self.roi_head {
            Some(stage) => {
                let props = self.proposals(stage.as_ref(), &dense, x.batch_size, false)?;
                let batch = ProposalBatch::collate(&props).to_device(self.device());
                let src = RoiSource { bev: &bev, voxels: voxels.as_deref(), points: self.pillar_points(x) };
                let out = stage.forward_t(&src, &batch.rois, &self.prep.map, train)?;
                Some(RoiStage { out, targets: None, proposals: Some(batch) })
            }
            None => None,
        };
        Ok(Forward { bev, dense, roi, rotation_deg })
    }

    /// The chain on a training batch: with a second stage, RoIs are sampled from the dense head's
    /// proposals (train limits) against `gt` (one entry per frame, detector frame).
    pub fn forward_train(&self, x: &Inputs, gt: &[FrameGt], rng: &mut ChaCha8Rng) -> Result<Forward> {
        let (NeckOutput { bev, rotation_deg }, voxels) = self.features(x, true)?;
        let dense = self.dense_head.forward_t(&bev, true);
        let roi = match &self.roi_head {
            Some(stage) => {
                if gt.len() as i64 != x.batch_size {
                    return Err(NnError::Input(format!(
                        "second stage: {} ground-truth lists for a batch of {}",
                        gt.len(),
                        x.batch_size
                    )));
                }
                let props = self.proposals(stage.as_ref(), &dense, x.batch_size, true)?;
                let targets = stage.sample(&props, gt, rng)?.to_device(self.device());
                let src = RoiSource { bev: &bev, voxels: voxels.as_deref(), points: self.pillar_points(x) };
                let out = stage.forward_t(&src, &targets.rois, &self.prep.map, true)?;
                Some(RoiStage { out, targets: Some(targets), proposals: None })
            }
            None => None,
        };
        Ok(Forward { bev, dense, roi, rotation_deg })
    }

    /// Proposals of each frame from the dense head's candidates (gradients do not flow into
    /// them: the RoIs are inputs of the second stage).
    fn proposals(&self, stage: &dyn SecondStage, dense: &DenseOutput, b: i64, train: bool) -> Result<Vec<Proposals>> {
        let cfg = stage.proposal_config();
        let pre_max = if train { cfg.nms_pre_max_train } else { cfg.nms_pre_max_test } as i64;
        let _guard = tch::no_grad_guard();
        (0..b)
            .map(|i| {
                let c = self.dense_head.candidates(dense, i, cfg.score_threshold, pre_max)?;
                cfg.select_tensors(&c.boxes, &c.scores, &c.labels, train)
            })
            .collect()
    }

    /// The named loss terms of a forward pass against the batch's targets: the dense head's and
    /// the second stage's, and on source batches GTD's `rot` (frames with platform jitter in
    /// `gt`) and PFA's `pfa_roi`.
    pub fn loss(&self, out: &Forward, targets: &BatchTargets, gt: &[FrameGt], domain: Domain) -> Result<LossTerms> {
        self.loss_impl(out, targets, gt, domain, None)
    }

    /// The loss of a Knowledge-Adaptation target batch whose background follows `neg`
    /// ([`crate::losses::target_negatives`]): the target's terms of [`loss`](Self::loss), with the
    /// dense head's and the second stage's classification under the rules; `teacher`: the
    /// pre-adapted model's dense outputs on the same batch ([`dense_eval`](Self::dense_eval)),
    /// whose scores the dense head's background learns.
    pub fn loss_target(
        &self,
        out: &Forward,
        targets: &BatchTargets,
        gt: &[FrameGt],
        neg: &crate::losses::target_negatives::TargetNegatives,
        teacher: Option<&DenseOutput>,
    ) -> Result<LossTerms> {
        self.loss_impl(out, targets, gt, Domain::Target, Some((neg, teacher)))
    }

    /// The dense head's outputs on a batch in eval mode, without gradients and without the
    /// second stage: what a teacher's scores need.
    pub fn dense_eval(&self, x: &Inputs) -> Result<DenseOutput> {
        let _guard = tch::no_grad_guard();
        let NeckOutput { bev, .. } = self.bev_features(x, false)?;
        Ok(self.dense_head.forward_t(&bev, false))
    }

    fn loss_impl(
        &self,
        out: &Forward,
        targets: &BatchTargets,
        gt: &[FrameGt],
        domain: Domain,
        neg: Option<(&crate::losses::target_negatives::TargetNegatives, Option<&DenseOutput>)>,
    ) -> Result<LossTerms> {
        let mut losses = LossTerms::new(&self.cfg().loss_weights);
        match neg {
            Some((n, teacher)) => self.dense_head.loss_target(&out.dense, targets, n, teacher, &mut losses)?,
            None => self.dense_head.loss(&out.dense, targets, &mut losses)?,
        }
        let neg = neg.map(|(n, _)| n);
        if let (Some(stage), Some(roi)) = (&self.roi_head, &out.roi) {
            let t = roi.targets.as_ref().ok_or_else(|| {
                NnError::Input("the second stage's loss needs a forward_train pass (sampled RoIs)".into())
            })?;
            match neg {
                Some(n) => stage.loss_target(&roi.out, t, n, &mut losses)?,
                None => stage.loss(&roi.out, t, &mut losses)?,
            }
        }
        if domain == Domain::Target {
            return Ok(losses);
        }
        if let (Some(neck), Some(pred)) = (&self.neck, &out.rotation_deg) {
            let jitter: Vec<Option<[f64; 2]>> = gt.iter().map(|g| g.platform_jitter).collect();
            if let Some(l) = rotation_loss(pred, &jitter) {
                losses.add("rot", l * neck.rotation_weight());
            }
        }
        if let (Some(pfa), Some(z)) = (&self.pfa, self.latent(out, Domain::Source)) {
            if let Some(l) = pfa.roi_loss(&z?) {
                losses.add("pfa_roi", l * self.cfg().pfa.as_ref().map_or(0.0, |c| c.roi_weight));
            }
        }
        Ok(losses)
    }

    /// PFA's latent Gaussians of a training pass's sampled RoIs (foreground: regressed RoIs);
    /// `None` without PFA or a second stage. Target RoIs skip the encoder's weights when the
    /// config keeps `L_KL` out of the encoder.
    pub fn latent(&self, out: &Forward, domain: Domain) -> Option<Result<Latent>> {
        let (pfa, roi) = (self.pfa.as_ref()?, out.roi.as_ref()?);
        let detach = domain == Domain::Target && self.cfg().pfa.as_ref().is_some_and(|c| !c.kl_into_encoder);
        Some(match &roi.targets {
            Some(t) => Ok(pfa.encode(&roi.out.features, &t.roi_labels.ge(0), &t.reg_valid.gt(0.5), detach)),
            None => Err(NnError::Input("PFA needs a forward_train pass (sampled RoIs)".into())),
        })
    }

    /// λ_KL times PFA's `L_KL` between a source and a target batch's latents.
    pub fn kl_loss(&self, source: &Latent, target: &Latent) -> Option<Tensor> {
        let cfg = self.cfg().pfa.as_ref()?;
        Some(crate::roi_heads::pfa::kl_loss(source, target, cfg.kl_estimator)? * cfg.kl_weight)
    }

    /// Final detections per frame in the detector's frame: the refined RoIs (second stage) or
    /// the dense head's candidates, score threshold, rotated NMS.
    pub fn post_process(&self, out: &Forward, batch_size: i64) -> Result<Vec<Vec<Detection>>> {
        let post = &self.cfg().post;
        let k = self.cfg().classes.len();
        if let (Some(stage), Some(roi)) = (&self.roi_head, &out.roi) {
            let p = roi.proposals.as_ref().ok_or_else(|| {
                NnError::Input("post-processing of the second stage needs an inference pass (proposals)".into())
            })?;
            let (boxes, scores) = stage.refine(&roi.out, &p.rois, &p.roi_scores, &p.roi_labels);
            let frames = refined_frames(&boxes, &scores, &p.roi_labels, &p.valid);
            return Ok(frames
                .into_iter()
                .map(|f| {
                    let dets: Vec<Detection> = f
                        .into_iter()
                        .filter(|(_, s, _)| *s >= post.score_threshold)
                        .map(|(b, score, class)| Detection { box3d: b.with_wrapped_heading(), score, class })
                        .collect();
                    nms_detections(&dets, post, k, post.nms_iou, post.nms_post_max)
                })
                .collect());
        }
        (0..batch_size)
            .map(|i| {
                let c = self.dense_head.candidates(&out.dense, i, post.score_threshold, post.nms_pre_max as i64)?;
                Ok(nms_detections(&to_detections(&c), post, k, post.nms_iou, post.nms_post_max))
            })
            .collect()
    }

    /// The network up to the dense head, as tensors `[bev, head outputs…]` (eval mode): what a
    /// TorchScript export of the first stage computes from `(features, cells)`.
    pub fn dense_tensors(&self, x: &Inputs) -> Result<Vec<Tensor>> {
        let NeckOutput { bev, .. } = self.bev_features(x, false)?;
        let dense = self.dense_head.forward_t(&bev, false);
        let mut out = vec![bev];
        out.extend(self.dense_head.output_tensors(&dense)?);
        Ok(out)
    }

    /// The second stage on `rois` `[B, N, 7]` as tensors `[features, iou_logits, box_codes,
    /// rois]` (eval mode); `None` without a second stage.
    pub fn roi_tensors(&self, bev: &Tensor, rois: &Tensor) -> Result<Option<Vec<Tensor>>> {
        match &self.roi_head {
            Some(stage) => {
                let src = RoiSource { bev, voxels: None, points: None };
                Ok(Some(stage.forward_t(&src, rois, &self.prep.map, false)?.to_tensors()))
            }
            None => Ok(None),
        }
    }

    /// RoIs per frame a traced second stage takes (the test-time proposal limit).
    pub fn fixed_roi_count(&self) -> Option<usize> {
        self.roi_head.as_ref().map(|s| s.proposal_config().nms_post_max_test)
    }

    /// A [`Forward`] of one frame rebuilt from [`dense_tensors`](Self::dense_tensors)' result,
    /// the second stage (if any) run by `roi` on the proposals padded to
    /// [`fixed_roi_count`](Self::fixed_roi_count): the inference path of an exported model,
    /// ready for [`post_process`](Self::post_process).
    pub fn forward_from_tensors(
        &self,
        mut dense: Vec<Tensor>,
        roi: &mut dyn FnMut(&Tensor, &Tensor) -> Result<Vec<Tensor>>,
    ) -> Result<Forward> {
        if dense.is_empty() {
            return Err(NnError::Model("an exported model returned no tensors".into()));
        }
        let bev = dense.remove(0);
        let dense = self.dense_head.output_from_tensors(dense)?;
        let roi = match &self.roi_head {
            Some(stage) => {
                let props = self.proposals(stage.as_ref(), &dense, 1, false)?;
                let n = stage.proposal_config().nms_post_max_test;
                let batch = ProposalBatch::collate_to(&props, n).to_device(self.device());
                let t = roi(&bev, &batch.rois)?;
                let k = t.len();
                let out = RoiOutput::from_tensors(t).ok_or_else(|| {
                    NnError::Model(format!("the exported second stage returned {k} tensors, expected 4"))
                })?;
                Some(RoiStage { out, targets: None, proposals: Some(batch) })
            }
            None => None,
        };
        Ok(Forward { bev, dense, roi, rotation_deg: None })
    }

    /// Inference on prepared inputs (no gradients, eval-mode batch norm); detector frame.
    pub fn predict(&self, x: &Inputs) -> Result<Vec<Vec<Detection>>> {
        let _guard = tch::no_grad_guard();
        let x = x.to_device(self.device());
        let out = self.forward_t(&x, false)?;
        self.post_process(&out, x.batch_size)
    }
}
