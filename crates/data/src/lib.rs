//! Frames and the dataset formats people have on disk: the released Pi3DET layout (`.bin` +
//! numpy pickles), KITTI object and nuScenes (mmdet3d info files).

pub mod dataset;
pub mod error;
mod fields;
pub mod frame;
pub mod io;
pub mod kitti;
pub mod nuscenes;
pub mod pi3det;
pub mod pickle;
pub mod points;
pub mod summary;

pub use dataset::{open, Dataset, Format, FrameMap, Mapped};
pub use error::DataError;
pub use frame::{Calib, CameraInfo, Frame, FrameInfo, KittiFields, Object, Platform};
pub use points::{read_bin, write_bin, IntensityCheck, IntensityScale, PointCloud};
