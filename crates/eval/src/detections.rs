//! Detections to evaluate, read from the three formats people have:
//!
//! * **OpenPCDet `result.pkl`** — a pickled list of dicts, one per frame: `frame_id`, `name`
//!   (numpy `<U` array), `score` (float array), `boxes_lidar` (N×7, `[x, y, z_center, dx, dy,
//!   dz, heading]`, extra columns ignored). KITTI results also carry `bbox` (N×4), `alpha`,
//!   `location` / `dimensions` / `rotation_y` (camera frame); these are used when present, as
//!   the reference uses them.
//! * **KITTI result folder** — one `<frame_id>.txt` per frame of label lines with a 16th column,
//!   the score: `type trunc occ alpha x1 y1 x2 y2 h w l x y z ry score` (camera frame, bottom
//!   centre). On frames without a KITTI calibration the boxes are taken to be in the identity
//!   ("fake") camera of the reference (camera x = −LiDAR y, y = −LiDAR z, z = LiDAR x).
//! * **pi3det JSON lines** (`.jsonl`) — one line per frame:
//!
//!   ```json
//!   {"frame_id": "000123", "names": ["Car", "Pedestrian"], "scores": [0.91, 0.45],
//!    "boxes_lidar": [[10.2, -3.1, -0.8, 4.1, 1.8, 1.6, 0.12], [6.0, 2.2, -0.9, 0.7, 0.6, 1.7, 1.5]]}
//!   ```
//!
//!   `boxes_lidar` rows are `[x, y, z_center, dx, dy, dz, heading]` in the LiDAR frame (metres,
//!   radians; z at the box centre). Optional per-detection arrays: `bbox` (`[x1, y1, x2, y2]`
//!   image box, pixels) and `alpha` (observation angle); without them both are derived as
//!   OpenPCDet does. `track_ids`, `timestamp_s` and `latency_ms` (written by `pi3det track` and
//!   `pi3det run`) are read and ignored. Frames without detections may be written with empty arrays or left out;
//!   blank lines are skipped. [`JsonlFrame`] is this line as a serde type.
//!
//! A frame id may appear only once. Frames of the ground truth missing here have no detections.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use pi3det_data::pickle::{self, Value};
use pi3det_data::Object;
use pi3det_geometry::kitti::CameraBox;
use pi3det_geometry::Box3d;
use serde::{Deserialize, Serialize};

use crate::anno::KittiObject;
use crate::error::EvalError;

/// One detection. At least one of `lidar` / `camera` is set.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    pub name: String,
    pub score: f64,
    pub lidar: Option<Box3d>,
    pub camera: Option<CameraBox>,
    /// Image box `[x1, y1, x2, y2]` when the source has one.
    pub bbox: Option<[f64; 4]>,
    pub alpha: Option<f64>,
}

/// Detections of a split, by frame id.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Detections {
    /// Where they were read from (for messages); empty when built in memory.
    pub source: PathBuf,
    pub frames: BTreeMap<String, Vec<Detection>>,
}

/// One line of the JSON-lines format (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JsonlFrame {
    pub frame_id: String,
    pub names: Vec<String>,
    pub scores: Vec<f64>,
    pub boxes_lidar: Vec<[f64; 7]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bbox: Option<Vec<[f64; 4]>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alpha: Option<Vec<f64>>,
    /// Track ids (`pi3det track`), one per box; the evaluator ignores them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub track_ids: Option<Vec<u64>>,
    /// The sweep's time (`pi3det run`); the evaluator ignores it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timestamp_s: Option<f64>,
    /// Where the frame's time went, by stage (`pi3det run`); the evaluator ignores it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub latency_ms: Option<BTreeMap<String, f64>>,
}

impl JsonlFrame {
    /// A line for detected objects (`score` `None` is written as 1).
    pub fn from_objects(frame_id: impl Into<String>, objects: &[Object]) -> Self {
        Self {
            frame_id: frame_id.into(),
            names: objects.iter().map(|o| o.name.clone()).collect(),
            scores: objects.iter().map(|o| o.score.unwrap_or(1.0)).collect(),
            boxes_lidar: objects.iter().map(|o| o.box3d.to_array()).collect(),
            bbox: None,
            alpha: None,
            track_ids: None,
            timestamp_s: None,
            latency_ms: None,
        }
    }
}

