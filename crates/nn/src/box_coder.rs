//! Box encodings.
//!
//! - [`ResidualCoder`] (SECOND / PointPillars; OpenPCDet `ResidualCoder`): a box relative to an
//!   anchor, `[(x−xa)/d, (y−ya)/d, (z−za)/dza, log(dx/dxa), log(dy/dya), log(dz/dza), θ−θa]` with
//!   `d = √(dxa² + dya²)`. Encoding runs in Rust (target assignment on the loader thread),
//!   decoding on tensors.
//! - The CenterPoint encoding (offset in the cell, z, log size, cos/sin heading) lives with
//!   [`crate::target_assigner::center`] and [`crate::dense_heads::center_head`].

use pi3det_geometry::Box3d;
use tch::Tensor;

/// Smallest size used in logs, so that degenerate boxes do not produce infinities.
const MIN_SIZE: f64 = 1e-3;

#[derive(Debug, Clone, Copy, Default)]
pub struct ResidualCoder;

impl ResidualCoder {
    pub const CODE_SIZE: usize = 7;

    /// Encodes `gt` against `anchor`.
    pub fn encode(gt: &Box3d, anchor: &Box3d) -> [f32; 7] {
        let diag = (anchor.dx * anchor.dx + anchor.dy * anchor.dy).sqrt();
        [
            ((gt.x - anchor.x) / diag) as f32,
            ((gt.y - anchor.y) / diag) as f32,
            ((gt.z - anchor.z) / anchor.dz) as f32,
            (gt.dx.max(MIN_SIZE) / anchor.dx).ln() as f32,
            (gt.dy.max(MIN_SIZE) / anchor.dy).ln() as f32,
            (gt.dz.max(MIN_SIZE) / anchor.dz).ln() as f32,
            (gt.heading - anchor.heading) as f32,
        ]
    }

    /// Decodes one code (Rust side; used by tests and target checks).
    pub fn decode(code: &[f32; 7], anchor: &Box3d) -> Box3d {
        let diag = (anchor.dx * anchor.dx + anchor.dy * anchor.dy).sqrt();
        let c = code.map(f64::from);
        Box3d {
            x: c[0] * diag + anchor.x,
            y: c[1] * diag + anchor.y,
            z: c[2] * anchor.dz + anchor.z,
            dx: c[3].exp() * anchor.dx,
            dy: c[4].exp() * anchor.dy,
            dz: c[5].exp() * anchor.dz,
            heading: c[6] + anchor.heading,
        }
    }

    /// Decodes `codes` `[..., 7]` against `anchors` `[..., 7]` (same shape or broadcastable).
    /// Log sizes are clamped to ±10 so that an untrained network cannot overflow.
    pub fn decode_tensor(codes: &Tensor, anchors: &Tensor) -> Tensor {
        let c = codes.unbind(-1);
        let a = anchors.unbind(-1);
        let diag = (&a[3] * &a[3] + &a[4] * &a[4]).sqrt();
        Tensor::stack(
            &[
                &c[0] * &diag + &a[0],
                &c[1] * &diag + &a[1],
                &c[2] * &a[5] + &a[2],
                c[3].clamp(-10.0, 10.0).exp() * &a[3],
                c[4].clamp(-10.0, 10.0).exp() * &a[4],
                c[5].clamp(-10.0, 10.0).exp() * &a[5],
                &c[6] + &a[6],
            ],
            -1,
        )
    }
}

/// `val − floor(val / period + offset) · period`: maps an angle into `[−offset·period,
/// (1−offset)·period)`.
pub fn limit_period(val: f64, offset: f64, period: f64) -> f64 {
    val - (val / period + offset).floor() * period
}

pub fn limit_period_tensor(val: &Tensor, offset: f64, period: f64) -> Tensor {
    val - (val / period + offset).floor() * period
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Kind;

    #[test]
    fn residual_round_trip_rust_and_tensor() {
        let anchor =
            Box3d { x: 10.0, y: -3.0, z: -1.0, dx: 4.2, dy: 2.0, dz: 1.6, heading: std::f64::consts::FRAC_PI_2 };
        let gt = Box3d { x: 10.4, y: -2.7, z: -0.9, dx: 4.6, dy: 1.9, dz: 1.5, heading: 1.4 };
        let code = ResidualCoder::encode(&gt, &anchor);
        let back = ResidualCoder::decode(&code, &anchor);
        for (a, b) in back.to_array().iter().zip(gt.to_array()) {
            assert!((a - b).abs() < 1e-5, "{back:?} vs {gt:?}");
        }
        let t = ResidualCoder::decode_tensor(
            &Tensor::from_slice(&code).view([1, 7]),
            &Tensor::from_slice(&anchor.to_array().map(|v| v as f32)).view([1, 7]),
        );
        let v: Vec<f32> = t.view([-1]).try_into().unwrap();
        for (a, b) in v.iter().zip(gt.to_array()) {
            assert!((*a as f64 - b).abs() < 1e-5);
        }
        // Untrained codes stay finite.
        let big = ResidualCoder::decode_tensor(&Tensor::full([1, 7], 1e6, (Kind::Float, tch::Device::Cpu)), &t);
        assert!(bool::try_from(big.isfinite().all()).unwrap());
    }

    #[test]
    fn limit_period_ranges() {
        use std::f64::consts::PI;
        assert!((limit_period(3.0 * PI / 2.0, 0.5, 2.0 * PI) + PI / 2.0).abs() < 1e-12);
        assert!((limit_period(-0.1, 0.0, PI) - (PI - 0.1)).abs() < 1e-12);
        assert!((limit_period(0.3, 0.0, PI) - 0.3).abs() < 1e-12);
    }
}
