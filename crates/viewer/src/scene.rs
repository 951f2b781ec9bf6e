//! Data → the scene payload the page draws: frames, boxes, and points packed compactly
//! (uint16-quantised xyz and uint8 intensity, base64) so a 130k-point frame stays ~1 MB of text.

use std::collections::HashMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

use pi3det_data::{Dataset, FrameInfo, Object, PointCloud};
use pi3det_eval::Detections;
use pi3det_geometry::Box3d;
use serde::{Deserialize, Serialize};

use crate::error::ViewerError;

/// What the points are coloured by (the page can switch; this is its start).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum ColorBy {
    #[default]
    Height,
    Intensity,
}

/// One box as the page and the edit requests carry it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LabelBox {
    pub name: String,
    /// `[x, y, z_center, dx, dy, dz, heading]`, LiDAR frame.
    #[serde(rename = "box")]
    pub box3d: [f64; 7],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub score: Option<f64>,
    /// Points inside as the dataset stored it; the page drops it when the box changes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub num_points: Option<u32>,
}

impl LabelBox {
    pub fn from_object(o: &Object) -> Self {
        Self { name: o.name.clone(), box3d: o.box3d.to_array(), score: o.score, num_points: o.num_points }
    }

    /// The object, rejecting non-finite numbers, negative sizes and empty names (user input).
    pub fn to_object(&self) -> Result<Object, String> {
        if self.name.trim().is_empty() {
            return Err("empty class name".into());
        }
        let b = Box3d::try_from_array(self.box3d).map_err(|e| e.to_string())?;
        if let Some(s) = self.score.filter(|s| !s.is_finite()) {
            return Err(format!("score {s} is not finite"));
        }
        let mut o = Object::new(self.name.clone(), b);
        o.score = self.score;
        o.num_points = self.num_points;
        Ok(o)
    }
}

/// A frame's points, packed: `xyz` is base64 of little-endian uint16 triples, decoded as
/// `offset + q * scale` per axis; `intensity` base64 of uint8 (0–255).
#[derive(Debug, Clone, Serialize)]
pub struct PackedPoints {
    pub n: usize,
    pub offset: [f32; 3],
    pub scale: [f32; 3],
    pub xyz: String,
    pub intensity: String,
    /// Robust height range (2nd–98th percentile of z) for the height colour map.
    pub z_range: [f32; 2],
}

