//! The headline numbers of a report: per class, moderate AP_R40 at the strict overlap (Car 0.7,
//! Pedestrian 0.5) in BEV and 3D, and at the loose overlap where it was evaluated. What training
//! logs, the demo's table, the benchmark and [`crate::bootstrap`] read from an [`EvalReport`].

use serde::{Deserialize, Serialize};

use crate::run::EvalReport;

/// One class's headline numbers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClassAp {
    pub class: String,
    /// IoU threshold of the strict set (BEV / 3D).
    pub iou: f64,
    pub bev_r40: f64,
    pub d3_r40: f64,
    pub num_gt: usize,
    pub num_det: usize,
    /// The loose set (KITTI's second overlap set: 0.5 for cars, 0.25 for pedestrians), when evaluated.
    #[serde(default)]
    pub loose: Option<LooseAp>,
}

/// BEV / 3D AP_R40 at the loose IoU threshold.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LooseAp {
    pub iou: f64,
    pub bev_r40: f64,
    pub d3_r40: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct ApSummary {
    pub frames: usize,
    pub classes: Vec<ClassAp>,
}

impl ApSummary {
    pub fn get(&self, class: &str) -> Option<&ClassAp> {
        self.classes.iter().find(|c| c.class.eq_ignore_ascii_case(class))
    }

    /// `Car BEV@0.7 71.2 3D 60.1 | Pedestrian …`.
    pub fn one_line(&self) -> String {
        self.classes
            .iter()
            .map(|c| format!("{} BEV@{:.1} {:.1} 3D {:.1}", c.class, c.iou, c.bev_r40, c.d3_r40))
            .collect::<Vec<_>>()
            .join(" | ")
    }
}

/// The report's overall group, moderate difficulty, each evaluated class (in the report's order).
pub fn summarize(report: &EvalReport) -> ApSummary {
    let g = &report.overall;
    ApSummary {
        frames: g.num_frames,
        classes: g
            .classes
            .iter()
            .filter_map(|c| {
                let s = c.sets.first()?;
                Some(ClassAp {
                    class: c.class.clone(),
                    iou: s.min_overlaps[1],
                    bev_r40: s.bev.r40[1],
                    d3_r40: s.d3.r40[1],
                    num_gt: c.num_gt[1],
                    num_det: c.num_det,
                    loose: c.sets.get(1).map(|l| LooseAp {
                        iou: l.min_overlaps[1],
                        bev_r40: l.bev.r40[1],
                        d3_r40: l.d3.r40[1],
                    }),
                })
            })
            .collect(),
    }
}
