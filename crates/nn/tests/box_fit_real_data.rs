//! The post-NMS box fits ([`pi3det_nn::post_process::ground_fit`], [`pi3det_nn::post_process::bev_fit`]) on real vehicles:
//! the KITTI scans of `../shared/data/pi3det_sample` (HDL-64, in the released Pi3DET layout) and
//! the nuScenes sweep of `../shared/data/nuscenes_demo` (32 beams). The fits' settings were
//! chosen on simulated cars, whose faces are opaque planes; real cars have windows the laser
//! passes through, mirrors outside the labelled width, rounded corners, and stand on kerbs and
//! sloping roads. Each labelled vehicle is fitted as labelled and disturbed the way a detector
//! errs; the fits must bring disturbed boxes closer and leave right ones about where they are.
//!
//! A known bias (measured in results/2026-12-03-box-fits-on-real-vehicles.md): labels fitted as
//! they are keep their top, but their bottom comes down, because the ground fit's low quantile of
//! the ring around the box sits in the real ground's noise, below where KITTI and nuScenes
//! annotators put a car's wheels. Simulated ground is quieter and prefers that quantile, so the
//! default stays; the bounds below hold the bias where it is, so a change that worsens it fails.

use std::path::Path;

use pi3det_geometry::{bev_iou, iou_3d, Box3d};
use pi3det_nn::data_loader::{open_split, Subset};
use pi3det_nn::post_process::bev_fit::{self, BevFitConfig};
use pi3det_nn::post_process::ground_fit::{self, GroundFitConfig, PointIndex, INDEX_CELL_M};

/// The real labelled vehicles within 50 m, each with its frame's point index.
fn real_vehicles() -> Vec<(Box3d, std::rc::Rc<PointIndex>)> {
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    let sources = [shared.join("pi3det_sample"), shared.join("nuscenes_demo/n015-2018-07-24-11-22-45+0800.pkl")];
    let mut out = Vec::new();
    for root in sources {
        let subset = Subset::all(open_split(&root, Some("train")).unwrap());
        for &i in &subset.indices {
            let frame = subset.dataset.load(i).unwrap();
            let pts: Vec<[f32; 4]> = frame.points.iter().map(|p| [p[0], p[1], p[2], p[3]]).collect();
            let idx = std::rc::Rc::new(PointIndex::new(&pts, INDEX_CELL_M));
            let vehicles = ["Car", "Van", "Truck", "car", "truck"];
            for o in frame.info.objects.iter().filter(|o| vehicles.contains(&o.name.as_str())) {
                if o.box3d.x.hypot(o.box3d.y) < 50.0 {
                    out.push((o.box3d, idx.clone()));
                }
            }
        }
    }
    out
}

fn fit(b: &Box3d, idx: &PointIndex) -> Box3d {
    let g = ground_fit::fit_box(b, idx, &GroundFitConfig::default()).0;
    // Both datasets' scans are in the sensor's own frame: the sensor sits at the origin.
    bev_fit::fit_box(&g, idx, [0.0, 0.0], &BevFitConfig::default()).0
}

fn mean(v: impl IntoIterator<Item = f64>) -> f64 {
    let v: Vec<f64> = v.into_iter().collect();
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
fn fits_leave_real_labels_about_where_they_are() {
    let vehicles = real_vehicles();
    assert!(vehicles.len() >= 8, "{} real vehicles within 50 m", vehicles.len());
    let fitted: Vec<(Box3d, Box3d)> = vehicles.iter().map(|(t, idx)| (*t, fit(t, idx))).collect();
    let (iou3, bev) = (mean(fitted.iter().map(|(t, f)| iou_3d(t, f))), mean(fitted.iter().map(|(t, f)| bev_iou(t, f))));
    let bottom = mean(fitted.iter().map(|(t, f)| f.bottom() - t.bottom()));
    let top = mean(fitted.iter().map(|(t, f)| f.top() - t.top()));
    eprintln!(
        "{} real vehicles fitted as labelled: 3D IoU {iou3:.3}, BEV IoU {bev:.3}, bottom {bottom:+.3} m, top {top:+.3} m",
        vehicles.len()
    );
    assert!(iou3 > 0.75 && bev > 0.85, "the fits moved right boxes: 3D IoU {iou3:.3}, BEV IoU {bev:.3}");
    assert!(top.abs() < 0.1, "the top fit moved right tops by {top:+.3} m on average");
    assert!(bottom < 0.0 && bottom > -0.2, "the ground fit's known real-data bias grew: bottom {bottom:+.3} m");
}

#[test]
fn fits_move_disturbed_real_vehicles_back_towards_their_labels() {
    let (mut before, mut after) = (Vec::new(), Vec::new());
    for (truth, idx) in real_vehicles() {
        // A detector's typical error (0.3 m off, turned 0.07 rad, sunk and too low), in eight directions.
        for k in 0..8 {
            let dir = std::f64::consts::FRAC_PI_4 * k as f64;
            let disturbed = Box3d {
                x: truth.x + 0.3 * dir.cos(),
                y: truth.y + 0.3 * dir.sin(),
                z: truth.z - 0.15,
                dz: truth.dz - 0.15,
                heading: truth.heading + if k % 2 == 0 { 0.07 } else { -0.07 },
                ..truth
            };
            let fitted = fit(&disturbed, &idx);
            before.push((bev_iou(&disturbed, &truth), iou_3d(&disturbed, &truth)));
            after.push((bev_iou(&fitted, &truth), iou_3d(&fitted, &truth)));
        }
    }
    let (b0, b1) = (mean(before.iter().map(|p| p.0)), mean(after.iter().map(|p| p.0)));
    let (d0, d1) = (mean(before.iter().map(|p| p.1)), mean(after.iter().map(|p| p.1)));
    eprintln!("{} disturbed real vehicles: BEV IoU {b0:.3} -> {b1:.3}, 3D IoU {d0:.3} -> {d1:.3}", before.len());
    // The planar fit brings them back; the vertical one's real-data bias (see the header) leaves
    // 3D IoU about where it was, which the second bound holds.
    assert!(b1 > b0 + 0.02, "BEV IoU {b0:.3} -> {b1:.3}");
    assert!(d1 >= d0, "3D IoU {d0:.3} -> {d1:.3}");
}
