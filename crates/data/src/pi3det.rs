//! The released Pi3DET layout (reference §1a): `ROOT/pi3det_infos_<split>.pkl` (a list of info
//! dicts with numpy arrays) and `ROOT/training/point_cloud/<frame_id>.bin` (float32 x, y, z,
//! intensity). Optional per-frame keys our simulator writes and the public release lacks:
//! `sequence`, `timestamp`, `pose` (4×4 world_from_lidar) and `annos.num_points_in_gt`.

use std::path::{Path, PathBuf};

use pi3det_geometry::{Box3d, Pose, PoseExt};

use crate::dataset::{Dataset, Format};
use crate::error::DataError;
use crate::fields::Record;
use crate::frame::{Calib, CameraInfo, Frame, FrameInfo, Object, Platform};
use crate::io::write_atomic;
use crate::pickle::{self, NdArray, Value};
use crate::points::write_bin;

/// A Pi3DET-layout dataset: one or more info files under one root.
pub struct Pi3detDataset {
    root: PathBuf,
    frames: Vec<FrameInfo>,
    splits: Vec<(String, usize)>,
}

/// The info files under `root`, sorted (train before val). Derived label sets written beside them
/// (`pi3det_infos_<split>.<label-set>.pkl`, e.g. by `pi3det annotate`) are not included: they hold
/// the same frames again; open such a file by its path.
pub fn info_files(root: &Path) -> Result<Vec<PathBuf>, DataError> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(root)
        .map_err(|e| DataError::io(root, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            name.strip_prefix("pi3det_infos_")
                .and_then(|rest| rest.strip_suffix(".pkl"))
                .is_some_and(|split| !split.contains('.'))
        })
        .collect();
    files.sort();
    Ok(files)
}

fn split_name(info_file: &Path) -> String {
    let stem = info_file.file_stem().and_then(|s| s.to_str()).unwrap_or("");
    stem.strip_prefix("pi3det_infos_").unwrap_or(stem).to_string()
}

impl Pi3detDataset {
    /// Opens a root folder (all its info files, in name order) or a single info `.pkl`.
    pub fn open(path: &Path) -> Result<Self, DataError> {
        let (root, files) = if path.is_file() {
            (path.parent().unwrap_or(Path::new(".")).to_path_buf(), vec![path.to_path_buf()])
        } else {
            let files = info_files(path)?;
            if files.is_empty() {
                return Err(DataError::UnknownFormat {
                    path: path.to_path_buf(),
                    hint: "no pi3det_infos_*.pkl in this folder".into(),
                });
            }
            (path.to_path_buf(), files)
        };
        Self::from_files(root, &files, None)
    }

    /// `decoded` is the already decoded single info file, when the caller has it.
    fn from_files(root: PathBuf, files: &[PathBuf], decoded: Option<&Value>) -> Result<Self, DataError> {
        let mut frames = Vec::new();
        let mut splits = Vec::new();
        for file in files {
            let infos = match decoded {
                Some(v) => parse_infos(&root, file, v)?,
                None => read_infos(&root, file)?,
            };
            splits.push((split_name(file), infos.len()));
            frames.extend(infos);
        }
        Ok(Self { root, frames, splits })
    }

    /// From a decoded info file (a list of info dicts) at `file`.
    pub fn from_value(file: &Path, value: &Value) -> Result<Self, DataError> {
        let root = file.parent().unwrap_or(Path::new(".")).to_path_buf();
        Self::from_files(root, &[file.to_path_buf()], Some(value))
    }

    /// Split names and their frame counts, in the order frames are indexed.
    pub fn splits(&self) -> &[(String, usize)] {
        &self.splits
    }
}

