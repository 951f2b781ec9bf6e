//! REDB's selection (Chen et al. 2023) over a self-training round's pseudo-labels.

use super::*;
use pi3det_adapt::baselines::redb as baseline;

/// REDB's selection over `labels` (positives only; the rest stay in the ignored band):
/// examination by the mirrored view, points per box from the frames, then [`baseline::select`].
pub(super) fn redb_select(
    det: &Detector,
    target: &Subset,
    mut labels: Vec<FrameDetections>,
    positive: f64,
    cfg: &baseline::RedbConfig,
) -> pi3det_nn::Result<Vec<FrameDetections>> {
    let prep = Preprocessor::new(det.cfg())?;
    let mirrored = detect_in_view(det, prep, target, View { flip_y: true, yaw_rad: 0.0 }, 4)
        .map_err(|e| pi3det_nn::NnError::Input(format!("REDB examination: {e:#}")))?;
    let mut cands = Vec::new();
    let mut slots = Vec::new();
    for (fi, (f, m)) in labels.iter().zip(&mirrored).enumerate() {
        let positives: Vec<usize> =
            (0..f.objects.len()).filter(|&k| f.objects[k].score.unwrap_or(1.0) >= positive).collect();
        if positives.is_empty() {
            continue;
        }
        let frame = target.dataset.load(target.indices[fi]).map_err(pi3det_nn::NnError::from)?;
        let pts: Vec<[f64; 3]> = frame.points.xyz_f64().collect();
        for k in positives {
            let o: &Object = &f.objects[k];
            let examination_iou = m
                .objects
                .iter()
                .filter(|x| x.name == o.name)
                .map(|x| pi3det_geometry::iou_3d(&x.box3d, &o.box3d))
                .fold(0.0, f64::max);
            let points = pts.iter().filter(|p| o.box3d.contains(**p)).count();
            cands.push(Candidate {
                class: det.cfg().class_index(&o.name).unwrap_or(0),
                score: o.score.unwrap_or(1.0),
                examination_iou,
                range_m: o.box3d.x.hypot(o.box3d.y),
                points,
            });
            slots.push((fi, k));
        }
    }
    let keep = baseline::select(&cands, cfg);
    for ((fi, k), kept) in slots.into_iter().zip(keep) {
        if !kept {
            labels[fi].objects[k].score = Some(0.0);
        }
    }
    Ok(labels)
}
