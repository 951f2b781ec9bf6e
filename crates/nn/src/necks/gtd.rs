//! Geometry-aware Transformation Descriptor (Pi3DET-Net §4.2): a BEV-to-BEV neck that learns
//! the platform's global transformation on the source and corrects it on the target.
//!
//! The residual branch is the public module: three parallel `Conv2d(C, C, k)` (k = 1, 3, 5,
//! "same" padding), each followed by ReLU, summed into the descriptor map `D`; squeeze-excitation
//! channel attention on `D` (global average pool → Linear C→C/r → ReLU → Linear → sigmoid);
//! output `ReLU(F + D·attention)`. The paper's rotation head, absent from the public code: a
//! global max pool of `D` (the compact descriptor `f_d`) → MLP → the roll and pitch Random
//! Platform Jitter applied, trained with `L_rot` (squared error, in degrees: in radians the ±5°
//! jitter gives errors below 0.01, which λ_rot = 0.1 would make vanish). `L_rot` only trains
//! where the angles are known (source frames with jitter); the residual is applied to every
//! frame, so the descriptor learnt on the source corrects the target at adaptation and test time.
//!
//! Two safeguards the public module does not need (it has no rotation head): the pooled
//! descriptor is layer-normalised and the regressor's last layer starts at zero, so `L_rot`
//! starts at the cost of predicting no tilt instead of at whatever an unnormalised max of a
//! 128×128 map gives (without them `L_rot` outweighed every detection term together over a first
//! epoch and the vehicle model lost most of its Car AP); and the residual is scaled by a learnt γ
//! that starts at 0 (ReZero), so Pre-Adaptation starts from the plain detector and lets the
//! offset in as it helps. `L_rot` trains the GTD branch, not the backbone: the descriptor is
//! computed again from the detached map (with the gradient reaching the backbone the vehicle
//! model still lost much of its Car AP, even after the two safeguards), on the windows around
//! each channel's maximum only, which gives the values and weight gradients of a full second pass.
//!
//! `inner_channels` (not in the public module) runs the branch on `c < C` channels between a 1×1
//! reduction and a 1×1 expansion: on the CPU preset's 192-channel, 128×128 map the C→C 5×5
//! convolution alone costs many times the whole 2D backbone.
//!
//! Measured: results/2026-12-05-pi3det-net-ablation-seed0.md (the safeguards, the detached map,
//! `inner_channels`) and results/2026-12-06-training-step.md (the windowed second pass).

use serde::{Deserialize, Serialize};
use tch::nn::{self, Module};
use tch::{Kind, Tensor};

use super::{Neck, NeckOutput};
use crate::precision::{conv2d, Conv2d};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GtdConfig {
    /// Kernel sizes of the parallel convolutions (odd).
    pub kernel_sizes: Vec<i64>,
    /// Squeeze-excitation reduction (C → C / r).
    pub reduction: i64,
    /// Width of the convolutions (`None`: the map's C, as the public module).
    pub inner_channels: Option<i64>,
    /// Hidden width of the rotation regressor.
    pub rotation_hidden: i64,
    /// λ_rot.
    pub rotation_weight: f64,
}

impl Default for GtdConfig {
    fn default() -> Self {
        Self {
            kernel_sizes: vec![1, 3, 5],
            reduction: 8,
            inner_channels: None,
            rotation_hidden: 64,
            rotation_weight: 0.1,
        }
    }
}

impl GtdConfig {
    pub fn validate(&self) -> crate::Result<()> {
        if self.kernel_sizes.is_empty()
            || self.kernel_sizes.iter().any(|&k| k < 1 || k % 2 == 0)
            || self.reduction < 1
            || self.inner_channels.is_some_and(|c| c < 1)
            || self.rotation_hidden < 1
            || !(self.rotation_weight.is_finite() && self.rotation_weight >= 0.0)
        {
            return Err(crate::NnError::config("neck", format!("neck gtd: invalid settings {self:?}")));
        }
        Ok(())
    }

