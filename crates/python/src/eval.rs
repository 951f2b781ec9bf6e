//! `pi3det.eval`: OpenPCDet's `get_official_eval_result` on its own annotation dicts (camera
//! frame, the KITTI fields), and the same evaluation of LiDAR-frame boxes through OpenPCDet's
//! `transform_annotations_to_kitti_format` (the fake KITTI camera), for data without cameras.

use std::collections::BTreeMap;
use std::path::PathBuf;

use pi3det_data::{FrameInfo, Object};
use pi3det_eval::classes::default_overlaps;
use pi3det_eval::{
    default_compute_aos, evaluate, evaluate_kitti, format_openpcdet, ClassSpec, Detections, EvalOptions, GroupResult,
    KittiFrame, KittiObject, MetricAp,
};
use pyo3::exceptions::{PyKeyError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::arrays::{boxes, item, rows, strings, vector};
use crate::error;

/// OpenPCDet's `class_to_name` (the classes its threshold table has, by index).
const CLASS_TO_NAME: [&str; 6] = ["Car", "Pedestrian", "Cyclist", "Van", "Person_sitting", "Truck"];

/// `current_classes` as OpenPCDet takes it: a name, an index, or a list of either.
fn class_names(classes: &Bound<'_, PyAny>) -> PyResult<Vec<String>> {
    let one = |c: &Bound<'_, PyAny>| -> PyResult<String> {
        if let Ok(i) = c.extract::<usize>() {
            return CLASS_TO_NAME.get(i).map(|s| s.to_string()).ok_or_else(|| {
                PyKeyError::new_err(format!("class index {i}: OpenPCDet's table has 0..=5 ({CLASS_TO_NAME:?})"))
            });
        }
        let s: String = c.extract().map_err(|_| PyTypeError::new_err("current_classes: expected str or int items"))?;
        // Canonical spelling, so the result string and the dict keys read as OpenPCDet's.
        Ok(CLASS_TO_NAME.iter().find(|n| n.eq_ignore_ascii_case(&s)).map_or(s, |n| n.to_string()))
    };
    if classes.is_instance_of::<pyo3::types::PyString>() || classes.extract::<usize>().is_ok() {
        return Ok(vec![one(classes)?]);
    }
    classes
        .try_iter()
        .map_err(|_| PyTypeError::new_err("current_classes: expected a class name, an index or a list of them"))?
        .map(|c| one(&c?))
        .collect()
}

fn class_specs(names: &[String]) -> PyResult<Vec<ClassSpec>> {
    names
        .iter()
        .map(|n| {
            let overlaps = default_overlaps(n).ok_or_else(|| {
                PyKeyError::new_err(format!(
                    "class {n:?} has no IoU thresholds in OpenPCDet's table ({CLASS_TO_NAME:?}); kitti_eval_lidar takes overlaps for other classes"
                ))
            })?;
            Ok(ClassSpec { name: n.clone(), overlaps })
        })
        .collect()
}

/// One of OpenPCDet's annotation dicts (`get_label_anno`, `generate_prediction_dicts`) as a frame.
fn kitti_frame(anno: &Bound<'_, PyAny>, what: &str, index: usize) -> PyResult<KittiFrame> {
    let at = || format!("{what}[{index}]");
    let d = anno.cast::<PyDict>().map_err(|_| PyTypeError::new_err(format!("{}: expected a dict", at())))?;
    let key = |k: &str| item(d, k, &at);
    let names = strings(&key("name")?, &|| format!("{}['name']", at()))?;
    let n = names.len();
    let vec_of = |k: &str, default: Option<f64>| -> PyResult<Vec<f64>> {
        let v = match (d.get_item(k)?, default) {
            (Some(x), _) => vector(&x, &|| format!("{}['{k}']", at()))?,
            (None, Some(v)) => vec![v; n],
            (None, None) => return Err(PyKeyError::new_err(format!("{}: no key '{k}'", at()))),
        };
        same_len(v.len(), n, k, &at)?;
        Ok(v)
    };
    let truncated = vec_of("truncated", None)?;
    let occluded = vec_of("occluded", None)?;
    let alpha = vec_of("alpha", None)?;
    let rotation_y = vec_of("rotation_y", None)?;
    let score = vec_of("score", Some(0.0))?;
    let bbox = rows::<4>(&key("bbox")?, &|| format!("{}['bbox']", at()))?;
    let dimensions = rows::<3>(&key("dimensions")?, &|| format!("{}['dimensions']", at()))?;
    let location = rows::<3>(&key("location")?, &|| format!("{}['location']", at()))?;
    for (k, len) in [("bbox", bbox.len()), ("dimensions", dimensions.len()), ("location", location.len())] {
        same_len(len, n, k, &at)?;
    }
    let objects = (0..n)
        .map(|i| KittiObject {
            name: names[i].clone(),
            truncated: truncated[i],
            occluded: occluded[i],
            alpha: alpha[i],
            bbox: bbox[i],
            dimensions: dimensions[i],
            location: location[i],
            rotation_y: rotation_y[i],
            score: score[i],
        })
        .collect();
    Ok(KittiFrame { id: index.to_string(), objects })
}