fn check_box(a: [f64; 7], what: impl Fn() -> String) -> Result<Box3d, String> {
    Box3d::try_from_array(a).map_err(|e| format!("{}: {e}", what()))
}

fn check_score(s: f64, what: impl Fn() -> String) -> Result<f64, String> {
    if s.is_finite() {
        Ok(s)
    } else {
        Err(format!("{}: score {s} is not finite", what()))
    }
}

impl Detections {
    /// Reads detections, choosing the format by the path: a folder is a KITTI result folder, a
    /// `.pkl` a `result.pkl`, anything else JSON lines.
    pub fn read(path: &Path) -> Result<Self, EvalError> {
        if path.is_dir() {
            Self::read_kitti_dir(path)
        } else if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("pkl")) {
            Self::read_result_pkl(path)
        } else {
            Self::read_jsonl(path)
        }
    }

    /// Builds detections from objects per frame (`score` `None` counts as 1).
    pub fn from_objects<I, S>(frames: I) -> Result<Self, EvalError>
    where
        I: IntoIterator<Item = (S, Vec<Object>)>,
        S: Into<String>,
    {
        let mut out = Self::default();
        for (id, objects) in frames {
            let dets = objects
                .into_iter()
                .map(|o| Detection {
                    name: o.name,
                    score: o.score.unwrap_or(1.0),
                    lidar: Some(o.box3d),
                    camera: None,
                    bbox: None,
                    alpha: None,
                })
                .collect();
            out.insert(id.into(), dets).map_err(EvalError::Input)?;
        }
        Ok(out)
    }

    fn insert(&mut self, id: String, dets: Vec<Detection>) -> Result<(), String> {
        if let Some(d) = dets.iter().find(|d| !d.score.is_finite()) {
            return Err(format!("frame {id}: score {} is not finite", d.score));
        }
        if self.frames.insert(id.clone(), dets).is_some() {
            return Err(format!("frame id {id:?} occurs twice"));
        }
        Ok(())
    }

    pub fn num_detections(&self) -> usize {
        self.frames.values().map(Vec::len).sum()
    }

    /// A KITTI result folder: `<frame_id>.txt` files with a score column.
    pub fn read_kitti_dir(dir: &Path) -> Result<Self, EvalError> {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(|e| EvalError::io(dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == "txt"))
            .collect();
        files.sort();
        if files.is_empty() {
            return Err(EvalError::invalid(dir, "no <frame_id>.txt result files in this folder"));
        }
        let mut out = Self { source: dir.to_path_buf(), ..Self::default() };
        for f in files {
            let id = f.file_stem().and_then(|s| s.to_str()).unwrap_or_default().to_string();
            let dets = KittiObject::read_file(&f, true)?
                .into_iter()
                .map(|o| Detection {
                    camera: Some(o.camera_box()),
                    lidar: None,
                    bbox: Some(o.bbox),
                    alpha: Some(o.alpha),
                    score: o.score,
                    name: o.name,
                })
                .collect();
            out.insert(id, dets).map_err(|m| EvalError::invalid(&f, m))?;
        }
        Ok(out)
    }

    /// Our JSON-lines format (a `.json` file holding one array of such objects is accepted too).
    pub fn read_jsonl(path: &Path) -> Result<Self, EvalError> {
        let text = std::fs::read_to_string(path).map_err(|e| EvalError::io(path, e))?;
        Self::parse_jsonl(&text, path)
    }

    /// [`Self::read_jsonl`] of text already in memory; `path` names it in messages.
    pub fn parse_jsonl(text: &str, path: &Path) -> Result<Self, EvalError> {
        let mut out = Self { source: path.to_path_buf(), ..Self::default() };
        // A JSON array instead of lines.
        if text.trim_start().starts_with('[') {
            let frames: Vec<JsonlFrame> =
                serde_json::from_str(text).map_err(|e| EvalError::invalid(path, e.to_string()))?;
            for f in frames {
                let (id, dets) = Self::from_jsonl(f).map_err(|m| EvalError::invalid(path, m))?;
                out.insert(id, dets).map_err(|m| EvalError::invalid(path, m))?;
            }
            return Ok(out);
        }
        for (i, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let f: JsonlFrame = serde_json::from_str(line).map_err(|e| EvalError::line(path, i + 1, e.to_string()))?;
            let (id, dets) = Self::from_jsonl(f).map_err(|m| EvalError::line(path, i + 1, m))?;
            out.insert(id, dets).map_err(|m| EvalError::line(path, i + 1, m))?;
        }
        Ok(out)
    }

    fn from_jsonl(f: JsonlFrame) -> Result<(String, Vec<Detection>), String> {
        let n = f.names.len();
        if f.scores.len() != n || f.boxes_lidar.len() != n {
            return Err(format!(
                "frame {}: {} names, {} scores, {} boxes_lidar",
                f.frame_id,
                n,
                f.scores.len(),
                f.boxes_lidar.len()
            ));
        }
        for (key, len) in [
            ("bbox", f.bbox.as_ref().map(Vec::len)),
            ("alpha", f.alpha.as_ref().map(Vec::len)),
            ("track_ids", f.track_ids.as_ref().map(Vec::len)),
        ] {
            if len.is_some_and(|l| l != n) {
                return Err(format!("frame {}: {key} has {} entries for {n} detections", f.frame_id, len.unwrap_or(0)));
            }
        }
        let mut dets = Vec::with_capacity(n);
        for (k, name) in f.names.into_iter().enumerate() {
            let what = || format!("frame {} detection {k}", f.frame_id);
            dets.push(Detection {
                name,
                score: check_score(f.scores[k], what)?,
                lidar: Some(check_box(f.boxes_lidar[k], what)?),
                camera: None,
                bbox: f.bbox.as_ref().map(|b| b[k]),
                alpha: f.alpha.as_ref().map(|a| a[k]),
            });
        }
        Ok((f.frame_id, dets))
    }

    /// OpenPCDet's `result.pkl`.
    pub fn read_result_pkl(path: &Path) -> Result<Self, EvalError> {
        // The pickle error names the file already.
        let value = pickle::from_path(path).map_err(|e| EvalError::Input(e.to_string()))?;
        Self::from_result_value(&value, path)
    }

    /// A `result.pkl` already unpickled; `path` names it in messages.
    pub fn from_result_value(value: &Value, path: &Path) -> Result<Self, EvalError> {
        let list = value.as_list().ok_or_else(|| {
            EvalError::invalid(path, format!("expected a list of per-frame dicts, found {}", value.type_name()))
        })?;
        let mut out = Self { source: path.to_path_buf(), ..Self::default() };
        for (i, frame) in list.iter().enumerate() {
            let (id, dets) = pkl_frame(frame).map_err(|m| EvalError::invalid(path, format!("entry {i}: {m}")))?;
            out.insert(id, dets).map_err(|m| EvalError::invalid(path, format!("entry {i}: {m}")))?;
        }
        Ok(out)
    }
}

