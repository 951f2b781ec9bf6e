//! Per-frame overlaps for the three metrics, kept sparse (only pairs that overlap at all), in
//! f64. Never across frames: most of the reference's wasted pairs come from concatenating frames.

use pi3det_geometry::iou::{height_overlap, BevFootprint};
use pi3det_geometry::Box3d;

/// A camera-frame box as the reference's rotated IoU sees it: the BEV rectangle in the camera
/// x–z plane and the vertical extent (camera y points down, location is the bottom centre).
#[derive(Debug, Clone, Copy)]
pub(crate) struct EvalBox {
    /// x = camera x, y = camera z, dx = l, dy = w, heading = −rotation_y (the reference's
    /// corners put the length axis along (cos ry, −sin ry)); z/dz carry the height as "up".
    pub bev: Box3d,
    /// Corners, circumradius and area of `bev`, computed once: a box meets every box of its frame.
    footprint: BevFootprint,
}

impl EvalBox {
    pub fn new(location: [f64; 3], lhw: [f64; 3], rotation_y: f64) -> Self {
        let [l, h, w] = lhw;
        // Up = −camera y: the box spans camera y ∈ [y − h, y], i.e. up ∈ [−y, −y + h].
        let bev = Box3d::new(location[0], location[2], -location[1] + 0.5 * h, l, w, h, -rotation_y);
        Self { bev, footprint: BevFootprint::new(&bev) }
    }

    fn volume(&self) -> f64 {
        self.bev.dx * self.bev.dz * self.bev.dy
    }
}

/// `image_box_overlap` of the reference for one pair (`criterion` −1: IoU, 0: over the first
/// box's area), with its order of float operations.
pub(crate) fn image_overlap(b: &[f64; 4], q: &[f64; 4], over_first: bool) -> f64 {
    let iw = b[2].min(q[2]) - b[0].max(q[0]);
    if iw <= 0.0 {
        return 0.0;
    }
    let ih = b[3].min(q[3]) - b[1].max(q[1]);
    if ih <= 0.0 {
        return 0.0;
    }
    let b_area = (b[2] - b[0]) * (b[3] - b[1]);
    let ua = if over_first { b_area } else { b_area + (q[2] - q[0]) * (q[3] - q[1]) - iw * ih };
    iw * ih / ua
}

/// BEV and 3D IoU from one polygon intersection (the reference's `bev_box_overlap` and
/// `d3_box_overlap`: intersection × height overlap over the union of volumes).
pub(crate) fn bev_and_3d(a: &EvalBox, b: &EvalBox) -> (f64, f64) {
    let inter = a.footprint.intersection(&b.footprint);
    if inter <= 0.0 {
        return (0.0, 0.0);
    }
    let bev = inter / (a.footprint.area + b.footprint.area - inter);
    let iw = height_overlap(&a.bev, &b.bev);
    let d3 = if iw > 0.0 {
        let inc = iw * inter;
        inc / (a.volume() + b.volume() - inc)
    } else {
        0.0
    };
    (bev, d3)
}

/// A sparse matrix in rows (ground truths, or DontCare regions) of `(detection, overlap)`
/// entries with overlap > 0, detections ascending: the reference scans detections in index
/// order and breaks ties by the first, so the order matters.
#[derive(Debug, Clone, Default)]
pub(crate) struct Sparse {
    offsets: Vec<u32>,
    entries: Vec<(u32, f64)>,
}

impl Sparse {
    pub fn with_rows(rows: usize) -> Self {
        let mut offsets = Vec::with_capacity(rows + 1);
        offsets.push(0);
        Self { offsets, entries: Vec::new() }
    }

    pub fn push(&mut self, det: usize, value: f64) {
        if value > 0.0 {
            self.entries.push((det as u32, value));
        }
    }

    pub fn end_row(&mut self) {
        self.offsets.push(self.entries.len() as u32);
    }

    #[inline]
    pub fn row(&self, r: usize) -> &[(u32, f64)] {
        match (self.offsets.get(r), self.offsets.get(r + 1)) {
            (Some(&a), Some(&b)) => &self.entries[a as usize..b as usize],
            _ => &[],
        }
    }

    pub fn rows(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_overlap_matches_the_reference_formula() {
        let a = [0.0, 0.0, 10.0, 10.0];
        let b = [5.0, 0.0, 15.0, 10.0];
        assert!((image_overlap(&a, &b, false) - 50.0 / 150.0).abs() < 1e-15);
        assert!((image_overlap(&a, &b, true) - 0.5).abs() < 1e-15);
        assert_eq!(image_overlap(&a, &[10.0, 0.0, 20.0, 10.0], false), 0.0);
    }

    #[test]
    fn camera_boxes_overlap_like_lidar_boxes() {
        // Same camera box shifted by half its length along its own axis: IoU 1/3 in BEV and 3D.
        let ry = 0.3f64;
        let a = EvalBox::new([1.0, 1.5, 20.0], [4.0, 1.5, 2.0], ry);
        let b = EvalBox::new([1.0 + 2.0 * ry.cos(), 1.5, 20.0 - 2.0 * ry.sin()], [4.0, 1.5, 2.0], ry);
        let (bev, d3) = bev_and_3d(&a, &b);
        assert!((bev - 1.0 / 3.0).abs() < 1e-12, "{bev}");
        assert!((d3 - 1.0 / 3.0).abs() < 1e-12);
        // Half the height overlapping: 3D = inter·h/2 / (2V − inter·h/2).
        let c = EvalBox::new([1.0, 1.5 + 0.75, 20.0], [4.0, 1.5, 2.0], ry);
        let (bev, d3) = bev_and_3d(&a, &c);
        assert!((bev - 1.0).abs() < 1e-12);
        assert!((d3 - 1.0 / 3.0).abs() < 1e-12, "{d3}");
        // Touching in height: no 3D overlap.
        let d = EvalBox::new([1.0, 1.5 + 1.5, 20.0], [4.0, 1.5, 2.0], ry);
        assert_eq!(bev_and_3d(&a, &d).1, 0.0);
    }

    #[test]
    fn sparse_rows() {
        let mut s = Sparse::with_rows(2);
        s.push(0, 0.5);
        s.push(1, 0.0);
        s.end_row();
        s.end_row();
        assert_eq!(s.rows(), 2);
        assert_eq!(s.row(0), &[(0, 0.5)]);
        assert!(s.row(1).is_empty() && s.row(7).is_empty());
    }
}
