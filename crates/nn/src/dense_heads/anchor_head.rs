//! Anchor head of SECOND / PointPillars (OpenPCDet `AnchorHeadSingle`): 1×1 convolutions give,
//! per anchor, class logits, a residual box code ([`ResidualCoder`]) and a two-bin direction
//! classifier. Loss: sigmoid focal (α 0.25, γ 2) + smooth-L1 with sin(Δθ) + direction
//! cross-entropy, weights 1 / 2 / 0.2, each normalised by the frame's positive anchors.
//!
//! Trained by `pi3det train --config configs/pointpillars_cpu.toml --data DIR`.

use serde::{Deserialize, Serialize};
use tch::nn::{self, Module};
use tch::{Device, Kind, Tensor};

use pi3det_geometry::Box3d;

use super::{Candidates, DenseHead, TargetAssigner, ToDevice};
use crate::box_coder::{limit_period_tensor, ResidualCoder};
use crate::losses::target_negatives::TargetNegatives;
use crate::losses::{self, LossTerms};
use crate::target_assigner::axis_aligned::{self, AnchorTargets, DIR_OFFSET, NUM_DIR_BINS};
use crate::target_assigner::{AnchorClassConfig, Anchors, CenterMap};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AnchorHeadConfig {
    /// One entry per class, in the order of the config's `classes`.
    pub anchors: Vec<AnchorClassConfig>,
    pub focal_alpha: f64,
    pub focal_gamma: f64,
    pub smooth_l1_beta: f64,
    pub code_weights: [f64; 7],
    pub cls_weight: f64,
    pub loc_weight: f64,
    pub dir_weight: f64,
}

impl Default for AnchorHeadConfig {
    /// OpenPCDet's PointPillars (reference §1c, §6), boxes in a frame whose ground is near z = 0.
    fn default() -> Self {
        Self {
            anchors: vec![
                AnchorClassConfig {
                    class: "Car".into(),
                    size: [4.2, 2.0, 1.6].into(),
                    bottom_z: 0.0,
                    rotations: vec![0.0, std::f64::consts::FRAC_PI_2],
                    matched_threshold: 0.6,
                    unmatched_threshold: 0.45,
                },
                AnchorClassConfig {
                    class: "Pedestrian".into(),
                    size: [0.8, 0.6, 1.73].into(),
                    bottom_z: 0.0,
                    rotations: vec![0.0, std::f64::consts::FRAC_PI_2],
                    matched_threshold: 0.5,
                    unmatched_threshold: 0.35,
                },
            ],
            focal_alpha: 0.25,
            focal_gamma: 2.0,
            smooth_l1_beta: 1.0 / 9.0,
            code_weights: [1.0; 7],
            cls_weight: 1.0,
            loc_weight: 2.0,
            dir_weight: 0.2,
        }
    }
}

impl AnchorHeadConfig {
    pub fn anchors_per_location(&self) -> i64 {
        self.anchors.iter().map(|a| (a.rotations.len() * a.size.as_slice().len()) as i64).sum()
    }

    /// The head on a map of geometry `map` (its anchors live on the head's device).
    pub fn init(&self, vs: nn::Path, in_channels: i64, num_classes: i64, map: &CenterMap) -> AnchorHead {
        let a = self.anchors_per_location();
        let pi = 0.01f64;
        let conv = |name: &str, out: i64, bias: f64, std: f64| {
            nn::conv2d(
                &vs / name,
                in_channels,
                out,
                1,
                nn::ConvConfig {
                    bias: true,
                    ws_init: nn::Init::Randn { mean: 0.0, stdev: std },
                    bs_init: nn::Init::Const(bias),
                    ..Default::default()
                },
            )
        };
        AnchorHead {
            cfg: self.clone(),
            num_classes,
            conv_cls: conv("conv_cls", a * num_classes, -((1.0 - pi) / pi).ln(), 0.01),
            conv_box: conv("conv_box", a * 7, 0.0, 0.001),
            conv_dir: conv("conv_dir_cls", a * NUM_DIR_BINS as i64, 0.0, 0.01),
            code_weights: Tensor::from_slice(&self.code_weights.map(|v| v as f32)).to_device(vs.device()),
            anchors: make_anchors(self, map.h, map.w, map.cell, map.origin).to_tensor().to_device(vs.device()),
        }
    }

