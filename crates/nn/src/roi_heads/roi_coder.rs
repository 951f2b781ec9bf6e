//! Box refinement residuals in each RoI's own frame (OpenPCDet `RoIHeadTemplate.assign_targets`
//! with its `ResidualCoder`): the GT is translated by −(RoI centre) and rotated by −(RoI
//! heading), its heading residual folded into `[−π/2, π/2]` (a GT facing the other way is flipped
//! by π, the corner loss does not care), then coded against the RoI as an anchor at the origin
//! with heading 0:
//!
//! `[x_l/d, y_l/d, z_l/dz_r, ln(dx/dx_r), ln(dy/dy_r), ln(dz/dz_r), Δθ]`, `d = √(dx_r² + dy_r²)`.
//!
//! Encoding runs in Rust (targets), decoding on tensors (back into the detector's frame:
//! rotate by the RoI heading, add the RoI centre, heading `Δθ + θ_r`). Also the corner loss
//! (OpenPCDet `get_corner_loss_lidar`).

use std::f64::consts::{FRAC_PI_2, PI, TAU};

use pi3det_geometry::Box3d;
use tch::Tensor;

/// Smallest RoI / GT size used in divisions and logs (zero-size padding RoIs stay finite).
const MIN_SIZE: f64 = 1e-3;

#[derive(Debug, Clone, Copy, Default)]
pub struct RoiCoder;

/// `Δθ = θ_gt − θ_roi` folded into `[−π/2, π/2]` (OpenPCDet: flip by π when the residual lies in
/// `(π/2, 3π/2)` modulo 2π).
pub fn folded_heading_residual(gt_heading: f64, roi_heading: f64) -> f64 {
    let mut r = (gt_heading - roi_heading).rem_euclid(TAU);
    if r > FRAC_PI_2 && r < 1.5 * PI {
        r = (r + PI).rem_euclid(TAU);
    }
    if r > PI {
        r -= TAU;
    }
    r.clamp(-FRAC_PI_2, FRAC_PI_2)
}

impl RoiCoder {
    pub const CODE_SIZE: usize = 7;

    /// Encodes `gt` against `roi` (both in the detector's frame).
    pub fn encode(gt: &Box3d, roi: &Box3d) -> [f32; 7] {
        let (dxr, dyr, dzr) = (roi.dx.max(MIN_SIZE), roi.dy.max(MIN_SIZE), roi.dz.max(MIN_SIZE));
        let diag = dxr.hypot(dyr);
        let [xl, yl, zl] = roi.to_local([gt.x, gt.y, gt.z]);
        [
            (xl / diag) as f32,
            (yl / diag) as f32,
            (zl / dzr) as f32,
            (gt.dx.max(MIN_SIZE) / dxr).ln() as f32,
            (gt.dy.max(MIN_SIZE) / dyr).ln() as f32,
            (gt.dz.max(MIN_SIZE) / dzr).ln() as f32,
            folded_heading_residual(gt.heading, roi.heading) as f32,
        ]
    }

    /// Decodes one code against its RoI (Rust side; tests and checks).
    pub fn decode(code: &[f32; 7], roi: &Box3d) -> Box3d {
        let c = code.map(f64::from);
        let (dxr, dyr, dzr) = (roi.dx.max(MIN_SIZE), roi.dy.max(MIN_SIZE), roi.dz.max(MIN_SIZE));
        let diag = dxr.hypot(dyr);
        let (xl, yl) = (c[0] * diag, c[1] * diag);
        let (s, co) = roi.heading.sin_cos();
        Box3d {
            x: roi.x + co * xl - s * yl,
            y: roi.y + s * xl + co * yl,
            z: roi.z + c[2] * dzr,
            dx: c[3].exp() * dxr,
            dy: c[4].exp() * dyr,
            dz: c[5].exp() * dzr,
            heading: c[6] + roi.heading,
        }
    }

    /// Decodes `codes [..., 7]` against `rois [..., 7]` (same shape) into boxes `[..., 7]` in the
    /// detector's frame. Differentiable in `codes` (the RoIs are treated as constants); log sizes
    /// are clamped to ±10 so that an untrained network cannot overflow.
    pub fn decode_tensor(codes: &Tensor, rois: &Tensor) -> Tensor {
        let rois = rois.detach();
        let c = codes.unbind(-1);
        let r = rois.unbind(-1);
        let (dxr, dyr, dzr) = (r[3].clamp_min(MIN_SIZE), r[4].clamp_min(MIN_SIZE), r[5].clamp_min(MIN_SIZE));
        let diag = (&dxr * &dxr + &dyr * &dyr).sqrt();
        let (xl, yl) = (&c[0] * &diag, &c[1] * &diag);
        let (s, co) = (r[6].sin(), r[6].cos());
        Tensor::stack(
            &[
                &r[0] + &co * &xl - &s * &yl,
                &r[1] + &s * &xl + &co * &yl,
                &r[2] + &c[2] * &dzr,
                c[3].clamp(-10.0, 10.0).exp() * &dxr,
                c[4].clamp(-10.0, 10.0).exp() * &dyr,
                c[5].clamp(-10.0, 10.0).exp() * &dzr,
                &c[6] + &r[6],
            ],
            -1,
        )
    }
}

