//! Point-pillar scatter (PointPillars; OpenPCDet `PointPillarScatter`): pillar features back onto
//! the dense BEV grid.

use tch::{Kind, Tensor};

/// `pillar_features`: `[P, C]`; `cells`: `[P]` int64 flat index `b·ny·nx + iy·nx + ix` →
/// `[B, C, ny, nx]` (zeros where there is no pillar), in channels-last memory layout when
/// `channels_last` (the canvas is `[B, ny, nx, C]` seen through a permutation; libtorch's oneDNN
/// convolutions then stay channels-last through the backbone), else contiguous NCHW.
pub fn scatter(
    pillar_features: &Tensor,
    cells: &Tensor,
    batch_size: i64,
    ny: i64,
    nx: i64,
    channels_last: bool,
) -> Tensor {
    let c = pillar_features.size()[1];
    let canvas = Tensor::zeros([batch_size * ny * nx, c], (pillar_features.kind(), pillar_features.device()));
    let bev = canvas
        .index_copy(0, &cells.to_kind(Kind::Int64), pillar_features)
        .view([batch_size, ny, nx, c])
        .permute([0, 3, 1, 2]);
    if channels_last {
        bev
    } else {
        bev.contiguous()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    #[test]
    fn places_features_and_passes_gradients() {
        let f = Tensor::from_slice(&[1.0f32, 2.0, 3.0, 4.0]).view([2, 2]).set_requires_grad(true);
        let cells = Tensor::from_slice(&[5i64, 3 * 4 + 2]); // (b0, y1, x1), (b1, y0, x2)
        let bev = scatter(&f, &cells, 2, 3, 4, false);
        assert!(bev.equal(&scatter(&f, &cells, 2, 3, 4, true)));
        assert_eq!(bev.size(), vec![2, 2, 3, 4]);
        assert_eq!(bev.double_value(&[0, 0, 1, 1]), 1.0);
        assert_eq!(bev.double_value(&[0, 1, 1, 1]), 2.0);
        assert_eq!(bev.double_value(&[1, 1, 0, 2]), 4.0);
        assert_eq!(bev.sum(Kind::Float).double_value(&[]), 10.0);
        (bev * Tensor::arange(24, (Kind::Float, Device::Cpu)).view([2, 1, 3, 4])).sum(Kind::Float).backward();
        let g: Vec<f32> = f.grad().view([-1]).try_into().unwrap();
        assert_eq!(g, vec![5.0, 5.0, 14.0, 14.0]);
    }
}
