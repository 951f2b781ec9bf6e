//! Center head of CenterPoint (Yin, Zhou, Krähenbühl, CVPR 2021; OpenPCDet `CenterHead` with one
//! task holding all classes): a shared 3×3 convolution, then separate heads for the class
//! heatmaps, the centre offset, z, log size and (cos, sin) heading. Loss: CornerNet focal loss on
//! the Gaussian heatmaps + masked L1 on the codes at box centres (weights 1 / 2). Decoding: peaks
//! of the heatmap (3×3 max), top-k, then the rotated NMS of [`crate::detector`].
//!
//! Trained by `pi3det train --config configs/centerpoint_cpu.toml --data DIR`.

use serde::{Deserialize, Serialize};
use tch::nn::{self, ModuleT};
use tch::{Device, Kind, Tensor};

use pi3det_geometry::Box3d;

use super::{Candidates, DenseHead, TargetAssigner, ToDevice};
use crate::losses::{self, LossTerms};
use crate::target_assigner::center::{self, CenterMap, CenterTargetConfig, CenterTargets, CENTER_CODE_SIZE};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CenterHeadConfig {
    pub shared_channels: i64,
    /// Convolutions per separate head (the last one is the output convolution).
    pub num_head_convs: usize,
    pub targets: CenterTargetConfig,
    pub code_weights: [f64; CENTER_CODE_SIZE],
    pub cls_weight: f64,
    pub loc_weight: f64,
    /// Candidates taken from the heatmap per frame before NMS.
    pub max_objects_per_frame: i64,
}

impl Default for CenterHeadConfig {
    /// OpenPCDet's CenterPoint-pillar head.
    fn default() -> Self {
        Self {
            shared_channels: 64,
            num_head_convs: 2,
            targets: CenterTargetConfig::default(),
            code_weights: [1.0; CENTER_CODE_SIZE],
            cls_weight: 1.0,
            loc_weight: 2.0,
            max_objects_per_frame: 500,
        }
    }
}

/// Output heads: name, channels. The regression heads' outputs concatenate to the code order
/// `[Δx, Δy, z, log dx, log dy, log dz, cos θ, sin θ]`.
const REG_HEADS: [(&str, i64); 4] = [("center", 2), ("center_z", 1), ("dim", 3), ("rot", 2)];

impl CenterHeadConfig {
    /// The head on a map of geometry `map`.
    pub fn init(
        &self,
        vs: nn::Path,
        in_channels: i64,
        num_classes: i64,
        bn: &crate::BatchNorm,
        map: &CenterMap,
    ) -> CenterHead {
        let c = self.shared_channels;
        let conv3 = |p: nn::Path, i: i64, o: i64, bias: bool, bs: f64| {
            nn::conv2d(
                p,
                i,
                o,
                3,
                nn::ConvConfig { padding: 1, bias, bs_init: nn::Init::Const(bs), ..Default::default() },
            )
        };
        let shared = nn::seq_t()
            .add(conv3(&vs / "shared_conv", in_channels, c, true, 0.0))
            .add(nn::batch_norm2d(&vs / "shared_bn", c, bn.config()))
            .add_fn(|x| x.relu());
        let head = |name: &str, out: i64, bias: f64| {
            let p = &vs / name;
            let mut seq = nn::seq_t();
            for k in 0..self.num_head_convs.saturating_sub(1) {
                seq = seq
                    .add(conv3(&p / format!("conv{k}"), c, c, false, 0.0))
                    .add(nn::batch_norm2d(&p / format!("bn{k}"), c, bn.config()))
                    .add_fn(|x| x.relu());
            }
            seq.add(conv3(&p / "out", c, out, true, bias))
        };
        CenterHead {
            cfg: self.clone(),
            shared,
            hm: head("hm", num_classes, -2.19),
            reg: REG_HEADS.iter().map(|(n, o)| head(n, *o, 0.0)).collect(),
            code_weights: Tensor::from_slice(&self.code_weights.map(|v| v as f32)).to_device(vs.device()),
            map: *map,
        }
    }

    pub fn assigner(&self, map: &CenterMap, num_classes: usize) -> CenterAssigner {
        CenterAssigner { cfg: self.targets, map: *map, num_classes }
    }
}

/// Gaussian heatmaps and centre codes ([`center::assign`]).
pub struct CenterAssigner {
    pub cfg: CenterTargetConfig,
    pub map: CenterMap,
    pub num_classes: usize,
}

impl TargetAssigner for CenterAssigner {
    type Frame = CenterTargets;
    type Batch = CenterBatchTargets;

