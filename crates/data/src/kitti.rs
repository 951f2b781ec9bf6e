//! KITTI object layout: `velodyne/<id>.bin`, `label_2/<id>.txt` (camera-frame boxes, bottom
//! centre), `calib/<id>.txt`. Boxes are converted to the LiDAR frame through the calibration;
//! DontCare lines become ignore regions; truncation, occlusion, alpha and the 2D box are kept for
//! evaluation. Also writes KITTI result files (label lines with a score) for the official devkit.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Matrix3x4};
use pi3det_geometry::kitti::{alpha_from_lidar, fake_camera_box, CameraBox, KittiCalib, FAKE_BBOX_2D};

use crate::dataset::{Dataset, Format};
use crate::error::DataError;
use crate::frame::{Calib, CameraInfo, FrameInfo, KittiFields, Object, Platform};
use crate::io::write_atomic;

pub struct KittiDataset {
    root: PathBuf,
    ids: Vec<String>,
}

impl KittiDataset {
    /// Opens a split folder holding `velodyne/` (e.g. `kitti/training`), or a KITTI root holding
    /// `training/`.
    pub fn open(path: &Path) -> Result<Self, DataError> {
        let root = if path.join("velodyne").is_dir() { path.to_path_buf() } else { path.join("training") };
        let velodyne = root.join("velodyne");
        if !velodyne.is_dir() {
            return Err(DataError::UnknownFormat { path: path.to_path_buf(), hint: "no velodyne/ folder".into() });
        }
        let mut ids: Vec<String> = std::fs::read_dir(&velodyne)
            .map_err(|e| DataError::io(&velodyne, e))?
            .filter_map(|e| e.ok())
            .filter_map(|e| {
                let p = e.path();
                (p.extension()? == "bin").then(|| p.file_stem()?.to_str().map(str::to_string))?
            })
            .collect();
        ids.sort();
        Ok(Self { root, ids })
    }

    pub fn ids(&self) -> &[String] {
        &self.ids
    }
}

impl Dataset for KittiDataset {
    fn format(&self) -> Format {
        Format::Kitti
    }
    fn root(&self) -> &Path {
        &self.root
    }
    fn len(&self) -> usize {
        self.ids.len()
    }
    fn info(&self, index: usize) -> Result<FrameInfo, DataError> {
        let id = self
            .ids
            .get(index)
            .ok_or_else(|| DataError::invalid(&self.root, format!("frame index {index} out of range")))?;
        let mut info = FrameInfo::new(id.clone(), self.root.join("velodyne").join(format!("{id}.bin")));
        info.platform = Platform::Vehicle;
        let calib_path = self.root.join("calib").join(format!("{id}.txt"));
        let calib = read_calib(&calib_path)?;
        let label_path = self.root.join("label_2").join(format!("{id}.txt"));
        if label_path.exists() {
            for label in read_labels(&label_path)? {
                if label.name == "DontCare" {
                    info.dont_care.push(label.bbox_2d);
                } else {
                    info.objects.push(label.to_object(&calib));
                }
            }
        }
        let image = self.root.join("image_2").join(format!("{id}.png"));
        info.cameras.push(CameraInfo::from_kitti(&calib, Some(image)));
        info.calib = Some(Calib::Kitti(calib));
        Ok(info)
    }
}

/// One label line.
#[derive(Debug, Clone, PartialEq)]
pub struct KittiLabel {
    pub name: String,
    pub truncation: f64,
    pub occlusion: i32,
    pub alpha: f64,
    pub bbox_2d: [f64; 4],
    pub camera_box: CameraBox,
    pub score: Option<f64>,
}

impl KittiLabel {
    pub fn to_object(&self, calib: &KittiCalib) -> Object {
        let mut o = Object::new(self.name.clone(), calib.camera_to_lidar(&self.camera_box));
        o.score = self.score;
        o.kitti = Some(KittiFields {
            truncation: self.truncation,
            occlusion: self.occlusion,
            alpha: self.alpha,
            bbox_2d: self.bbox_2d,
        });
        o
    }
}

/// Parses a label line: `type trunc occ alpha x1 y1 x2 y2 h w l x y z ry [score]`.
pub fn parse_label_line(line: &str) -> Result<KittiLabel, String> {
    let f: Vec<&str> = line.split_whitespace().collect();
    if f.len() != 15 && f.len() != 16 {
        return Err(format!("expected 15 or 16 fields, found {}", f.len()));
    }
    let num = |i: usize| -> Result<f64, String> {
        let v: f64 = f[i].parse().map_err(|_| format!("field {} ('{}') is not a number", i + 1, f[i]))?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!("field {} is not finite", i + 1))
        }
    };
    let occlusion = f[2].parse::<f64>().map_err(|_| format!("occlusion '{}' is not a number", f[2]))? as i32;
    let [h, w, l] = [num(8)?, num(9)?, num(10)?];
    Ok(KittiLabel {
        name: f[0].to_string(),
        truncation: num(1)?,
        occlusion,
        alpha: num(3)?,
        bbox_2d: [num(4)?, num(5)?, num(6)?, num(7)?],
        camera_box: CameraBox {
            location: [num(11)?, num(12)?, num(13)?],
            dimensions_lhw: [l, h, w],
            rotation_y: num(14)?,
        },
        score: if f.len() == 16 { Some(num(15)?) } else { None },
    })
}

