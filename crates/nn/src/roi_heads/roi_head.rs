//! The RoI head: [`BevRoiPool`] samples of each RoI → an optional per-sample point layer
//! (Linear, BN, ReLU, shared by all samples: the same as a 1×1 convolution on the map, but only
//! where samples fall) → flattened → shared MLP (Linear without bias + BN + ReLU, dropout between the
//! layers; OpenPCDet's Voxel R-CNN head) → two branches: an IoU-score logit and a 7-value
//! [`RoiCoder`] residual.
//!
//! Losses (OpenPCDet `RoIHeadTemplate`): `rcnn_iou` binary cross-entropy of the score logit
//! against the IoU-guided target, averaged over the sampled RoIs; `rcnn_reg` smooth-L1 (β 1/9) of
//! the residuals, summed over the 7 codes and averaged over the regressed RoIs; `rcnn_corner` the
//! corner loss of the decoded boxes, averaged over the regressed RoIs. Weights 1 / 1 / 1.
//!
//! Refinement decodes the residuals back into the detector's frame and fuses the first-stage
//! score with the predicted IoU ([`ScoreFusion`]).

use pi3det_geometry::Box3d;
use serde::{Deserialize, Serialize};
use tch::nn::{self, Module, ModuleT};
use tch::{Device, Kind, Reduction, Tensor};

use super::bev_roi_pool::{BevRoiPool, BevRoiPoolConfig};
use super::point_roi_pool::{PillarPoints, PointRoiPool, PointRoiPoolConfig};
use super::proposal::ProposalConfig;
use super::roi_coder::{corner_loss, RoiCoder};
use super::roi_sampler::{RoiBatchTargets, RoiSamplerConfig};
use super::voxel_roi_pool::{StageGeometry, VoxelRoiPool, VoxelRoiPoolConfig};
use crate::box_coder::limit_period_tensor;
use crate::error::{NnError, Result};
use crate::losses;
use crate::losses::target_negatives::TargetNegatives;
use crate::sparse::SparseTensor;
use crate::target_assigner::center::CenterMap;
use crate::BatchNorm;

/// What the score branch learns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ScoreTarget {
    /// The IoU-guided target `clip((IoU − 0.25)/0.5, 0, 1)` (OpenPCDet `CLS_SCORE_TYPE: roi_iou`).
    #[default]
    Iou,
}

/// The final score of a refined box from the first-stage score `s` and the predicted IoU `q`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ScoreFusion {
    /// `√(s·q)` (CenterPoint's two-stage score): the default, because it keeps the dense head's
    /// class confidence (the IoU branch knows nothing of the class) while still reordering by
    /// localisation quality, and degrades gracefully while the IoU branch is undertrained.
    #[default]
    GeometricMean,
    /// `s·q`.
    Product,
    /// `q` (Voxel R-CNN).
    IouOnly,
    /// ST3D++'s hybrid criterion `w·q + (1 − w)·s` with the class's `w` from
    /// [`RoiHeadConfig::hybrid_iou_weights`] ([`crate::baselines::hybrid_score`]).
    Hybrid,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RoiHeadConfig {
    pub pool: BevRoiPoolConfig,
    /// Voxel R-CNN: pool from the sparse 3-D backbone's voxels instead of the BEV map (`pool`
    /// is then unused); needs a `[backbone_3d]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub voxel_pool: Option<VoxelRoiPoolConfig>,
    /// Raw-point features of each RoI ([`PointRoiPool`]), concatenated to the pooled BEV
    /// features before the shared MLP; pillar detectors only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub point_pool: Option<PointRoiPoolConfig>,
    /// Channels of the per-sample point layer; 0 feeds the raw `C·P` pooled values to the MLP.
    pub point_channels: i64,
    /// Shared MLP; its output is [`RoiOutput::features`].
    pub shared_fc: Vec<i64>,
    /// Hidden layers of the score and box branches (each then a final Linear).
    pub cls_fc: Vec<i64>,
    pub reg_fc: Vec<i64>,
    /// Dropout between the shared layers and after the first layer of each branch (0 disables).
    pub dropout: f64,
    pub score: ScoreTarget,
    pub rcnn_cls_weight: f64,
    pub rcnn_reg_weight: f64,
    pub rcnn_corner_weight: f64,
    /// Smooth-L1 β of the residual loss.
    pub reg_beta: f64,
    pub code_weights: [f64; 7],
    pub score_fusion: ScoreFusion,
    /// Per class (the detector's order), the IoU weight of [`ScoreFusion::Hybrid`]; classes
    /// past the end take 0.5 (ST3D++: car 0.8, pedestrian 0.5).
    pub hybrid_iou_weights: Vec<f64>,
    pub sampler: RoiSamplerConfig,
    pub proposal: ProposalConfig,
}

