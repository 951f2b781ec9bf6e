//! The projection check over a dataset: each frame's ground truth and detections drawn into
//! every camera, and the boxes no camera sees flagged.

use std::path::{Path, PathBuf};

use image::RgbImage;
use pi3det_data::{Calib, CameraInfo, FrameInfo};
use pi3det_eval::{Detection, Detections};
use pi3det_geometry::kitti::CameraBox;
use pi3det_geometry::Box3d;
use rayon::prelude::*;

use super::camera::CameraModel;
use super::draw::{self, DET_COLOUR, GT_COLOUR};
use super::report::{BoxReport, CameraReport, Flag, FrameReport, ProjectionReport, Source, Summary};
use super::verify::Verifier;
use super::wireframe::{view_box, BoxView};
use crate::error::AutolabelError;

/// Canvas size for a camera with neither an image nor a known size.
const DEFAULT_CANVAS: [u32; 2] = [1280, 800];

/// Frame indices `start..end` (`end` `None`: to the last frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameRange {
    pub start: usize,
    pub end: Option<usize>,
}

impl std::str::FromStr for FrameRange {
    type Err = String;
    /// `A..B` (B excluded), `A..`, `..B` or a single index `N`.
    fn from_str(s: &str) -> Result<Self, String> {
        let num = |t: &str| t.trim().parse::<usize>().map_err(|_| format!("{s:?}: expected A..B, A.., ..B or N"));
        match s.split_once("..") {
            Some((a, b)) => Ok(Self {
                start: if a.trim().is_empty() { 0 } else { num(a)? },
                end: if b.trim().is_empty() { None } else { Some(num(b)?) },
            }),
            None => {
                let n = num(s)?;
                Ok(Self { start: n, end: Some(n + 1) })
            }
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ImageKind {
    #[default]
    Jpeg,
    Png,
}

#[derive(Debug, Clone, Default)]
pub struct ProjectOptions {
    pub data: PathBuf,
    pub det: Option<PathBuf>,
    pub frames: Option<FrameRange>,
    pub out: PathBuf,
    pub overwrite: bool,
    /// Only these cameras (all when empty); each must exist in every calibrated frame.
    pub cameras: Vec<String>,
    /// Detections scoring below this are left out.
    pub score_threshold: Option<f64>,
    pub verify_cmd: Option<String>,
    pub image_kind: ImageKind,
}

/// The cameras of a frame: the reader's list, else one built from the calibration.
pub fn frame_cameras(info: &FrameInfo) -> Vec<CameraModel> {
    if !info.cameras.is_empty() {
        return info.cameras.iter().map(CameraModel::from_info).collect();
    }
    match &info.calib {
        Some(Calib::Kitti(k)) => vec![CameraModel::from_info(&CameraInfo::from_kitti(k, None))],
        Some(Calib::Pinhole { camera_from_lidar, intrinsics, distortion }) => {
            let e = nalgebra::Matrix4::from_fn(|i, j| camera_from_lidar[i][j]);
            let k = nalgebra::Matrix3::from_fn(|i, j| intrinsics[i][j]);
            vec![CameraModel::new("camera", e, k, distortion)]
        }
        None => Vec::new(),
    }
}

/// One box to check.
#[derive(Debug, Clone, PartialEq)]
pub struct Item {
    pub source: Source,
    pub class: String,
    pub score: Option<f64>,
    pub box3d: Box3d,
}

impl Item {
    fn label(&self) -> String {
        match self.score {
            Some(s) => format!("{} {s:.2}", self.class),
            None => self.class.clone(),
        }
    }
}

/// A detection's LiDAR box; camera-only boxes (KITTI result files) go back through the frame's
/// KITTI calibration, or the identity camera of the evaluator elsewhere.
fn detection_box(info: &FrameInfo, d: &Detection) -> Option<Box3d> {
    if let Some(b) = d.lidar {
        return Some(b);
    }
    let c: CameraBox = d.camera?;
    Some(match &info.calib {
        Some(Calib::Kitti(k)) => k.camera_to_lidar(&c),
        _ => {
            let [l, h, w] = c.dimensions_lhw;
            let [x, y, z] = c.location;
            Box3d::new(z, -x, -y + 0.5 * h, l, w, h, -(c.rotation_y + std::f64::consts::FRAC_PI_2))
        }
    })
}

/// The boxes of a frame: ground truth, then its detections above the threshold.
pub fn frame_items(info: &FrameInfo, dets: &[Detection], score_threshold: Option<f64>) -> Vec<Item> {
    let gt =
        info.objects.iter().map(|o| Item { source: Source::Gt, class: o.name.clone(), score: o.score, box3d: o.box3d });
    let det = dets.iter().filter(|d| score_threshold.is_none_or(|t| d.score >= t)).filter_map(|d| {
        Some(Item { source: Source::Det, class: d.name.clone(), score: Some(d.score), box3d: detection_box(info, d)? })
    });
    gt.chain(det).collect()
}

/// The projected views of every item in every camera, and the resulting per-box verdicts.
pub struct FrameViews {
    pub views: Vec<Vec<BoxView>>,
    pub sizes: Vec<[u32; 2]>,
}

/// Which cameras see each item, and its flag.
pub fn verdicts(cameras: &[CameraModel], fv: &FrameViews, n_items: usize) -> Vec<(Vec<String>, Option<Flag>)> {
    (0..n_items)
        .map(|i| {
            let seen: Vec<String> = cameras
                .iter()
                .enumerate()
                .filter(|&(c, _)| fv.views[c][i].in_image(fv.sizes[c][0], fv.sizes[c][1]))
                .map(|(_, cam)| cam.name.clone())
                .collect();
            let flag = if !seen.is_empty() {
                None
            } else if fv.views.iter().all(|v| v[i].behind) {
                Some(Flag::BehindAllCameras)
            } else {
                Some(Flag::OutsideAllImages)
            };
            (seen, flag)
        })
        .collect()
}

fn load_image(cam: &CameraModel) -> (RgbImage, Option<String>) {
    let size = cam.size.unwrap_or(DEFAULT_CANVAS);
    let blank = || draw::canvas(size[0].max(1), size[1].max(1));
    let Some(path) = &cam.image_path else { return (blank(), Some("no image path in the calibration".into())) };
    if !path.exists() {
        return (blank(), Some(format!("{} not found", path.display())));
    }
    match image::io::Reader::open(path).and_then(|r| r.with_guessed_format()).map_err(|e| e.to_string()) {
        Ok(r) => match r.decode() {
            Ok(img) => (img.to_rgb8(), None),
            Err(e) => (blank(), Some(format!("{}: {e}", path.display()))),
        },
        Err(e) => (blank(), Some(format!("{}: {e}", path.display()))),
    }
}

fn sanitize(s: &str) -> String {
    s.chars().map(|c| if c.is_ascii_alphanumeric() || "-_.".contains(c) { c } else { '_' }).collect()
}

fn save(img: &RgbImage, path: &Path, kind: ImageKind) -> Result<(), AutolabelError> {
    let file = std::fs::File::create(path).map_err(|e| AutolabelError::io(path, e))?;
    let mut w = std::io::BufWriter::new(file);
    let r = match kind {
        ImageKind::Jpeg => image::codecs::jpeg::JpegEncoder::new_with_quality(&mut w, 90).encode_image(img),
        ImageKind::Png => img.write_to(&mut w, image::ImageOutputFormat::Png),
    };
    r.map_err(|e| AutolabelError::invalid(path, e.to_string()))
}

/// Every camera named by `--camera` must exist in a calibrated frame.
fn check_cameras(info: &FrameInfo, cameras: &[CameraModel], wanted: &[String]) -> Result<(), AutolabelError> {
    match wanted.iter().find(|n| !cameras.iter().any(|c| &c.name == *n)) {
        Some(missing) if !cameras.is_empty() => {
            let have: Vec<&str> = cameras.iter().map(|c| c.name.as_str()).collect();
            Err(AutolabelError::Input(format!(
                "--camera {missing}: frame {} has no such camera; its cameras are {}",
                info.id,
                have.join(", ")
            )))
        }
        _ => Ok(()),
    }
}

/// Checks one frame: draws into `out` and returns its report.
pub fn project_frame(
    index: usize,
    info: &FrameInfo,
    items: &[Item],
    opts: &ProjectOptions,
    verifier: Option<&Verifier>,
) -> Result<FrameReport, AutolabelError> {
    let mut cameras = frame_cameras(info);
    let box_report = |it: &Item| BoxReport {
        source: it.source,
        class: it.class.clone(),
        score: it.score,
        box_lidar: it.box3d.to_array(),
        cameras: Vec::new(),
        flag: None,
        verify: None,
        verify_error: None,
    };
    if cameras.is_empty() {
        return Ok(FrameReport {
            frame_id: info.id.clone(),
            index,
            cameras: Vec::new(),
            message: Some("no calibration: boxes not checked".into()),
            boxes: items.iter().map(box_report).collect(),
        });
    }
    if !opts.cameras.is_empty() {
        check_cameras(info, &cameras, &opts.cameras)?;
        cameras.retain(|c| opts.cameras.contains(&c.name));
    }
    let images: Vec<(RgbImage, Option<String>)> = cameras.iter().map(load_image).collect();
    let fv = FrameViews {
        views: cameras.iter().map(|c| items.iter().map(|it| view_box(c, &it.box3d)).collect()).collect(),
        sizes: images.iter().map(|(img, _)| [img.width(), img.height()]).collect(),
    };
    let verdicts = verdicts(&cameras, &fv, items.len());
    let mut boxes: Vec<BoxReport> = items.iter().map(box_report).collect();
    for (b, (seen, flag)) in boxes.iter_mut().zip(&verdicts) {
        b.cameras = seen.clone();
        b.flag = *flag;
    }
    if let Some(v) = verifier {
        for (i, b) in boxes.iter_mut().enumerate() {
            // The crop from the camera where the box covers most pixels, taken before drawing.
            let best = (0..cameras.len())
                .filter_map(|c| {
                    let [w, h] = fv.sizes[c];
                    fv.views[c][i].image_bbox(w, h).map(|r| (c, (r[2] - r[0]) * (r[3] - r[1]), r))
                })
                .max_by(|a, b| a.1.total_cmp(&b.1));
            let Some((c, _, r)) = best else { continue };
            let (x0, y0) = (r[0].floor().max(0.0) as u32, r[1].floor().max(0.0) as u32);
            let (x1, y1) = (r[2].ceil() as u32, r[3].ceil() as u32);
            let img = &images[c].0;
            let (w, h) =
                (x1.min(img.width()).saturating_sub(x0).max(1), y1.min(img.height()).saturating_sub(y0).max(1));
            let crop = image::imageops::crop_imm(
                img,
                x0.min(img.width().saturating_sub(1)),
                y0.min(img.height().saturating_sub(1)),
                w,
                h,
            )
            .to_image();
            match v.verify(&crop, &b.class) {
                Ok(answer) => b.verify = Some(answer),
                Err(e) => b.verify_error = Some(e),
            }
        }
    }
    let font = draw::font();
    let ext = match opts.image_kind {
        ImageKind::Jpeg => "jpg",
        ImageKind::Png => "png",
    };
    let mut reports = Vec::new();
    for (c, (cam, (mut img, missing))) in cameras.iter().zip(images).enumerate() {
        let [w, h] = fv.sizes[c];
        // Ground truth first, so detections are drawn over it.
        for (it, view) in items.iter().zip(&fv.views[c]) {
            let colour = if it.source == Source::Gt { GT_COLOUR } else { DET_COLOUR };
            draw::draw_box(&mut img, view, colour);
        }
        for (it, view) in items.iter().zip(&fv.views[c]) {
            if let Some(r) = view.image_bbox(w, h) {
                let colour = if it.source == Source::Gt { GT_COLOUR } else { DET_COLOUR };
                draw::draw_label(&mut img, &font, r[0], r[1] - 20.0, &it.label(), colour);
            }
        }
        let name = format!("{}_{}.{ext}", sanitize(&info.id), sanitize(&cam.name));
        save(&img, &opts.out.join(&name), opts.image_kind)?;
        reports.push(CameraReport {
            name: cam.name.clone(),
            image: match (&missing, &cam.image_path) {
                (None, Some(p)) => p.display().to_string(),
                _ => "none, canvas".into(),
            },
            image_missing: missing,
            width: w,
            height: h,
            output: name,
            boxes_seen: verdicts.iter().filter(|(seen, _)| seen.contains(&cam.name)).count(),
        });
    }
    Ok(FrameReport { frame_id: info.id.clone(), index, cameras: reports, message: None, boxes })
}

fn prepare_out(out: &Path, overwrite: bool) -> Result<(), AutolabelError> {
    if out.exists() {
        if !out.is_dir() {
            return Err(AutolabelError::invalid(out, "--out exists and is not a folder"));
        }
        let non_empty = std::fs::read_dir(out).map_err(|e| AutolabelError::io(out, e))?.next().is_some();
        if non_empty && !overwrite {
            return Err(AutolabelError::invalid(
                out,
                "--out exists and is not empty (pass --overwrite to write into it)",
            ));
        }
    }
    std::fs::create_dir_all(out).map_err(|e| AutolabelError::io(out, e))
}

/// Runs the check and writes the drawings and `projection_report.json` under `opts.out`.
pub fn project(opts: &ProjectOptions) -> Result<ProjectionReport, AutolabelError> {
    let dataset = pi3det_data::open(&opts.data)?;
    let infos: Vec<FrameInfo> = dataset.infos()?;
    let dets = match &opts.det {
        Some(p) => Detections::read(p)?,
        None => Detections::default(),
    };
    if let Some(id) = dets.frames.keys().find(|id| !infos.iter().any(|f| &f.id == *id)) {
        return Err(AutolabelError::invalid(
            &dets.source,
            format!("frame {id:?} is not in {} ({} frames)", opts.data.display(), infos.len()),
        ));
    }
    let range = opts.frames.unwrap_or(FrameRange { start: 0, end: None });
    let end = range.end.unwrap_or(infos.len()).min(infos.len());
    if range.start >= end {
        return Err(AutolabelError::Input(format!(
            "--frames {}..{}: selects no frame of {} ({} frames)",
            range.start,
            range.end.map_or(String::new(), |e| e.to_string()),
            opts.data.display(),
            infos.len()
        )));
    }
    if !opts.cameras.is_empty() {
        for info in &infos[range.start..end] {
            check_cameras(info, &frame_cameras(info), &opts.cameras)?;
        }
    }
    // Inputs first: nothing is written unless they check out.
    let verifier = opts.verify_cmd.as_deref().map(Verifier::new).transpose()?;
    prepare_out(&opts.out, opts.overwrite)?;
    let frames: Vec<FrameReport> = (range.start..end)
        .into_par_iter()
        .map(|i| {
            let info = &infos[i];
            let d = dets.frames.get(&info.id).map_or(&[][..], Vec::as_slice);
            project_frame(i, info, &frame_items(info, d, opts.score_threshold), opts, verifier.as_ref())
        })
        .collect::<Result<_, _>>()?;
    let report = ProjectionReport {
        data: opts.data.display().to_string(),
        det: opts.det.as_ref().map(|p| p.display().to_string()),
        summary: Summary::of(&frames),
        frames,
    };
    let path = opts.out.join("projection_report.json");
    let json = serde_json::to_vec_pretty(&report).map_err(|e| AutolabelError::invalid(&path, e.to_string()))?;
    std::fs::write(&path, json).map_err(|e| AutolabelError::io(&path, e))?;
    Ok(report)
}
