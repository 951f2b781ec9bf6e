//! PointPillars (Lang et al., "PointPillars: Fast Encoders for Object Detection from Point Clouds",
//! CVPR 2019) as OpenPCDet builds it: pillar feature net → scatter → BEV backbone → dense head,
//! with either the SECOND-style anchor head or the CenterPoint center head (Yin et al., CVPR 2021).
//!
//! Train: `pi3det train --config configs/pointpillars_cpu.toml --data DIR --out runs/pp`;
//! detect: `pi3det detect --ckpt runs/pp/final.safetensors --data DIR --out det/`.
//!
//! The network runs on libtorch (tch); everything around it — pillarization, augmentation, target
//! assignment (on the loader thread), NMS — is Rust.

use std::sync::Arc;

use pi3det_geometry::{nms, Box3d, NmsConfig};
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

use crate::augment::Sample;
use crate::backbone_2d::Backbone2d;
use crate::config::{DetectorConfig, HeadConfig};
use crate::dense_heads::anchor_head::{make_anchors, AnchorBatchTargets, AnchorHead, AnchorOutput};
use crate::dense_heads::center_head::{CenterBatchTargets, CenterHead, CenterOutput};
use crate::error::Result;
use crate::pillarize::{Grid, Pillarizer, Pillars, POINT_FEATURES};
use crate::scatter::scatter;
use crate::target_assigner::center::CenterMap;
use crate::target_assigner::{axis_aligned, center, AnchorTargets, Anchors, CenterTargets};
use crate::vfe::PillarVfe;

/// One detection in the detector's (shifted) frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    pub box3d: Box3d,
    pub score: f64,
    pub class: usize,
}

/// Targets of one frame.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameTargets {
    Anchor(AnchorTargets),
    Center(CenterTargets),
}

/// Network input of a batch: pillars of all frames.
pub struct Inputs {
    /// `[ΣP, M, 10]` decorated points.
    pub features: Tensor,
    /// `[ΣP]` flat BEV index `b·ny·nx + cell`.
    pub cells: Tensor,
    pub batch_size: i64,
}

impl Inputs {
    pub fn to_device(&self, d: Device) -> Self {
        Self { features: self.features.to_device(d), cells: self.cells.to_device(d), batch_size: self.batch_size }
    }
}

pub enum Targets {
    Anchor(AnchorBatchTargets),
    Center(CenterBatchTargets),
}

impl Targets {
    pub fn to_device(&self, d: Device) -> Self {
        match self {
            Self::Anchor(t) => Self::Anchor(t.to_device(d)),
            Self::Center(t) => Self::Center(t.to_device(d)),
        }
    }
}

pub enum Output {
    Anchor(AnchorOutput),
    Center(CenterOutput),
}

/// Loss total and named, weighted terms.
pub struct Losses {
    pub total: Tensor,
    pub terms: Vec<(&'static str, Tensor)>,
}

/// Everything needed to turn frames into network inputs and targets, without the network: shared
/// with the loader thread.
pub struct Preprocessor {
    pub cfg: DetectorConfig,
    pub grid: Grid,
    pub map: CenterMap,
    pub anchors: Option<Anchors>,
}

impl Preprocessor {
    pub fn new(cfg: &DetectorConfig) -> Result<Self> {
        cfg.validate()?;
        let grid = Grid::new(&cfg.pillars)?;
        let s = cfg.backbone.output_stride() as usize;
        let map = CenterMap {
            h: grid.ny / s,
            w: grid.nx / s,
            cell: [grid.vx * s as f64, grid.vy * s as f64],
            origin: [grid.x_min, grid.y_min],
        };
        let anchors = match &cfg.head {
            HeadConfig::Anchor(a) => Some(make_anchors(a, map.h, map.w, map.cell, map.origin)),
            HeadConfig::Center(_) => None,
        };
        Ok(Self { cfg: cfg.clone(), grid, map, anchors })
    }

    pub fn pillarizer(&self) -> Result<Pillarizer> {
        Pillarizer::new(&self.cfg.pillars)
    }

    /// Training targets of a sample (boxes in the detector's frame).
    pub fn targets(&self, s: &Sample) -> FrameTargets {
        match (&self.cfg.head, &self.anchors) {
            (HeadConfig::Anchor(a), Some(anchors)) => {
                FrameTargets::Anchor(axis_aligned::assign(anchors, &a.anchors, &s.boxes, &s.classes))
            }
            (HeadConfig::Center(c), _) => FrameTargets::Center(center::assign(
                &c.targets,
                &self.map,
                self.cfg.classes.len(),
                &s.boxes,
                &s.classes,
            )),
            (HeadConfig::Anchor(_), None) => unreachable!("anchors are built with an anchor head"),
        }
    }