impl Dataset for Pi3detDataset {
    fn format(&self) -> Format {
        Format::Pi3det
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

/// Reads one info file into frame infos (points are not read).
pub fn read_infos(root: &Path, file: &Path) -> Result<Vec<FrameInfo>, DataError> {
    let value = pickle::from_path(file).map_err(|source| DataError::Pickle { path: file.to_path_buf(), source })?;
    parse_infos(root, file, &value)
}

fn parse_infos(root: &Path, file: &Path, value: &Value) -> Result<Vec<FrameInfo>, DataError> {
    let list = value.as_list().ok_or_else(|| {
        DataError::invalid(file, format!("expected a list of info dicts, found {}", value.type_name()))
    })?;
    list.iter().enumerate().map(|(i, v)| parse_info(root, file, i, v)).collect()
}

fn parse_info(root: &Path, file: &Path, index: usize, v: &Value) -> Result<FrameInfo, DataError> {
    let mut rec = Record { path: file, what: format!("info #{index}") };
    let id = rec.str(v, "frame_id")?;
    rec.what = format!("info #{index} (frame {id})");
    let rel = match rec.opt_str(v, "point_clout_path")? {
        Some(p) => p,
        None => rec.opt_str(v, "point_cloud_path")?.unwrap_or_else(|| format!("training/point_cloud/{id}.bin")),
    };
    let mut info = FrameInfo::new(id, root.join(rel));
    info.platform = rec.opt_str(v, "platform")?.map(|s| Platform::parse(&s)).unwrap_or_default();
    info.sequence = rec.opt_str(v, "sequence")?;
    info.timestamp_s = rec.opt_f64(v, "timestamp")?;
    if let Some(p) = v.get("pose").filter(|p| !p.is_none()) {
        let m = rec.square::<4>(p, "pose")?;
        info.world_from_lidar = Some(Pose::try_from_matrix(&m).map_err(|e| rec.err(e))?);
    }
    if let Some(c) = v.get("calib").filter(|c| !c.is_none()) {
        let calib = parse_calib(&rec, c)?;
        if let Calib::Pinhole { camera_from_lidar, intrinsics, distortion } = &calib {
            info.cameras.push(CameraInfo {
                name: "camera".into(),
                image_path: rec.opt_str(v, "image_path")?.map(|p| root.join(p)),
                camera_from_lidar: *camera_from_lidar,
                intrinsics: *intrinsics,
                distortion: distortion.clone(),
                // The released frames' camera; the image's own size wins when it exists.
                image_size: Some([1280, 800]),
            });
        }
        info.calib = Some(calib);
    }
    if let Some(annos) = v.get("annos").filter(|a| !a.is_none()) {
        info.objects = parse_annos(&rec, annos)?;
    }
    Ok(info)
}

fn parse_calib(rec: &Record, c: &Value) -> Result<Calib, DataError> {
    let camera_from_lidar = rec.square::<4>(rec.get(c, "E")?, "calib.E")?;
    let intrinsics = rec.square::<3>(rec.get(c, "I")?, "calib.I")?;
    let distortion = match c.get("D") {
        Some(Value::Array(a)) => a.to_f64_vec().ok_or_else(|| rec.err("'calib.D' should be numeric"))?,
        _ => Vec::new(),
    };
    Ok(Calib::Pinhole { camera_from_lidar, intrinsics, distortion })
}

fn parse_annos(rec: &Record, annos: &Value) -> Result<Vec<Object>, DataError> {
    let names = rec.strings(rec.get(annos, "gt_names")?, "gt_names")?;
    let boxes = rec.matrix(rec.get(annos, "gt_boxes_lidar")?, "gt_boxes_lidar", 7)?;
    if names.len() != boxes.len() {
        return Err(rec.err(format!("{} gt_names but {} gt_boxes_lidar rows", names.len(), boxes.len())));
    }
    let counts = match annos.get("num_points_in_gt") {
        Some(Value::Array(a)) => {
            let c = a.to_i64_vec().ok_or_else(|| rec.err("'num_points_in_gt' should be integers"))?;
            if c.len() != names.len() {
                return Err(rec.err(format!("{} num_points_in_gt for {} boxes", c.len(), names.len())));
            }
            Some(c)
        }
        _ => None,
    };
    names
        .into_iter()
        .zip(boxes)
        .enumerate()
        .map(|(k, (name, row))| {
            let b =
                Box3d::try_from_array(std::array::from_fn(|j| row[j])).map_err(|e| rec.err(format!("box {k}: {e}")))?;
            let mut o = Object::new(name, b);
            // numpy files use -1 for "not counted".
            o.num_points = counts.as_ref().and_then(|c| u32::try_from(c[k]).ok());
            Ok(o)
        })
        .collect()
}

/// Writes frames in the Pi3DET layout. Point files go to `training/point_cloud/<id>.bin`; the info
/// file is written by [`Pi3detWriter::finish`]. Existing files are never replaced unless
/// `overwrite` is set.
pub struct Pi3detWriter {
    root: PathBuf,
    split: String,
    overwrite: bool,
    infos: Vec<Value>,
}

impl Pi3detWriter {
    pub fn create(root: &Path, split: &str, overwrite: bool) -> Result<Self, DataError> {
        let info_path = root.join(format!("pi3det_infos_{split}.pkl"));
        if !overwrite && info_path.exists() {
            return Err(DataError::Exists { path: info_path });
        }
        Ok(Self { root: root.to_path_buf(), split: split.to_string(), overwrite, infos: Vec::new() })
    }

    pub fn write_frame(&mut self, frame: &Frame) -> Result<(), DataError> {
        let info = &frame.info;
        let rel = format!("training/point_cloud/{}.bin", info.id);
        write_bin(&self.root.join(&rel), &frame.points.to_xyzi(), self.overwrite)?;
        self.infos.push(info_value(info, &rel, &self.root));
        Ok(())
    }

    /// Writes the info file and returns its path.
    pub fn finish(self) -> Result<PathBuf, DataError> {
        let path = self.root.join(format!("pi3det_infos_{}.pkl", self.split));
        let bytes = pickle::to_vec(&Value::List(self.infos))
            .map_err(|source| DataError::Pickle { path: path.clone(), source })?;
        write_atomic(&path, &bytes, self.overwrite)?;
        Ok(path)
    }
}

/// Writes an info file for frames whose point files already exist (a corrected label set beside
/// the original): each `points_path` is kept, written relative to the info file's folder when it
/// lies under it (as the released files do) and absolute otherwise. No point file is written;
/// an existing `path` is not replaced unless `overwrite`.
pub fn write_infos(path: &Path, infos: &[FrameInfo], overwrite: bool) -> Result<(), DataError> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    // Canonical paths, so that a point path relative to the working directory (data opened by a
    // relative path) still resolves from the info file's folder.
    let dir = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.to_path_buf());
    let values = infos
        .iter()
        .map(|info| {
            let points = std::fs::canonicalize(&info.points_path).unwrap_or_else(|_| info.points_path.clone());
            let rel = points.strip_prefix(&dir).unwrap_or(&points);
            let rel = rel.to_str().ok_or_else(|| {
                DataError::invalid(&info.points_path, "point file path is not UTF-8; cannot be written to an info file")
            })?;
            Ok(info_value(info, rel, &dir))
        })
        .collect::<Result<Vec<_>, DataError>>()?;
    let bytes = pickle::to_vec(&Value::List(values))
        .map_err(|source| DataError::Pickle { path: path.to_path_buf(), source })?;
    write_atomic(path, &bytes, overwrite)
}

