//! `map_to_bev` for sparse backbones (OpenPCDet `HeightCompression`): the sparse output made
//! dense and its height folded into channels, `[B, C, D, H, W]` → `[B, C·D, H, W]` (channel
//! `c·D + d`, as OpenPCDet's `view`).

use tch::Tensor;

use crate::sparse::SparseTensor;

/// The BEV map of `x`, in channels-last memory when `channels_last` (as the pillar scatter).
pub fn height_compression(x: &SparseTensor, channels_last: bool) -> Tensor {
    let [d, h, w] = x.spatial_shape;
    let (b, c) = (x.batch_size, x.channels());
    // Rows ordered (b, y, x, z): the channels-last canvas is one permute and one copy away.
    let rows: Vec<i64> =
        x.coords.iter().map(|q| ((q[0] as i64 * h + q[2] as i64) * w + q[3] as i64) * d + q[1] as i64).collect();
    let idx = Tensor::from_slice(&rows).to_device(x.features.device());
    let canvas = Tensor::zeros([b * h * w * d, c], (x.features.kind(), x.features.device()));
    let bev = canvas
        .index_copy(0, &idx, &x.features)
        .view([b, h, w, d, c])
        .permute([0, 1, 2, 4, 3])
        .reshape([b, h, w, c * d])
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
    use tch::{Device, Kind};

    /// Equal to OpenPCDet's `dense().view(B, C·D, H, W)`, with gradients into the features.
    #[test]
    fn equals_dense_view() {
        tch::manual_seed(0);
        let coords = vec![[0, 0, 1, 2], [1, 2, 0, 0], [0, 1, 1, 2], [1, 0, 2, 1]];
        let f = Tensor::randn([4, 3], (Kind::Float, Device::Cpu)).set_requires_grad(true);
        let s = SparseTensor::new(f.shallow_clone(), coords, [3, 3, 4], 2).unwrap();
        let want = s.dense().reshape([2, 9, 3, 4]);
        for cl in [false, true] {
            let got = height_compression(&s, cl);
            assert!(got.equal(&want), "channels_last {cl}");
        }
        height_compression(&s, true).sum(Kind::Float).backward();
        assert!(f.grad().equal(&f.ones_like()));
    }
}