fn same_len(len: usize, n: usize, key: &str, at: &dyn Fn() -> String) -> PyResult<()> {
    if len == n {
        Ok(())
    } else {
        Err(PyValueError::new_err(format!("{}: '{key}' has {len} entries for {n} names", at())))
    }
}

fn frames(annos: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<KittiFrame>> {
    annos
        .try_iter()
        .map_err(|_| PyTypeError::new_err(format!("{what}: expected a list of annotation dicts")))?
        .enumerate()
        .map(|(i, a)| kitti_frame(&a?, what, i))
        .collect()
}

fn triple(py: Python<'_>, v: [f64; 3]) -> PyResult<Bound<'_, PyList>> {
    PyList::new(py, v)
}

fn metric<'py>(py: Python<'py>, m: &MetricAp) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("r11", triple(py, m.r11)?)?;
    d.set_item("r40", triple(py, m.r40)?)?;
    Ok(d)
}

/// OpenPCDet's return value: the text block and `ret_dict` (R40 at the strict overlaps: aos when
/// computed, then 3d, bev, image, per class, in its insertion order), plus every number as
/// `{class: {num_gt, num_det, sets: [{min_overlaps, bbox, bev, 3d, aos?: {r11, r40}}]}}`.
fn results<'py>(py: Python<'py>, g: &GroupResult) -> PyResult<(String, Bound<'py, PyDict>, Bound<'py, PyDict>)> {
    let ret = PyDict::new(py);
    let detail = PyDict::new(py);
    for c in &g.classes {
        if let Some(s) = c.sets.first() {
            if let Some(aos) = &s.aos {
                for (d, diff) in ["easy", "moderate", "hard"].iter().enumerate() {
                    ret.set_item(format!("{}_aos/{diff}_R40", c.class), aos.r40[d])?;
                }
            }
            for (name, m) in [("3d", &s.d3), ("bev", &s.bev), ("image", &s.bbox)] {
                for (d, diff) in ["easy", "moderate", "hard"].iter().enumerate() {
                    ret.set_item(format!("{}_{name}/{diff}_R40", c.class), m.r40[d])?;
                }
            }
        }
        let sets = PyList::empty(py);
        for s in &c.sets {
            let sd = PyDict::new(py);
            sd.set_item("min_overlaps", triple(py, s.min_overlaps)?)?;
            sd.set_item("bbox", metric(py, &s.bbox)?)?;
            sd.set_item("bev", metric(py, &s.bev)?)?;
            sd.set_item("3d", metric(py, &s.d3)?)?;
            if let Some(aos) = &s.aos {
                sd.set_item("aos", metric(py, aos)?)?;
            }
            sets.append(sd)?;
        }
        let cd = PyDict::new(py);
        cd.set_item("num_gt", PyList::new(py, c.num_gt)?)?;
        cd.set_item("num_det", c.num_det)?;
        cd.set_item("sets", sets)?;
        detail.set_item(&c.class, cd)?;
    }
    Ok((format_openpcdet(g), ret, detail))
}

type Results<'py> = (String, Bound<'py, PyDict>, Bound<'py, PyDict>);

/// Minimum overlaps `[bbox, bev, 3d]` of the strict and the loose set.
type StrictLoose = ([f64; 3], [f64; 3]);

/// Camera-frame annotation dicts (OpenPCDet / mmdet3d) → `(result_str, ret_dict, detail)`.
#[pyfunction]
#[pyo3(signature = (gt_annos, dt_annos, current_classes, compute_aos=None))]
pub fn kitti_eval<'py>(
    py: Python<'py>,
    gt_annos: &Bound<'py, PyAny>,
    dt_annos: &Bound<'py, PyAny>,
    current_classes: &Bound<'py, PyAny>,
    compute_aos: Option<bool>,
) -> PyResult<Results<'py>> {
    let specs = class_specs(&class_names(current_classes)?)?;
    let gt = frames(gt_annos, "gt_annos")?;
    let dt = frames(dt_annos, "dt_annos")?;
    if gt.len() != dt.len() {
        return Err(PyValueError::new_err(format!("{} gt_annos but {} dt_annos", gt.len(), dt.len())));
    }
    let aos = compute_aos.unwrap_or_else(|| default_compute_aos(&dt));
    let g = py.detach(|| evaluate_kitti("all", &gt, &dt, &specs, aos)).map_err(error::eval)?;
    results(py, &g)
}