/// The 8 corners `[..., 8, 3]` of boxes `[..., 7]`, in the order of [`Box3d::corners`] (OpenPCDet
/// `boxes_to_corners_3d`). Differentiable.
pub fn boxes_to_corners(boxes: &Tensor) -> Tensor {
    const TEMPLATE: [[f32; 3]; 8] = [
        [1., 1., -1.],
        [1., -1., -1.],
        [-1., -1., -1.],
        [-1., 1., -1.],
        [1., 1., 1.],
        [1., -1., 1.],
        [-1., -1., 1.],
        [-1., 1., 1.],
    ];
    let t = Tensor::from_slice(TEMPLATE.as_flattened()).view([8, 3]).to_device(boxes.device()).to_kind(boxes.kind());
    let half = boxes.narrow(-1, 3, 3).unsqueeze(-2) * 0.5; // [..., 1, 3]
    let local = t * half; // [..., 8, 3]
    let l = local.unbind(-1);
    let b = boxes.unbind(-1);
    let (s, c) = (b[6].sin().unsqueeze(-1), b[6].cos().unsqueeze(-1));
    Tensor::stack(
        &[
            b[0].unsqueeze(-1) + &c * &l[0] - &s * &l[1],
            b[1].unsqueeze(-1) + &s * &l[0] + &c * &l[1],
            b[2].unsqueeze(-1) + &l[2],
        ],
        -1,
    )
}