    /// Stacks frames' pillars into network inputs.
    pub fn collate_inputs(&self, pillars: &[&Pillars]) -> Inputs {
        let m = self.cfg.pillars.max_points_per_pillar;
        let total: usize = pillars.iter().map(|p| p.len()).sum();
        let mut cells = Vec::with_capacity(total);
        let plane = (self.grid.nx * self.grid.ny) as i64;
        for (b, p) in pillars.iter().enumerate() {
            cells.extend(p.cells.iter().map(|&c| c + b as i64 * plane));
        }
        // The frames' features go straight into the tensor's memory (one copy).
        let features =
            Tensor::empty([total as i64, m as i64, POINT_FEATURES as i64], (tch::Kind::Float, tch::Device::Cpu));
        let n = total * m * POINT_FEATURES;
        if n > 0 {
            // SAFETY: a fresh, contiguous CPU float tensor of exactly `n` elements, not shared.
            let dst = unsafe { std::slice::from_raw_parts_mut(features.data_ptr() as *mut f32, n) };
            let mut at = 0;
            for p in pillars {
                dst[at..at + p.features.len()].copy_from_slice(&p.features);
                at += p.features.len();
            }
        }
        Inputs { features, cells: Tensor::from_slice(&cells), batch_size: pillars.len() as i64 }
    }

    /// Stacks frames' targets (all of the same kind).
    pub fn collate_targets(&self, targets: &[&FrameTargets]) -> Targets {
        let b = targets.len() as i64;
        match (&self.cfg.head, &self.anchors) {
            (HeadConfig::Anchor(_), Some(anchors)) => {
                let n = anchors.len() as i64;
                let mut labels = Vec::with_capacity(targets.len() * anchors.len());
                let (mut idx, mut codes, mut dir, mut w) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
                for (k, t) in targets.iter().enumerate() {
                    let FrameTargets::Anchor(t) = t else { continue };
                    labels.extend_from_slice(&t.labels);
                    idx.extend(t.pos_index.iter().map(|&i| i + k as i64 * n));
                    codes.extend_from_slice(&t.pos_codes);
                    dir.extend_from_slice(&t.pos_dir);
                    let inv = 1.0 / t.pos_index.len().max(1) as f32;
                    w.extend(std::iter::repeat_n(inv, t.pos_index.len()));
                }
                let p = idx.len() as i64;
                Targets::Anchor(AnchorBatchTargets {
                    labels: Tensor::from_slice(&labels).view([b, n]),
                    pos_index: Tensor::from_slice(&idx),
                    pos_codes: Tensor::from_slice(&codes).view([p, 7]),
                    pos_dir: Tensor::from_slice(&dir),
                    pos_weight: Tensor::from_slice(&w),
                })
            }
            _ => {
                let (h, w) = (self.map.h as i64, self.map.w as i64);
                let c = self.cfg.classes.len() as i64;
                let mut hm = Vec::with_capacity((b * c * h * w) as usize);
                let (mut idx, mut codes) = (Vec::new(), Vec::new());
                for (k, t) in targets.iter().enumerate() {
                    let FrameTargets::Center(t) = t else { continue };
                    hm.extend_from_slice(&t.heatmap);
                    idx.extend(t.index.iter().map(|&i| i + k as i64 * h * w));
                    codes.extend_from_slice(&t.codes);
                }
                let kk = idx.len() as i64;
                Targets::Center(CenterBatchTargets {
                    heatmap: Tensor::from_slice(&hm).view([b, c, h, w]),
                    index: Tensor::from_slice(&idx),
                    codes: Tensor::from_slice(&codes).view([kk, center::CENTER_CODE_SIZE as i64]),
                })
            }
        }
    }
}

enum Head {
    Anchor(Box<AnchorHead>),
    Center(Box<CenterHead>),
}

/// The network with its weights.
pub struct Detector {
    pub vs: VarStore,
    pub prep: Arc<Preprocessor>,
    vfe: PillarVfe,
    backbone: Backbone2d,
    head: Head,
    /// Anchors on the device (anchor head only).
    anchors: Option<Tensor>,
}

impl Detector {
    pub fn new(cfg: &DetectorConfig, device: Device) -> Result<Self> {
        let prep = Arc::new(Preprocessor::new(cfg)?);
        let vs = VarStore::new(device);
        let root = vs.root();
        let bn = &cfg.batch_norm;
        let vfe = cfg.vfe.init(&root / "vfe", bn);
        let backbone = cfg.backbone.init(&root / "backbone_2d", cfg.vfe.out_channels(), bn);
        let c = cfg.backbone.out_channels();
        let k = cfg.classes.len() as i64;
        let head = match &cfg.head {
            HeadConfig::Anchor(a) => Head::Anchor(Box::new(a.init(&root / "dense_head", c, k))),
            HeadConfig::Center(h) => Head::Center(Box::new(h.init(&root / "dense_head", c, k, bn))),
        };
        let anchors = prep.anchors.as_ref().map(|a| a.to_tensor().to_device(device));
        Ok(Self { vs, prep, vfe, backbone, head, anchors })
    }

