//! The reference's per-frame annotation (`get_label_anno` dicts of OpenPCDet / mmdet3d), one
//! struct per object, and KITTI label lines (`type trunc occ alpha x1 y1 x2 y2 h w l x y z ry
//! [score]`, camera frame, bottom centre).

use std::path::Path;

use pi3det_geometry::kitti::CameraBox;
use serde::{Deserialize, Serialize};

use crate::error::EvalError;

/// One object as the reference sees it: camera-frame box and KITTI image fields.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KittiObject {
    pub name: String,
    #[serde(default)]
    pub truncated: f64,
    #[serde(default)]
    pub occluded: f64,
    #[serde(default)]
    pub alpha: f64,
    /// Image box `[x1, y1, x2, y2]` (pixels).
    pub bbox: [f64; 4],
    /// `(l, h, w)` as the reference orders them.
    pub dimensions: [f64; 3],
    /// Bottom centre in the rectified camera frame.
    pub location: [f64; 3],
    pub rotation_y: f64,
    /// Detection confidence (0 for ground truth).
    #[serde(default)]
    pub score: f64,
}

impl KittiObject {
    pub fn camera_box(&self) -> CameraBox {
        CameraBox { location: self.location, dimensions_lhw: self.dimensions, rotation_y: self.rotation_y }
    }

    /// Parses one label line; `need_score` demands the 16th column.
    pub fn parse_line(line: &str, path: &Path, line_no: usize, need_score: bool) -> Result<Self, EvalError> {
        let cols: Vec<&str> = line.split_whitespace().collect();
        if cols.len() != 15 && cols.len() != 16 {
            return Err(EvalError::line(path, line_no, format!("expected 15 or 16 columns, found {}", cols.len())));
        }
        if need_score && cols.len() != 16 {
            return Err(EvalError::line(path, line_no, "detection line has no score (16th column)"));
        }
        let mut v = [0.0f64; 15];
        for (k, c) in cols[1..].iter().enumerate() {
            let x: f64 = c
                .parse()
                .map_err(|_| EvalError::line(path, line_no, format!("column {} is not a number: {c:?}", k + 2)))?;
            if !x.is_finite() {
                return Err(EvalError::line(path, line_no, format!("column {} is not finite: {c:?}", k + 2)));
            }
            v[k] = x;
        }
        Ok(Self {
            name: cols[0].to_string(),
            truncated: v[0],
            occluded: v[1],
            alpha: v[2],
            bbox: [v[3], v[4], v[5], v[6]],
            // File order is h, w, l; the reference reorders to l, h, w.
            dimensions: [v[9], v[7], v[8]],
            location: [v[10], v[11], v[12]],
            rotation_y: v[13],
            score: if cols.len() == 16 { v[14] } else { 0.0 },
        })
    }

    /// Reads a label / result file (blank lines skipped).
    pub fn read_file(path: &Path, need_score: bool) -> Result<Vec<Self>, EvalError> {
        let text = std::fs::read_to_string(path).map_err(|e| EvalError::io(path, e))?;
        text.lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty())
            .map(|(i, l)| Self::parse_line(l, path, i + 1, need_score))
            .collect()
    }
}

/// One frame of annotations or detections in the reference's form.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct KittiFrame {
    #[serde(default)]
    pub id: String,
    pub objects: Vec<KittiObject>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_label_and_result_lines() {
        let p = Path::new("x.txt");
        let o = KittiObject::parse_line(
            "Pedestrian 0.00 0 -0.20 712.40 143.00 810.73 307.92 1.89 0.48 1.20 1.84 1.47 8.41 0.01",
            p,
            1,
            false,
        )
        .unwrap();
        assert_eq!(o.dimensions, [1.2, 1.89, 0.48]);
        assert_eq!(o.location, [1.84, 1.47, 8.41]);
        assert_eq!(o.score, 0.0);
        assert!(KittiObject::parse_line("Car 0 0 0 0 0 1 1 1 1 1 0 0 5 0", p, 3, true).is_err());
        let e = KittiObject::parse_line("Car 0 0 x 0 0 1 1 1 1 1 0 0 5 0 0.5", p, 7, true).unwrap_err();
        assert!(e.to_string().contains("x.txt:7"), "{e}");
    }
}
