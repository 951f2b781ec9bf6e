//! Dense (single-stage) detection heads on the BEV feature map.

pub mod anchor_head;
pub mod center_head;

pub use anchor_head::{AnchorHead, AnchorHeadConfig};
pub use center_head::{CenterHead, CenterHeadConfig};
