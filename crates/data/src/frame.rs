//! The in-memory frame every reader produces and every consumer takes.

use std::fmt;
use std::path::PathBuf;

use pi3det_geometry::kitti::KittiCalib;
use pi3det_geometry::{Box3d, Pose};
use serde::{Deserialize, Serialize};

use crate::points::{IntensityScale, PointCloud};

/// The platform carrying the sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Platform {
    Vehicle,
    Drone,
    Quadruped,
    #[default]
    Unknown,
}

impl Platform {
    pub const ALL: [Platform; 3] = [Platform::Vehicle, Platform::Drone, Platform::Quadruped];

    /// Accepts Pi3DET's names and the M3ED robot names (Car, Falcon, Spot); anything else is
    /// `Unknown`.
    pub fn parse(s: &str) -> Self {
        match s.trim().to_ascii_lowercase().as_str() {
            "vehicle" | "car" => Platform::Vehicle,
            "drone" | "falcon" | "uav" => Platform::Drone,
            "quadruped" | "spot" | "legged" => Platform::Quadruped,
            _ => Platform::Unknown,
        }
    }

    pub fn as_str(&self) -> &'static str {
        match self {
            Platform::Vehicle => "vehicle",
            Platform::Drone => "drone",
            Platform::Quadruped => "quadruped",
            Platform::Unknown => "unknown",
        }
    }
}

impl fmt::Display for Platform {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Fields only KITTI labels carry; the evaluator uses them for difficulty and the bbox/AOS metrics.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct KittiFields {
    pub truncation: f64,
    /// 0 visible, 1 partly, 2 largely occluded, 3 unknown.
    pub occlusion: i32,
    pub alpha: f64,
    /// Image box `[x1, y1, x2, y2]` in pixels.
    pub bbox_2d: [f64; 4],
}

/// One annotated (or detected) object. The class is kept as the dataset's own string, so
/// unknown names survive a round trip; mapping to evaluation classes happens in the evaluator.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Object {
    pub name: String,
    pub box3d: Box3d,
    /// Detection confidence; `None` for ground truth.
    pub score: Option<f64>,
    /// Points inside the box as the dataset stored it (nuScenes `num_lidar_pts`, simulator).
    pub num_points: Option<u32>,
    pub kitti: Option<KittiFields>,
}

impl Object {
    pub fn new(name: impl Into<String>, box3d: Box3d) -> Self {
        Self { name: name.into(), box3d, score: None, num_points: None, kitti: None }
    }
}

/// Sensor calibration a frame may carry.
#[derive(Debug, Clone, PartialEq)]
pub enum Calib {
    Kitti(KittiCalib),
    /// Pi3DET's `calib`: `E` 4×4 LiDAR→camera, `I` 3×3 intrinsics, `D` distortion.
    Pinhole {
        camera_from_lidar: [[f64; 4]; 4],
        intrinsics: [[f64; 3]; 3],
        distortion: Vec<f64>,
    },
}

/// One camera of a frame, as a pinhole model with OpenCV plumb-bob distortion: a LiDAR point `p`
/// reaches pixels as `intrinsics · distort(camera_from_lidar · p)`. Filled by the nuScenes (six
/// cameras of `images`), Pi3DET (`calib` + `image_path`) and KITTI (P2 split into intrinsics and
/// a translation) readers.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    pub name: String,
    /// Where the image should be (resolved against the dataset root); it may not exist.
    pub image_path: Option<PathBuf>,
    pub camera_from_lidar: [[f64; 4]; 4],
    pub intrinsics: [[f64; 3]; 3],
    /// `k1 k2 p1 p2 k3` (OpenCV order; shorter lists mean the rest are 0; empty: none).
    pub distortion: Vec<f64>,
    /// The dataset's usual image size `[width, height]`, for drawing when the image is missing;
    /// the image file's own size wins when it is read.
    pub image_size: Option<[u32; 2]>,
}

impl CameraInfo {
    /// KITTI's left colour camera: `P2 = K·[I | t]`, so `K` is P2's left 3×3 block and
    /// `camera_from_lidar = [I | K⁻¹·p4] · R0_rect · Tr_velo_to_cam` (the rectified camera
    /// shifted to camera 2's centre, so the near plane is the real one).
    pub fn from_kitti(calib: &KittiCalib, image_path: Option<PathBuf>) -> Self {
        let k = calib.p2.fixed_view::<3, 3>(0, 0).into_owned();
        let t = k.try_inverse().map(|ki| ki * calib.p2.column(3)).unwrap_or_else(nalgebra::Vector3::zeros);
        let mut shift = nalgebra::Matrix4::identity();
        shift.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
        let m = shift * calib.rect_from_lidar();
        Self {
            name: "image_2".into(),
            image_path,
            camera_from_lidar: std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)])),
            intrinsics: std::array::from_fn(|i| std::array::from_fn(|j| k[(i, j)])),
            distortion: Vec::new(),
            image_size: Some([1242, 375]),
        }
    }
}

/// Everything about a frame except its points: what a dataset index holds, cheap to load for
/// evaluation and statistics.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameInfo {
    pub id: String,
    pub platform: Platform,
    pub sequence: Option<String>,
    pub timestamp_s: Option<f64>,
    pub objects: Vec<Object>,
    /// KITTI DontCare regions (image boxes): detections inside them are ignored by the bbox metric.
    pub dont_care: Vec<[f64; 4]>,
    pub world_from_lidar: Option<Pose>,
    pub calib: Option<Calib>,
    /// The frame's cameras (empty when the dataset has none).
    pub cameras: Vec<CameraInfo>,
    /// The point file and its float32 channels (x, y, z, intensity, extras…).
    pub points_path: PathBuf,
    pub point_channels: Vec<String>,
    /// The scale the point file stores intensity in; loading brings it to [0, 1].
    pub intensity_scale: IntensityScale,
}

impl FrameInfo {
    pub fn new(id: impl Into<String>, points_path: PathBuf) -> Self {
        Self {
            id: id.into(),
            platform: Platform::Unknown,
            sequence: None,
            timestamp_s: None,
            objects: Vec::new(),
            dont_care: Vec::new(),
            world_from_lidar: None,
            calib: None,
            cameras: Vec::new(),
            points_path,
            point_channels: PointCloud::XYZI.iter().map(|s| s.to_string()).collect(),
            intensity_scale: IntensityScale::Unit,
        }
    }
}

/// A LiDAR frame: its info and its points.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub info: FrameInfo,
    pub points: PointCloud,
}

impl Frame {
    /// Number of points inside each object's box (inclusive test), counted on this frame's points.
    pub fn points_per_object(&self) -> Vec<usize> {
        self.info.objects.iter().map(|o| o.box3d.count_points(self.points.xyz_f64())).collect()
    }
}