#[derive(Debug, Clone, Serialize)]
pub struct SceneFrame {
    pub index: usize,
    pub id: String,
    /// Absent when the page fetches points from the server.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub points: Option<PackedPoints>,
    pub gt: Vec<LabelBox>,
    pub det: Vec<LabelBox>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Scene {
    pub title: String,
    /// "view" (static page) or "edit" (served by `pi3det annotate`).
    pub mode: &'static str,
    pub color: ColorBy,
    pub frames: Vec<SceneFrame>,
}

impl Scene {
    /// Points and boxes of frame `k` as embedded (what the page must report drawing).
    pub fn counts(&self, k: usize) -> Option<(usize, usize)> {
        let f = self.frames.get(k)?;
        Some((f.points.as_ref().map_or(0, |p| p.n), f.gt.len() + f.det.len()))
    }
}

/// Parses `A..B` (B excluded), `A..=B`, `A..` or a single `A` against `len` frames.
pub fn parse_frames(spec: &str, len: usize, data: &Path) -> Result<Range<usize>, ViewerError> {
    let bad = || ViewerError::Option(format!("--frames {spec:?}: expected A..B, A..=B, A.. or A"));
    let num = |s: &str| s.trim().parse::<usize>().map_err(|_| bad());
    let range = if let Some((a, b)) = spec.split_once("..=") {
        num(a)?..num(b)?.checked_add(1).ok_or_else(bad)?
    } else if let Some((a, b)) = spec.split_once("..") {
        num(a)?..if b.trim().is_empty() { len } else { num(b)? }
    } else {
        let a = num(spec)?;
        a..a.saturating_add(1)
    };
    if range.start >= range.end || range.end > len {
        return Err(ViewerError::invalid(
            data,
            format!("--frames {spec}: outside the data's {len} frames (valid indices 0..{len})"),
        ));
    }
    Ok(range)
}

/// A dataset with optional detections, checked against each other.
pub struct Source {
    pub path: PathBuf,
    pub dataset: Box<dyn Dataset>,
    /// Every frame's info, in dataset order.
    pub infos: Vec<FrameInfo>,
    /// Detections per dataset frame (empty without `--det`).
    pub dets: Vec<Vec<LabelBox>>,
    pub has_dets: bool,
    /// The dataset indices shown.
    pub shown: Range<usize>,
}

impl Source {
    pub fn open(data: &Path, det: Option<&Path>, frames: Option<&str>) -> Result<Self, ViewerError> {
        let dataset = pi3det_data::open(data)?;
        if dataset.is_empty() {
            return Err(ViewerError::invalid(data, "the dataset has no frames"));
        }
        let infos = dataset.infos()?;
        let shown = match frames {
            Some(spec) => parse_frames(spec, infos.len(), data)?,
            None => 0..infos.len(),
        };
        let mut dets = vec![Vec::new(); infos.len()];
        if let Some(det) = det {
            let by_id: HashMap<&str, usize> = infos.iter().enumerate().map(|(i, f)| (f.id.as_str(), i)).collect();
            let read = Detections::read(det)?;
            for (id, list) in &read.frames {
                let &i = by_id.get(id.as_str()).ok_or_else(|| {
                    ViewerError::invalid(
                        det,
                        format!("detections for frame {id:?}, which is not in {}", data.display()),
                    )
                })?;
                dets[i] = list
                    .iter()
                    .enumerate()
                    .map(|(k, d)| {
                        let b = d.lidar.ok_or_else(|| {
                            ViewerError::invalid(
                                det,
                                format!("frame {id} detection {k}: no LiDAR-frame box (the viewer reads boxes_lidar)"),
                            )
                        })?;
                        Ok(LabelBox {
                            name: d.name.clone(),
                            box3d: b.to_array(),
                            score: Some(d.score),
                            num_points: None,
                        })
                    })
                    .collect::<Result<_, ViewerError>>()?;
            }
        }
        Ok(Self { path: data.to_path_buf(), dataset, infos, dets, has_dets: det.is_some(), shown })
    }

    pub fn gt(&self, i: usize) -> Vec<LabelBox> {
        self.infos[i].objects.iter().map(LabelBox::from_object).collect()
    }

    /// Frame `i`'s points, at most `max_points` of them (an even subsample).
    pub fn points(&self, i: usize, max_points: usize) -> Result<PackedPoints, ViewerError> {
        let frame = self.dataset.load(i)?;
        Ok(pack_points(&frame.points, max_points))
    }

