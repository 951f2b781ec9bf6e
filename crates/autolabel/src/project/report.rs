//! `projection_report.json`: per frame, per camera what was drawn on, per box which cameras see
//! it and whether it is outside every image or behind every camera.

use std::fmt;

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Source {
    Gt,
    Det,
}

/// Why a box is not seen by any camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Flag {
    /// Every corner is behind the near plane of every camera.
    BehindAllCameras,
    /// In front of some camera, but no drawn edge falls inside any image.
    OutsideAllImages,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BoxReport {
    pub source: Source,
    pub class: String,
    pub score: Option<f64>,
    /// `[x, y, z_center, dx, dy, dz, heading]`, LiDAR frame.
    pub box_lidar: [f64; 7],
    /// Cameras in whose image part of the box is drawn.
    pub cameras: Vec<String>,
    pub flag: Option<Flag>,
    /// First stdout line of `--verify-cmd` on the box's crop.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub verify: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub verify_error: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraReport {
    pub name: String,
    /// The image drawn on, or `"none, canvas"` when it is missing (with the path looked for).
    pub image: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub image_missing: Option<String>,
    pub width: u32,
    pub height: u32,
    /// The written drawing, relative to `--out`.
    pub output: String,
    pub boxes_seen: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameReport {
    pub frame_id: String,
    pub index: usize,
    pub cameras: Vec<CameraReport>,
    /// Set when the frame could not be checked (no calibration).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub message: Option<String>,
    pub boxes: Vec<BoxReport>,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub frames: usize,
    pub images_written: usize,
    pub frames_without_calibration: usize,
    pub cameras_without_image: usize,
    pub boxes_gt: usize,
    pub boxes_det: usize,
    pub seen: usize,
    pub outside_all_images: usize,
    pub behind_all_cameras: usize,
    /// Boxes of frames without calibration (neither seen nor flagged).
    pub unchecked: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProjectionReport {
    pub data: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub det: Option<String>,
    pub summary: Summary,
    pub frames: Vec<FrameReport>,
}

impl Summary {
    pub fn of(frames: &[FrameReport]) -> Self {
        let mut s = Summary { frames: frames.len(), ..Default::default() };
        for f in frames {
            s.images_written += f.cameras.len();
            s.cameras_without_image += f.cameras.iter().filter(|c| c.image_missing.is_some()).count();
            s.frames_without_calibration += usize::from(f.message.is_some());
            for b in &f.boxes {
                match b.source {
                    Source::Gt => s.boxes_gt += 1,
                    Source::Det => s.boxes_det += 1,
                }
                match (b.flag, f.message.is_some()) {
                    (_, true) => s.unchecked += 1,
                    (Some(Flag::BehindAllCameras), _) => s.behind_all_cameras += 1,
                    (Some(Flag::OutsideAllImages), _) => s.outside_all_images += 1,
                    (None, _) => s.seen += 1,
                }
            }
        }
        s
    }
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} frames, {} images: {} boxes ({} gt, {} det): {} seen, {} outside all images, {} behind all cameras",
            self.frames,
            self.images_written,
            self.boxes_gt + self.boxes_det,
            self.boxes_gt,
            self.boxes_det,
            self.seen,
            self.outside_all_images,
            self.behind_all_cameras
        )?;
        if self.frames_without_calibration > 0 {
            write!(
                f,
                "; {} frames without calibration ({} boxes unchecked)",
                self.frames_without_calibration, self.unchecked
            )?;
        }
        if self.cameras_without_image > 0 {
            write!(f, "; {} cameras drawn on a blank canvas (image missing)", self.cameras_without_image)?;
        }
        Ok(())
    }
}