    /// The IoU-based assigner of this head's anchors on a map of geometry `map`.
    pub fn assigner(&self, map: &CenterMap) -> AnchorAssigner {
        AnchorAssigner {
            anchors: make_anchors(self, map.h, map.w, map.cell, map.origin),
            classes: self.anchors.clone(),
        }
    }
}

/// Raw head outputs, flattened per anchor.
pub struct AnchorOutput {
    /// `[B, N, classes]` logits.
    pub cls: Tensor,
    /// `[B, N, 7]` box codes.
    pub boxes: Tensor,
    /// `[B, N, 2]` direction logits.
    pub dir: Tensor,
}

/// Training targets of a batch (built on the loader thread, see [`crate::data_loader`]).
pub struct AnchorBatchTargets {
    /// `[B, N]`: −1 ignored, 0 background, `k + 1` class `k`.
    pub labels: Tensor,
    /// `[P]` flat `b·N + anchor` of the positives, their codes `[P, 7]`, direction bins `[P]` and
    /// weights `[P]` (1 / positives of their frame).
    pub pos_index: Tensor,
    pub pos_codes: Tensor,
    pub pos_dir: Tensor,
    pub pos_weight: Tensor,
    /// `[Q]` flat `b·N + anchor` of the background anchors that overlap a box of their class
    /// ([`AnchorTargets::near_positive`]).
    pub near_index: Tensor,
}

impl ToDevice for AnchorBatchTargets {
    fn to_device(&self, d: Device) -> Self {
        Self {
            labels: self.labels.to_device(d),
            pos_index: self.pos_index.to_device(d),
            pos_codes: self.pos_codes.to_device(d),
            pos_dir: self.pos_dir.to_device(d),
            pos_weight: self.pos_weight.to_device(d),
            near_index: self.near_index.to_device(d),
        }
    }
}

#[derive(Debug)]
pub struct AnchorHead {
    pub cfg: AnchorHeadConfig,
    num_classes: i64,
    conv_cls: nn::Conv2D,
    conv_box: nn::Conv2D,
    conv_dir: nn::Conv2D,
    code_weights: Tensor,
    /// `[N, 7]` anchors of the map, in the order of the outputs.
    anchors: Tensor,
}

impl DenseHead for AnchorHead {
    type Output = AnchorOutput;
    type Targets = AnchorBatchTargets;

    fn forward_t(&self, bev: &Tensor, _train: bool) -> AnchorOutput {
        self.forward(bev)
    }

    fn output_tensors(out: &AnchorOutput) -> Vec<Tensor> {
        vec![out.cls.shallow_clone(), out.boxes.shallow_clone(), out.dir.shallow_clone()]
    }

    fn output_from_tensors(t: Vec<Tensor>) -> Option<AnchorOutput> {
        let [cls, boxes, dir]: [Tensor; 3] = t.try_into().ok()?;
        Some(AnchorOutput { cls, boxes, dir })
    }

    fn loss(&self, out: &AnchorOutput, t: &AnchorBatchTargets, losses: &mut LossTerms) {
        let (_, [cls, loc, dir]) = AnchorHead::loss(self, out, t);
        losses.add("cls", cls);
        losses.add("loc", loc);
        losses.add("dir", dir);
    }

    fn loss_target(
        &self,
        out: &AnchorOutput,
        t: &AnchorBatchTargets,
        neg: &TargetNegatives,
        teacher: Option<&AnchorOutput>,
        losses: &mut LossTerms,
    ) {
        let (_, [cls, loc, dir]) = AnchorHead::loss_with(self, out, t, Some((neg, teacher.map(|o| &o.cls))));
        losses.add("cls", cls);
        losses.add("loc", loc);
        losses.add("dir", dir);
    }

