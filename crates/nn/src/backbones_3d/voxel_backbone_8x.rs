//! OpenPCDet's `VoxelBackBone8x` (SECOND, Yan et al., Sensors 2018; Voxel R-CNN, Deng et al.,
//! AAAI 2021): a submanifold input layer, then four stages — the first at full resolution, the
//! others opened by a stride-2 sparse convolution — of submanifold blocks, and a last
//! convolution down along z (kernel 3×1×1, stride 2×1×1). Every layer is conv → BN → ReLU.
//!
//! Train a SECOND: `pi3det train --config configs/second_cpu.toml --data DIR --out runs/second`.

use serde::{Deserialize, Serialize};
use tch::nn::{self, ModuleT};
use tch::Tensor;

use super::{Backbone3d, Backbone3dOutput};
use crate::error::{NnError, Result};
use crate::sparse::{SparseConv3d, SparseConv3dConfig, SparseTensor};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VoxelBackbone8xConfig {
    /// Channels of stages 1–4 (OpenPCDet: 16, 32, 64, 64).
    pub channels: [i64; 4],
    /// Submanifold blocks of each stage after its first layer (OpenPCDet: 1, 2, 2, 2; the first
    /// stage's first layer is the input layer).
    pub blocks: [usize; 4],
    /// Channels of the last (z-reducing) convolution (OpenPCDet: 128).
    pub out_channels: i64,
}

impl Default for VoxelBackbone8xConfig {
    fn default() -> Self {
        Self { channels: [16, 32, 64, 64], blocks: [1, 2, 2, 2], out_channels: 128 }
    }
}

/// The layers in order: (config, output channels), stage boundaries after entries `ends`.
fn layers(cfg: &VoxelBackbone8xConfig) -> (Vec<(SparseConv3dConfig, i64)>, [usize; 4]) {
    let mut v = Vec::new();
    let mut ends = [0; 4];
    let subm = |s: usize| SparseConv3dConfig::submanifold(3).with_key(&format!("subm{}", s + 1));
    for (s, end) in ends.iter_mut().enumerate() {
        let c = cfg.channels[s];
        v.push(match s {
            0 => (subm(0), c),
            // Stage 4 keeps z unpadded (OpenPCDet: padding (0, 1, 1)).
            3 => (SparseConv3dConfig::regular([3; 3], [2; 3], [0, 1, 1]).with_key("spconv4"), c),
            _ => (SparseConv3dConfig::regular([3; 3], [2; 3], [1; 3]).with_key(&format!("spconv{}", s + 1)), c),
        });
        for _ in 0..cfg.blocks[s] {
            v.push((subm(s), c));
        }
        *end = v.len();
    }
    v.push((SparseConv3dConfig::regular([3, 1, 1], [2, 1, 1], [0; 3]).with_key("spconv_down2"), cfg.out_channels));
    (v, ends)
}

impl VoxelBackbone8xConfig {
    /// Every layer's convolution and output channels, in order.
    pub fn layer_specs(&self) -> Vec<(SparseConv3dConfig, i64)> {
        layers(self).0
    }

    /// [`layer_specs`](Self::layer_specs) and the index after each of the four stages' last layer.
    pub fn stages(&self) -> (Vec<(SparseConv3dConfig, i64)>, [usize; 4]) {
        layers(self)
    }

    /// The output grid on an input grid of `shape` `[D, H, W]`.
    pub fn output_shape(&self, shape: [i64; 3]) -> [i64; 3] {
        layers(self).0.iter().fold(shape, |s, (c, _)| c.output_shape(s))
    }

    pub fn validate(&self, shape: [i64; 3]) -> Result<()> {
        if self.channels.iter().any(|&c| c < 1) || self.out_channels < 1 {
            return Err(NnError::config("backbone_3d", "backbone_3d: channels and out_channels must be positive"));
        }
        let mut s = shape;
        for (c, _) in &layers(self).0 {
            s = c.output_shape(s);
            if s.iter().any(|&d| d < 1) {
                return Err(NnError::config("backbone_3d", format!(
                    "backbone_3d: a sparse grid of {shape:?} (z × y × x, z padded by one) vanishes inside VoxelBackBone8x: it needs at least 25 voxels along z (set [pillars] voxel_height smaller)"
                )));
            }
        }
        if shape[1] % 8 != 0 || shape[2] % 8 != 0 {
            return Err(NnError::config(
                "backbone_3d",
                format!("backbone_3d: the voxel grid's y × x ({} × {}) must be divisible by 8", shape[1], shape[2]),
            ));
        }
        Ok(())
    }

    pub fn init(&self, vs: nn::Path, c_in: i64, bn: &crate::BatchNorm) -> VoxelBackbone8x {
        let (specs, ends) = layers(self);
        let mut c = c_in;
        let layers = specs
            .iter()
            .enumerate()
            .map(|(i, (spec, c_out))| {
                let p = &vs / format!("layer{i}");
                let conv = spec.init(&p / "conv", c, *c_out);
                let norm = nn::batch_norm1d(&p / "norm", *c_out, bn.config());
                c = *c_out;
                (conv, norm)
            })
            .collect();
        VoxelBackbone8x { layers, ends, eps: bn.eps }
    }
}

#[derive(Debug)]
pub struct VoxelBackbone8x {
    layers: Vec<(SparseConv3d, nn::BatchNorm)>,
    ends: [usize; 4],
    eps: f64,
}

