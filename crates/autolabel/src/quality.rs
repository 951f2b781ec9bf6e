//! How good a label set is against ground truth: precision and recall per class at 3-D IoU
//! thresholds (greedy by score, one ground-truth box per label), the numbers an annotator reads
//! to decide whether fused or tracked labels are worth keeping.

use pi3det_data::FrameInfo;
use pi3det_geometry::iou_3d;
use serde::{Deserialize, Serialize};

use crate::labels::LabelSet;

/// Precision and recall of one class at one IoU.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Quality {
    pub class: String,
    pub iou: f64,
    /// Label boxes and ground-truth boxes compared.
    pub labels: usize,
    pub ground_truth: usize,
    pub true_positives: usize,
    pub precision: f64,
    pub recall: f64,
}

/// Quality of `labels` against the ground truth of `gt` (frames of `gt` without labels have
/// none). `class_of` maps a class name on either side to an evaluation class (`None` skips
/// the box); `classes` are the evaluation classes to report.
pub fn quality(
    labels: &LabelSet,
    gt: &[FrameInfo],
    classes: &[&str],
    class_of: impl Fn(&str) -> Option<String>,
    ious: &[f64],
) -> Vec<Quality> {
    let mut out = Vec::new();
    for &class in classes {
        for &thr in ious {
            let (mut n_labels, mut n_gt, mut tp) = (0, 0, 0);
            for info in gt {
                let mut preds: Vec<(f64, &pi3det_geometry::Box3d)> = labels
                    .frames
                    .get(&info.id)
                    .into_iter()
                    .flatten()
                    .filter(|o| class_of(&o.name).as_deref() == Some(class))
                    .map(|o| (o.score.unwrap_or(1.0), &o.box3d))
                    .collect();
                preds.sort_by(|a, b| b.0.total_cmp(&a.0));
                let truth: Vec<_> = info
                    .objects
                    .iter()
                    .filter(|o| class_of(&o.name).as_deref() == Some(class))
                    .map(|o| &o.box3d)
                    .collect();
                let mut used = vec![false; truth.len()];
                for (_, p) in &preds {
                    let best = truth
                        .iter()
                        .enumerate()
                        .filter(|(j, _)| !used[*j])
                        .map(|(j, t)| (j, iou_3d(p, t)))
                        .max_by(|a, b| a.1.total_cmp(&b.1));
                    if let Some((j, _)) = best.filter(|(_, iou)| *iou >= thr) {
                        used[j] = true;
                        tp += 1;
                    }
                }
                n_labels += preds.len();
                n_gt += truth.len();
            }
            let ratio = |a: usize, b: usize| if b == 0 { 0.0 } else { a as f64 / b as f64 };
            out.push(Quality {
                class: class.to_string(),
                iou: thr,
                labels: n_labels,
                ground_truth: n_gt,
                true_positives: tp,
                precision: ratio(tp, n_labels),
                recall: ratio(tp, n_gt),
            });
        }
    }
    out
}

/// A markdown table, one row per (stage, class, IoU), percentages; `what` heads the stage column.
pub fn quality_table(what: &str, rows: &[(String, Vec<Quality>)]) -> String {
    let mut s = format!(
        "| {what} | class | IoU | boxes | GT | precision | recall |\n| --- | --- | --- | --- | --- | --- | --- |\n"
    );
    for (name, qs) in rows {
        for q in qs {
            s += &format!(
                "| {name} | {} | {} | {} | {} | {:.1} | {:.1} |\n",
                q.class,
                q.iou,
                q.labels,
                q.ground_truth,
                100.0 * q.precision,
                100.0 * q.recall
            );
        }
    }
    s
}