    pub fn init(&self, vs: nn::Path, channels: i64) -> Gtd {
        let inner = self.inner_channels.unwrap_or(channels);
        let (reduce, expand) = if inner == channels {
            (None, None)
        } else {
            let one = |name: &str, i, o| conv2d(&vs / name, i, o, 1, Default::default());
            (Some(one("reduce", channels, inner)), Some(one("expand", inner, channels)))
        };
        let convs = self
            .kernel_sizes
            .iter()
            .map(|&k| {
                let c = nn::ConvConfig { padding: k / 2, ..Default::default() };
                conv2d(&vs / format!("conv{k}"), inner, inner, k, c)
            })
            .collect();
        let squeeze = (inner / self.reduction).max(1);
        let se = nn::seq()
            .add(nn::linear(&vs / "se1", inner, squeeze, Default::default()))
            .add_fn(|x| x.relu())
            .add(nn::linear(&vs / "se2", squeeze, inner, Default::default()));
        let h = self.rotation_hidden;
        let zero = nn::LinearConfig { ws_init: nn::Init::Const(0.0), bs_init: Some(nn::Init::Const(0.0)), bias: true };
        let rotation = nn::seq()
            .add(nn::layer_norm(&vs / "rot_norm", vec![inner], Default::default()))
            .add(nn::linear(&vs / "rot1", inner, h, Default::default()))
            .add_fn(|x| x.relu())
            .add(nn::linear(&vs / "rot2", h, h, Default::default()))
            .add_fn(|x| x.relu())
            .add(nn::linear(&vs / "rot3", h, 2, zero));
        let gamma = vs.var("gamma", &[1], nn::Init::Const(0.0));
        Gtd { reduce, convs, se, expand, rotation, gamma, channels, inner, rotation_weight: self.rotation_weight }
    }
}

pub struct Gtd {
    reduce: Option<Conv2d>,
    convs: Vec<Conv2d>,
    se: nn::Sequential,
    expand: Option<Conv2d>,
    rotation: nn::Sequential,
    /// Scale of the residual offset (starts at 0).
    gamma: Tensor,
    channels: i64,
    inner: i64,
    rotation_weight: f64,
}

impl Gtd {
    /// `bev [B, C, H, W]` → (`[B, C, H, W]`, predicted `[roll, pitch]` in degrees `[B, 2]`).
    /// The descriptor map `D` of `bev` (`[B, c, H, W]`).
    fn descriptor_map(&self, bev: &Tensor) -> Tensor {
        let x = match &self.reduce {
            Some(r) => r.forward(bev).relu(),
            None => bev.shallow_clone(),
        };
        // Not in place: each ReLU's backward needs its own output.
        self.convs.iter().map(|c| c.forward(&x).relu()).reduce(|a, b| a + b).unwrap_or_else(|| x.zeros_like())
    }

    pub fn forward(&self, bev: &Tensor) -> (Tensor, Tensor) {
        // In bf16 (mixed precision) the maps stay in `bev`'s kind; the pooled vectors, the
        // attention MLP and the rotation regressor run in f32.
        let kind = bev.kind();
        let d = self.descriptor_map(bev);
        let attention = self.se.forward(&d.mean_dim(&[2i64, 3][..], false, Kind::Float)).sigmoid();
        let b = attention.size()[0];
        let attended = &d * attention.view([b, self.inner, 1, 1]).to_kind(kind);
        let offset = match &self.expand {
            Some(e) => e.forward(&attended),
            None => attended,
        };
        let out = (bev + offset * self.gamma.to_kind(kind)).relu();
        // Without gradients inference reads the descriptor off D directly.
        let descriptor = if bev.requires_grad() {
            self.detached_descriptor(bev, &d)
        } else {
            d.amax(&[2i64, 3][..], false).to_kind(Kind::Float)
        };
        (out, self.rotation.forward(&descriptor))
    }

