//! The `map_to_bev` slot (OpenPCDet `map_to_bev`): the 3-D stage's output as the dense BEV map the
//! 2-D backbone takes — pillar features scattered back onto the grid (PointPillars), or a sparse
//! backbone's voxels with their height folded into channels (SECOND, Voxel R-CNN).

pub mod height_compression;
pub mod pointpillar_scatter;

pub use height_compression::height_compression;
pub use pointpillar_scatter::scatter;