    fn candidates(&self, out: &AnchorOutput, frame: i64, score_threshold: f64, pre_max: i64) -> Candidates {
        let (boxes, scores, labels) = AnchorHead::candidates(self, out, &self.anchors, frame, score_threshold, pre_max);
        Candidates { boxes, scores, labels }
    }
}

/// Anchors and per-class thresholds: the anchor head's targets ([`axis_aligned::assign`]).
pub struct AnchorAssigner {
    pub anchors: Anchors,
    pub classes: Vec<AnchorClassConfig>,
}

impl TargetAssigner for AnchorAssigner {
    type Frame = AnchorTargets;
    type Batch = AnchorBatchTargets;

    fn assign(
        &self,
        boxes: &[Box3d],
        classes: &[usize],
        ignored: &[Box3d],
        ignored_classes: &[usize],
    ) -> AnchorTargets {
        axis_aligned::assign(&self.anchors, &self.classes, boxes, classes, ignored, ignored_classes)
    }

    /// Positives are weighted by 1 / (positives of their frame).
    fn collate(&self, frames: &[&AnchorTargets]) -> AnchorBatchTargets {
        let b = frames.len() as i64;
        let n = self.anchors.len() as i64;
        let mut labels = Vec::with_capacity(frames.len() * self.anchors.len());
        let (mut idx, mut codes, mut dir, mut w) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut near = Vec::new();
        for (k, t) in frames.iter().enumerate() {
            labels.extend_from_slice(&t.labels);
            idx.extend(t.pos_index.iter().map(|&i| i + k as i64 * n));
            near.extend(t.near_positive.iter().map(|&i| i + k as i64 * n));
            codes.extend_from_slice(&t.pos_codes);
            dir.extend_from_slice(&t.pos_dir);
            let inv = 1.0 / t.pos_index.len().max(1) as f32;
            w.extend(std::iter::repeat_n(inv, t.pos_index.len()));
        }
        let p = idx.len() as i64;
        AnchorBatchTargets {
            labels: Tensor::from_slice(&labels).view([b, n]),
            pos_index: Tensor::from_slice(&idx),
            pos_codes: Tensor::from_slice(&codes).view([p, 7]),
            pos_dir: Tensor::from_slice(&dir),
            pos_weight: Tensor::from_slice(&w),
            near_index: Tensor::from_slice(&near),
        }
    }
}

impl AnchorHead {
    /// `[B, C, H, W]` → per-anchor outputs, anchors ordered (y, x, class, rotation).
    pub fn forward(&self, x: &Tensor) -> AnchorOutput {
        let b = x.size()[0];
        let flat = |t: Tensor, k: i64| t.permute([0, 2, 3, 1]).contiguous().view([b, -1, k]);
        AnchorOutput {
            cls: flat(self.conv_cls.forward(x), self.num_classes),
            boxes: flat(self.conv_box.forward(x), 7),
            dir: flat(self.conv_dir.forward(x), NUM_DIR_BINS as i64),
        }
    }

    /// Returns `(total, [cls, loc, dir])`, each already weighted and averaged over the batch.
    pub fn loss(&self, out: &AnchorOutput, t: &AnchorBatchTargets) -> (Tensor, [Tensor; 3]) {
        self.loss_with(out, t, None)
    }

