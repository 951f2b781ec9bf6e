//! KITTI-protocol evaluation of 3D detections, number for number with OpenPCDet's and
//! mmdet3d's `kitti_object_eval_python` (the same numba code in both), without a GPU and fast.
//!
//! * [`evaluate()`] / [`evaluate_dataset`]: detections ([`Detections`], read from `result.pkl`, a
//!   KITTI result folder or JSON lines — formats in [`detections`]) against ground-truth frames
//!   of any `pi3det-data` reader, with [`EvalOptions`]; returns an [`EvalReport`] (serde).
//! * [`format_report`]: OpenPCDet's text block plus the paper's "BEV / 3D" lines.
//! * [`breakdown()`] / [`breakdown_dataset`]: the error breakdown (AP and recall by distance and
//!   by points per box, found-but-misplaced misses, localisation errors) as a [`Breakdown`]
//!   (serde); [`format_breakdown`] prints it; module [`mod@breakdown`] says how each figure is
//!   made.
//! * [`bootstrap::compare`]: one detection set against another on the same split, per class,
//!   with a paired bootstrap interval over sequences (within noise or resolved).
//! * [`summarize`]: a report's headline numbers ([`ApSummary`]: per class, strict-overlap
//!   moderate AP_R40 in BEV and 3D, and the loose overlap's).
//! * [`evaluate_kitti`]: the protocol itself on frames already in the reference's camera-frame
//!   form ([`KittiFrame`]).
//!
//! What is reproduced, quirks included: R11 and R40 AP whose 41 slots are indexed by score
//! threshold (one found GT gives R40 0 and R11 100/11); matching with overlap strictly above the
//! threshold, greedy over ground truths in file order; ignored ground truths (too hard, or a
//! neighbour class: Van for Car, Person_sitting for Pedestrian) consuming detections; detections
//! smaller than the difficulty's minimum height ignored whatever their class; detections of
//! another class neither TP nor FP; DontCare regions forgiving false positives of the 2D metric
//! only; AOS from the TPs' alpha; 0/0 precision giving NaN like numpy. Overlaps are exact f64
//! (the reference's float32 kernel is wrong for identical boxes, mmdet3d issue #972).

pub mod anno;
pub mod ap;
pub mod bootstrap;
pub mod breakdown;
pub mod classes;
mod convert;
pub mod detections;
pub mod difficulty;
pub mod error;
mod matching;
pub mod options;
mod overlaps;
mod prepare;
pub mod protocol;
pub mod report;
pub mod run;
pub mod summary;

#[cfg(feature = "cli")]
pub mod cli;

pub use anno::{KittiFrame, KittiObject};
pub use breakdown::{
    breakdown, breakdown_dataset, format_breakdown, AxisError, BinResult, BoxErrors, Breakdown, ClassBreakdown,
    DistanceBin, Localisation, Misplaced, PointsBin,
};
pub use classes::Overlaps;
pub use detections::{Detection, Detections, JsonlFrame};
pub use error::EvalError;
pub use options::EvalOptions;
pub use prepare::METRICS;
pub use protocol::{default_compute_aos, evaluate_kitti, ClassResult, ClassSpec, GroupResult, MetricAp, SetResult};
pub use report::{format_openpcdet, format_paper, format_report};
pub use run::{evaluate, evaluate_dataset, EvalReport};
pub use summary::{summarize, ApSummary, ClassAp, LooseAp};
