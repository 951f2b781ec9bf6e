//! Voxel / pillar feature encoders: the pillar feature net for pillar grids, the mean of each
//! voxel's points for voxel grids (`[pillars] voxel_height`).

pub mod mean_vfe;
pub mod pillar_vfe;

pub use mean_vfe::MeanVfe;
pub use pillar_vfe::{PillarVfe, PillarVfeConfig};

use tch::Tensor;

/// The `vfe` slot: which encoder follows from the grid.
#[derive(Debug)]
pub enum Vfe {
    Pillar(PillarVfe),
    Mean(MeanVfe),
}

impl Vfe {
    /// `[P, M, F]` → `[P, C]`.
    pub fn forward_t(&self, features: &Tensor, train: bool) -> Tensor {
        match self {
            Vfe::Pillar(v) => v.forward_t(features, train),
            Vfe::Mean(v) => v.forward(features),
        }
    }
}
