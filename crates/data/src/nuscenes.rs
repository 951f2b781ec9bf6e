//! nuScenes through mmdet3d v1.1 info files: a dict with `metainfo.categories` (name → label) and
//! `data_list`, one sample each with `lidar_points.lidar_path` (float32 ×5: x, y, z, intensity,
//! ring), `lidar2ego`, `ego2global` and `instances` whose `bbox_3d` is
//! `[x, y, z_gravity_centre, l, w, h, yaw]` in the LiDAR frame — already our box convention.

use std::path::{Path, PathBuf};

use pi3det_geometry::{Box3d, Pose, PoseExt};

use crate::dataset::{Dataset, Format};
use crate::error::DataError;
use crate::fields::Record;
use crate::frame::{CameraInfo, FrameInfo, Object, Platform};
use crate::pickle::{self, Value};
use crate::points::IntensityScale;

pub struct NuscenesDataset {
    root: PathBuf,
    frames: Vec<FrameInfo>,
}

/// Whether a decoded pickle looks like an mmdet3d v1.x info file.
pub fn looks_like_mmdet3d(v: &Value) -> bool {
    v.get("data_list").is_some() && v.get("metainfo").is_some()
}

impl NuscenesDataset {
    /// Opens an info `.pkl`; point files are looked up beside it, under `samples/LIDAR_TOP/`
    /// beside it, or under `data_root` when given.
    pub fn open(info_file: &Path, data_root: Option<&Path>) -> Result<Self, DataError> {
        let value = pickle::from_path(info_file)
            .map_err(|source| DataError::Pickle { path: info_file.to_path_buf(), source })?;
        Self::from_value(info_file, &value, data_root)
    }

    /// From an already decoded info file.
    pub fn from_value(info_file: &Path, value: &Value, data_root: Option<&Path>) -> Result<Self, DataError> {
        let dir = info_file.parent().unwrap_or(Path::new(".")).to_path_buf();
        let root = data_root.map(Path::to_path_buf).unwrap_or(dir);
        let top = Record { path: info_file, what: "info file".into() };
        let categories = top.get(top.get(value, "metainfo")?, "categories")?;
        let mut label_names: Vec<(i64, String)> = categories
            .as_dict()
            .ok_or_else(|| top.err("'metainfo.categories' should be a dict"))?
            .iter()
            .filter_map(|(k, v)| Some((v.as_i64()?, k.as_str()?.to_string())))
            .collect();
        label_names.sort();
        let samples = top.get(value, "data_list")?.as_list().ok_or_else(|| top.err("'data_list' should be a list"))?;
        let frames = samples
            .iter()
            .enumerate()
            .map(|(i, s)| parse_sample(info_file, &root, &label_names, i, s))
            .collect::<Result<_, _>>()?;
        Ok(Self { root, frames })
    }
}

fn resolve_points(root: &Path, lidar_path: &str) -> PathBuf {
    let candidates = [root.join(lidar_path), root.join("samples/LIDAR_TOP").join(lidar_path)];
    candidates.iter().find(|p| p.exists()).cloned().unwrap_or_else(|| candidates[0].clone())
}