/// OpenPCDet's `get_corner_loss_lidar`: per box `[N]`, the mean over the 8 corners of
/// `huber(min(‖p − g‖, ‖p − g_flip‖), δ = 1)` where `g_flip` is the GT turned by π, so a
/// prediction facing backwards is not punished. `pred [N, 7]`, `gt [N, 7]`.
pub fn corner_loss(pred: &Tensor, gt: &Tensor) -> Tensor {
    let gt = gt.detach();
    let pc = boxes_to_corners(pred);
    let gc = boxes_to_corners(&gt);
    let flip = Tensor::cat(&[gt.narrow(-1, 0, 6), gt.narrow(-1, 6, 1) + PI], -1);
    let gfc = boxes_to_corners(&flip);
    // ‖·‖ with a zero gradient (not NaN) where the distance is exactly zero.
    let dist = |a: &Tensor, b: &Tensor| {
        (a - b).square().sum_dim_intlist([-1i64].as_slice(), false, pred.kind()).clamp_min(1e-12).sqrt()
    };
    let d = dist(&pc, &gc).minimum(&dist(&pc, &gfc)); // [N, 8]
    let quad = d.lt(1.0).to_kind(pred.kind());
    let l: Tensor = &quad * 0.5 * d.square() + (1.0 - &quad) * (&d - 0.5);
    l.mean_dim([-1i64].as_slice(), false, pred.kind())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use tch::{Device, Kind};

    fn boxes_tensor(b: &[Box3d], kind: Kind) -> Tensor {
        let v: Vec<f64> = b.iter().flat_map(|b| b.to_array()).collect();
        Tensor::from_slice(&v).view([b.len() as i64, 7]).to_kind(kind)
    }

    /// Same box up to a half turn of the heading (same corner set).
    fn assert_same_box(a: &Box3d, b: &Box3d, tol: f64) {
        for (u, v) in a.to_array()[..6].iter().zip(&b.to_array()[..6]) {
            assert!((u - v).abs() < tol, "{a:?} vs {b:?}");
        }
        let d = (a.heading - b.heading).rem_euclid(PI);
        assert!(d.min(PI - d) < tol, "{a:?} vs {b:?}");
        assert!(pi3det_geometry::iou_3d(a, b) > 1.0 - 1e-4);
    }

    #[test]
    fn round_trip_random_boxes_including_headings_near_pi() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut gts = Vec::new();
        let mut rois = Vec::new();
        for k in 0..400 {
            let roi_heading = match k % 4 {
                0 => PI - rng.random_range(0.0..0.05),
                1 => -PI + rng.random_range(0.0..0.05),
                _ => rng.random_range(-4.0..4.0),
            };
            let roi = Box3d::new(
                rng.random_range(-40.0..40.0),
                rng.random_range(-40.0..40.0),
                rng.random_range(-1.0..2.0),
                rng.random_range(0.5..5.0),
                rng.random_range(0.5..2.5),
                rng.random_range(0.5..2.0),
                roi_heading,
            );
            // GT near the RoI, its heading anywhere around it (also across ±π and backwards).
            let gt = Box3d::new(
                roi.x + rng.random_range(-2.0..2.0),
                roi.y + rng.random_range(-2.0..2.0),
                roi.z + rng.random_range(-0.5..0.5),
                roi.dx * rng.random_range(0.6..1.5),
                roi.dy * rng.random_range(0.6..1.5),
                roi.dz * rng.random_range(0.6..1.5),
                (roi_heading + rng.random_range(-PI..PI) + PI).rem_euclid(TAU) - PI,
            );
            let code = RoiCoder::encode(&gt, &roi);
            assert!(code[6].abs() <= FRAC_PI_2 as f32 + 1e-6, "{code:?}");
            assert_same_box(&RoiCoder::decode(&code, &roi), &gt, 1e-4);
            gts.push(gt);
            rois.push(roi);
        }
        let codes: Vec<[f32; 7]> = gts.iter().zip(&rois).map(|(g, r)| RoiCoder::encode(g, r)).collect();
        let ct = Tensor::from_slice(codes.as_flattened()).view([-1, 7]).to_kind(Kind::Double);
        let dec = RoiCoder::decode_tensor(&ct, &boxes_tensor(&rois, Kind::Double));
        let v: Vec<f64> = Vec::try_from(dec.reshape([-1])).unwrap();
        for (k, gt) in gts.iter().enumerate() {
            assert_same_box(&Box3d::from_array(std::array::from_fn(|j| v[k * 7 + j])), gt, 1e-4);
        }
        // The identity: a RoI coded against itself is all zeros.
        let code = RoiCoder::encode(&rois[0], &rois[0]);
        assert!(code.iter().all(|v| v.abs() < 1e-6));
        // A GT facing backwards gets the flipped residual.
        let roi = Box3d::new(0.0, 0.0, 0.0, 4.0, 2.0, 1.5, 3.1);
        let gt = Box3d { heading: 3.1 - PI + 0.2, ..roi };
        assert!((RoiCoder::encode(&gt, &roi)[6] - 0.2).abs() < 1e-5);
        // Padding (all-zero) RoIs decode to finite boxes.
        let z = RoiCoder::decode_tensor(
            &Tensor::ones([2, 7], (Kind::Float, Device::Cpu)),
            &Tensor::zeros([2, 7], (Kind::Float, Device::Cpu)),
        );
        assert!(bool::try_from(z.isfinite().all()).unwrap());
    }

    #[test]
    fn corners_match_geometry() {
        let b = Box3d::new(1.0, -2.0, 0.5, 4.0, 2.0, 1.5, 0.7);
        let c = boxes_to_corners(&boxes_tensor(&[b], Kind::Double));
        assert_eq!(c.size(), [1, 8, 3]);
        let v: Vec<f64> = Vec::try_from(c.reshape([-1])).unwrap();
        for (k, p) in b.corners().iter().enumerate() {
            for j in 0..3 {
                assert!((v[k * 3 + j] - p[j]).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn corner_loss_values_and_gradient() {
        let gt = Box3d::new(1.0, 2.0, 0.0, 4.0, 2.0, 1.5, 0.3);
        // Shifted by 0.4 m along x: every corner 0.4 away → 0.5·0.16; by 3 m up: 3 − 0.5 (the
        // flipped GT's corners are farther still).
        let shifted = [Box3d { x: 1.4, ..gt }, Box3d { z: 3.0, ..gt }, Box3d { heading: 0.3 + PI, ..gt }, gt];
        let l = corner_loss(&boxes_tensor(&shifted, Kind::Double), &boxes_tensor(&[gt; 4], Kind::Double));
        let v: Vec<f64> = Vec::try_from(l).unwrap();
        assert!((v[0] - 0.08).abs() < 1e-9, "{v:?}");
        assert!((v[1] - 2.5).abs() < 1e-9, "{v:?}");
        assert!(v[2].abs() < 1e-9 && v[3].abs() < 1e-9, "a box turned by π costs nothing: {v:?}");

        // Autograd against central finite differences on a generic case.
        let pred = Box3d::new(1.3, 1.6, 0.2, 3.5, 2.3, 1.2, 0.6);
        let p = boxes_tensor(&[pred], Kind::Double).set_requires_grad(true);
        let g = boxes_tensor(&[gt], Kind::Double);
        corner_loss(&p, &g).sum(Kind::Double).backward();
        let grad: Vec<f64> = Vec::try_from(p.grad().reshape([-1])).unwrap();
        let f = |a: [f64; 7]| corner_loss(&boxes_tensor(&[Box3d::from_array(a)], Kind::Double), &g).double_value(&[0]);
        let h = 1e-6;
        for j in 0..7 {
            let (mut a, mut b) = (pred.to_array(), pred.to_array());
            a[j] += h;
            b[j] -= h;
            let fd = (f(a) - f(b)) / (2.0 * h);
            assert!((fd - grad[j]).abs() < 1e-6, "d/d{j}: autograd {} vs fd {fd}", grad[j]);
        }
        // At an exact match the gradient is finite (zero).
        let p = boxes_tensor(&[gt], Kind::Double).set_requires_grad(true);
        corner_loss(&p, &g).sum(Kind::Double).backward();
        assert!(bool::try_from(p.grad().isfinite().all()).unwrap());
    }
}