    /// `f_d = amax_{H,W} D(bev)` `[B, c]` (f32) with gradients to the branch's weights but not to
    /// `bev`, given `d = D(bev)`. Each channel's maximum sits at one position and D there reads
    /// only the k_max × k_max window of the reduced map around it, so the branch runs again on
    /// those `B·c` windows of the detached map rather than on the whole map: the values and
    /// weight gradients of a second full pass (amax's gradient goes to the argmax; ties share
    /// the same window) at a small fraction of its cost. Measured:
    /// results/2026-12-06-training-step.md.
    fn detached_descriptor(&self, bev: &Tensor, d: &Tensor) -> Tensor {
        let (b, c_in, h, w) = bev.size4().expect("bev is [B, C, H, W]");
        let dev = bev.device();
        let k_max = self.convs.iter().map(|c| c.conv.ws.size()[2]).max().unwrap_or(1);
        let r = k_max / 2;
        let n = b * self.inner;
        // Window positions around each channel's argmax: [B·c, K, K].
        let at = d.detach().flatten(2, 3).argmax(2, false).view([n, 1, 1]);
        let offsets = Tensor::arange_start(-r, r + 1, (Kind::Int64, dev));
        let y = at.divide_scalar_mode(w, "floor") + offsets.view([1, k_max, 1]);
        let x = at.remainder(w) + offsets.view([1, 1, k_max]);
        let inside = y.ge(0).logical_and(&y.lt(h)).logical_and(&x.ge(0)).logical_and(&x.lt(w));
        let frame = Tensor::arange(b, (Kind::Int64, dev)).repeat_interleave_self_int(self.inner, 0, None);
        let cell = frame.view([n, 1, 1]) * (h * w) + y.clamp(0, h - 1) * w + x.clamp(0, w - 1);
        // [B·H·W, C] rows (a view for channels-last maps) → windows [B·c, C, K, K] in f32.
        let rows = bev.detach().permute([0, 2, 3, 1]).reshape([b * h * w, c_in]);
        let windows = rows
            .index_select(0, &cell.view([-1]))
            .to_kind(Kind::Float)
            .view([n, k_max, k_max, c_in])
            .permute([0, 3, 1, 2]);
        // The weights are f32 in every precision (the conv wrappers cast them per call).
        let reduced = match &self.reduce {
            Some(r) => windows.conv2d(&r.conv.ws, r.conv.bs.as_ref(), [1; 2], [0; 2], [1; 2], 1).relu(),
            None => windows,
        };
        // D pads the reduced map with zeros: window cells outside the map read zero.
        let reduced = reduced * inside.unsqueeze(1).to_kind(Kind::Float);
        let at_max: Tensor = self
            .convs
            .iter()
            .map(|c| {
                let k = c.conv.ws.size()[2];
                let o = (k_max - k) / 2;
                let centre = reduced.narrow(2, o, k).narrow(3, o, k);
                centre.conv2d(&c.conv.ws, c.conv.bs.as_ref(), [1; 2], [0; 2], [1; 2], 1).relu()
            })
            .reduce(|a, b| a + b)
            .expect("at least one kernel size");
        // Row (frame, channel) keeps its own channel: [B, c, c] → diagonal [B, c].
        at_max.view([b, self.inner, self.inner]).diagonal(0, 1, 2)
    }
}

impl Neck for Gtd {
    fn forward_t(&self, bev: &Tensor, _train: bool) -> NeckOutput {
        let (bev, rotation) = self.forward(bev);
        NeckOutput { bev, rotation_deg: Some(rotation) }
    }

    fn out_channels(&self) -> i64 {
        self.channels
    }

    fn rotation_weight(&self) -> f64 {
        self.rotation_weight
    }
}

