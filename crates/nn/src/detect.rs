//! Inference over a dataset: frames → detections (in the dataset's own frame: the config's z
//! shift undone), per-frame latency, and the files the evaluator reads: JSON lines
//! (`detections.jsonl`) and OpenPCDet's `result.pkl`.
//!
//! `pi3det detect --ckpt runs/pp/final.safetensors --data DIR --out det/`.

use std::io::Write;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use pi3det_data::pickle::{self, NdArray, Value};
use pi3det_data::{FrameInfo, Object};
use serde::{Deserialize, Serialize};

use crate::augment::Augment;
use crate::data_loader::{Loader, LoaderOptions, Subset};
use crate::detector::{Detection, Detector};
use crate::error::{NnError, Result};
use crate::preprocess::Preprocessor;

/// Detections of one frame, as dataset objects (boxes in the dataset's frame).
#[derive(Debug, Clone, PartialEq)]
pub struct FrameDetections {
    pub info: FrameInfo,
    pub objects: Vec<Object>,
}

/// Where the time of a frame went (milliseconds, means over frames).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Latency {
    pub frames: usize,
    /// Reading the file and pillarization (on the loader thread).
    pub prep_ms: f64,
    /// Network forward (libtorch), including the transfer to the device.
    pub network_ms: f64,
    /// Candidate decoding and NMS.
    pub post_ms: f64,
}

impl Latency {
    pub fn total_ms(&self) -> f64 {
        self.prep_ms + self.network_ms + self.post_ms
    }
}

/// Turns detections (detector frame) into objects in the LiDAR frame named by the config's
/// classes.
pub fn to_objects(det: &Detector, dets: &[Detection], detector_from_lidar: &pi3det_geometry::Pose) -> Vec<Object> {
    let cfg = det.cfg();
    dets.iter()
        .map(|d| {
            let b = crate::preprocess::to_lidar(&d.box3d, detector_from_lidar);
            let name = cfg.classes.get(d.class).cloned().unwrap_or_else(|| format!("class{}", d.class));
            Object { score: Some(d.score), ..Object::new(name, b) }
        })
        .collect()
}

/// Runs the detector over a subset, with the config's test-time augmentation when it has one.
/// `on_frame(done, total)` reports progress.
pub fn detect(
    det: &Detector,
    subset: &Subset,
    batch_size: usize,
    on_batch: &mut dyn FnMut(usize, usize),
) -> Result<(Vec<FrameDetections>, Latency)> {
    detect_with(det, det.prep.clone(), subset, batch_size, true, on_batch)
}

/// [`detect`] with frames prepared by `prep` (e.g. one with Virtual Platform Pose) instead of
/// the detector's own preprocessor; detections go back through each frame's transform. `tta`:
/// whether the config's test-time augmentation (`[post.tta]`, [`crate::post_process::tta`]) runs, when it has one.
pub fn detect_with(
    det: &Detector,
    prep: Arc<Preprocessor>,
    subset: &Subset,
    batch_size: usize,
    tta: bool,
    on_batch: &mut dyn FnMut(usize, usize),
) -> Result<(Vec<FrameDetections>, Latency)> {
    let tta_cfg = det.cfg().post.tta.as_ref().filter(|_| tta);
    let views = tta_cfg.map_or_else(|| vec![pi3det_geometry::View::IDENTITY], |t| t.views());
    let opts = LoaderOptions {
        batch_size: batch_size.max(1),
        train: false,
        seed: 0,
        epoch: 0,
        prefetch: 2,
        drop_last: false,
        views: views[1..].to_vec(),
    };
    let loader = Loader::new(prep, Arc::new(Vec::<Box<dyn Augment>>::new()), subset.clone(), opts);
    let total = subset.len();
    let mut out = Vec::with_capacity(total);
    let mut lat = Latency::default();
    let _guard = tch::no_grad_guard();
    for batch in loader {
        let batch = batch?;
        let n = batch.infos.len();
        let t0 = Instant::now();
        let x = batch.inputs.to_device(det.device());
        let y = det.forward_t(&x, false)?;
        if det.device().is_cuda() {
            tch::Cuda::synchronize(0);
        }
        let t1 = Instant::now();
        let mut dets = det.post_process(&y, x.batch_size)?;
        let post = &det.cfg().post;
        let classes = &det.cfg().classes;
        if let Some(t) = tta_cfg {
            // Each view's boxes back in the frame and fitted to its points there, then fused.
            let v = batch.views_per_frame;
            for (k, d) in dets.iter_mut().enumerate() {
                crate::post_process::tta::out_of_view(d, views[k % v]);
                let (index, pose) = (&batch.point_index[k / v], &batch.detector_from_lidar[k / v]);
                let one = std::slice::from_mut(d);
                crate::post_process::fit_to_points(
                    post,
                    classes,
                    one,
                    std::slice::from_ref(index),
                    std::slice::from_ref(pose),
                );
            }
            dets = dets.chunks(v).map(|views| t.merge(views, classes, post)).collect();
        } else {
            crate::post_process::fit_to_points(
                post,
                classes,
                &mut dets,
                &batch.point_index,
                &batch.detector_from_lidar,
            );
        }
        let t2 = Instant::now();
        lat.frames += n;
        lat.prep_ms += batch.prep_seconds * 1e3;
        lat.network_ms += (t1 - t0).as_secs_f64() * 1e3;
        lat.post_ms += (t2 - t1).as_secs_f64() * 1e3;
        for ((info, d), pose) in batch.infos.into_iter().zip(dets).zip(&batch.detector_from_lidar) {
            let objects = to_objects(det, &d, pose);
            out.push(FrameDetections { info, objects });
        }
        on_batch(out.len(), total);
    }
    if lat.frames > 0 {
        let f = lat.frames as f64;
        lat.prep_ms /= f;
        lat.network_ms /= f;
        lat.post_ms /= f;
    }
    Ok((out, lat))
}

