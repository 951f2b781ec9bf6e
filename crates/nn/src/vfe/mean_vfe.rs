//! Mean voxel feature encoder (OpenPCDet `MeanVFE`, SECOND / Voxel R-CNN): each voxel's feature is
//! the mean (x, y, z, intensity) of its points. The averaging happens in the voxelizer
//! ([`crate::pillarize`]), so this layer only reshapes; it has no weights.

use tch::Tensor;

use crate::pillarize::VOXEL_FEATURES;

#[derive(Debug, Clone, Copy, Default)]
pub struct MeanVfe;

impl MeanVfe {
    pub fn out_channels(&self) -> i64 {
        VOXEL_FEATURES as i64
    }

    /// `features`: `[V, M, 4]` point means (M = 1 from the voxelizer) → `[V, 4]`.
    pub fn forward(&self, features: &Tensor) -> Tensor {
        features.mean_dim([1].as_slice(), false, features.kind())
    }
}