impl Default for RoiHeadConfig {
    /// Voxel R-CNN's head (shared [256, 256], branches [256, 256], dropout 0.3, IoU score, loss
    /// weights 1) on a 6×6 BEV lattice, with a 64-channel point layer so that the first shared
    /// layer sees 36·64 inputs instead of 36·C.
    fn default() -> Self {
        Self {
            pool: BevRoiPoolConfig::default(),
            voxel_pool: None,
            point_pool: None,
            point_channels: 64,
            shared_fc: vec![256, 256],
            cls_fc: vec![256, 256],
            reg_fc: vec![256, 256],
            dropout: 0.3,
            score: ScoreTarget::Iou,
            rcnn_cls_weight: 1.0,
            rcnn_reg_weight: 1.0,
            rcnn_corner_weight: 1.0,
            reg_beta: 1.0 / 9.0,
            code_weights: [1.0; 7],
            score_fusion: ScoreFusion::GeometricMean,
            hybrid_iou_weights: vec![0.8, 0.5],
            sampler: RoiSamplerConfig::default(),
            proposal: ProposalConfig::default(),
        }
    }
}

impl RoiHeadConfig {
    pub fn validate(&self) -> Result<()> {
        self.pool.validate()?;
        if let Some(v) = &self.voxel_pool {
            v.validate()?;
        }
        if let Some(p) = &self.point_pool {
            p.validate()?;
        }
        self.sampler.validate()?;
        self.proposal.validate()?;
        if self.point_channels < 0 {
            return Err(NnError::config("roi_head", "roi head: point_channels must be ≥ 0"));
        }
        if self.shared_fc.iter().chain(&self.cls_fc).chain(&self.reg_fc).any(|&c| c < 1) {
            return Err(NnError::config(
                "roi_head",
                "roi head: shared_fc, cls_fc and reg_fc channels must be positive",
            ));
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return Err(NnError::config("roi_head", format!("roi head: dropout {} is not in [0, 1)", self.dropout)));
        }
        let weights = [self.rcnn_cls_weight, self.rcnn_reg_weight, self.rcnn_corner_weight, self.reg_beta];
        if weights.iter().chain(&self.code_weights).any(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(NnError::config(
                "roi_head",
                "roi head: loss weights, reg_beta and code_weights must be finite and ≥ 0",
            ));
        }
        Ok(())
    }

    /// Builds the head for a BEV map of `in_channels` channels (and, with `voxel_pool`, a 3-D
    /// backbone whose stages have `stage_channels`).
    pub fn init(&self, vs: nn::Path, in_channels: i64, bn: &BatchNorm) -> Result<RoiHead> {
        self.init_with_stages(vs, in_channels, &[], bn)
    }

    pub fn init_with_stages(
        &self,
        vs: nn::Path,
        bev_channels: i64,
        stage_channels: &[i64],
        bn: &BatchNorm,
    ) -> Result<RoiHead> {
        self.validate()?;
        let pool = self.pool.init()?;
        let voxel_pool = match &self.voxel_pool {
            Some(v) => Some(v.init(&vs / "voxel_pool", stage_channels, bn)?),
            None => None,
        };
        let (in_channels, p) = match &voxel_pool {
            Some(v) => (v.out_channels(), v.num_points()),
            None => (bev_channels, pool.num_points()),
        };
        if in_channels < 1 {
            return Err(NnError::config("roi_head", "roi head: in_channels must be positive"));
        }
        let point =
            (self.point_channels > 0).then(|| FcLayer::new(&vs / "point", in_channels, self.point_channels, bn));
        let point_pool = match &self.point_pool {
            Some(c) => Some(c.init(&vs / "point_pool")?),
            None => None,
        };
        let mut dim = if self.point_channels > 0 { self.point_channels * p } else { in_channels * p };
        dim += point_pool.as_ref().map_or(0, PointRoiPool::out_channels);
        let stack = |name: &str, dim: &mut i64, channels: &[i64]| -> Vec<FcLayer> {
            channels
                .iter()
                .enumerate()
                .map(|(k, &c)| {
                    let l = FcLayer::new(&vs / format!("{name}{k}"), *dim, c, bn);
                    *dim = c;
                    l
                })
                .collect()
        };
        let shared = stack("shared", &mut dim, &self.shared_fc);
        let feature_dim = dim;
        let (mut cdim, mut rdim) = (dim, dim);
        let cls = stack("cls", &mut cdim, &self.cls_fc);
        let reg = stack("reg", &mut rdim, &self.reg_fc);
        let xavier = |i: i64, o: i64| nn::Init::Randn { mean: 0.0, stdev: (2.0 / (i + o) as f64).sqrt() };
        let cls_out = nn::linear(
            &vs / "cls_out",
            cdim,
            1,
            nn::LinearConfig { ws_init: xavier(cdim, 1), bs_init: Some(nn::Init::Const(0.0)), bias: true },
        );
        let reg_out = nn::linear(
            &vs / "reg_out",
            rdim,
            7,
            nn::LinearConfig {
                ws_init: nn::Init::Randn { mean: 0.0, stdev: 0.001 },
                bs_init: Some(nn::Init::Const(0.0)),
                bias: true,
            },
        );
        let code_weights = Tensor::from_slice(&self.code_weights.map(|v| v as f32)).to_device(vs.device());
        Ok(RoiHead {
            cfg: self.clone(),
            in_channels,
            feature_dim,
            pool,
            voxel_pool,
            point_pool,
            point,
            shared,
            cls,
            reg,
            cls_out,
            reg_out,
            code_weights,
        })
    }
}

/// Linear (no bias, Xavier-normal), BN, ReLU.
#[derive(Debug)]
struct FcLayer {
    linear: nn::Linear,
    bn: nn::BatchNorm,
}

