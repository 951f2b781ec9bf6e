//! Necks: BEV map → BEV map, between the 2D backbone and the dense head (the model chain's
//! `neck` slot). A neck implements [`Neck`] and gets a variant in [`NeckConfig`] with its `init`
//! arm. [`gtd`]: Pi3DET-Net's Geometry-aware Transformation Descriptor.

pub mod gtd;

use serde::{Deserialize, Serialize};
use tch::nn;
use tch::Tensor;

pub use gtd::{Gtd, GtdConfig};

/// What a neck returns: the map for the heads, and what auxiliary losses need.
pub struct NeckOutput {
    pub bev: Tensor,
    /// `[B, 2]` predicted (roll, pitch) of the frame in degrees (GTD).
    pub rotation_deg: Option<Tensor>,
}

/// A BEV-to-BEV module.
pub trait Neck {
    /// `bev`: `[B, C, H, W]` → `[B, C', H, W]` with `C' = out_channels()`.
    fn forward_t(&self, bev: &Tensor, train: bool) -> NeckOutput;
    fn out_channels(&self) -> i64;
    /// λ of the rotation loss, for necks that predict the frame's rotation.
    fn rotation_weight(&self) -> f64 {
        0.0
    }
}

/// The necks there are (`[neck] type = "gtd"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum NeckConfig {
    Gtd(GtdConfig),
}

impl NeckConfig {
    pub fn validate(&self) -> crate::Result<()> {
        match self {
            Self::Gtd(c) => c.validate(),
        }
    }

    /// Builds the neck on `in_channels` BEV channels.
    pub fn init(&self, vs: nn::Path, in_channels: i64, _bn: &crate::BatchNorm) -> Box<dyn Neck> {
        match self {
            Self::Gtd(c) => Box::new(c.init(vs, in_channels)),
        }
    }
}