fn array2(rows: usize, cols: usize, data: Vec<f64>) -> Value {
    Value::Array(NdArray { shape: vec![rows, cols], data: data.into() })
}

/// The info dict of a frame. The camera image is not copied: its path is kept, relative to
/// `root` (the info file's folder) when inside it.
fn info_value(info: &FrameInfo, rel_points: &str, root: &Path) -> Value {
    let names: Vec<String> = info.objects.iter().map(|o| o.name.clone()).collect();
    let boxes: Vec<f32> = info.objects.iter().flat_map(|o| o.box3d.to_array().map(|v| v as f32)).collect();
    let counts: Vec<i64> = info.objects.iter().map(|o| o.num_points.map_or(-1, i64::from)).collect();
    let n = names.len();
    let annos = Value::dict([
        ("gt_names", Value::Array(NdArray::from_vec(names))),
        ("gt_boxes_lidar", Value::Array(NdArray { shape: vec![n, 7], data: boxes.into() })),
        ("num_points_in_gt", Value::Array(NdArray::from_vec(counts))),
    ]);
    let mut d: Vec<(&str, Value)> = vec![
        ("frame_id", Value::Str(info.id.clone())),
        ("platform", Value::Str(info.platform.as_str().into())),
        // The released files spell the key this way; readers of the public code expect it.
        ("point_clout_path", Value::Str(rel_points.into())),
    ];
    if let Some(s) = &info.sequence {
        d.push(("sequence", Value::Str(s.clone())));
    }
    if let Some(t) = info.timestamp_s {
        d.push(("timestamp", Value::Float(t)));
    }
    if let Some(p) = &info.world_from_lidar {
        d.push(("pose", array2(4, 4, p.to_matrix_rows().iter().flatten().copied().collect())));
    }
    if let Some(Calib::Pinhole { camera_from_lidar, intrinsics, distortion }) = &info.calib {
        d.push((
            "calib",
            Value::dict([
                ("E", array2(4, 4, camera_from_lidar.iter().flatten().copied().collect())),
                ("I", array2(3, 3, intrinsics.iter().flatten().copied().collect())),
                ("D", Value::Array(NdArray::from_vec(distortion.clone()))),
            ]),
        ));
    }
    let image = info.cameras.first().and_then(|c| c.image_path.as_ref()).map(|image| {
        let image = std::fs::canonicalize(image).unwrap_or_else(|_| image.clone());
        let root = std::fs::canonicalize(root).unwrap_or_else(|_| root.to_path_buf());
        image.strip_prefix(&root).unwrap_or(&image).to_string_lossy().into_owned()
    });
    if let Some(image) = &image {
        d.push(("image_path", Value::Str(image.clone())));
    }
    d.push(("annos", annos));
    Value::dict(d)
}
