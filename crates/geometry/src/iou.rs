//! Rotated BEV and 3D IoU in f64, and parallel pairwise matrices.

use rayon::prelude::*;

use crate::boxes::Box3d;
use crate::polygon::quad_intersection_area;

/// Area of the BEV (x–y) intersection of two boxes.
pub fn bev_intersection(a: &Box3d, b: &Box3d) -> f64 {
    let (ra, rb) = (a.bev_radius(), b.bev_radius());
    let (dx, dy) = (a.x - b.x, a.y - b.y);
    if dx * dx + dy * dy >= (ra + rb) * (ra + rb) {
        return 0.0;
    }
    quad_intersection_area(&a.bev_corners(), &b.bev_corners())
}

fn ratio(inter: f64, area_a: f64, area_b: f64) -> f64 {
    let union = area_a + area_b - inter;
    if inter <= 0.0 || union <= 0.0 {
        0.0
    } else {
        (inter / union).min(1.0)
    }
}

/// Rotated bird's-eye-view IoU.
pub fn bev_iou(a: &Box3d, b: &Box3d) -> f64 {
    ratio(bev_intersection(a, b), a.dx * a.dy, b.dx * b.dy)
}

/// Vertical overlap of the two boxes' height ranges (0 when they only touch or are apart).
pub fn height_overlap(a: &Box3d, b: &Box3d) -> f64 {
    (a.top().min(b.top()) - a.bottom().max(b.bottom())).max(0.0)
}

/// 3D IoU of upright boxes: BEV intersection × height overlap over the union of volumes.
pub fn iou_3d(a: &Box3d, b: &Box3d) -> f64 {
    let h = height_overlap(a, b);
    if h <= 0.0 {
        return 0.0;
    }
    ratio(bev_intersection(a, b) * h, a.volume(), b.volume())
}

/// A dense row-major matrix of pairwise values (rows: first box set, cols: second).
#[derive(Debug, Clone, PartialEq)]
pub struct IouMatrix {
    pub rows: usize,
    pub cols: usize,
    pub data: Vec<f64>,
}

impl IouMatrix {
    #[inline]
    pub fn get(&self, row: usize, col: usize) -> f64 {
        self.data[row * self.cols + col]
    }

    pub fn row(&self, row: usize) -> &[f64] {
        &self.data[row * self.cols..(row + 1) * self.cols]
    }

    /// Fills the matrix with `f(a[i], b[j])`, rows in parallel.
    pub fn pairwise(a: &[Box3d], b: &[Box3d], f: impl Fn(&Box3d, &Box3d) -> f64 + Sync) -> Self {
        let cols = b.len();
        let mut data = vec![0.0; a.len() * cols];
        if cols > 0 {
            data.par_chunks_mut(cols).zip(a.par_iter()).for_each(|(row, ai)| {
                for (v, bj) in row.iter_mut().zip(b) {
                    *v = f(ai, bj);
                }
            });
        }
        Self { rows: a.len(), cols, data }
    }
}

pub fn bev_iou_matrix(a: &[Box3d], b: &[Box3d]) -> IouMatrix {
    IouMatrix::pairwise(a, b, bev_iou)
}

pub fn iou_3d_matrix(a: &[Box3d], b: &[Box3d]) -> IouMatrix {
    IouMatrix::pairwise(a, b, iou_3d)
}
