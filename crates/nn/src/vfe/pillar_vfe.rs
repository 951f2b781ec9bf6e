//! Pillar feature net of PointPillars (Lang et al., CVPR 2019; OpenPCDet `PillarVFE`): a shared
//! `Linear → BatchNorm → ReLU` over each decorated point (see [`crate::pillarize`]) and a max over
//! the pillar's points. Stacked layers concatenate the pillar maximum back onto each point.

use serde::{Deserialize, Serialize};
use tch::nn::{self, Module, ModuleT};
use tch::Tensor;

use crate::pillarize::POINT_FEATURES;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PillarVfeConfig {
    /// Output channels of each point-net layer; the last is the BEV feature depth.
    pub num_filters: Vec<i64>,
}

impl Default for PillarVfeConfig {
    fn default() -> Self {
        Self { num_filters: vec![64] }
    }
}

impl PillarVfeConfig {
    pub fn out_channels(&self) -> i64 {
        self.num_filters.last().copied().unwrap_or(POINT_FEATURES as i64)
    }

    pub fn init(&self, vs: nn::Path, bn: &crate::BatchNorm) -> PillarVfe {
        let mut layers = Vec::new();
        let mut c_in = POINT_FEATURES as i64;
        let n = self.num_filters.len();
        for (i, &c) in self.num_filters.iter().enumerate() {
            let last = i + 1 == n;
            // Non-last layers output half their channels per point; the max is concatenated.
            let c_out = if last { c } else { c / 2 };
            let p = &vs / format!("pfn{i}");
            let linear = nn::linear(&p / "linear", c_in, c_out, nn::LinearConfig { bias: false, ..Default::default() });
            let norm = nn::batch_norm1d(&p / "norm", c_out, bn.config());
            layers.push((linear, norm, last));
            c_in = c;
        }
        PillarVfe { layers }
    }
}

#[derive(Debug)]
pub struct PillarVfe {
    layers: Vec<(nn::Linear, nn::BatchNorm, bool)>,
}

impl PillarVfe {
    /// `features`: `[P, M, 10]` decorated points (padding rows all zero) → `[P, C]`.
    pub fn forward_t(&self, features: &Tensor, train: bool) -> Tensor {
        // P stays symbolic (-1, expand_as) so a TorchScript trace runs on any pillar count.
        let (_, m, _) = features.size3().expect("pillar features are [P, M, F]");
        let mut x = features.shallow_clone();
        for (linear, norm, last) in &self.layers {
            let y = linear.forward(&x); // [P, M, C]
            let c = y.size()[2];
            let y = norm.forward_t(&y.view([-1, c]), train).view([-1, m, c]).relu();
            let max = y.amax([1].as_slice(), true); // [P, 1, C]
            if *last {
                return max.squeeze_dim(1);
            }
            let max = max.expand_as(&y);
            x = Tensor::cat(&[y, max], 2);
        }
        x.amax([1].as_slice(), false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn shapes() {
        let vs = nn::VarStore::new(Device::Cpu);
        let vfe = PillarVfeConfig { num_filters: vec![32, 64] }.init(vs.root(), &crate::BatchNorm::default());
        let x = Tensor::randn([5, 7, POINT_FEATURES as i64], (Kind::Float, Device::Cpu));
        assert_eq!(vfe.forward_t(&x, true).size(), vec![5, 64]);
        let vfe = PillarVfeConfig::default().init(vs.root() / "b", &crate::BatchNorm::default());
        assert_eq!(vfe.forward_t(&x, false).size(), vec![5, 64]);
    }
}