    /// [`loss`](Self::loss) of a target batch under KA's background rules
    /// ([`crate::losses::target_negatives`]): background anchors the model scores at least
    /// `neg.unsure_score` and that overlap no box are ignored, and each frame's background
    /// anchors are weighted by its `neg.frame_weight`. The normalisation (positives per frame)
    /// is unchanged, so a frame's background can only lose weight. With the teacher's class
    /// logits `[B, N, C]` (the pre-adapted model on the same batch), the background anchors
    /// that are not next to a positive learn the teacher's scores instead of 0
    /// ([`losses::quality_focal_loss`]).
    pub fn loss_with(
        &self,
        out: &AnchorOutput,
        t: &AnchorBatchTargets,
        neg: Option<(&TargetNegatives, Option<&Tensor>)>,
    ) -> (Tensor, [Tensor; 3]) {
        let (b, n, c) = out.cls.size3().expect("cls is [B, N, C]");
        let mut soft: Option<(Tensor, Tensor)> = None;
        let (labels, bg_weights) = match neg {
            Some((neg, teacher)) => {
                let _no_grad = tch::no_grad_guard();
                let scores = out.cls.detach().sigmoid().amax([-1].as_slice(), false);
                let background = t.labels.eq(0);
                let near = (t.near_index.size()[0] > 0).then(|| {
                    Tensor::zeros([b * n], (Kind::Bool, t.labels.device())).index_fill(0, &t.near_index, 1).view([b, n])
                });
                let unsure = neg.unsure(&scores, &background, near.as_ref());
                let labels = t.labels.masked_fill(&unsure, -1);
                let w = neg.background_weights(&labels.eq(0));
                if let Some(teacher) = teacher {
                    let far = match &near {
                        Some(near) => labels.eq(0).logical_and(&near.logical_not()),
                        None => labels.eq(0),
                    };
                    soft = Some((far.to_kind(Kind::Float), teacher.detach().sigmoid()));
                }
                (labels, Some(w))
            }
            None => (t.labels.shallow_clone(), None),
        };
        let labels = &labels;
        let positives = labels.gt(0).to_kind(Kind::Float);
        let cared = labels.ge(0).to_kind(Kind::Float);
        let pos_norm = positives.sum_dim_intlist([1].as_slice(), true, Kind::Float).clamp_min(1.0);
        let cared = match &bg_weights {
            Some(w) => cared * w,
            None => cared,
        };
        let cls_weights = cared / &pos_norm;
        let one_hot = Tensor::zeros([b, n, c + 1], (Kind::Float, out.cls.device())).scatter_value(
            -1,
            &labels.clamp_min(0).unsqueeze(-1),
            1.0,
        );
        let one_hot = one_hot.narrow(-1, 1, c);
        let bs = b as f64;
        let (alpha, gamma) = (self.cfg.focal_alpha, self.cfg.focal_gamma);
        let cls = match &soft {
            None => losses::sigmoid_focal_loss(&out.cls, &one_hot, &cls_weights, alpha, gamma),
            Some((far, teacher)) => {
                let hard = losses::sigmoid_focal_loss(&out.cls, &one_hot, &(&cls_weights * (1.0 - far)), alpha, gamma);
                hard + losses::quality_focal_loss(&out.cls, teacher, &(&cls_weights * far), alpha, gamma)
            }
        } * (self.cfg.cls_weight / bs);
        let (loc, dir) = if t.pos_index.size()[0] > 0 {
            let box_preds = out.boxes.view([b * n, 7]).index_select(0, &t.pos_index);
            let (p, tg) = losses::add_sin_difference(&box_preds, &t.pos_codes, 6);
            let loc = losses::weighted_smooth_l1(&p, &tg, &self.code_weights, &t.pos_weight, self.cfg.smooth_l1_beta)
                * (self.cfg.loc_weight / bs);
            let dir_preds = out.dir.view([b * n, NUM_DIR_BINS as i64]).index_select(0, &t.pos_index);
            let dir =
                losses::weighted_cross_entropy(&dir_preds, &t.pos_dir, &t.pos_weight) * (self.cfg.dir_weight / bs);
            (loc, dir)
        } else {
            let z = out.boxes.sum(Kind::Float) * 0.0;
            (z.shallow_clone(), z)
        };
        (&cls + &loc + &dir, [cls, loc, dir])
    }