/// Writes one JSON line per frame (`frame_id`, `names`, `scores`, `boxes_lidar`), the format
/// `pi3det eval` reads.
pub fn write_jsonl(path: &Path, frames: &[FrameDetections]) -> Result<()> {
    let mut buf = Vec::new();
    for f in frames {
        let line = serde_json::json!({
            "frame_id": f.info.id,
            "names": f.objects.iter().map(|o| o.name.as_str()).collect::<Vec<_>>(),
            "scores": f.objects.iter().map(|o| o.score.unwrap_or(1.0)).collect::<Vec<_>>(),
            "boxes_lidar": f.objects.iter().map(|o| o.box3d.to_array()).collect::<Vec<_>>(),
        });
        serde_json::to_writer(&mut buf, &line).map_err(|e| NnError::Input(e.to_string()))?;
        buf.write_all(b"\n").map_err(|e| NnError::io(path, e))?;
    }
    pi3det_data::io::write_atomic(path, &buf, true)?;
    Ok(())
}

/// Writes OpenPCDet's `result.pkl`: a list of dicts with `frame_id`, `name`, `score`,
/// `boxes_lidar` (N×7) and `pred_labels` (1-based class indices).
pub fn write_result_pkl(path: &Path, frames: &[FrameDetections], classes: &[String]) -> Result<()> {
    let list: Vec<Value> = frames
        .iter()
        .map(|f| {
            let n = f.objects.len();
            let names: Vec<String> = f.objects.iter().map(|o| o.name.clone()).collect();
            let scores: Vec<f32> = f.objects.iter().map(|o| o.score.unwrap_or(1.0) as f32).collect();
            let boxes: Vec<f32> = f.objects.iter().flat_map(|o| o.box3d.to_array().map(|v| v as f32)).collect();
            let labels: Vec<i64> = f
                .objects
                .iter()
                .map(|o| classes.iter().position(|c| *c == o.name).map_or(0, |k| k as i64 + 1))
                .collect();
            Value::dict([
                ("frame_id", Value::Str(f.info.id.clone())),
                ("name", Value::Array(NdArray::from_vec(names))),
                ("score", Value::Array(NdArray::from_vec(scores))),
                ("boxes_lidar", Value::Array(NdArray { shape: vec![n, 7], data: boxes.into() })),
                ("pred_labels", Value::Array(NdArray::from_vec(labels))),
            ])
        })
        .collect();
    let bytes = pickle::to_vec(&Value::List(list)).map_err(|e| NnError::Input(format!("{}: {e}", path.display())))?;
    pi3det_data::io::write_atomic(path, &bytes, true)?;
    Ok(())
}
