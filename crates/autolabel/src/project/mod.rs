//! Camera projection check (`pi3det project`): 3-D boxes drawn into the dataset's camera images
//! through its calibration, boxes no camera sees flagged, and an optional external class check.

pub mod camera;
pub mod check;
pub mod draw;
pub mod report;
pub mod verify;
pub mod wireframe;

pub use camera::{CameraModel, NEAR};
pub use check::{frame_cameras, frame_items, project, project_frame, FrameRange, ImageKind, Item, ProjectOptions};
pub use report::{BoxReport, CameraReport, Flag, FrameReport, ProjectionReport, Source, Summary};
pub use wireframe::{view_box, BoxView};
