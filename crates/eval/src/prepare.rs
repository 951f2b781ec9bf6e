//! One frame turned into what the passes need: class/difficulty states of every object, the
//! sparse overlaps of the three metrics and the DontCare overlaps.

use crate::anno::KittiFrame;
use crate::difficulty::{ignored_dt, ignored_gt, GtFields, MIN_HEIGHT};
use crate::overlaps::{bev_and_3d, image_overlap, EvalBox, Sparse};

/// Metrics in the reference's order.
pub const METRICS: [&str; 3] = ["bbox", "bev", "3d"];

/// The states of one class at one difficulty (`clean_data`'s output).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct States {
    pub gt: Vec<i8>,
    pub dt: Vec<i8>,
    pub num_valid_gt: usize,
}

#[derive(Debug)]
pub(crate) struct PreparedFrame {
    pub gt_alpha: Vec<f64>,
    pub dt_alpha: Vec<f64>,
    pub dt_score: Vec<f64>,
    /// `[class][difficulty]`.
    pub states: Vec<[States; 3]>,
    /// Rows: ground truths; entries: detections. `[bbox, bev, 3d]`.
    pub overlaps: [Sparse; 3],
    /// `Some(v)` when every used ground truth overlaps every used detection by the same `v` in
    /// that metric: the 2D metric of datasets with the fake 50 px boxes (all overlaps 1), where
    /// matching reduces to taking detections in order (see `matching`).
    pub uniform: [Option<f64>; 3],
    /// Rows: DontCare regions; entries: detections with their intersection over the
    /// detection's own image area.
    pub dontcare: Sparse,
    /// Detections per evaluated class (for the report).
    pub num_dt: Vec<usize>,
}

impl PreparedFrame {
    /// `classes_lc`: evaluated class names in lower case.
    pub fn new(gt: &KittiFrame, dt: &KittiFrame, classes_lc: &[String]) -> Self {
        let gt_fields: Vec<GtFields> = gt
            .objects
            .iter()
            .map(|o| GtFields {
                name_lc: o.name.to_lowercase(),
                height: o.bbox[3] - o.bbox[1],
                occluded: o.occluded,
                truncated: o.truncated,
            })
            .collect();
        let dt_name_lc: Vec<String> = dt.objects.iter().map(|o| o.name.to_lowercase()).collect();
        let dt_height: Vec<f64> = dt.objects.iter().map(|o| (o.bbox[3] - o.bbox[1]).abs()).collect();

        let states: Vec<[States; 3]> = classes_lc
            .iter()
            .map(|c| {
                std::array::from_fn(|d| {
                    let g: Vec<i8> = gt_fields.iter().map(|f| ignored_gt(f, c, d)).collect();
                    let num_valid_gt = g.iter().filter(|&&s| s == 0).count();
                    let t = dt_name_lc.iter().zip(&dt_height).map(|(n, &h)| ignored_dt(n, h, c, d)).collect();
                    States { gt: g, dt: t, num_valid_gt }
                })
            })
            .collect();

        // Only pairs some class/difficulty can use: GTs not -1 everywhere, detections that are of
        // an evaluated class or small enough to be ignored (which makes them matchable).
        let gt_used: Vec<bool> =
            (0..gt.objects.len()).map(|i| states.iter().any(|s| s.iter().any(|s| s.gt[i] != -1))).collect();
        let max_min_height = MIN_HEIGHT.iter().cloned().fold(f64::MIN, f64::max);
        let dt_used: Vec<bool> = dt_name_lc
            .iter()
            .zip(&dt_height)
            .map(|(n, &h)| h < max_min_height || classes_lc.iter().any(|c| c == n))
            .collect();
        let dt_boxes: Vec<EvalBox> =
            dt.objects.iter().map(|o| EvalBox::new(o.location, o.dimensions, o.rotation_y)).collect();

        let mut overlaps: [Sparse; 3] = std::array::from_fn(|_| Sparse::with_rows(gt.objects.len()));
        // Track whether each metric is one value over all used pairs.
        let mut first: [Option<f64>; 3] = [None; 3];
        let mut uniform = [true; 3];
        for (i, g) in gt.objects.iter().enumerate() {
            if gt_used[i] {
                let gb = EvalBox::new(g.location, g.dimensions, g.rotation_y);
                for (j, d) in dt.objects.iter().enumerate() {
                    if !dt_used[j] {
                        continue;
                    }
                    let (bev, d3) = bev_and_3d(&dt_boxes[j], &gb);
                    let v = [image_overlap(&d.bbox, &g.bbox, false), bev, d3];
                    for m in 0..3 {
                        overlaps[m].push(j, v[m]);
                        uniform[m] &= *first[m].get_or_insert(v[m]) == v[m];
                    }
                }
            }
            for m in &mut overlaps {
                m.end_row();
            }
        }
        let uniform = std::array::from_fn(|m| if uniform[m] { first[m] } else { None });

        // DontCare regions: the exact (case-sensitive) name, as the reference checks it.
        let mut dontcare = Sparse::with_rows(0);
        for g in gt.objects.iter().filter(|g| g.name == "DontCare") {
            for (j, d) in dt.objects.iter().enumerate() {
                if classes_lc.iter().any(|c| *c == dt_name_lc[j]) {
                    dontcare.push(j, image_overlap(&d.bbox, &g.bbox, true));
                }
            }
            dontcare.end_row();
        }

        let num_dt = classes_lc.iter().map(|c| dt_name_lc.iter().filter(|n| *n == c).count()).collect();
        Self {
            gt_alpha: gt.objects.iter().map(|o| o.alpha).collect(),
            dt_alpha: dt.objects.iter().map(|o| o.alpha).collect(),
            dt_score: dt.objects.iter().map(|o| o.score).collect(),
            states,
            overlaps,
            uniform,
            dontcare,
            num_dt,
        }
    }
}