fn parse_sample(
    file: &Path,
    root: &Path,
    labels: &[(i64, String)],
    index: usize,
    s: &Value,
) -> Result<FrameInfo, DataError> {
    let rec = Record { path: file, what: format!("data_list[{index}]") };
    let id = rec.opt_str(s, "token")?.unwrap_or_else(|| index.to_string());
    let lidar = rec.get(s, "lidar_points")?;
    let lidar_path = rec.str(lidar, "lidar_path")?;
    let mut info = FrameInfo::new(id, resolve_points(root, &lidar_path));
    let n_feats = rec.opt_f64(lidar, "num_pts_feats")?.unwrap_or(5.0) as usize;
    let extra = ["ring", "time", "extra"];
    info.point_channels.extend(extra.iter().take(n_feats.saturating_sub(4)).map(|s| s.to_string()));
    info.platform = Platform::Vehicle;
    // nuScenes stores the sensor's 8-bit intensity, and mmdet3d's infos pass it through.
    info.intensity_scale = IntensityScale::Byte;
    info.timestamp_s = rec.opt_f64(s, "timestamp")?;
    if let (Some(l2e), Some(e2g)) = (lidar.get("lidar2ego"), s.get("ego2global")) {
        let ego_from_lidar = Pose::try_from_matrix(&rec.square::<4>(l2e, "lidar2ego")?).map_err(|e| rec.err(e))?;
        let world_from_ego = Pose::try_from_matrix(&rec.square::<4>(e2g, "ego2global")?).map_err(|e| rec.err(e))?;
        info.world_from_lidar = Some(world_from_ego * ego_from_lidar);
    }
    if let Some(images) = s.get("images").filter(|v| !v.is_none()) {
        info.cameras = parse_cameras(&rec, root, images)?;
    }
    let instances = match s.get("instances") {
        Some(v) => v.as_list().ok_or_else(|| rec.err("'instances' should be a list"))?,
        None => &[],
    };
    for (k, inst) in instances.iter().enumerate() {
        let r = Record { path: file, what: format!("data_list[{index}].instances[{k}]") };
        let row = r.matrix(&Value::List(vec![r.get(inst, "bbox_3d")?.clone()]), "bbox_3d", 7)?.remove(0);
        let b = Box3d::try_from_array(std::array::from_fn(|j| row[j])).map_err(|e| r.err(e))?;
        let label =
            r.get(inst, "bbox_label_3d")?.as_i64().ok_or_else(|| r.err("'bbox_label_3d' should be an integer"))?;
        // mmdet3d marks classes outside its list with -1; keep them under a visible name.
        let name = labels.iter().find(|(l, _)| *l == label).map_or_else(|| format!("label{label}"), |(_, n)| n.clone());
        let mut o = Object::new(name, b);
        o.num_points = inst.get("num_lidar_pts").and_then(Value::as_i64).and_then(|n| u32::try_from(n).ok());
        info.objects.push(o);
    }
    Ok(info)
}

/// The image of a camera: mmdet3d writes a bare file name (its `data_prefix` adds
/// `samples/CAM_X/`) or a path relative to the data root. The first candidate that exists, else
/// the first one.
fn resolve_image(root: &Path, camera: &str, img_path: &str) -> PathBuf {
    let rel = Path::new(img_path);
    let mut candidates = vec![root.join(rel), root.join("samples").join(camera).join(rel)];
    if let Some(name) = rel.file_name() {
        candidates.push(root.join(name));
        candidates.push(root.join("samples").join(camera).join(name));
    }
    candidates.iter().find(|p| p.exists()).cloned().unwrap_or_else(|| candidates.swap_remove(0))
}

/// `images`: camera name → `img_path`, `cam2img` (3×3, or 3×4 whose last column is folded into
/// the extrinsics), `lidar2cam` (4×4). Cameras without `cam2img` or `lidar2cam` (mmdet3d leaves
/// them out for samples without that camera) are skipped; malformed ones are an error.
fn parse_cameras(rec: &Record, root: &Path, images: &Value) -> Result<Vec<CameraInfo>, DataError> {
    let dict = images.as_dict().ok_or_else(|| rec.err("'images' should be a dict"))?;
    let mut cameras = Vec::new();
    for (key, cam) in dict.iter() {
        let Some(name) = key.as_str() else { continue };
        let (Some(c2i), Some(l2c)) = (cam.get("cam2img"), cam.get("lidar2cam")) else { continue };
        let r = Record { path: rec.path, what: format!("{}.images.{name}", rec.what) };
        let mut camera_from_lidar = r.square::<4>(l2c, "lidar2cam")?;
        let rows = r.matrix(c2i, "cam2img", 3)?;
        if !(3..=4).contains(&rows.len()) || rows.iter().any(|row| row.len() != rows[0].len()) || rows[0].len() > 4 {
            return Err(r.err("'cam2img' should be 3x3, 3x4 or 4x4"));
        }
        let intrinsics: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| rows[i][j]));
        if rows[0].len() == 4 {
            // [K | p4]: the camera centre is shifted by K⁻¹·p4 (as KITTI's P2).
            let k = nalgebra::Matrix3::from_fn(|i, j| intrinsics[i][j]);
            let p4 = nalgebra::Vector3::new(rows[0][3], rows[1][3], rows[2][3]);
            let t = k.try_inverse().ok_or_else(|| r.err("'cam2img' is singular"))? * p4;
            // [I | t] · M adds t_i · (M's last row) to row i.
            let last = camera_from_lidar[3];
            for (i, row) in camera_from_lidar.iter_mut().take(3).enumerate() {
                for (v, l) in row.iter_mut().zip(last) {
                    *v += t[i] * l;
                }
            }
        }
        let image_path = r.opt_str(cam, "img_path")?.map(|p| resolve_image(root, name, &p));
        cameras.push(CameraInfo {
            name: name.to_string(),
            image_path,
            camera_from_lidar,
            intrinsics,
            distortion: Vec::new(),
            image_size: Some([1600, 900]),
        });
    }
    Ok(cameras)
}

