//! The `backbone_3d` slot: sparse 3-D convolutional backbones over voxels ([`crate::sparse`]);
//! [`crate::map_to_bev`] turns their output into the BEV map the 2-D backbone takes.

pub mod voxel_backbone_8x;

use serde::{Deserialize, Serialize};
use tch::nn;

pub use voxel_backbone_8x::{VoxelBackbone8x, VoxelBackbone8xConfig};

use crate::error::Result;
use crate::sparse::SparseTensor;

/// What a 3-D backbone computed: its output and the per-stage features (finest first) with
/// their strides, for RoI heads that pool from voxels (Voxel R-CNN).
pub struct Backbone3dOutput {
    pub out: SparseTensor,
    pub stages: Vec<(SparseTensor, i64)>,
}

pub trait Backbone3d: std::fmt::Debug {
    /// `x`: voxel features `[N, C_in]` on a `[D, H, W]` grid → the backbone's sparse output.
    fn forward_t(&self, x: &SparseTensor, train: bool) -> Result<Backbone3dOutput>;
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum Backbone3dConfig {
    /// OpenPCDet's `VoxelBackBone8x` (SECOND, Voxel R-CNN, PV-RCNN).
    #[serde(rename = "voxel_backbone_8x")]
    VoxelBackbone8x(VoxelBackbone8xConfig),
}

impl Backbone3dConfig {
    pub fn validate(&self, input_shape: [i64; 3]) -> Result<()> {
        match self {
            Self::VoxelBackbone8x(c) => c.validate(input_shape),
        }
    }

    /// The sparse grid of a voxel grid of `nz × ny × nx` cells (OpenPCDet pads z by one).
    pub fn input_shape(nz: usize, ny: usize, nx: usize) -> [i64; 3] {
        [nz as i64 + 1, ny as i64, nx as i64]
    }

    /// Down-sampling of the output in x and y.
    pub fn xy_stride(&self) -> i64 {
        match self {
            Self::VoxelBackbone8x(_) => 8,
        }
    }

    /// Channels of stages 1–4.
    pub fn stage_channels(&self) -> Vec<i64> {
        match self {
            Self::VoxelBackbone8x(c) => c.channels.to_vec(),
        }
    }

    /// Channels of the BEV map after height compression.
    pub fn bev_channels(&self, input_shape: [i64; 3]) -> i64 {
        match self {
            Self::VoxelBackbone8x(c) => c.out_channels * c.output_shape(input_shape)[0],
        }
    }

    pub fn init(&self, vs: nn::Path, c_in: i64, bn: &crate::BatchNorm) -> Box<dyn Backbone3d> {
        match self {
            Self::VoxelBackbone8x(c) => Box::new(c.init(vs, c_in, bn)),
        }
    }
}