impl FcLayer {
    fn new(vs: nn::Path, i: i64, o: i64, bn: &BatchNorm) -> Self {
        let ws_init = nn::Init::Randn { mean: 0.0, stdev: (2.0 / (i + o) as f64).sqrt() };
        Self {
            linear: nn::linear(&vs / "linear", i, o, nn::LinearConfig { ws_init, bs_init: None, bias: false }),
            bn: nn::batch_norm1d(&vs / "bn", o, bn.config()),
        }
    }

    /// `[M, i]` → `[M, o]`.
    fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        self.bn.forward_t(&self.linear.forward(x), train).relu()
    }
}

/// What a second stage pools from: the BEV map, and for voxel detectors the 3-D backbone's
/// stages (stage `s` at index `s − 1`) with their geometry.
pub struct RoiSource<'a> {
    pub bev: &'a Tensor,
    pub voxels: Option<&'a [(SparseTensor, StageGeometry)]>,
    /// The batch's pillars, for a head with a [`PointRoiPool`].
    pub points: Option<PillarPoints<'a>>,
}

/// The head's outputs for `rois [B, N, 7]`.
#[derive(Debug)]
pub struct RoiOutput {
    /// `[B, N, F]` shared-MLP features (`F` = last of `shared_fc`), one per RoI of `rois`.
    pub features: Tensor,
    /// `[B, N]` score logits (sigmoid: predicted IoU-guided score).
    pub iou_logits: Tensor,
    /// `[B, N, 7]` [`RoiCoder`] residuals against `rois`.
    pub box_codes: Tensor,
    /// `[B, N, 7]` the RoIs the rows belong to (detector frame), as given to the forward pass.
    pub rois: Tensor,
}

impl RoiOutput {
    /// `[features, iou_logits, box_codes, rois]` (a TorchScript module's results)…
    pub fn to_tensors(&self) -> Vec<Tensor> {
        [&self.features, &self.iou_logits, &self.box_codes, &self.rois].iter().map(|t| t.shallow_clone()).collect()
    }

    /// …and back.
    pub fn from_tensors(t: Vec<Tensor>) -> Option<Self> {
        let [features, iou_logits, box_codes, rois]: [Tensor; 4] = t.try_into().ok()?;
        Some(Self { features, iou_logits, box_codes, rois })
    }
}

/// Loss total and its weighted terms (scalars).
#[derive(Debug)]
pub struct RoiLosses {
    pub total: Tensor,
    pub rcnn_iou: Tensor,
    pub rcnn_reg: Tensor,
    pub rcnn_corner: Tensor,
}

impl RoiLosses {
    pub fn terms(&self) -> [(&'static str, &Tensor); 3] {
        [("rcnn_iou", &self.rcnn_iou), ("rcnn_reg", &self.rcnn_reg), ("rcnn_corner", &self.rcnn_corner)]
    }
}

#[derive(Debug)]
pub struct RoiHead {
    pub cfg: RoiHeadConfig,
    in_channels: i64,
    feature_dim: i64,
    pool: BevRoiPool,
    voxel_pool: Option<VoxelRoiPool>,
    point_pool: Option<PointRoiPool>,
    point: Option<FcLayer>,
    shared: Vec<FcLayer>,
    cls: Vec<FcLayer>,
    reg: Vec<FcLayer>,
    cls_out: nn::Linear,
    reg_out: nn::Linear,
    code_weights: Tensor,
}

impl RoiHead {
    /// Length `F` of a RoI's feature vector.
    pub fn feature_dim(&self) -> i64 {
        self.feature_dim
    }

    pub fn pool(&self) -> &BevRoiPool {
        &self.pool
    }

    /// `bev [B, C, H, W]` (laid out as `map`), `rois [B, N, 7]` (detector frame, f32, no
    /// gradient) → [`RoiOutput`]. Errors on mismatched shapes, and in training on a single RoI
    /// (batch norm needs two rows).
    pub fn forward_t(&self, bev: &Tensor, rois: &Tensor, map: &CenterMap, train: bool) -> Result<RoiOutput> {
        self.forward_source(&RoiSource { bev, voxels: None, points: None }, rois, map, train)
    }

    /// Whether the head pools from voxels (Voxel R-CNN).
    pub fn pools_voxels(&self) -> bool {
        self.voxel_pool.is_some()
    }