    fn assign(
        &self,
        boxes: &[Box3d],
        classes: &[usize],
        ignored: &[Box3d],
        ignored_classes: &[usize],
    ) -> CenterTargets {
        center::assign(&self.cfg, &self.map, self.num_classes, boxes, classes, ignored, ignored_classes)
    }

    fn collate(&self, frames: &[&CenterTargets]) -> CenterBatchTargets {
        let b = frames.len() as i64;
        let (h, w) = (self.map.h as i64, self.map.w as i64);
        let c = self.num_classes as i64;
        let mut hm = Vec::with_capacity((b * c * h * w) as usize);
        let (mut idx, mut codes) = (Vec::new(), Vec::new());
        // A batch mask only when some frame ignores cells (frames without one count everywhere).
        let any_mask = frames.iter().any(|t| !t.mask.is_empty());
        let mut mask = Vec::with_capacity(if any_mask { hm.capacity() } else { 0 });
        for (k, t) in frames.iter().enumerate() {
            hm.extend_from_slice(&t.heatmap);
            idx.extend(t.index.iter().map(|&i| i + k as i64 * h * w));
            codes.extend_from_slice(&t.codes);
            if any_mask {
                if t.mask.is_empty() {
                    mask.extend(std::iter::repeat_n(1f32, t.heatmap.len()));
                } else {
                    mask.extend_from_slice(&t.mask);
                }
            }
        }
        let kk = idx.len() as i64;
        CenterBatchTargets {
            heatmap: Tensor::from_slice(&hm).view([b, c, h, w]),
            index: Tensor::from_slice(&idx),
            codes: Tensor::from_slice(&codes).view([kk, CENTER_CODE_SIZE as i64]),
            mask: any_mask.then(|| Tensor::from_slice(&mask).view([b, c, h, w])),
        }
    }
}

pub struct CenterOutput {
    /// `[B, classes, H, W]` heatmap logits.
    pub heatmap: Tensor,
    /// `[B, 8, H, W]` codes.
    pub codes: Tensor,
}

pub struct CenterBatchTargets {
    /// `[B, classes, H, W]`.
    pub heatmap: Tensor,
    /// `[K]` flat `b·H·W + cell` of the boxes and their codes `[K, 8]`.
    pub index: Tensor,
    pub codes: Tensor,
    /// `[B, classes, H, W]` 1 where the heatmap loss counts, 0 on ignored boxes; `None`: all count.
    pub mask: Option<Tensor>,
}

impl ToDevice for CenterBatchTargets {
    fn to_device(&self, d: Device) -> Self {
        Self {
            heatmap: self.heatmap.to_device(d),
            index: self.index.to_device(d),
            codes: self.codes.to_device(d),
            mask: self.mask.as_ref().map(|m| m.to_device(d)),
        }
    }
}

#[derive(Debug)]
pub struct CenterHead {
    pub cfg: CenterHeadConfig,
    shared: nn::SequentialT,
    hm: nn::SequentialT,
    reg: Vec<nn::SequentialT>,
    code_weights: Tensor,
    map: CenterMap,
}

impl DenseHead for CenterHead {
    type Output = CenterOutput;
    type Targets = CenterBatchTargets;

    fn forward_t(&self, bev: &Tensor, train: bool) -> CenterOutput {
        CenterHead::forward_t(self, bev, train)
    }

    fn output_tensors(out: &CenterOutput) -> Vec<Tensor> {
        vec![out.heatmap.shallow_clone(), out.codes.shallow_clone()]
    }

    fn output_from_tensors(t: Vec<Tensor>) -> Option<CenterOutput> {
        let [heatmap, codes]: [Tensor; 2] = t.try_into().ok()?;
        Some(CenterOutput { heatmap, codes })
    }

    fn loss(&self, out: &CenterOutput, t: &CenterBatchTargets, losses: &mut LossTerms) {
        let (_, [hm, loc]) = CenterHead::loss(self, out, t);
        losses.add("hm", hm);
        losses.add("loc", loc);
    }

    /// `pre_max` is ignored: the head takes `max_objects_per_frame` peaks.
    fn candidates(&self, out: &CenterOutput, frame: i64, score_threshold: f64, _pre_max: i64) -> Candidates {
        let (boxes, scores, labels) = CenterHead::candidates(self, out, &self.map, frame, score_threshold);
        Candidates { boxes, scores, labels }
    }
}

impl CenterHead {
    /// `[B, C, H, W]` → heatmap logits and codes on the same grid.
    pub fn forward_t(&self, x: &Tensor, train: bool) -> CenterOutput {
        let x = self.shared.forward_t(x, train);
        let codes: Vec<Tensor> = self.reg.iter().map(|h| h.forward_t(&x, train)).collect();
        CenterOutput { heatmap: self.hm.forward_t(&x, train), codes: Tensor::cat(&codes, 1) }
    }