    /// Candidate boxes of frame `i`: the `pre_max` best anchors scoring at least
    /// `score_threshold`, decoded. Returns `(boxes [K, 7], scores [K], labels [K])` on the CPU.
    pub fn candidates(
        &self,
        out: &AnchorOutput,
        anchors: &Tensor,
        i: i64,
        score_threshold: f64,
        pre_max: i64,
    ) -> (Tensor, Tensor, Tensor) {
        // Max over classes on the logits (sigmoid is monotonic), threshold, then the best
        // `pre_max` of the survivors (NMS sorts them).
        let (logits, labels) = out.cls.get(i).max_dim(1, false); // [N]
        let logit_threshold = (score_threshold / (1.0 - score_threshold).max(1e-12)).ln();
        let idx = logits.ge(logit_threshold).nonzero().squeeze_dim(1);
        let mut scores = logits.index_select(0, &idx);
        let mut idx = idx;
        if scores.size()[0] > pre_max {
            let (top, j) = scores.topk(pre_max, 0, true, false);
            idx = idx.index_select(0, &j);
            scores = top;
        }
        let scores = scores.sigmoid();
        let labels = labels.index_select(0, &idx);
        let codes = out.boxes.get(i).index_select(0, &idx);
        let anchors = anchors.index_select(0, &idx);
        let boxes = ResidualCoder::decode_tensor(&codes, &anchors);
        // Direction: fold the heading into a half turn and pick the half the classifier says.
        let dir_labels = out.dir.get(i).index_select(0, &idx).argmax(-1, false).to_kind(Kind::Float);
        let period = 2.0 * std::f64::consts::PI / NUM_DIR_BINS as f64;
        let rot = boxes.select(1, 6);
        let dir_rot = limit_period_tensor(&(&rot - DIR_OFFSET), 0.0, period);
        let heading = dir_rot + DIR_OFFSET + period * dir_labels;
        let boxes = Tensor::cat(&[boxes.narrow(1, 0, 6), heading.unsqueeze(1)], 1);
        (boxes.to_device(Device::Cpu), scores.to_device(Device::Cpu), labels.to_device(Device::Cpu))
    }
}