/// The same numbers with full precision (no string): kept for the tests and notebooks.
#[pyfunction]
#[pyo3(signature = (gt_annos, dt_annos, current_classes, compute_aos=None))]
pub fn kitti_eval_detail<'py>(
    py: Python<'py>,
    gt_annos: &Bound<'py, PyAny>,
    dt_annos: &Bound<'py, PyAny>,
    current_classes: &Bound<'py, PyAny>,
    compute_aos: Option<bool>,
) -> PyResult<Bound<'py, PyDict>> {
    Ok(kitti_eval(py, gt_annos, dt_annos, current_classes, compute_aos)?.2)
}

/// LiDAR-frame boxes of one frame: `name` and `gt_boxes_lidar` / `boxes_lidar`, with `score`
/// for detections.
fn lidar_objects(anno: &Bound<'_, PyAny>, what: &str, index: usize, scored: bool) -> PyResult<Vec<Object>> {
    let at = || format!("{what}[{index}]");
    let d = anno.cast::<PyDict>().map_err(|_| PyTypeError::new_err(format!("{}: expected a dict", at())))?;
    let names = strings(&item(d, "name", &at)?, &|| format!("{}['name']", at()))?;
    let key = ["gt_boxes_lidar", "boxes_lidar"].into_iter().find(|k| d.contains(*k).unwrap_or(false));
    let Some(key) = key else {
        return Err(PyKeyError::new_err(format!("{}: no key 'gt_boxes_lidar' or 'boxes_lidar'", at())));
    };
    let bxs = boxes(&item(d, key, &at)?, &|| format!("{}['{key}']", at()))?;
    same_len(bxs.len(), names.len(), key, &at)?;
    let scores = if scored {
        let s = vector(&item(d, "score", &at)?, &|| format!("{}['score']", at()))?;
        same_len(s.len(), names.len(), "score", &at)?;
        s.into_iter().map(Some).collect()
    } else {
        vec![None; names.len()]
    };
    Ok(names.into_iter().zip(bxs).zip(scores).map(|((n, b), s)| Object { score: s, ..Object::new(n, b) }).collect())
}

/// LiDAR-frame boxes (Pi3DET, nuScenes, the simulator: no camera) evaluated as OpenPCDet does
/// after `transform_annotations_to_kitti_format`; names go through `name_map` (default
/// Vehicle → Car), `overlaps` adds classes outside OpenPCDet's table.
#[pyfunction]
#[pyo3(signature = (gt_annos, dt_annos, current_classes, name_map=None, score_threshold=None, bev_range=None, overlaps=None))]
#[allow(clippy::too_many_arguments)]
pub fn kitti_eval_lidar<'py>(
    py: Python<'py>,
    gt_annos: &Bound<'py, PyAny>,
    dt_annos: &Bound<'py, PyAny>,
    current_classes: &Bound<'py, PyAny>,
    name_map: Option<BTreeMap<String, String>>,
    score_threshold: Option<f64>,
    bev_range: Option<[f64; 4]>,
    overlaps: Option<BTreeMap<String, StrictLoose>>,
) -> PyResult<Results<'py>> {
    let classes = class_names(current_classes)?;
    let mut infos = Vec::new();
    let mut dets = Vec::new();
    let gts: Vec<Bound<'py, PyAny>> = gt_annos.try_iter()?.collect::<PyResult<_>>()?;
    let dts: Vec<Bound<'py, PyAny>> = dt_annos.try_iter()?.collect::<PyResult<_>>()?;
    if gts.len() != dts.len() {
        return Err(PyValueError::new_err(format!("{} gt_annos but {} dt_annos", gts.len(), dts.len())));
    }
    for (i, (g, d)) in gts.iter().zip(&dts).enumerate() {
        // Frames are matched by position, as OpenPCDet zips the two lists.
        let id = format!("{i:06}");
        let mut info = FrameInfo::new(id.clone(), PathBuf::new());
        info.objects = lidar_objects(g, "gt_annos", i, false)?;
        infos.push(info);
        dets.push((id, lidar_objects(d, "dt_annos", i, true)?));
    }
    let dets = Detections::from_objects(dets).map_err(error::eval)?;
    let mut opts = EvalOptions {
        classes,
        score_threshold,
        bev_range,
        per_platform: false,
        per_sequence: false,
        ..EvalOptions::default()
    };
    if let Some(m) = name_map {
        opts.name_map = m;
    }
    for (k, (strict, loose)) in overlaps.unwrap_or_default() {
        opts.overlaps.insert(k, pi3det_eval::Overlaps { strict, loose });
    }
    let report = py.detach(|| evaluate(&infos, &dets, &opts)).map_err(error::eval)?;
    results(py, &report.overall)
}