    /// Returns `(total, [heatmap, loc])`, weighted; the heatmap loss is normalised by the number
    /// of boxes in the batch, the regression loss by the number of boxes.
    pub fn loss(&self, out: &CenterOutput, t: &CenterBatchTargets) -> (Tensor, [Tensor; 2]) {
        let hm = match &t.mask {
            Some(m) => losses::center_focal_loss_masked(&out.heatmap, &t.heatmap, m),
            None => losses::center_focal_loss(&out.heatmap, &t.heatmap),
        } * self.cfg.cls_weight;
        let k = t.index.size()[0];
        let loc = if k > 0 {
            let (b, c, h, w) = out.codes.size4().expect("codes are [B, 8, H, W]");
            let preds = out.codes.permute([0, 2, 3, 1]).reshape([b * h * w, c]).index_select(0, &t.index);
            losses::reg_l1_loss(&preds, &t.codes, &self.code_weights, k as f64) * self.cfg.loc_weight
        } else {
            out.codes.sum(Kind::Float) * 0.0
        };
        (&hm + &loc, [hm, loc])
    }

    /// Candidates of frame `i`: heatmap peaks (3×3 max) above `score_threshold`, at most
    /// `max_objects_per_frame`, decoded. Returns `(boxes [K, 7], scores [K], labels [K])` on the CPU.
    pub fn candidates(
        &self,
        out: &CenterOutput,
        map: &CenterMap,
        i: i64,
        score_threshold: f64,
    ) -> (Tensor, Tensor, Tensor) {
        let hm = out.heatmap.get(i).sigmoid(); // [C, H, W]
        let (c, h, w) = hm.size3().expect("[C, H, W]");
        let peaks = hm.unsqueeze(0).max_pool2d([3, 3], [1, 1], [1, 1], [1, 1], false).squeeze_dim(0);
        let hm = &hm * hm.eq_tensor(&peaks).to_kind(Kind::Float);
        let flat = hm.reshape([c * h * w]);
        let k = self.cfg.max_objects_per_frame.min(c * h * w);
        let (top, idx) = flat.topk(k, 0, true, true);
        let keep = top.ge(score_threshold);
        let idx = idx.masked_select(&keep);
        let scores = top.masked_select(&keep);
        let labels = idx.divide_scalar_mode(h * w, "floor").to_kind(Kind::Int64);
        let cell = &idx - &labels * (h * w);
        let iy_i = cell.divide_scalar_mode(w, "floor").to_kind(Kind::Int64);
        let ix = (&cell - &iy_i * w).to_kind(Kind::Float);
        let iy = iy_i.to_kind(Kind::Float);
        let codes = out.codes.get(i).reshape([CENTER_CODE_SIZE as i64, h * w]).index_select(1, &cell).transpose(0, 1);
        let col = |j: i64| codes.select(1, j);
        let x = (ix + col(0)) * map.cell[0] + map.origin[0];
        let y = (iy + col(1)) * map.cell[1] + map.origin[1];
        let size = |j: i64| col(j).clamp(-10.0, 10.0).exp();
        let heading = col(7).atan2(&col(6)) / self.cfg.targets.heading.factor();
        let boxes = Tensor::stack(&[x, y, col(2), size(3), size(4), size(5), heading], 1);
        (boxes.to_device(Device::Cpu), scores.to_device(Device::Cpu), labels.to_device(Device::Cpu))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hm_loss(head: &CenterHead, heatmap: &Tensor, codes: &Tensor, t: &CenterBatchTargets) -> [f64; 2] {
        let (_, [hm, loc]) =
            head.loss(&CenterOutput { heatmap: heatmap.shallow_clone(), codes: codes.shallow_clone() }, t);
        [hm.double_value(&[]), loc.double_value(&[])]
    }

    /// An ignored car masks the car-class cells of its Gaussian footprint (and nothing of the
    /// pedestrian class): the heatmap loss there is gone, predictions there change nothing, and
    /// the normalisation (real positives) and the regression targets are those without it.
    #[test]
    fn ignored_cells_add_nothing_to_the_heatmap_loss() {
        let map = CenterMap { h: 12, w: 12, cell: [0.8, 0.8], origin: [-4.8, -4.8] };
        let cfg = CenterHeadConfig::default();
        let assigner = cfg.assigner(&map, 2);
        let vs = nn::VarStore::new(Device::Cpu);
        let head = cfg.init(vs.root(), 8, 2, &crate::BatchNorm::default(), &map);
        let ped = [Box3d::new(-3.0, 2.9, 0.85, 0.7, 0.6, 1.7, 1.2)];
        let car = [Box3d::new(0.5, -1.3, 0.8, 4.3, 1.9, 1.6, 0.7)];
        let ign = assigner.assign(&ped, &[1], &car, &[0]);
        let plain = assigner.assign(&ped, &[1], &[], &[]);
        let as_ped = assigner.assign(&ped, &[1], &car, &[1]);
        assert!(plain.mask.is_empty(), "no mask without ignored boxes");
        assert_eq!((&ign.heatmap, &ign.index, &ign.codes), (&plain.heatmap, &plain.index, &plain.codes));
        let plane = map.h * map.w;
        // The footprint: a (2r + 1)² square about the car's cell, in the car plane only.
        let (ix, iy) = (((0.5 + 4.8) / 0.8) as usize, ((-1.3 + 4.8) / 0.8) as usize);
        let r = (gaussian_radius_cells(&cfg, &map, &car[0])) as usize;
        let masked: Vec<usize> = (0..2 * plane).filter(|&i| ign.mask[i] == 0.0).collect();
        assert_eq!(masked.len(), (2 * r + 1) * (2 * r + 1));
        for &i in &masked {
            let (y, x) = ((i % plane) / map.w, i % map.w);
            assert!(i < plane && x.abs_diff(ix) <= r && y.abs_diff(iy) <= r, "cell {i}");
        }
        // As a pedestrian, the same box masks the pedestrian plane instead.
        let ped_masked: Vec<usize> = (0..2 * plane).filter(|&i| as_ped.mask[i] == 0.0).collect();
        assert_eq!(ped_masked, masked.iter().map(|i| i + plane).collect::<Vec<_>>());

        tch::manual_seed(5);
        let f = (Kind::Float, Device::Cpu);
        let hm = Tensor::randn([1, 2, 12, 12], f);
        let codes = Tensor::randn([1, 8, 12, 12], f) * 0.1;
        let t_ign = assigner.collate(&[&ign]);
        let t_plain = assigner.collate(&[&plain]);
        let t_ped = assigner.collate(&[&as_ped]);
        assert!(t_ign.mask.is_some() && t_plain.mask.is_none());
        let l_ign = hm_loss(&head, &hm, &codes, &t_ign);
        let l_plain = hm_loss(&head, &hm, &codes, &t_plain);
        assert!(l_ign[0] < l_plain[0], "{l_ign:?} vs {l_plain:?}");
        assert_eq!(l_ign[1], l_plain[1]);
        // By hand: the plain loss minus the masked cells' negative terms, same normaliser (1).
        let p: Vec<f32> = Vec::try_from(hm.sigmoid().clamp(1e-4, 1.0 - 1e-4).view([-1])).unwrap();
        let dropped: f64 = masked
            .iter()
            .map(|&i| {
                let (p, t) = (p[i] as f64, plain.heatmap[i] as f64);
                -(1.0 - p).ln() * p * p * (1.0 - t).powi(4)
            })
            .sum();
        assert!(dropped > 0.1);
        assert!(
            (l_plain[0] - dropped - l_ign[0]).abs() < 1e-5 * l_plain[0],
            "{} vs {}",
            l_plain[0] - dropped,
            l_ign[0]
        );
        // Heatmap logits perturbed on the masked cells only.
        let mut m = vec![0f32; 2 * plane];
        for &i in &masked {
            m[i] = 1.0;
        }
        let noisy = &hm + Tensor::from_slice(&m).view([1, 2, 12, 12]) * Tensor::randn([1, 2, 12, 12], f) * 4.0;
        assert_eq!(hm_loss(&head, &noisy, &codes, &t_ign), l_ign, "ignored cells changed the loss");
        assert_ne!(hm_loss(&head, &noisy, &codes, &t_plain)[0], l_plain[0]);
        assert_ne!(
            hm_loss(&head, &noisy, &codes, &t_ped)[0],
            hm_loss(&head, &hm, &codes, &t_ped)[0],
            "a pedestrian-class box does not mask car cells"
        );
        // A batch mixing both frames: the plain frame counts everywhere.
        let both = assigner.collate(&[&ign, &plain]);
        let m = both.mask.as_ref().unwrap();
        assert_eq!(m.get(1).sum(Kind::Float).double_value(&[]), (2 * plane) as f64);
    }

    fn gaussian_radius_cells(cfg: &CenterHeadConfig, map: &CenterMap, b: &Box3d) -> f64 {
        let r = center::gaussian_radius(b.dx / map.cell[0], b.dy / map.cell[1], cfg.targets.gaussian_overlap);
        r.max(0.0).floor().max(cfg.targets.min_radius as f64)
    }
}
