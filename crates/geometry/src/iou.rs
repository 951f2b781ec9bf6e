//! Rotated BEV and 3D IoU in f64, and parallel pairwise matrices.

use rayon::prelude::*;

use crate::boxes::Box3d;
use crate::polygon::quad_intersection_area;

/// A box's bird's-eye-view footprint with what every pairwise test needs (corners, circumradius,
/// area, bounding box) computed once: NMS and IoU matrices meet each box many times, and the corners' sin/cos
/// and the radius were most of a pair's cost when the circles do not overlap.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BevFootprint {
    pub x: f64,
    pub y: f64,
    pub radius: f64,
    pub area: f64,
    pub corners: [[f64; 2]; 4],
    /// `[min x, min y, max x, max y]` of the corners.
    pub aabb: [f64; 4],
}

impl BevFootprint {
    pub fn new(b: &Box3d) -> Self {
        let corners = b.bev_corners();
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for c in &corners {
            for k in 0..2 {
                lo[k] = lo[k].min(c[k]);
                hi[k] = hi[k].max(c[k]);
            }
        }
        let aabb = [lo[0], lo[1], hi[0], hi[1]];
        Self { x: b.x, y: b.y, radius: b.bev_radius(), area: b.dx * b.dy, corners, aabb }
    }

    /// Area of the intersection with `other` (0 when the circumscribed circles are apart).
    pub fn intersection(&self, other: &Self) -> f64 {
        let (dx, dy, r) = (self.x - other.x, self.y - other.y, self.radius + other.radius);
        if dx * dx + dy * dy >= r * r {
            return 0.0;
        }
        quad_intersection_area(&self.corners, &other.corners)
    }

    pub fn iou(&self, other: &Self) -> f64 {
        ratio(self.intersection(other), self.area, other.area)
    }

    /// `self.iou(other) > threshold`, skipping the polygon clip where a bound already says no:
    /// IoU > t needs an intersection above `t·(A + B)/(1 + t)`, and the intersection is at most
    /// the smaller area and the overlap of the two axis-aligned bounding boxes. Greedy NMS meets
    /// mostly such pairs (the proposals around one object at IoU 0.7).
    pub fn iou_exceeds(&self, other: &Self, threshold: f64) -> bool {
        let need = threshold / (1.0 + threshold) * (self.area + other.area);
        if self.area.min(other.area) <= need {
            return false;
        }
        let (a, b) = (&self.aabb, &other.aabb);
        let overlap = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0) * (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
        overlap > need && self.iou(other) > threshold
    }
}

/// Area of the BEV (x–y) intersection of two boxes.
pub fn bev_intersection(a: &Box3d, b: &Box3d) -> f64 {
    BevFootprint::new(a).intersection(&BevFootprint::new(b))
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
    BevFootprint::new(a).iou(&BevFootprint::new(b))
}

/// Vertical overlap of the two boxes' height ranges (0 when they only touch or are apart).
pub fn height_overlap(a: &Box3d, b: &Box3d) -> f64 {
    (a.top().min(b.top()) - a.bottom().max(b.bottom())).max(0.0)
}

/// 3D IoU of upright boxes: BEV intersection × height overlap over the union of volumes.
pub fn iou_3d(a: &Box3d, b: &Box3d) -> f64 {
    iou_3d_with(a, &BevFootprint::new(a), b, &BevFootprint::new(b))
}

fn iou_3d_with(a: &Box3d, fa: &BevFootprint, b: &Box3d, fb: &BevFootprint) -> f64 {
    let h = height_overlap(a, b);
    if h <= 0.0 {
        return 0.0;
    }
    ratio(fa.intersection(fb) * h, a.volume(), b.volume())
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
    pub fn pairwise<A: Sync, B: Sync>(a: &[A], b: &[B], f: impl Fn(&A, &B) -> f64 + Sync) -> Self {
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
    let (fa, fb) = (footprints(a), footprints(b));
    IouMatrix::pairwise(&fa, &fb, BevFootprint::iou)
}

pub fn iou_3d_matrix(a: &[Box3d], b: &[Box3d]) -> IouMatrix {
    let with =
        |boxes: &[Box3d]| -> Vec<(Box3d, BevFootprint)> { boxes.iter().map(|b| (*b, BevFootprint::new(b))).collect() };
    let (fa, fb) = (with(a), with(b));
    IouMatrix::pairwise(&fa, &fb, |(a, fa), (b, fb)| iou_3d_with(a, fa, b, fb))
}

/// Each box's [`BevFootprint`].
pub fn footprints(boxes: &[Box3d]) -> Vec<BevFootprint> {
    boxes.iter().map(BevFootprint::new).collect()
}