impl VoxelBackbone8x {
    /// The same network on a dense grid with dense `conv3d`s (eval-mode batch norm): each layer's
    /// output masked to the sites the sparse network keeps active (a submanifold layer keeps its
    /// input's, a regular one every site its kernel reaches). What a dense implementation would
    /// cost (`pi3det bench sparse`), and a check of the sparse one.
    ///
    /// `x`: `[B, C_in, D, H, W]`, zero off the active sites; `mask`: `[B, 1, D, H, W]` of 0/1.
    pub fn forward_dense(&self, x: &Tensor, mask: &Tensor) -> Tensor {
        let (mut x, mut mask) = (x.shallow_clone(), mask.shallow_clone());
        for (conv, norm) in &self.layers {
            let c = conv.config();
            let y = x.conv3d(&conv.weight, conv.bias.as_ref(), c.stride, c.padding, [1, 1, 1], 1);
            if c.kind != crate::sparse::SparseConvKind::Submanifold {
                let ones = Tensor::ones([1, 1, c.kernel[0], c.kernel[1], c.kernel[2]], (mask.kind(), mask.device()));
                mask =
                    mask.conv3d(&ones, None::<Tensor>, c.stride, c.padding, [1, 1, 1], 1).gt(0.5).to_kind(mask.kind());
            }
            let y = Tensor::batch_norm(
                &y,
                norm.ws.as_ref(),
                norm.bs.as_ref(),
                Some(&norm.running_mean),
                Some(&norm.running_var),
                false,
                0.0,
                self.eps,
                false,
            );
            x = y.relu() * &mask;
        }
        x
    }
}

impl Backbone3d for VoxelBackbone8x {
    /// `x`: `[N, C_in]` voxels on `[D, H, W]` → `[N', out_channels]` on
    /// [`output_shape`](VoxelBackbone8xConfig::output_shape); stages at strides 1, 2, 4, 8.
    fn forward_t(&self, x: &SparseTensor, train: bool) -> Result<Backbone3dOutput> {
        let mut x = x.with_features(x.features.shallow_clone());
        let mut stages = Vec::with_capacity(4);
        for (i, (conv, norm)) in self.layers.iter().enumerate() {
            let y = conv.forward(&x)?;
            // Batch statistics need two rows (an empty or one-voxel batch uses the running ones).
            let f = norm.forward_t(&y.features, train && y.len() > 1).relu();
            x = y.with_features(f);
            if let Some(s) = self.ends.iter().position(|&e| e == i + 1) {
                stages.push((x.with_features(x.features.shallow_clone()), 1 << s));
            }
        }
        Ok(Backbone3dOutput { out: x, stages })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    /// OpenPCDet's KITTI shapes: [41, 1600, 1408] → [2, 200, 176] with 128 channels (256 in BEV).
    #[test]
    fn shapes_follow_openpcdet() {
        let cfg = VoxelBackbone8xConfig::default();
        assert_eq!(cfg.output_shape([41, 1600, 1408]), [2, 200, 176]);
        cfg.validate([41, 1600, 1408]).unwrap();
        assert!(cfg.validate([11, 64, 64]).unwrap_err().to_string().contains("voxel_height"));
        let vs = nn::VarStore::new(Device::Cpu);
        let small = VoxelBackbone8xConfig { channels: [4, 8, 8, 8], blocks: [1, 1, 1, 1], out_channels: 8 };
        let bb = small.init(vs.root(), 4, &crate::BatchNorm::default());
        let coords: Vec<_> = (0..60).map(|i| [i % 2, (i * 7) % 25, (i * 5) % 16, (i * 3) % 16]).collect();
        let mut uniq = coords.clone();
        uniq.sort();
        uniq.dedup();
        let f = Tensor::randn([uniq.len() as i64, 4], (Kind::Float, Device::Cpu));
        let x = SparseTensor::new(f, uniq, [25, 16, 16], 2).unwrap();
        let out = bb.forward_t(&x, true).unwrap();
        assert_eq!(out.out.spatial_shape, small.output_shape([25, 16, 16]));
        assert_eq!(out.out.spatial_shape, [1, 2, 2]);
        assert_eq!(
            out.stages.iter().map(|(s, k)| (s.spatial_shape[1], *k)).collect::<Vec<_>>(),
            [(16, 1), (8, 2), (4, 4), (2, 8)]
        );
        assert_eq!(out.out.channels(), 8);
    }

    /// In eval mode the sparse network equals the same weights as dense `conv3d`s masked to the
    /// active sites, layer after layer, down to the output.
    #[test]
    fn sparse_equals_dense_emulation() {
        tch::manual_seed(1);
        let mut vs = nn::VarStore::new(Device::Cpu);
        let small = VoxelBackbone8xConfig { channels: [4, 6, 6, 8], blocks: [1, 1, 1, 1], out_channels: 5 };
        let bb = small.init(vs.root(), 4, &crate::BatchNorm::default());
        vs.double();
        // Non-trivial running statistics.
        let _ = bb.forward_t(&random(0, 400), true).unwrap();
        let x = random(1, 300);
        let sparse = bb.forward_t(&x, false).unwrap().out;
        let ones = x.with_features(Tensor::ones([x.len() as i64, 1], (Kind::Double, Device::Cpu)));
        let dense = bb.forward_dense(&x.dense(), &ones.dense());
        let d = (sparse.dense() - &dense).abs().max().double_value(&[]);
        assert!(d < 1e-9, "sparse vs dense differ by {d}");
        assert!(!sparse.is_empty());
    }

    fn random(seed: u64, n: usize) -> SparseTensor {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut coords: Vec<_> = (0..n)
            .map(|_| {
                [rng.random_range(0..2), rng.random_range(0..25), rng.random_range(0..16), rng.random_range(0..16)]
            })
            .collect();
        coords.sort();
        coords.dedup();
        let f = Tensor::randn([coords.len() as i64, 4], (Kind::Double, Device::Cpu));
        SparseTensor::new(f, coords, [25, 16, 16], 2).unwrap()
    }
}
