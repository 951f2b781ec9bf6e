//! Geometry for LiDAR 3D detection in f64: upright boxes `[x, y, z_center, dx, dy, dz, heading]`
//! in the LiDAR frame (the OpenPCDet / Pi3DET convention), SE(3) poses named by frames, exact
//! rotated BEV / 3D IoU by convex polygon clipping, rotated NMS, and KITTI camera ↔ LiDAR boxes.

pub mod box_fusion;
pub mod boxes;
pub mod iou;
pub mod kitti;
pub mod nms;
pub mod polygon;
pub mod pose;
pub mod view;

pub use box_fusion::{weighted_box_fusion, BoxFusionConfig, FusedBox, FusionMember};
pub use boxes::Box3d;
pub use iou::{bev_iou, bev_iou_matrix, iou_3d, iou_3d_matrix, BevFootprint, IouMatrix};
pub use nms::{nms, NmsConfig};
pub use pose::{level_from_sensor, Pose, PoseExt, RollPitchYaw};
pub use view::View;

/// Errors of geometric conversions fed with user data.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GeometryError {
    #[error("box has a non-finite value: {0:?}")]
    NonFiniteBox([f64; 7]),
    #[error("box has a negative size: {0:?}")]
    NegativeSize([f64; 7]),
    #[error("matrix is not a rigid transform (rotation part not orthonormal to 1e-4 or last row not 0,0,0,1): {0}")]
    NotRigid(String),
}
