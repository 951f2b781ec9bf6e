//! Evaluation of detections against a dataset's ground truth, with the per-platform and
//! per-sequence breakdowns.

use std::collections::BTreeSet;

use pi3det_data::{Dataset, FrameInfo};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::anno::KittiFrame;
use crate::classes::NameMap;
use crate::convert::{self, Filter};
use crate::detections::Detections;
use crate::error::EvalError;
use crate::options::EvalOptions;
use crate::protocol::{default_compute_aos, evaluate_kitti, GroupResult};

/// Everything an evaluation produced; serialises to the `--json` output.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub options: EvalOptions,
    /// Frames evaluated with a real KITTI calibration (the rest use the fake KITTI fields).
    pub kitti_frames: usize,
    /// Ground-truth frames without any detection entry.
    pub frames_without_detections: usize,
    /// Detection frames not in the ground truth (only with `allow_unknown_frames`).
    pub unknown_detection_frames: usize,
    /// The whole split.
    pub overall: GroupResult,
    /// Per platform / per sequence, when the split has several.
    pub groups: Vec<GroupResult>,
}

/// Reads every frame's annotations of a dataset (in parallel) and evaluates.
pub fn evaluate_dataset(ds: &dyn Dataset, dets: &Detections, opts: &EvalOptions) -> Result<EvalReport, EvalError> {
    let infos: Vec<FrameInfo> = ds.infos()?;
    evaluate(&infos, dets, opts)
}

/// Evaluates detections against ground-truth frames (matched by frame id).
pub fn evaluate(gt: &[FrameInfo], dets: &Detections, opts: &EvalOptions) -> Result<EvalReport, EvalError> {
    let unknown = check_inputs(gt, dets, opts)?;
    let names = NameMap::new(&opts.name_map);
    let filter = filter(opts, &names);
    let pairs: Vec<(KittiFrame, KittiFrame)> = gt
        .par_iter()
        .map(|info| {
            let d = dets.frames.get(&info.id).map(Vec::as_slice).unwrap_or(&[]);
            (convert::ground_truth(info, &filter), convert::detections(info, d, &filter))
        })
        .collect();
    let present: BTreeSet<&str> = pairs.iter().flat_map(|(g, _)| g.objects.iter().map(|o| o.name.as_str())).collect();
    let classes = opts.class_specs(present)?;
    let (gts, dts): (Vec<KittiFrame>, Vec<KittiFrame>) = pairs.into_iter().unzip();
    let compute_aos = default_compute_aos(&dts);
    let overall = evaluate_kitti("all", &gts, &dts, &classes, compute_aos)?;

    let mut groups = Vec::new();
    let mut subsets: Vec<(String, Vec<usize>)> = Vec::new();
    if opts.per_platform {
        let platforms: BTreeSet<_> = gt.iter().map(|f| f.platform).collect();
        if platforms.len() > 1 {
            for p in platforms {
                subsets.push((format!("platform={p}"), (0..gt.len()).filter(|&i| gt[i].platform == p).collect()));
            }
        }
    }
    if opts.per_sequence {
        let seqs: BTreeSet<Option<&str>> = gt.iter().map(|f| f.sequence.as_deref()).collect();
        if seqs.len() > 1 {
            for s in seqs {
                let name = format!("sequence={}", s.unwrap_or("(none)"));
                subsets.push((name, (0..gt.len()).filter(|&i| gt[i].sequence.as_deref() == s).collect()));
            }
        }
    }
    for (name, idx) in subsets {
        let g: Vec<KittiFrame> = idx.iter().map(|&i| gts[i].clone()).collect();
        let d: Vec<KittiFrame> = idx.iter().map(|&i| dts[i].clone()).collect();
        groups.push(evaluate_kitti(&name, &g, &d, &classes, compute_aos)?);
    }
    Ok(EvalReport {
        options: opts.clone(),
        kitti_frames: gt.iter().filter(|f| matches!(convert::Camera::of(f), convert::Camera::Kitti(_))).count(),
        frames_without_detections: gt.iter().filter(|f| !dets.frames.contains_key(&f.id)).count(),
        unknown_detection_frames: unknown,
        overall,
        groups,
    })
}

/// Checks options and frame ids (shared with the error breakdown); returns the number of
/// detection frames not in the ground truth (an error unless `allow_unknown_frames`).
pub(crate) fn check_inputs(gt: &[FrameInfo], dets: &Detections, opts: &EvalOptions) -> Result<usize, EvalError> {
    opts.validate()?;
    let mut ids = BTreeSet::new();
    for f in gt {
        if !ids.insert(f.id.as_str()) {
            return Err(EvalError::Input(format!("ground-truth frame id {:?} occurs twice", f.id)));
        }
    }
    let unknown: Vec<&String> = dets.frames.keys().filter(|k| !ids.contains(k.as_str())).collect();
    if !unknown.is_empty() && !opts.allow_unknown_frames {
        let few: Vec<&str> = unknown.iter().take(5).map(|s| s.as_str()).collect();
        return Err(EvalError::Input(format!(
            "{}: {} detection frame(s) are not in the ground truth (e.g. {:?}); wrong split? (allow_unknown_frames skips them)",
            dets.source.display(),
            unknown.len(),
            few
        )));
    }
    Ok(unknown.len())
}

/// The conversion filter the options ask for.
pub(crate) fn filter<'a>(opts: &EvalOptions, names: &'a NameMap) -> Filter<'a> {
    Filter { names, score_threshold: opts.score_threshold, bev_range: opts.bev_range, image_size: opts.image_size }
}