/// Anchors for the head's output map (`cfg.anchors[k]` is class `k`, see
/// [`crate::config::DetectorConfig::validate`]).
pub fn make_anchors(cfg: &AnchorHeadConfig, h: usize, w: usize, cell: [f64; 2], origin: [f64; 2]) -> Anchors {
    let per_class: Vec<(usize, AnchorClassConfig)> = cfg.anchors.iter().cloned().enumerate().collect();
    Anchors::generate(&per_class, h, w, cell, origin)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn loss_values(head: &AnchorHead, out: &AnchorOutput, t: &AnchorBatchTargets) -> [f64; 4] {
        let (total, [cls, loc, dir]) = head.loss(out, t);
        [total, cls, loc, dir].map(|v| v.double_value(&[]))
    }

    /// An ignored car: the car anchors on it are −1 and count in no loss term (changing the
    /// predictions there changes nothing), while as plain background they did count.
    #[test]
    fn ignored_anchors_add_nothing_to_the_loss() {
        let map = CenterMap { h: 16, w: 16, cell: [0.8, 0.8], origin: [-6.4, -6.4] };
        let cfg = AnchorHeadConfig::default();
        let vs = nn::VarStore::new(Device::Cpu);
        let head = cfg.init(vs.root(), 8, 2, &map);
        let assigner = cfg.assigner(&map);
        let a = assigner.anchors.per_location;
        let ped = [Box3d::new(-3.0, 2.9, 0.85, 0.7, 0.6, 1.7, 1.2)];
        let car = [Box3d::new(1.1, -0.7, 0.8, 4.4, 1.9, 1.6, 0.2)];
        let ignored = assigner.assign(&ped, &[1], &car, &[0]);
        let plain = assigner.assign(&ped, &[1], &[], &[]);
        // Anchors the ignored box changed (the pedestrian's own in-between anchors are −1 in both).
        let on_car: Vec<usize> = (0..plain.labels.len()).filter(|&k| ignored.labels[k] != plain.labels[k]).collect();
        assert!(!on_car.is_empty());
        for &k in &on_car {
            assert_eq!(assigner.anchors.slot_class[k % a], 0, "only car anchors are ignored");
            assert_eq!((ignored.labels[k], plain.labels[k]), (-1, 0), "background without the ignored box");
        }
        assert_eq!(ignored.pos_index, plain.pos_index, "an ignored box makes no positive");
        // The ignored pedestrian-class version leaves every car anchor background.
        let as_ped = assigner.assign(&ped, &[1], &car, &[1]);
        assert!(on_car.iter().all(|&k| as_ped.labels[k] == 0));

        let n = assigner.anchors.len() as i64;
        tch::manual_seed(7);
        let f = (Kind::Float, Device::Cpu);
        let out = AnchorOutput {
            cls: Tensor::randn([1, n, 2], f),
            boxes: Tensor::randn([1, n, 7], f) * 0.1,
            dir: Tensor::randn([1, n, 2], f),
        };
        let t_ign = assigner.collate(&[&ignored]);
        let t_plain = assigner.collate(&[&plain]);
        let l_ign = loss_values(&head, &out, &t_ign);
        let l_plain = loss_values(&head, &out, &t_plain);
        assert!(l_ign[1] < l_plain[1], "classification: {l_ign:?} vs {l_plain:?}");
        assert_eq!(l_ign[2..], l_plain[2..], "same positives, same regression and direction");
        assert!(l_ign[2] > 0.0);
        // Predictions perturbed at the ignored anchors only.
        let idx: Vec<i64> = on_car.iter().map(|&k| k as i64).collect();
        let mut m = vec![0f32; n as usize];
        for &k in &on_car {
            m[k] = 1.0;
        }
        let mask = Tensor::from_slice(&m).view([1, n, 1]);
        let noisy = AnchorOutput {
            cls: &out.cls + &mask * Tensor::randn([1, n, 2], f) * 4.0,
            boxes: &out.boxes + &mask * Tensor::randn([1, n, 7], f),
            dir: &out.dir + &mask * Tensor::randn([1, n, 2], f) * 4.0,
        };
        let changed = (noisy.cls.get(0).index_select(0, &Tensor::from_slice(&idx))
            - out.cls.get(0).index_select(0, &Tensor::from_slice(&idx)))
        .abs()
        .sum(Kind::Float)
        .double_value(&[]);
        assert!(changed > 1.0);
        assert_eq!(loss_values(&head, &noisy, &t_ign), l_ign, "ignored anchors changed the loss");
        assert_ne!(loss_values(&head, &noisy, &t_plain)[1], l_plain[1], "background anchors do count");
    }

    /// A two-class anchor head on a 16 × 16 map, its assigner and a car on the map: the KA
    /// target-loss tests' batch.
    fn small_target_head() -> (nn::VarStore, AnchorHead, AnchorAssigner, Box3d) {
        let map = CenterMap { h: 16, w: 16, cell: [0.8, 0.8], origin: [-6.4, -6.4] };
        let cfg = AnchorHeadConfig::default();
        let vs = nn::VarStore::new(Device::Cpu);
        let head = cfg.init(vs.root(), 8, 2, &map);
        (vs, head, cfg.assigner(&map), Box3d::new(1.1, -0.7, 0.8, 4.4, 1.9, 1.6, 0.2))
    }

    /// KA's background rules on a hand-built target batch of two frames: frame 0 has a positive
    /// car, frame 1 only an ignored one (coverage 0). The coverage weight scales exactly the
    /// background part of each frame's classification loss, a frame without positives pushes
    /// nothing down, and unsure background anchors leave the loss unless they overlap a box.
    #[test]
    fn target_background_follows_coverage_and_unsure_outputs() {
        let (_vs, head, assigner, car) = small_target_head();
        let f0 = assigner.assign(&[car], &[0], &[], &[]);
        let f1 = assigner.assign(&[], &[], &[Box3d { x: -3.0, y: 3.0, ..car }], &[0]);
        assert!(!f0.pos_index.is_empty() && !f0.near_positive.is_empty() && f1.pos_index.is_empty());
        assert!(f0.near_positive.iter().all(|&k| f0.labels[k as usize] <= 0), "near anchors are not positives");
        let t = assigner.collate(&[&f0, &f1]);
        let n = assigner.anchors.len() as i64;
        tch::manual_seed(11);
        let f = (Kind::Float, Device::Cpu);
        let cls = (Tensor::randn([2, n, 2], f) - 3.0).set_requires_grad(true);
        let out = AnchorOutput {
            cls: cls.shallow_clone(),
            boxes: Tensor::randn([2, n, 7], f) * 0.1,
            dir: Tensor::randn([2, n, 2], f),
        };
        let cls_loss =
            |neg: Option<&TargetNegatives>| head.loss_with(&out, &t, neg.map(|n| (n, None))).1[0].double_value(&[]);
        // With an unsure score no output reaches, the rules are the frame weights alone.
        let rules = |w1: f64| TargetNegatives { unsure_score: 1.0, frame_weight: vec![1.0, w1] };
        let plain = cls_loss(None);
        assert!((cls_loss(Some(&rules(1.0))) - plain).abs() < 1e-6, "weight 1: the plain loss");
        let (l0, l_half) = (cls_loss(Some(&rules(0.0))), cls_loss(Some(&rules(0.5))));
        assert!(l0 < plain, "{l0} vs {plain}");
        assert!((l_half - 0.5 * (l0 + plain)).abs() < 1e-6, "the background loss is linear in the weight");
        // Weight 0 equals frame 1 with every anchor ignored.
        let all_ignored = AnchorTargets { labels: vec![-1; f1.labels.len()], ..Default::default() };
        let t_ign = assigner.collate(&[&f0, &all_ignored]);
        let want = head.loss(&out, &t_ign).1[0].double_value(&[]);
        assert!((l0 - want).abs() < 1e-6, "{l0} vs {want}");
        // No gradient at all on the frame without positives.
        head.loss_with(&out, &t, Some((&rules(0.0), None))).0.backward();
        let g = cls.grad();
        assert_eq!(g.get(1).abs().sum(Kind::Float).double_value(&[]), 0.0, "frame 1 pushed down");
        assert!(g.get(0).abs().sum(Kind::Float).double_value(&[]) > 0.0);

        // Unsure outputs: a far background anchor and a near-positive one scored 0.95.
        let far = (0..n as usize).find(|&k| f0.labels[k] == 0 && !f0.near_positive.contains(&(k as i64))).unwrap();
        let near = *f0.near_positive.iter().find(|&&k| f0.labels[k as usize] == 0).unwrap() as usize;
        let mut bump = vec![0f32; 2 * n as usize * 2];
        for k in [far, near] {
            bump[2 * k] = 6.0;
        }
        let cls2 = (&out.cls.detach() + Tensor::from_slice(&bump).view([2, n, 2])).set_requires_grad(true);
        let out2 =
            AnchorOutput { cls: cls2.shallow_clone(), boxes: out.boxes.shallow_clone(), dir: out.dir.shallow_clone() };
        let unsure = TargetNegatives { unsure_score: 0.5, frame_weight: vec![1.0, 1.0] };
        head.loss_with(&out2, &t, Some((&unsure, None))).0.backward();
        let g: Vec<f32> = Vec::try_from(cls2.grad().get(0).view([-1])).unwrap();
        assert_eq!((g[2 * far], g[2 * far + 1]), (0.0, 0.0), "an unsure background anchor is ignored");
        assert!(g[2 * near] > 0.0, "one overlapping a box stays background");
        // And without the rules the unsure one is pushed down hardest.
        let cls3 = cls2.detach().set_requires_grad(true);
        let out3 =
            AnchorOutput { cls: cls3.shallow_clone(), boxes: out.boxes.shallow_clone(), dir: out.dir.shallow_clone() };
        head.loss(&out3, &t).0.backward();
        assert!(cls3.grad().get(0).get(far as i64).get(0).double_value(&[]) > 0.0);
    }

    /// The teacher's scores on a hand-built target batch: a background anchor far from the
    /// positive, which the student scores below the teacher, is pushed up towards the teacher's
    /// score (without the teacher it is pushed down); one next to the positive stays a hard
    /// negative; and a student equal to the teacher on every soft anchor has exactly the
    /// classification loss of the hard anchors alone.
    #[test]
    fn target_background_learns_the_teachers_scores() {
        let (_vs, head, assigner, car) = small_target_head();
        let f0 = assigner.assign(&[car], &[0], &[], &[]);
        let t = assigner.collate(&[&f0]);
        let n = assigner.anchors.len() as i64;
        let far = (0..n as usize).find(|&k| f0.labels[k] == 0 && !f0.near_positive.contains(&(k as i64))).unwrap();
        let near = *f0.near_positive.iter().find(|&&k| f0.labels[k as usize] == 0).unwrap() as usize;
        tch::manual_seed(5);
        let f = (Kind::Float, Device::Cpu);
        let student = Tensor::randn([1, n, 2], f) - 4.0;
        // The teacher believes both anchors hold a car at 0.4 (logit ≈ −0.41); the student
        // scores them ≈ 0.02, below the unsure floor, so they are background for the rules.
        let mut bump = vec![0f32; n as usize * 2];
        for k in [far, near] {
            bump[2 * k] = 1.0;
        }
        let bump = Tensor::from_slice(&bump).view([1, n, 2]);
        let teacher = &student * (1.0 - &bump) + &bump * (0.4f64 / 0.6).ln();
        let cls = student.set_requires_grad(true);
        let out = AnchorOutput {
            cls: cls.shallow_clone(),
            boxes: Tensor::zeros([1, n, 7], f),
            dir: Tensor::zeros([1, n, 2], f),
        };
        let rules = TargetNegatives { unsure_score: 0.3, frame_weight: vec![1.0] };
        head.loss_with(&out, &t, Some((&rules, Some(&teacher)))).0.backward();
        let g: Vec<f32> = Vec::try_from(cls.grad().view([-1])).unwrap();
        assert!(g[2 * far] < 0.0, "a far background anchor rises towards the teacher's score: {}", g[2 * far]);
        assert!(g[2 * near] > 0.0, "next to a positive it stays a hard negative: {}", g[2 * near]);
        let plain = cls.detach().set_requires_grad(true);
        let out_plain =
            AnchorOutput { cls: plain.shallow_clone(), boxes: out.boxes.shallow_clone(), dir: out.dir.shallow_clone() };
        head.loss_with(&out_plain, &t, Some((&rules, None))).0.backward();
        assert!(plain.grad().view([-1]).double_value(&[2 * far as i64]) > 0.0, "without a teacher it is pushed down");

        // Student = teacher everywhere: the soft anchors add nothing, so the loss is that of
        // the same batch with every soft anchor ignored.
        let same = AnchorOutput {
            cls: teacher.shallow_clone(),
            boxes: out.boxes.shallow_clone(),
            dir: out.dir.shallow_clone(),
        };
        let with_teacher = head.loss_with(&same, &t, Some((&rules, Some(&teacher)))).1[0].double_value(&[]);
        let mut hard_only = f0.clone();
        for k in 0..n as usize {
            if hard_only.labels[k] == 0 && !f0.near_positive.contains(&(k as i64)) {
                hard_only.labels[k] = -1;
            }
        }
        let t_hard = assigner.collate(&[&hard_only]);
        let want = head.loss_with(&same, &t_hard, Some((&rules, None))).1[0].double_value(&[]);
        assert!((with_teacher - want).abs() < 1e-6 * want.max(1.0), "{with_teacher} vs {want}");
    }
}