    pub fn title(&self) -> String {
        format!("pi3det — {}", self.path.display())
    }
}

/// Writes the static scene: every shown frame with its points embedded.
pub fn build_scene(src: &Source, max_points: usize, color: ColorBy) -> Result<Scene, ViewerError> {
    let frames = src
        .shown
        .clone()
        .map(|i| {
            Ok(SceneFrame {
                index: i,
                id: src.infos[i].id.clone(),
                points: Some(src.points(i, max_points)?),
                gt: src.gt(i),
                det: src.dets[i].clone(),
            })
        })
        .collect::<Result<_, ViewerError>>()?;
    Ok(Scene { title: src.title(), mode: "view", color, frames })
}

/// Quantises and base64-encodes points; keeps an even subsample of at most `max_points`.
pub fn pack_points(cloud: &PointCloud, max_points: usize) -> PackedPoints {
    let n_all = cloud.len();
    let n = n_all.min(max_points);
    let pick = |k: usize| if n == n_all { k } else { (k as u128 * n_all as u128 / n as u128) as usize };
    let pts: Vec<&[f32]> = (0..n).map(|k| cloud.point(pick(k))).collect();
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &pts {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    if n == 0 {
        (lo, hi) = ([0.0; 3], [0.0; 3]);
    }
    let scale: [f32; 3] = std::array::from_fn(|a| ((hi[a] - lo[a]) / 65535.0).max(f32::MIN_POSITIVE));
    let mut xyz = Vec::with_capacity(n * 6);
    let mut zs = Vec::with_capacity(n);
    let max_i = pts.iter().filter_map(|p| p.get(3)).fold(0f32, |m, &v| if v.is_finite() { m.max(v) } else { m });
    // KITTI reflectance is in [0, 1], nuScenes intensity in [0, 255].
    let i_scale = if max_i <= 1.0 { 255.0 } else { 1.0 };
    let mut inten = Vec::with_capacity(n);
    for p in &pts {
        for a in 0..3 {
            let q = ((p[a] - lo[a]) / scale[a]).round().clamp(0.0, 65535.0) as u16;
            xyz.extend_from_slice(&q.to_le_bytes());
        }
        zs.push(p[2]);
        let v = p.get(3).copied().unwrap_or(0.0);
        inten.push(if v.is_finite() { (v * i_scale).round().clamp(0.0, 255.0) as u8 } else { 0 });
    }
    let z_range = percentiles(&mut zs);
    PackedPoints { n, offset: lo, scale, xyz: base64(&xyz), intensity: base64(&inten), z_range }
}

fn percentiles(zs: &mut [f32]) -> [f32; 2] {
    if zs.is_empty() {
        return [-2.0, 2.0];
    }
    let k = |q: f64| ((zs.len() - 1) as f64 * q) as usize;
    let (lo_k, hi_k) = (k(0.02), k(0.98));
    let lo = *zs.select_nth_unstable_by(lo_k, f32::total_cmp).1;
    let hi = *zs.select_nth_unstable_by(hi_k, f32::total_cmp).1;
    if hi > lo {
        [lo, hi]
    } else {
        [lo - 1.0, lo + 1.0]
    }
}

/// Standard base64 with padding (no dependency for 20 lines).
pub fn base64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let b = [c[0], c.get(1).copied().unwrap_or(0), c.get(2).copied().unwrap_or(0)];
        let v = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for (k, shift) in [18, 12, 6, 0].into_iter().enumerate() {
            out.push(if k <= c.len() { T[(v >> shift) as usize & 63] as char } else { '=' });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_the_rfc_vectors() {
        for (i, o) in [("", ""), ("f", "Zg=="), ("fo", "Zm8="), ("foo", "Zm9v"), ("foobar", "Zm9vYmFy")] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }

    #[test]
    fn frame_ranges() {
        let p = Path::new("d");
        assert_eq!(parse_frames("2..4", 6, p).unwrap(), 2..4);
        assert_eq!(parse_frames("2..=4", 6, p).unwrap(), 2..5);
        assert_eq!(parse_frames("3", 6, p).unwrap(), 3..4);
        assert_eq!(parse_frames("1..", 6, p).unwrap(), 1..6);
        let e = parse_frames("4..9", 6, p).unwrap_err().to_string();
        assert!(e.contains("outside the data's 6 frames") && e.starts_with("d:"), "{e}");
        assert!(parse_frames("x..2", 6, p).is_err());
        assert!(parse_frames("3..3", 6, p).is_err());
    }

    #[test]
    fn packing_subsamples_and_quantises() {
        let pts: Vec<[f32; 4]> = (0..1000).map(|i| [i as f32 * 0.1, -(i as f32), 1.0, 0.5]).collect();
        let p = pack_points(&PointCloud::from_xyzi(&pts), 100);
        assert_eq!(p.n, 100);
        assert_eq!(p.xyz.len(), 100 * 6 / 3 * 4);
        assert_eq!(p.offset, [0.0, -990.0, 1.0], "points 0, 10, …, 990");
        assert!((p.scale[0] * 65535.0 - 99.0).abs() < 1e-3);
        assert_eq!(&p.intensity[..4], &base64(&[128, 128, 128])[..4]);
        let all = pack_points(&PointCloud::from_xyzi(&pts), usize::MAX);
        assert_eq!(all.n, 1000);
        assert_eq!(pack_points(&PointCloud::from_xyzi(&[]), 10).n, 0);
    }

    #[test]
    fn label_boxes_reject_bad_numbers() {
        let mut b =
            LabelBox { name: "Car".into(), box3d: [1., 2., 3., 4., 2., 1.5, 0.], score: None, num_points: None };
        assert!(b.to_object().is_ok());
        b.box3d[3] = -1.0;
        assert!(b.to_object().unwrap_err().contains("negative") || b.to_object().is_err());
        b.box3d[3] = f64::NAN;
        assert!(b.to_object().is_err());
        b.box3d[3] = 1.0;
        b.name = " ".into();
        assert!(b.to_object().is_err());
        assert!(serde_json::from_str::<LabelBox>(r#"{"name":"Car","box":[1,2,3,4,5,6,7],"colour":1}"#).is_err());
    }
}