impl Dataset for NuscenesDataset {
    fn format(&self) -> Format {
        Format::Nuscenes
    }
    fn root(&self) -> &Path {
        &self.root
    }
    fn len(&self) -> usize {
        self.frames.len()
    }
    fn info(&self, index: usize) -> Result<FrameInfo, DataError> {
        self.frames
            .get(index)
            .cloned()
            .ok_or_else(|| DataError::invalid(&self.root, format!("frame index {index} out of range")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(m: &[&[f64]]) -> Value {
        Value::List(m.iter().map(|r| Value::List(r.iter().map(|&x| Value::Float(x)).collect())).collect())
    }

    fn info(images: Value) -> Value {
        let sample = Value::dict([
            ("token", Value::Str("t0".into())),
            ("lidar_points", Value::dict([("lidar_path", Value::Str("x.bin".into()))])),
            ("images", images),
        ]);
        Value::dict([
            ("metainfo", Value::dict([("categories", Value::dict([("car", Value::Int(0))]))])),
            ("data_list", Value::List(vec![sample])),
        ])
    }

    const ID4: &[&[f64]] = &[&[1., 0., 0., 0.], &[0., 1., 0., 0.], &[0., 0., 1., 0.], &[0., 0., 0., 1.]];

    #[test]
    fn cameras_with_3x4_cam2img_fold_the_offset_into_the_extrinsics() {
        // [K | K·(0.5, 0, 0)] with K = diag(100, 100, 1): the camera sits 0.5 m along −x.
        let k34: &[&[f64]] = &[&[100., 0., 10., 50.], &[0., 100., 20., 0.], &[0., 0., 1., 0.]];
        let images = Value::dict([
            (
                "CAM_A",
                Value::dict([
                    ("img_path", Value::Str("a.jpg".into())),
                    ("cam2img", rows(k34)),
                    ("lidar2cam", rows(ID4)),
                ]),
            ),
            // mmdet3d leaves a missing camera's matrices out: skipped.
            ("CAM_B", Value::dict([("img_path", Value::Str("b.jpg".into()))])),
        ]);
        let dir = Path::new("/nonexistent");
        let ds = NuscenesDataset::from_value(&dir.join("i.pkl"), &info(images), None).unwrap();
        let f = ds.info(0).unwrap();
        assert_eq!(f.cameras.len(), 1);
        let c = &f.cameras[0];
        assert_eq!(c.name, "CAM_A");
        assert_eq!(c.intrinsics, [[100., 0., 10.], [0., 100., 20.], [0., 0., 1.]]);
        assert!((c.camera_from_lidar[0][3] - 0.5).abs() < 1e-12, "{:?}", c.camera_from_lidar);
        assert_eq!(c.camera_from_lidar[1][3], 0.0);
        // Not found anywhere: the first candidate (beside the info file) is kept.
        assert_eq!(c.image_path.as_deref(), Some(dir.join("a.jpg").as_path()));
    }

    #[test]
    fn malformed_cam2img_names_the_camera_and_key() {
        let images = Value::dict([(
            "CAM_A",
            Value::dict([("cam2img", rows(&[&[1., 0.], &[0., 1.]])), ("lidar2cam", rows(ID4))]),
        )]);
        let e = NuscenesDataset::from_value(Path::new("i.pkl"), &info(images), None).err().unwrap().to_string();
        assert!(e.contains("images.CAM_A") && e.contains("cam2img"), "{e}");
    }
}