fn pkl_frame(v: &Value) -> Result<(String, Vec<Detection>), String> {
    let id = match v.get("frame_id") {
        Some(Value::Str(s)) => s.clone(),
        Some(Value::Int(i)) => i.to_string(),
        Some(Value::Array(a)) if a.len() == 1 => {
            a.to_strings().and_then(|s| s.into_iter().next()).ok_or("frame_id is not a string")?
        }
        Some(other) => return Err(format!("frame_id is a {}, not a string", other.type_name())),
        None => return Err("no frame_id".into()),
    };
    let ctx = |m: String| format!("frame {id}: {m}");
    let names: Vec<String> = match v.get("name") {
        // OpenPCDet writes empty frames with `np.zeros(0)` (float) names.
        Some(Value::Array(a)) if a.is_empty() => Vec::new(),
        Some(Value::Array(a)) => a.to_strings().ok_or_else(|| ctx("'name' is not a string array".into()))?,
        Some(Value::List(l)) => l
            .iter()
            .map(|x| x.as_str().map(str::to_string))
            .collect::<Option<_>>()
            .ok_or_else(|| ctx("'name' is not a list of strings".into()))?,
        _ => return Err(ctx("no 'name' array".into())),
    };
    let n = names.len();
    let floats = |key: &str| -> Result<Option<Vec<f64>>, String> {
        match v.get(key) {
            None | Some(Value::None) => Ok(None),
            Some(Value::Array(a)) => a.to_f64_vec().map(Some).ok_or_else(|| ctx(format!("'{key}' is not numeric"))),
            Some(Value::List(l)) => l
                .iter()
                .map(Value::as_f64)
                .collect::<Option<Vec<_>>>()
                .map(Some)
                .ok_or_else(|| ctx(format!("'{key}' is not numeric"))),
            Some(o) => Err(ctx(format!("'{key}' is a {}", o.type_name()))),
        }
    };
    let rows = |key: &str, width: usize, min_width: usize| -> Result<Option<Vec<Vec<f64>>>, String> {
        let Some(flat) = floats(key)? else { return Ok(None) };
        if n == 0 {
            return Ok(Some(Vec::new()));
        }
        if flat.len() % n != 0 || flat.len() / n < min_width {
            return Err(ctx(format!("'{key}' has {} values for {n} detections (need {width} per row)", flat.len())));
        }
        let w = flat.len() / n;
        Ok(Some(flat.chunks(w).map(|c| c[..width.min(w)].to_vec()).collect()))
    };
    let scores = floats("score")?.ok_or_else(|| ctx("no 'score' array".into()))?;
    if scores.len() != n {
        return Err(ctx(format!("{} scores for {n} names", scores.len())));
    }
    let lidar = rows("boxes_lidar", 7, 7)?;
    let bbox = rows("bbox", 4, 4)?;
    let alpha = floats("alpha")?;
    let loc = rows("location", 3, 3)?;
    let dims = rows("dimensions", 3, 3)?;
    let ry = floats("rotation_y")?;
    if alpha.as_ref().is_some_and(|a| a.len() != n) || ry.as_ref().is_some_and(|a| a.len() != n) {
        return Err(ctx("'alpha' / 'rotation_y' length differs from 'name'".into()));
    }
    let camera: Option<Vec<CameraBox>> = match (loc, dims, ry) {
        (Some(l), Some(d), Some(r)) => Some(
            (0..n)
                .map(|k| CameraBox {
                    location: [l[k][0], l[k][1], l[k][2]],
                    dimensions_lhw: [d[k][0], d[k][1], d[k][2]],
                    rotation_y: r[k],
                })
                .collect(),
        ),
        _ => None,
    };
    if lidar.is_none() && camera.is_none() {
        return Err(ctx("neither 'boxes_lidar' nor 'location'/'dimensions'/'rotation_y'".into()));
    }
    let mut dets = Vec::with_capacity(n);
    for (k, name) in names.into_iter().enumerate() {
        let what = || format!("frame {id} detection {k}");
        let lidar = match &lidar {
            Some(rows) => {
                let r = &rows[k];
                Some(check_box([r[0], r[1], r[2], r[3], r[4], r[5], r[6]], what)?)
            }
            None => None,
        };
        let camera = camera.as_ref().map(|c| c[k]);
        if let Some(c) = &camera {
            if c.location.iter().chain(&c.dimensions_lhw).any(|v| !v.is_finite()) || !c.rotation_y.is_finite() {
                return Err(format!("{}: camera box is not finite", what()));
            }
        }
        dets.push(Detection {
            name,
            score: check_score(scores[k], what)?,
            lidar,
            camera,
            bbox: bbox.as_ref().map(|b| [b[k][0], b[k][1], b[k][2], b[k][3]]),
            alpha: alpha.as_ref().map(|a| a[k]),
        });
    }
    Ok((id, dets))
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_data::pickle::NdArray;

    #[test]
    fn jsonl_lines_and_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("d.jsonl");
        std::fs::write(
            &p,
            "{\"frame_id\": \"a\", \"names\": [\"Car\"], \"scores\": [0.5], \"boxes_lidar\": [[1,2,3,4,2,1.5,0.1]]}\n\n\
             {\"frame_id\": \"b\", \"names\": [], \"scores\": [], \"boxes_lidar\": []}\n",
        )
        .unwrap();
        let d = Detections::read(&p).unwrap();
        assert_eq!(d.frames.len(), 2);
        assert_eq!(d.frames["a"][0].lidar.unwrap().dx, 4.0);
        std::fs::write(&p, "{\"frame_id\": \"a\", \"names\": [\"Car\"], \"scores\": [], \"boxes_lidar\": []}\n")
            .unwrap();
        let e = Detections::read(&p).unwrap_err().to_string();
        assert!(e.contains("d.jsonl:1") && e.contains("1 names, 0 scores"), "{e}");
        std::fs::write(
            &p,
            "{\"frame_id\": \"a\", \"names\": [], \"scores\": [], \"boxes_lidar\": []}\n{\"frame_id\": \"a\", \"names\": [], \"scores\": [], \"boxes_lidar\": []}\n",
        )
        .unwrap();
        assert!(Detections::read(&p).unwrap_err().to_string().contains("twice"));
        // A whole-file array.
        let line = JsonlFrame::from_objects("z", &[Object::new("Car", Box3d::new(1., 2., 3., 4., 2., 1., 0.))]);
        std::fs::write(&p, serde_json::to_string(&vec![line]).unwrap()).unwrap();
        assert_eq!(Detections::read(&p).unwrap().frames["z"][0].score, 1.0);
    }

    #[test]
    fn kitti_result_folder() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("000001.txt"), "Car -1 -1 0.2 10 20 110 80 1.5 1.6 3.9 1.0 1.6 20.0 0.3 0.87\n")
            .unwrap();
        std::fs::write(dir.path().join("000002.txt"), "").unwrap();
        let d = Detections::read(dir.path()).unwrap();
        let c = d.frames["000001"][0].camera.unwrap();
        assert_eq!(c.dimensions_lhw, [3.9, 1.5, 1.6]);
        assert_eq!(d.frames["000001"][0].score, 0.87);
        assert!(d.frames["000002"].is_empty());
        std::fs::write(dir.path().join("000003.txt"), "Car -1 -1 0.2 10 20 110 80 1.5 1.6 3.9 1.0 1.6 20.0 0.3\n")
            .unwrap();
        let e = Detections::read(dir.path()).unwrap_err().to_string();
        assert!(e.contains("000003.txt:1"), "{e}");
    }

    #[test]
    fn result_pkl() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("result.pkl");
        let frame = |id: &str, n: usize| {
            Value::dict([
                ("frame_id", Value::from(id)),
                ("name", NdArray::from_vec(vec!["Car".to_string(); n]).into()),
                ("score", NdArray::from_vec(vec![0.75f32; n]).into()),
                (
                    "boxes_lidar",
                    NdArray::new(vec![n, 7], [10.0f32, 1.0, -1.0, 4.0, 1.8, 1.6, 0.2].repeat(n)).unwrap().into(),
                ),
            ])
        };
        let list = Value::List(vec![frame("000000", 2), frame("000001", 0)]);
        pickle::to_path(&p, &list, true).unwrap();
        let d = Detections::read(&p).unwrap();
        assert_eq!(d.frames["000000"].len(), 2);
        assert_eq!(d.frames["000000"][1].lidar.unwrap().heading, 0.2f32 as f64);
        assert!(d.frames["000001"].is_empty());
        pickle::to_path(&p, &Value::List(vec![Value::dict([("frame_id", Value::from("x"))])]), true).unwrap();
        let e = Detections::read(&p).unwrap_err().to_string();
        assert!(e.contains("result.pkl") && e.contains("frame x: no 'name'"), "{e}");
    }
}