/// `L_rot`: mean over the frames with known angles of the squared error summed over roll and
/// pitch (degrees). `pred [B, 2]`; `truth[b]` = RPJ's (roll, pitch) in radians, `None` where
/// no jitter was drawn. `None` when no frame has angles.
pub fn rotation_loss(pred_deg: &Tensor, truth_rad: &[Option<[f64; 2]>]) -> Option<Tensor> {
    let rows: Vec<i64> = truth_rad.iter().enumerate().filter(|(_, t)| t.is_some()).map(|(i, _)| i as i64).collect();
    if rows.is_empty() {
        return None;
    }
    let target: Vec<f32> =
        truth_rad.iter().flatten().flat_map(|t| [t[0].to_degrees() as f32, t[1].to_degrees() as f32]).collect();
    let dev = pred_deg.device();
    let target = Tensor::from_slice(&target).view([rows.len() as i64, 2]).to_device(dev);
    let pred = pred_deg.index_select(0, &Tensor::from_slice(&rows).to_device(dev));
    Some((pred - target).square().sum_dim_intlist(&[1i64][..], false, Kind::Float).mean(Kind::Float))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use tch::nn::OptimizerConfig;
    use tch::Device;

    #[test]
    fn shapes_and_residual() {
        let vs = nn::VarStore::new(Device::Cpu);
        let gtd = GtdConfig::default().init(vs.root(), 16);
        let x = Tensor::randn([2, 16, 12, 10], (Kind::Float, Device::Cpu));
        let (y, rot) = gtd.forward(&x);
        assert_eq!(y.size(), vec![2, 16, 12, 10]);
        assert_eq!(rot.size(), vec![2, 2]);
        assert!(y.min().double_value(&[]) >= 0.0, "ReLU output");
        // γ = 0 and a zero last layer: the neck starts as ReLU and predicts no tilt.
        assert!(y.equal(&x.relu()) && rot.abs().max().double_value(&[]) == 0.0);
        assert_eq!(gtd.out_channels(), 16);
        let narrow = GtdConfig { inner_channels: Some(4), ..Default::default() }.init(vs.root() / "narrow", 16);
        let (y, rot) = narrow.forward(&x);
        assert_eq!((y.size(), rot.size()), (vec![2, 16, 12, 10], vec![2, 2]));
        // Mixed precision: a bf16 map stays bf16, the pooled descriptor's regressor runs in f32.
        let (y16, rot16) = narrow.forward(&x.to_kind(Kind::BFloat16));
        assert_eq!((y16.kind(), rot16.kind(), y16.size()), (Kind::BFloat16, Kind::Float, vec![2, 16, 12, 10]));
        // L_rot trains the branch, not what feeds it.
        let x = x.set_requires_grad(true);
        let (_, rot) = narrow.forward(&x);
        rotation_loss(&(rot + 1.0), &[Some([0.01, 0.02]), Some([0.0, -0.03])]).unwrap().backward();
        assert!(!x.grad().defined() || x.grad().abs().sum(Kind::Float).double_value(&[]) == 0.0);
    }

    /// The windowed descriptor equals a second full pass of the branch on the detached map, in
    /// value and in its gradients to the weights: maxima at the border (zero padding), flat
    /// regions (ties) and both kernel layouts.
    #[test]
    fn detached_descriptor_matches_a_full_pass() {
        for (inner, flat) in [(None, false), (Some(6), false), (Some(6), true)] {
            tch::manual_seed(3);
            let vs = nn::VarStore::new(Device::Cpu);
            let cfg = GtdConfig { inner_channels: inner, ..Default::default() };
            let gtd = cfg.init(vs.root(), 10);
            let x = Tensor::randn([2, 10, 9, 11], (Kind::Float, Device::Cpu));
            // A flat quarter (equal values: ties) and a large value at a corner; or a map flat
            // everywhere (an empty scene: every interior position ties).
            let _ = x.narrow(2, 0, 5).narrow(3, 0, 5).fill_(0.3);
            let _ = x.narrow(2, 8, 1).narrow(3, 10, 1).fill_(4.0);
            if flat {
                let _ = x.narrow(0, 1, 1).fill_(0.5);
            }
            let x = x.set_requires_grad(true);
            let grads = |f: &dyn Fn() -> Tensor| {
                vs.trainable_variables().iter().for_each(|v| {
                    let mut g = v.grad();
                    if g.defined() {
                        let _ = g.zero_();
                    }
                });
                let value = f();
                (value.shallow_clone()
                    * Tensor::arange(value.numel() as i64, (Kind::Float, Device::Cpu)).view_as(&value))
                .sum(Kind::Float)
                .backward();
                let g: Vec<Tensor> = vs
                    .trainable_variables()
                    .iter()
                    .map(|v| if v.grad().defined() { v.grad().copy() } else { v.zeros_like() })
                    .collect();
                (value.detach(), g)
            };
            let (full, g_full) = grads(&|| gtd.descriptor_map(&x.detach()).amax(&[2i64, 3][..], false));
            let (window, g_window) = grads(&|| gtd.detached_descriptor(&x, &gtd.descriptor_map(&x)));
            assert!(full.allclose(&window, 1e-5, 1e-6, false), "{full} vs {window}");
            for (a, b) in g_full.iter().zip(&g_window) {
                assert!(a.allclose(b, 1e-4, 1e-5, false), "gradient {a} vs {b}");
            }
            assert!(!x.grad().defined() || x.grad().abs().sum(Kind::Float).double_value(&[]) == 0.0);
        }
    }

    /// Redraws the randomly initialised variables (weights and biases) from a local generator:
    /// libtorch's generator is global, and tests running beside this one draw from it between a
    /// seed and an init. Constant-initialised ones (norm weights, zero-initialised layers) keep
    /// their values.
    fn redraw_random_weights(vs: &nn::VarStore, seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut vars: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
        vars.sort_by(|a, b| a.0.cmp(&b.0));
        tch::no_grad(|| {
            for (_, mut v) in vars {
                if v.max().double_value(&[]) == v.min().double_value(&[]) {
                    continue;
                }
                let bound = if v.dim() < 2 { 0.1 } else { (3.0 * v.size()[0] as f64 / v.numel() as f64).sqrt() };
                let values: Vec<f32> = (0..v.numel()).map(|_| rng.random_range(-bound..bound) as f32).collect();
                v.copy_(&Tensor::from_slice(&values).view(v.size().as_slice()));
            }
        });
    }

    /// A toy input whose tilt shows as a gradient across the map: L_rot learns to read it back.
    #[test]
    fn rotation_loss_learns_a_known_rotation() {
        let vs = nn::VarStore::new(Device::Cpu);
        let gtd = GtdConfig { kernel_sizes: vec![1, 3], ..Default::default() }.init(vs.root(), 4);
        redraw_random_weights(&vs, 7);
        let mut opt = nn::Adam::default().build(&vs, 3e-3).unwrap();
        let map = |roll: f64, pitch: f64| {
            let xs = Tensor::linspace(-1.0, 1.0, 8, (Kind::Float, Device::Cpu));
            let plane = xs.view([1, 8]) * pitch.to_degrees() + xs.view([8, 1]) * roll.to_degrees();
            Tensor::stack(&[plane.relu(), (-&plane).relu(), plane.shallow_clone() * 0.0, plane.abs()], 0)
        };
        let mut rng = ChaCha8Rng::seed_from_u64(1234567);
        let mut draw = || rng.random_range(-5f64..5.0).to_radians();
        let mut losses = Vec::new();
        for _ in 0..1000 {
            let angles: Vec<[f64; 2]> = (0..8).map(|_| [draw(), draw()]).collect();
            let x = Tensor::stack(&angles.iter().map(|a| map(a[0], a[1])).collect::<Vec<_>>(), 0);
            let (_, pred) = gtd.forward(&x);
            let truth: Vec<Option<[f64; 2]>> = angles.iter().map(|a| Some(*a)).collect();
            let loss = rotation_loss(&pred, &truth).unwrap();
            opt.backward_step(&loss);
            losses.push(loss.double_value(&[]));
        }
        // Angles span ±5°: predicting 0 costs ≈ 2·25/3 ≈ 17 deg². The mean of the last 50 batches
        // (one batch of 8 frames is a noisy read) must fall well below that for any weight draw.
        let tail = losses[losses.len() - 50..].iter().sum::<f64>() / 50.0;
        assert!(tail < 1.5 && tail < losses[0] / 5.0, "L_rot {} → {tail}", losses[0]);
        // Frames without angles are left out; none at all gives no loss.
        let p = Tensor::from_slice(&[1.0f32, 2.0, 3.0, 4.0]).view([2, 2]);
        let l = rotation_loss(&p, &[None, Some([0.0, 0.0])]).unwrap();
        assert!((l.double_value(&[]) - 25.0).abs() < 1e-4);
        assert!(rotation_loss(&p, &[None, None]).is_none());
    }
}