    pub fn cfg(&self) -> &DetectorConfig {
        &self.prep.cfg
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

    /// BEV features `[B, C, H, W]` of a batch.
    pub fn bev_features(&self, x: &Inputs, train: bool) -> Tensor {
        let pillar = self.vfe.forward_t(&x.features, train);
        let channels_last = self.cfg().channels_last && self.device() == tch::Device::Cpu;
        let bev =
            scatter(&pillar, &x.cells, x.batch_size, self.prep.grid.ny as i64, self.prep.grid.nx as i64, channels_last);
        self.backbone.forward_t(&bev, train)
    }

    pub fn forward_t(&self, x: &Inputs, train: bool) -> Output {
        let f = self.bev_features(x, train);
        match &self.head {
            Head::Anchor(h) => Output::Anchor(h.forward(&f)),
            Head::Center(h) => Output::Center(h.forward_t(&f, train)),
        }
    }

    pub fn loss(&self, out: &Output, t: &Targets) -> Losses {
        match (&self.head, out, t) {
            (Head::Anchor(h), Output::Anchor(o), Targets::Anchor(t)) => {
                let (total, [cls, loc, dir]) = h.loss(o, t);
                Losses { total, terms: vec![("cls", cls), ("loc", loc), ("dir", dir)] }
            }
            (Head::Center(h), Output::Center(o), Targets::Center(t)) => {
                let (total, [hm, loc]) = h.loss(o, t);
                Losses { total, terms: vec![("hm", hm), ("loc", loc)] }
            }
            _ => unreachable!("outputs and targets come from the same head"),
        }
    }

    /// Score threshold, candidates, rotated NMS; boxes in the detector's (shifted) frame.
    pub fn post_process(&self, out: &Output, batch_size: i64) -> Vec<Vec<Detection>> {
        let post = &self.cfg().post;
        (0..batch_size)
            .map(|i| {
                let (boxes, scores, labels) = match (&self.head, out) {
                    (Head::Anchor(h), Output::Anchor(o)) => h.candidates(
                        o,
                        self.anchors.as_ref().expect("anchor head has anchors"),
                        i,
                        post.score_threshold,
                        post.nms_pre_max as i64,
                    ),
                    (Head::Center(h), Output::Center(o)) => h.candidates(o, &self.prep.map, i, post.score_threshold),
                    _ => unreachable!("outputs come from the head"),
                };
                self.nms(&boxes, &scores, &labels)
            })
            .collect()
    }

    fn nms(&self, boxes: &Tensor, scores: &Tensor, labels: &Tensor) -> Vec<Detection> {
        let post = &self.cfg().post;
        let b: Vec<f32> = Vec::try_from(boxes.to_kind(Kind::Float).reshape([-1])).unwrap_or_default();
        let s: Vec<f32> = Vec::try_from(scores.to_kind(Kind::Float)).unwrap_or_default();
        let l: Vec<i64> = Vec::try_from(labels.to_kind(Kind::Int64)).unwrap_or_default();
        let dets: Vec<Detection> = (0..s.len())
            .filter(|&k| b[k * 7..k * 7 + 7].iter().all(|v| v.is_finite()) && s[k].is_finite())
            .map(|k| {
                let a: [f64; 7] = std::array::from_fn(|j| b[k * 7 + j] as f64);
                Detection {
                    box3d: Box3d::from_array(a).with_wrapped_heading(),
                    score: s[k] as f64,
                    class: l[k] as usize,
                }
            })
            .collect();
        let cfg = NmsConfig {
            iou_threshold: post.nms_iou,
            score_threshold: post.score_threshold,
            pre_max_size: post.nms_pre_max,
            post_max_size: post.nms_post_max,
        };
        let run = |subset: &[Detection]| -> Vec<Detection> {
            let boxes: Vec<Box3d> = subset.iter().map(|d| d.box3d).collect();
            let scores: Vec<f64> = subset.iter().map(|d| d.score).collect();
            nms(&boxes, &scores, &cfg).into_iter().map(|k| subset[k]).collect()
        };
        if post.per_class_nms {
            let mut out: Vec<Detection> = (0..self.cfg().classes.len())
                .flat_map(|c| run(&dets.iter().copied().filter(|d| d.class == c).collect::<Vec<_>>()))
                .collect();
            out.sort_by(|a, b| b.score.total_cmp(&a.score));
            out.truncate(post.nms_post_max);
            out
        } else {
            run(&dets)
        }
    }

    /// Inference on prepared inputs (no gradients, eval-mode batch norm).
    pub fn predict(&self, x: &Inputs) -> Vec<Vec<Detection>> {
        let _guard = tch::no_grad_guard();
        let x = x.to_device(self.device());
        let out = self.forward_t(&x, false);
        self.post_process(&out, x.batch_size)
    }
}