    /// As [`forward_t`](Self::forward_t), pooling from the BEV map or, with a voxel pool, from the
    /// backbone's stages in `src`.
    pub fn forward_source(&self, src: &RoiSource, rois: &Tensor, map: &CenterMap, train: bool) -> Result<RoiOutput> {
        let pooled = match (&self.voxel_pool, src.voxels) {
            (Some(v), Some(stages)) => v.forward_t(stages, rois, train)?,
            (Some(_), None) => {
                return Err(NnError::Input("roi head: a voxel RoI pool needs the 3-D backbone's voxels".into()))
            }
            (None, _) => self.pool.forward(src.bev, rois, map)?,
        }; // [B, N, C, P]
        let (b, n, c, p) = pooled.size4()?;
        if c != self.in_channels {
            return Err(NnError::Input(format!(
                "roi head: bev has {c} channels, the head was built for {}",
                self.in_channels
            )));
        }
        if train && b * n < 2 {
            return Err(NnError::Input("roi head: training needs at least two RoIs in the batch".into()));
        }
        let mut x = match &self.point {
            Some(layer) => {
                let y = pooled.permute([0, 1, 3, 2]).reshape([b * n * p, c]);
                layer.forward_t(&y, train).view([b * n, -1])
            }
            None => pooled.reshape([b * n, c * p]),
        };
        if let Some(pp) = &self.point_pool {
            let pts = src.points.as_ref().ok_or_else(|| {
                NnError::Input("roi head: its point pool needs the batch's pillars, which this path does not have (the TorchScript export of the second stage takes only the BEV map and the RoIs)".into())
            })?;
            let pf = pp.forward(pts, rois)?.view([b * n, -1]).to_kind(x.kind());
            x = Tensor::cat(&[x, pf], 1);
        }
        let dropout = |x: Tensor| if self.cfg.dropout > 0.0 { x.dropout(self.cfg.dropout, train) } else { x };
        for (k, layer) in self.shared.iter().enumerate() {
            x = layer.forward_t(&x, train);
            if k + 1 < self.shared.len() {
                x = dropout(x);
            }
        }
        let branch = |layers: &[FcLayer], out: &nn::Linear| {
            let mut h = x.shallow_clone();
            for (k, layer) in layers.iter().enumerate() {
                h = layer.forward_t(&h, train);
                if k == 0 {
                    h = dropout(h);
                }
            }
            out.forward(&h)
        };
        let iou_logits = branch(&self.cls, &self.cls_out).view([b, n]);
        let box_codes = branch(&self.reg, &self.reg_out).view([b, n, 7]);
        Ok(RoiOutput { features: x.view([b, n, -1]), iou_logits, box_codes, rois: rois.shallow_clone() })
    }

    /// Losses of `out` against the sampled targets (`out` computed on `t.rois`, same device).
    pub fn loss(&self, out: &RoiOutput, t: &RoiBatchTargets) -> Result<RoiLosses> {
        self.loss_with(out, t, None)
    }

    /// [`loss`](Self::loss) of a target batch under KA's background rules
    /// ([`crate::losses::target_negatives`]): sampled RoIs that overlap no box (IoU 0) and whose
    /// first-stage score is at least `neg.unsure_score` leave the score loss, and RoIs with a
    /// zero score target are weighted by their frame's `neg.frame_weight`. The score loss is
    /// still averaged over the rows it keeps.
    pub fn loss_with(&self, out: &RoiOutput, t: &RoiBatchTargets, neg: Option<&TargetNegatives>) -> Result<RoiLosses> {
        let (b, n) = out.iou_logits.size2()?;
        if t.iou_targets.size() != [b, n] || t.reg_targets.size() != [b, n, 7] {
            return Err(NnError::Input(format!(
                "roi loss: outputs are [{b}, {n}], targets {:?}",
                t.iou_targets.size()
            )));
        }
        let cfg = &self.cfg;
        let k = out.iou_logits.kind();
        // Score: BCE against the IoU-guided target over the valid rows.
        let (cls_valid, cls_weight) = match neg {
            Some(neg) => {
                let valid = t.cls_valid.gt(0.5);
                let unsure = neg.unsure(&t.roi_scores, &valid.logical_and(&t.ious.le(0.0)), None);
                let valid = valid.logical_and(&unsure.logical_not());
                let w = neg.background_weights(&valid.logical_and(&t.iou_targets.le(0.0)));
                let valid = valid.to_kind(k);
                let weight = &valid * w.to_kind(k);
                (valid, weight)
            }
            None => {
                let valid = t.cls_valid.to_kind(k);
                (valid.shallow_clone(), valid)
            }
        };
        let bce = out.iou_logits.binary_cross_entropy_with_logits::<Tensor>(
            &t.iou_targets.to_kind(k),
            None,
            None,
            Reduction::None,
        );
        let rcnn_iou = (bce * &cls_weight).sum(k) / cls_valid.sum(k).clamp_min(1.0) * cfg.rcnn_cls_weight;
        // Residuals and corners over the regressed rows.
        let reg_valid = t.reg_valid.to_kind(k).view([-1]);
        let fg_weight = &reg_valid / reg_valid.sum(k).clamp_min(1.0);
        let codes = out.box_codes.view([-1, 7]);
        let rcnn_reg = losses::weighted_smooth_l1(
            &codes,
            &t.reg_targets.view([-1, 7]).to_kind(k),
            &self.code_weights.to_kind(k),
            &fg_weight,
            cfg.reg_beta,
        ) * cfg.rcnn_reg_weight;
        let boxes = RoiCoder::decode_tensor(&codes, &out.rois.view([-1, 7]).to_kind(k));
        let corners = corner_loss(&boxes, &t.gt_of_rois.view([-1, 7]).to_kind(k));
        let rcnn_corner = (corners * &fg_weight).sum(k) * cfg.rcnn_corner_weight;
        let total = &rcnn_iou + &rcnn_reg + &rcnn_corner;
        Ok(RoiLosses { total, rcnn_iou, rcnn_reg, rcnn_corner })
    }

