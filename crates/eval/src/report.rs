//! Text output: OpenPCDet's `get_official_eval_result` block, the paper's "BEV / 3D" line, and
//! the report as a whole.

use std::fmt::Write as _;

use crate::protocol::{GroupResult, MetricAp};
use crate::run::EvalReport;

/// Python's `{:.Nf}` (which writes `nan`, not Rust's `NaN`).
fn num(v: f64, digits: usize) -> String {
    if v.is_nan() {
        "nan".into()
    } else {
        format!("{v:.digits$}")
    }
}

fn line(out: &mut String, label: &str, v: &[f64; 3], digits: usize) {
    let _ = writeln!(out, "{label}:{}, {}, {}", num(v[0], digits), num(v[1], digits), num(v[2], digits));
}

/// The block OpenPCDet prints, per class and overlap set: R11 (`AP@`) then R40 (`AP_R40@`).
pub fn format_openpcdet(g: &GroupResult) -> String {
    let mut out = String::new();
    for c in &g.classes {
        for s in &c.sets {
            let [a, b, d] = s.min_overlaps;
            for (tag, pick) in [("AP", false), ("AP_R40", true)] {
                let v = |m: &MetricAp| if pick { m.r40 } else { m.r11 };
                let _ = writeln!(out, "{} {tag}@{a:.2}, {b:.2}, {d:.2}:", c.class);
                line(&mut out, "bbox AP", &v(&s.bbox), 4);
                line(&mut out, "bev  AP", &v(&s.bev), 4);
                line(&mut out, "3d   AP", &v(&s.d3), 4);
                if let Some(aos) = &s.aos {
                    line(&mut out, "aos  AP", &v(aos), 2);
                }
            }
        }
    }
    out
}

/// One line per class in the paper's form: R40 at moderate, "BEV / 3D" at the strict set's
/// thresholds (Car 0.7, Pedestrian 0.5) and at the loose set's (0.5 / 0.25).
pub fn format_paper(g: &GroupResult) -> String {
    let mut out = String::new();
    for c in &g.classes {
        let _ = write!(out, "{:<12} R40 moderate BEV / 3D", c.class);
        for s in &c.sets {
            let _ = write!(out, "  @{:.2}: {} / {}", s.min_overlaps[2], num(s.bev.r40[1], 2), num(s.d3.r40[1], 2));
        }
        let _ = writeln!(out, "   ({} GT, {} det)", c.num_gt[1], c.num_det);
    }
    out
}

/// The whole report: the OpenPCDet block and paper lines for the split, then paper lines for
/// each platform / sequence.
pub fn format_report(r: &EvalReport) -> String {
    let mut out = String::new();
    let o = &r.overall;
    let _ = writeln!(
        out,
        "KITTI-protocol evaluation of {} frames ({} with KITTI calibration, {} with the fake KITTI fields){}",
        o.num_frames,
        r.kitti_frames,
        o.num_frames - r.kitti_frames,
        r.options.score_threshold.map(|t| format!(", detections scoring ≥ {t}")).unwrap_or_default()
    );
    if r.frames_without_detections > 0 {
        let _ = writeln!(out, "{} ground-truth frames have no detection entry", r.frames_without_detections);
    }
    if r.unknown_detection_frames > 0 {
        let _ = writeln!(out, "{} detection frames are not in the ground truth (skipped)", r.unknown_detection_frames);
    }
    out.push('\n');
    out.push_str(&format_openpcdet(o));
    out.push('\n');
    out.push_str(&format_paper(o));
    for g in &r.groups {
        let _ = writeln!(out, "\n[{}] {} frames", g.name, g.num_frames);
        out.push_str(&format_paper(g));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{ClassResult, SetResult};

    #[test]
    fn openpcdet_layout() {
        let m = MetricAp { r11: [90.77501, 89.9, f64::NAN], r40: [1.0, 2.0, 3.0] };
        let g = GroupResult {
            name: "all".into(),
            num_frames: 1,
            compute_aos: true,
            classes: vec![ClassResult {
                class: "Car".into(),
                num_gt: [1, 2, 3],
                num_det: 4,
                sets: vec![SetResult { min_overlaps: [0.7, 0.5, 0.5], bbox: m, bev: m, d3: m, aos: Some(m) }],
            }],
        };
        let t = format_openpcdet(&g);
        let want = "Car AP@0.70, 0.50, 0.50:\nbbox AP:90.7750, 89.9000, nan\nbev  AP:90.7750, 89.9000, nan\n\
                    3d   AP:90.7750, 89.9000, nan\naos  AP:90.78, 89.90, nan\nCar AP_R40@0.70, 0.50, 0.50:\n\
                    bbox AP:1.0000, 2.0000, 3.0000\n";
        assert!(t.starts_with(want), "{t}");
        assert!(format_paper(&g).contains("@0.50: 2.00 / 2.00"));
    }
}
