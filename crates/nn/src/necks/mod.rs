//! Necks: BEV map → BEV map, between the 2D backbone and the dense head (the model chain's
//! `neck` slot; Pi3DET-Net's Geometry-aware Transformation Descriptor goes here). A neck
//! implements [`Neck`] and gets a variant in [`NeckConfig`] with its `init` arm.

use serde::{Deserialize, Serialize};
use tch::nn;
use tch::Tensor;

/// A BEV-to-BEV module.
pub trait Neck {
    /// `bev`: `[B, C, H, W]` → `[B, C', H, W]` with `C' = out_channels()`.
    fn forward_t(&self, bev: &Tensor, train: bool) -> Tensor;
    fn out_channels(&self) -> i64;
}

/// The necks there are (none yet: the slot stays empty unless a config names one).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NeckConfig {}

impl NeckConfig {
    /// Builds the neck on `in_channels` BEV channels.
    pub fn init(&self, _vs: nn::Path, _in_channels: i64, _bn: &crate::BatchNorm) -> Box<dyn Neck> {
        match *self {}
    }
}