    /// Refined boxes `[B, N, 7]` in the detector's frame (heading wrapped to `[−π, π)`) and fused
    /// scores `[B, N]` (see [`ScoreFusion`]) from `out` on `rois [B, N, 7]` with first-stage
    /// `roi_scores [B, N]` and classes `roi_labels [B, N]` (0-based).
    pub fn refine(&self, out: &RoiOutput, rois: &Tensor, roi_scores: &Tensor, roi_labels: &Tensor) -> (Tensor, Tensor) {
        let boxes = RoiCoder::decode_tensor(&out.box_codes, &rois.to_kind(out.box_codes.kind()));
        let heading = limit_period_tensor(&boxes.narrow(-1, 6, 1), 0.5, std::f64::consts::TAU);
        let boxes = Tensor::cat(&[boxes.narrow(-1, 0, 6), heading], -1);
        let q = out.iou_logits.sigmoid();
        let s = roi_scores.to_kind(q.kind()).clamp(0.0, 1.0);
        let scores = match self.cfg.score_fusion {
            ScoreFusion::GeometricMean => (s * &q).sqrt(),
            ScoreFusion::Product => s * &q,
            ScoreFusion::IouOnly => q,
            ScoreFusion::Hybrid => {
                let w = &self.cfg.hybrid_iou_weights;
                let table: Vec<f32> = w.iter().map(|&x| x as f32).chain(std::iter::once(0.5)).collect();
                let table = Tensor::from_slice(&table).to_device(q.device()).to_kind(q.kind());
                let idx = roi_labels.to_kind(Kind::Int64).clamp(0, w.len() as i64);
                let wq = table.index_select(0, &idx.reshape([-1])).view_as(&q);
                &wq * &q + (1.0 - &wq) * s
            }
        };
        (boxes, scores)
    }
}

/// Per frame, the valid rows of refined `boxes [B, N, 7]`, `scores [B, N]`, `labels [B, N]` and
/// `valid [B, N]` as `(box, score, class)`, best first; rows with a non-finite value are dropped.
pub fn refined_frames(
    boxes: &Tensor,
    scores: &Tensor,
    labels: &Tensor,
    valid: &Tensor,
) -> Vec<Vec<(Box3d, f64, usize)>> {
    let (b, n) = match scores.size2() {
        Ok(s) => s,
        Err(_) => return Vec::new(),
    };
    let cpu = |t: &Tensor, k: Kind| t.to_device(Device::Cpu).to_kind(k).reshape([-1]);
    let bx: Vec<f64> = Vec::try_from(cpu(boxes, Kind::Double)).unwrap_or_default();
    let sc: Vec<f64> = Vec::try_from(cpu(scores, Kind::Double)).unwrap_or_default();
    let lb: Vec<i64> = Vec::try_from(cpu(labels, Kind::Int64)).unwrap_or_default();
    let ok: Vec<bool> = Vec::try_from(cpu(valid, Kind::Bool)).unwrap_or_default();
    let (b, n) = (b as usize, n as usize);
    if bx.len() != b * n * 7 || sc.len() != b * n || lb.len() != b * n || ok.len() != b * n {
        return vec![Vec::new(); b];
    }
    (0..b)
        .map(|f| {
            let mut v: Vec<(Box3d, f64, usize)> = (f * n..(f + 1) * n)
                .filter(|&r| {
                    ok[r] && lb[r] >= 0 && sc[r].is_finite() && bx[r * 7..r * 7 + 7].iter().all(|x| x.is_finite())
                })
                .map(|r| (Box3d::from_array(std::array::from_fn(|j| bx[r * 7 + j])), sc[r], lb[r] as usize))
                .collect();
            v.sort_by(|a, b| b.1.total_cmp(&a.1));
            v
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::proposal::Proposals;
    use super::*;
    use pi3det_geometry::iou_3d;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn jitter(b: &Box3d, rng: &mut ChaCha8Rng) -> Box3d {
        Box3d {
            x: b.x + rng.random_range(-0.6..0.6),
            y: b.y + rng.random_range(-0.6..0.6),
            z: b.z + rng.random_range(-0.2..0.2),
            dx: b.dx * rng.random_range(0.85..1.15),
            dy: b.dy * rng.random_range(0.85..1.15),
            dz: b.dz * rng.random_range(0.85..1.15),
            heading: b.heading + rng.random_range(-0.25..0.25),
        }
    }

    fn proposals(gt: &[Box3d], per_gt: usize, bg: usize, rng: &mut ChaCha8Rng) -> (Proposals, Vec<usize>) {
        let mut p = Proposals::default();
        let mut owner = Vec::new();
        for (g, b) in gt.iter().enumerate() {
            for _ in 0..per_gt {
                p.boxes.push(jitter(b, rng));
                p.scores.push(rng.random_range(0.3..1.0));
                p.labels.push(0);
                owner.push(g);
            }
        }
        for _ in 0..bg {
            p.boxes.push(Box3d::new(
                rng.random_range(0.5..9.0),
                rng.random_range(0.5..9.0),
                0.8,
                3.8,
                1.7,
                1.5,
                rng.random_range(-3.0..3.0),
            ));
            p.scores.push(rng.random_range(0.0..0.5));
            p.labels.push(0);
            owner.push(usize::MAX);
        }
        (p, owner)
    }

    fn pearson(a: &[f64], b: &[f64]) -> f64 {
        let n = a.len() as f64;
        let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
        let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
        let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
        let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
        cov / (va * vb).sqrt()
    }

    /// The detector's entry point passes each frame's ignored boxes to the sampler.
    #[test]
    fn second_stage_sampling_sees_the_ignored_boxes() {
        use crate::data_loader::FrameGt;
        use crate::roi_heads::SecondStage;
        let vs = nn::VarStore::new(Device::Cpu);
        let cfg = RoiHeadConfig {
            point_channels: 8,
            shared_fc: vec![16],
            cls_fc: vec![8],
            reg_fc: vec![8],
            sampler: RoiSamplerConfig { roi_per_image: 32, ..Default::default() },
            ..Default::default()
        };
        let head = cfg.init(&vs.root() / "roi_head", 8, &BatchNorm { eps: 1e-3, momentum: 0.1 }).unwrap();
        let gt = [Box3d::new(3.0, 3.2, 0.8, 3.9, 1.8, 1.5, 0.3), Box3d::new(9.4, 6.5, 0.8, 3.6, 1.7, 1.5, -1.9)];
        let (p, owner) = proposals(&gt, 12, 6, &mut ChaCha8Rng::seed_from_u64(1));
        // The second car is only a middling pseudo-label: ignored.
        let frame = FrameGt {
            boxes: gt[..1].to_vec(),
            classes: vec![0],
            ignored: gt[1..].to_vec(),
            ignored_classes: vec![0],
            ..Default::default()
        };
        let t = head.sample(std::slice::from_ref(&p), &[frame], &mut ChaCha8Rng::seed_from_u64(2)).unwrap();
        let direct = cfg.sampler.sample(&p, &gt[..1], &[0], &gt[1..], &[0], &mut ChaCha8Rng::seed_from_u64(2)).unwrap();
        let want = RoiBatchTargets::collate(std::slice::from_ref(&direct)).unwrap();
        assert!(t.rois.equal(&want.rois) && t.iou_targets.equal(&want.iou_targets));
        let on_ignored = |k: i64| {
            let k = k as usize;
            k < owner.len() && owner[k] == 1 && iou_3d(&p.boxes[k], &gt[1]) >= cfg.sampler.ignore_thresh()
        };
        assert!((0..p.len() as i64).any(on_ignored));
        assert!(!direct.source.iter().any(|&k| on_ignored(k)));
    }

    #[test]
    fn overfits_two_boxes() {
        // Tiny tensors: on a busy two-core machine, libtorch's thread hand-offs cost far more
        // than they save.
        tch::set_num_threads(1);
        tch::manual_seed(0);
        let map = CenterMap { h: 24, w: 24, cell: [0.4, 0.4], origin: [0.0, 0.0] };
        let vs = nn::VarStore::new(Device::Cpu);
        let root = vs.root();
        let c = 16;
        // Learnable map: the head and the map learn together, as with a backbone in front.
        let bev = root.var("bev", &[1, c, 24, 24], nn::Init::Randn { mean: 0.0, stdev: 1.0 });
        let cfg = RoiHeadConfig {
            point_channels: 16,
            shared_fc: vec![128, 128],
            cls_fc: vec![64],
            reg_fc: vec![64],
            dropout: 0.0,
            sampler: RoiSamplerConfig { roi_per_image: 32, ..Default::default() },
            ..Default::default()
        };
        let head = cfg.init(&root / "roi_head", c, &BatchNorm { eps: 1e-3, momentum: 0.1 }).unwrap();
        let gt = [Box3d::new(3.0, 3.2, 0.8, 3.9, 1.8, 1.5, 0.3), Box3d::new(6.4, 6.5, 0.8, 3.6, 1.7, 1.5, -1.9)];
        let classes = [0, 0];
        // A fixed pool of jittered RoIs (and some background) the sampler draws from every step.
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let (pool, owner) = proposals(&gt, 24, 12, &mut rng);
        let mut opt = nn::OptimizerConfig::build(nn::Adam::default(), &vs, 3e-3).unwrap();
        let t0 = std::time::Instant::now();
        let mut t_sample = 0.0;
        let mut first = None;
        let mut last = 0.0;
        for _ in 0..200 {
            let ts = std::time::Instant::now();
            let s = cfg.sampler.sample(&pool, &gt, &classes, &[], &[], &mut rng).unwrap();
            let t = RoiBatchTargets::collate(&[s]).unwrap();
            t_sample += ts.elapsed().as_secs_f64();
            let out = head.forward_t(&bev, &t.rois, &map, true).unwrap();
            let l = head.loss(&out, &t).unwrap();
            opt.backward_step(&l.total);
            let v = l.total.double_value(&[]);
            first.get_or_insert(v);
            last = v;
        }
        let train_s = t0.elapsed().as_secs_f64();

        // The pool's RoIs in eval mode, through the inference path.
        let batch = super::super::proposal::ProposalBatch::collate(std::slice::from_ref(&pool));
        let _guard = tch::no_grad_guard();
        let out = head.forward_t(&bev, &batch.rois, &map, false).unwrap();
        assert_eq!(out.features.size(), [1, pool.len() as i64, 128]);
        let (boxes, scores) =
            head.refine(&out, &batch.rois, &batch.roi_scores, &batch.roi_scores.zeros_like().to_kind(Kind::Int64));
        let frames = refined_frames(&boxes, &scores, &batch.roi_labels, &batch.valid);
        assert_eq!(frames[0].len(), pool.len());
        let refined: Vec<f64> = Vec::try_from(boxes.to_kind(Kind::Double).reshape([-1])).unwrap();
        let q: Vec<f64> = Vec::try_from(out.iou_logits.sigmoid().to_kind(Kind::Double).reshape([-1])).unwrap();
        let (mut before, mut after, mut pred_q, mut true_q) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (k, roi) in pool.boxes.iter().enumerate() {
            let best = gt.iter().map(|g| iou_3d(roi, g)).fold(0.0, f64::max);
            pred_q.push(q[k]);
            true_q.push(cfg.sampler.iou_target(best) as f64);
            if owner[k] == usize::MAX || best <= cfg.sampler.reg_fg_thresh {
                continue;
            }
            let r = Box3d::from_array(std::array::from_fn(|j| refined[k * 7 + j]));
            before.push(best);
            after.push(iou_3d(&r, &gt[owner[k]]));
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let corr = pearson(&pred_q, &true_q);
        eprintln!(
            "overfit: loss {:.3} → {last:.3} in {train_s:.1} s (sampling {t_sample:.2} s); {} fg RoIs, mean 3D IoU {:.3} → {:.3} (min {:.3}); IoU-score correlation {corr:.3}",
            first.unwrap(),
            before.len(),
            mean(&before),
            mean(&after),
            after.iter().copied().fold(1.0, f64::min)
        );
        assert!(before.len() >= 15);
        assert!(mean(&after) > 0.8, "refined mean IoU {}", mean(&after));
        assert!(mean(&after) > mean(&before) + 0.1);
        assert!(corr > 0.7, "predicted vs true IoU correlation {corr}");
    }

    #[test]
    fn shapes_losses_and_variants() {
        let map = CenterMap { h: 16, w: 20, cell: [0.5, 0.5], origin: [-2.0, -4.0] };
        let gt = [Box3d::new(2.0, 0.0, 0.8, 3.9, 1.8, 1.5, 0.3)];
        for (pool, point_channels) in [
            (BevRoiPoolConfig::default(), 0),
            (BevRoiPoolConfig { layout: super::super::PoolLayout::CenterFaces, margin: 0.3, ..Default::default() }, 8),
        ] {
            let vs = nn::VarStore::new(Device::Cpu);
            let cfg = RoiHeadConfig {
                pool,
                point_channels,
                shared_fc: vec![32],
                cls_fc: vec![],
                reg_fc: vec![16, 16],
                sampler: RoiSamplerConfig { roi_per_image: 8, ..Default::default() },
                ..Default::default()
            };
            let head = cfg.init(vs.root(), 6, &BatchNorm::default()).unwrap();
            let bev = Tensor::randn([2, 6, 16, 20], (Kind::Float, Device::Cpu)).set_requires_grad(true);
            let mut rng = ChaCha8Rng::seed_from_u64(4);
            let (p, _) = proposals(&gt, 10, 4, &mut rng);
            let frames = [
                cfg.sampler.sample(&p, &gt, &[0], &[], &[], &mut rng).unwrap(),
                cfg.sampler.sample(&Proposals::default(), &[], &[], &[], &[], &mut rng).unwrap(),
            ];
            let t = RoiBatchTargets::collate(&frames).unwrap();
            let out = head.forward_t(&bev, &t.rois, &map, true).unwrap();
            assert_eq!(out.features.size(), [2, 8, 32]);
            assert_eq!(head.feature_dim(), 32);
            assert_eq!(out.iou_logits.size(), [2, 8]);
            assert_eq!(out.box_codes.size(), [2, 8, 7]);
            let l = head.loss(&out, &t).unwrap();
            for (name, v) in l.terms() {
                let v = v.double_value(&[]);
                assert!(v.is_finite() && v >= 0.0, "{name} = {v}");
            }
            l.total.backward();
            let g = bev.grad();
            assert!(f64::try_from(g.get(0).abs().sum(Kind::Float)).unwrap() > 0.0, "gradients reach the map");
            // Fusion rules.
            for (fusion, want) in [
                (ScoreFusion::GeometricMean, 0.5f64.sqrt() * 0.5),
                (ScoreFusion::Product, 0.125),
                (ScoreFusion::IouOnly, 0.5),
                // Class 0 at the default IoU weight 0.8: 0.8·0.5 + 0.2·0.25.
                (ScoreFusion::Hybrid, 0.45),
            ] {
                let mut h = cfg.clone();
                h.score_fusion = fusion;
                let head = h.init(nn::VarStore::new(Device::Cpu).root(), 6, &BatchNorm::default()).unwrap();
                let o = RoiOutput {
                    features: Tensor::zeros([1, 1, 32], (Kind::Float, Device::Cpu)),
                    iou_logits: Tensor::zeros([1, 1], (Kind::Float, Device::Cpu)),
                    box_codes: Tensor::zeros([1, 1, 7], (Kind::Float, Device::Cpu)),
                    rois: t.rois.narrow(1, 0, 1).narrow(0, 0, 1),
                };
                let (b, s) = head.refine(
                    &o,
                    &o.rois,
                    &Tensor::from_slice(&[0.25f32]).view([1, 1]),
                    &Tensor::zeros([1, 1], (Kind::Int64, Device::Cpu)),
                );
                assert!((s.double_value(&[0, 0]) - want).abs() < 1e-6, "{fusion:?}");
                assert!(bool::try_from((b - &o.rois).abs().max().lt(1e-5)).unwrap(), "zero codes keep the RoI");
            }
        }
    }

    #[test]
    fn errors_not_panics() {
        let map = CenterMap { h: 8, w: 8, cell: [0.5, 0.5], origin: [0.0, 0.0] };
        assert!(RoiHeadConfig { dropout: 1.0, ..Default::default() }.validate().is_err());
        assert!(RoiHeadConfig { shared_fc: vec![0], ..Default::default() }.validate().is_err());
        assert!(RoiHeadConfig { rcnn_reg_weight: f64::NAN, ..Default::default() }.validate().is_err());
        let toml = "score_fusion = \"product\"\n[pool]\nlayout = \"center_faces\"\n[sampler]\nroi_per_image = 64\n";
        let cfg: RoiHeadConfig = toml::from_str(toml).unwrap();
        assert_eq!(cfg.pool.layout, super::super::PoolLayout::CenterFaces);
        assert_eq!(cfg.sampler.roi_per_image, 64);
        assert!(toml::from_str::<RoiHeadConfig>("shared = [1]").is_err());
        let vs = nn::VarStore::new(Device::Cpu);
        let head = RoiHeadConfig::default().init(vs.root(), 4, &BatchNorm::default()).unwrap();
        let bev = Tensor::zeros([1, 4, 8, 8], (Kind::Float, Device::Cpu));
        let wrong_c = Tensor::zeros([1, 5, 8, 8], (Kind::Float, Device::Cpu));
        let rois = Tensor::zeros([1, 3, 7], (Kind::Float, Device::Cpu));
        assert!(head.forward_t(&wrong_c, &rois, &map, false).is_err());
        assert!(head.forward_t(&bev, &rois.narrow(1, 0, 1), &map, true).is_err());
        assert!(head.forward_t(&bev, &rois, &map, false).is_ok());
        assert!(RoiHeadConfig::default().init(vs.root(), 0, &BatchNorm::default()).is_err());
    }

    /// Forward + backward time of the default head for 128 RoIs on a `[1, 192, 128, 128]` map
    /// (the CPU PointPillars preset's BEV map), 2 threads (`ROI_TIMING_THREADS` to change):
    /// `cargo test -p pi3det-nn --lib roi_heads::roi_head::tests::timing -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn timing() {
        let map = CenterMap { h: 128, w: 128, cell: [0.64, 0.64], origin: [-40.96, -40.96] };
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let gt: Vec<Box3d> = (0..12)
            .map(|_| {
                Box3d::new(
                    rng.random_range(-35.0..35.0),
                    rng.random_range(-35.0..35.0),
                    0.8,
                    4.0,
                    1.8,
                    1.5,
                    rng.random_range(-3.0..3.0),
                )
            })
            .collect();
        let classes = vec![0; gt.len()];
        let mut p = Proposals::default();
        for b in &gt {
            for _ in 0..30 {
                p.boxes.push(jitter(b, &mut rng));
                p.scores.push(0.5);
                p.labels.push(0);
            }
        }
        let variants: [(&str, RoiHeadConfig); 5] = [
            ("default (grid 6, point 64, fc 256)", RoiHeadConfig::default()),
            ("grid 6, no point layer", RoiHeadConfig { point_channels: 0, ..Default::default() }),
            (
                "centre + faces, point 64",
                RoiHeadConfig {
                    pool: BevRoiPoolConfig { layout: super::super::PoolLayout::CenterFaces, ..Default::default() },
                    ..Default::default()
                },
            ),
            (
                "centre + faces, no point layer",
                RoiHeadConfig {
                    pool: BevRoiPoolConfig { layout: super::super::PoolLayout::CenterFaces, ..Default::default() },
                    point_channels: 0,
                    ..Default::default()
                },
            ),
            ("default again", RoiHeadConfig::default()),
        ];
        let threads: i32 = std::env::var("ROI_TIMING_THREADS").ok().and_then(|v| v.parse().ok()).unwrap_or(2);
        tch::set_num_threads(threads);
        eprintln!("{threads} torch threads");
        for (name, cfg) in variants {
            let vs = nn::VarStore::new(Device::Cpu);
            let head = cfg.init(vs.root(), 192, &BatchNorm::default()).unwrap();
            let bev = Tensor::randn([1, 192, 128, 128], (Kind::Float, Device::Cpu)).set_requires_grad(true);
            let s = cfg.sampler.sample(&p, &gt, &classes, &[], &[], &mut rng).unwrap();
            let t = RoiBatchTargets::collate(&[s]).unwrap();
            let mut times = Vec::new();
            for k in 0..15 {
                let t0 = std::time::Instant::now();
                let out = head.forward_t(&bev, &t.rois, &map, true).unwrap();
                let l = head.loss(&out, &t).unwrap();
                l.total.backward();
                if k >= 3 {
                    times.push(t0.elapsed().as_secs_f64() * 1e3); // after 3 warm-up steps
                }
            }
            times.sort_by(f64::total_cmp);
            let params: i64 = vs.trainable_variables().iter().map(|v| v.numel() as i64).sum();
            eprintln!("{name}: forward+backward median {:.1} ms (min {:.1}), {params} parameters", times[6], times[0]);
        }
    }
}
