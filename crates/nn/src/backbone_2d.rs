//! BEV backbone of PointPillars / SECOND (OpenPCDet `BaseBEVBackbone`): blocks of 3×3 convolutions,
//! each starting with a strided one, and per block a transposed convolution back to a common
//! resolution; the upsampled maps are concatenated.

use serde::{Deserialize, Serialize};
use tch::nn::{self, ModuleT};
use tch::Tensor;

use crate::error::{NnError, Result};
use crate::precision::{conv2d, conv_transpose2d};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Backbone2dConfig {
    /// Extra (stride 1) convolutions after each block's strided one.
    pub layer_nums: Vec<usize>,
    pub layer_strides: Vec<i64>,
    pub num_filters: Vec<i64>,
    /// Upsampling factor of each block's output (1: a 1×1 convolution).
    pub upsample_strides: Vec<i64>,
    pub num_upsample_filters: Vec<i64>,
}

impl Default for Backbone2dConfig {
    /// OpenPCDet's PointPillars (reference §6).
    fn default() -> Self {
        Self {
            layer_nums: vec![3, 5, 5],
            layer_strides: vec![2, 2, 2],
            num_filters: vec![64, 128, 256],
            upsample_strides: vec![1, 2, 4],
            num_upsample_filters: vec![128, 128, 128],
        }
    }
}

impl Backbone2dConfig {
    pub fn validate(&self) -> Result<()> {
        let n = self.layer_nums.len();
        if n == 0
            || self.layer_strides.len() != n
            || self.num_filters.len() != n
            || self.upsample_strides.len() != n
            || self.num_upsample_filters.len() != n
        {
            return Err(NnError::config("backbone_2d", "backbone: layer_nums, layer_strides, num_filters, upsample_strides and num_upsample_filters must have the same non-zero length"));
        }
        if self.layer_strides.iter().chain(&self.upsample_strides).chain(&self.num_filters).any(|&v| v < 1) {
            return Err(NnError::config("backbone_2d", "backbone: strides and filters must be positive"));
        }
        // All upsampled maps must share one resolution.
        let mut stride = 1;
        let mut out = None;
        for (s, u) in self.layer_strides.iter().zip(&self.upsample_strides) {
            stride *= s;
            if stride % u != 0 {
                return Err(NnError::config(
                    "backbone_2d",
                    format!("backbone: block stride {stride} is not divisible by upsample {u}"),
                ));
            }
            let o = stride / u;
            if *out.get_or_insert(o) != o {
                return Err(NnError::config("backbone_2d", "backbone: upsampled maps have different strides"));
            }
        }
        Ok(())
    }

    /// Stride of the output map relative to the input grid.
    pub fn output_stride(&self) -> i64 {
        self.layer_strides[0] / self.upsample_strides[0]
    }

    pub fn out_channels(&self) -> i64 {
        self.num_upsample_filters.iter().sum()
    }

    pub fn init(&self, vs: nn::Path, in_channels: i64, bn: &crate::BatchNorm) -> Backbone2d {
        let conv = |p: nn::Path, i: i64, o: i64, stride: i64| {
            conv2d(p, i, o, 3, nn::ConvConfig { stride, padding: 1, bias: false, ..Default::default() })
        };
        let mut blocks = Vec::new();
        let mut deblocks = Vec::new();
        let mut c_in = in_channels;
        for b in 0..self.layer_nums.len() {
            let c = self.num_filters[b];
            let p = &vs / format!("block{b}");
            let mut seq = nn::seq_t()
                .add(conv(&p / "conv0", c_in, c, self.layer_strides[b]))
                .add(nn::batch_norm2d(&p / "bn0", c, bn.config()))
                .add_fn(|x| x.relu());
            for k in 1..=self.layer_nums[b] {
                seq = seq
                    .add(conv(&p / format!("conv{k}"), c, c, 1))
                    .add(nn::batch_norm2d(&p / format!("bn{k}"), c, bn.config()))
                    .add_fn(|x| x.relu());
            }
            blocks.push(seq);
            let u = self.upsample_strides[b];
            let uc = self.num_upsample_filters[b];
            let p = &vs / format!("deblock{b}");
            let up = nn::seq_t()
                .add(conv_transpose2d(
                    &p / "deconv",
                    c,
                    uc,
                    u,
                    nn::ConvTransposeConfig { stride: u, bias: false, ..Default::default() },
                ))
                .add(nn::batch_norm2d(&p / "bn", uc, bn.config()))
                .add_fn(|x| x.relu());
            deblocks.push(up);
            c_in = c;
        }
        Backbone2d { blocks, deblocks }
    }
}

#[derive(Debug)]
pub struct Backbone2d {
    blocks: Vec<nn::SequentialT>,
    deblocks: Vec<nn::SequentialT>,
}

impl Backbone2d {
    /// `[B, C_in, ny, nx]` → `[B, Σ upsample filters, ny / s, nx / s]` with `s` the output stride
    /// (input sides must be divisible by the product of the layer strides), in `x`'s kind.
    pub fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        let mut x = x.shallow_clone();
        let mut ups = Vec::with_capacity(self.blocks.len());
        for (block, deblock) in self.blocks.iter().zip(&self.deblocks) {
            x = block.forward_t(&x, train);
            ups.push(deblock.forward_t(&x, train));
        }
        if ups.len() == 1 {
            return ups.pop().unwrap_or(x);
        }
        Tensor::cat(&ups, 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn shapes_and_validation() {
        let cfg = Backbone2dConfig {
            layer_nums: vec![1, 1, 1],
            layer_strides: vec![2, 2, 2],
            num_filters: vec![8, 16, 32],
            upsample_strides: vec![1, 2, 4],
            num_upsample_filters: vec![8, 8, 8],
        };
        cfg.validate().unwrap();
        assert_eq!(cfg.output_stride(), 2);
        let vs = nn::VarStore::new(Device::Cpu);
        let bb = cfg.init(vs.root(), 4, &crate::BatchNorm::default());
        let y = bb.forward_t(&Tensor::randn([2, 4, 32, 48], (Kind::Float, Device::Cpu)), true);
        assert_eq!(y.size(), vec![2, 24, 16, 24]);
        let mut bad = cfg.clone();
        bad.upsample_strides = vec![1, 1, 4];
        assert!(bad.validate().is_err());
        bad.upsample_strides = vec![1, 2];
        assert!(bad.validate().is_err());
    }
}