/// Reads a label (or result) file; blank lines are skipped, bad lines are errors with file:line.
pub fn read_labels(path: &Path) -> Result<Vec<KittiLabel>, DataError> {
    let text = std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))?;
    parse_labels(&text, path)
}

/// [`read_labels`] of text already in memory; `path` names it in messages.
pub fn parse_labels(text: &str, path: &Path) -> Result<Vec<KittiLabel>, DataError> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| parse_label_line(l).map_err(|m| DataError::line(path, i + 1, m)))
        .collect()
}

/// Reads `calib/<id>.txt` (P2, R0_rect, Tr_velo_to_cam are required).
pub fn read_calib(path: &Path) -> Result<KittiCalib, DataError> {
    let text = std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))?;
    parse_calib(&text, path)
}

/// [`read_calib`] of text already in memory; `path` names it in messages.
pub fn parse_calib(text: &str, path: &Path) -> Result<KittiCalib, DataError> {
    let find = |key: &str, n: usize| -> Result<Vec<f64>, DataError> {
        let (i, line) = text
            .lines()
            .enumerate()
            .find(|(_, l)| l.split(':').next().map(str::trim) == Some(key))
            .ok_or_else(|| DataError::invalid(path, format!("missing '{key}'")))?;
        let vals: Result<Vec<f64>, _> =
            line.split_once(':').map(|x| x.1).unwrap_or("").split_whitespace().map(str::parse).collect();
        match vals {
            Ok(v) if v.len() == n && v.iter().all(|x| x.is_finite()) => Ok(v),
            _ => Err(DataError::line(path, i + 1, format!("'{key}' needs {n} finite numbers"))),
        }
    };
    Ok(KittiCalib {
        p2: Matrix3x4::from_row_slice(&find("P2", 12)?),
        r0_rect: Matrix3::from_row_slice(&find("R0_rect", 9)?),
        tr_velo_to_cam: Matrix3x4::from_row_slice(&find("Tr_velo_to_cam", 12)?),
    })
}

/// Formats detections as KITTI result lines (OpenPCDet's layout, score last). With a calibration
/// the camera box and the 2D box come from it; without one the identity "fake" camera of
/// reference §3 is used and the 2D box is the fixed 50 px box.
pub fn format_result_lines(objects: &[Object], calib: Option<&KittiCalib>) -> String {
    let mut out = String::new();
    for o in objects {
        let (cam, alpha, bbox) = match calib {
            Some(c) => {
                let cam = c.lidar_to_camera(&o.box3d);
                let bbox = c.image_box(&o.box3d, Some([1242.0, 375.0])).unwrap_or([0.0, 0.0, 0.0, 0.0]);
                (cam, alpha_from_lidar(&o.box3d, cam.rotation_y), bbox)
            }
            None => {
                let (cam, alpha) = fake_camera_box(&o.box3d);
                (cam, alpha, FAKE_BBOX_2D)
            }
        };
        let [l, h, w] = cam.dimensions_lhw;
        let [x, y, z] = cam.location;
        let _ = writeln!(
            out,
            "{} -1 -1 {alpha:.4} {:.4} {:.4} {:.4} {:.4} {h:.4} {w:.4} {l:.4} {x:.4} {y:.4} {z:.4} {:.4} {:.4}",
            o.name,
            bbox[0],
            bbox[1],
            bbox[2],
            bbox[3],
            cam.rotation_y,
            o.score.unwrap_or(1.0)
        );
    }
    out
}

/// Writes `<dir>/<frame_id>.txt` result files.
pub fn write_result_file(
    dir: &Path,
    frame_id: &str,
    objects: &[Object],
    calib: Option<&KittiCalib>,
    overwrite: bool,
) -> Result<(), DataError> {
    write_atomic(&dir.join(format!("{frame_id}.txt")), format_result_lines(objects, calib).as_bytes(), overwrite)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_label_and_result_lines() {
        let l =
            parse_label_line("Pedestrian 0.00 0 -0.20 712.40 143.00 810.73 307.92 1.89 0.48 1.20 1.84 1.47 8.41 0.01")
                .unwrap();
        assert_eq!(l.name, "Pedestrian");
        assert_eq!(l.camera_box.dimensions_lhw, [1.2, 1.89, 0.48]);
        assert_eq!(l.score, None);
        let r = parse_label_line("Car -1 -1 0.1 0 0 50 50 1.5 1.6 3.9 1 2 10 0.2 0.87").unwrap();
        assert_eq!(r.score, Some(0.87));
    }

    #[test]
    fn malformed_lines_are_explained() {
        assert!(parse_label_line("Car 0 0").unwrap_err().contains("15 or 16"));
        let e = parse_label_line("Car 0.00 0 -0.20 712.40 143.00 810.73 307.92 1.89 abc 1.20 1.84 1.47 8.41 0.01")
            .unwrap_err();
        assert!(e.contains("field 10") && e.contains("abc"), "{e}");
        assert!(
            parse_label_line("Car 0.00 0 -0.20 712.40 143.00 810.73 307.92 1.89 NaN 1.20 1.84 1.47 8.41 0.01").is_err()
        );
    }
}
