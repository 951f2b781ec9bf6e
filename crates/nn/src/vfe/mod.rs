//! Voxel / pillar feature encoders.

pub mod pillar_vfe;

pub use pillar_vfe::{PillarVfe, PillarVfeConfig};
