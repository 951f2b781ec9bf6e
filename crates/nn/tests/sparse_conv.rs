//! Sparse 3-D convolution against dense `conv3d` / `conv_transpose3d` on small random grids:
//! outputs on the active sites, and gradients of inputs and weights, equal to float tolerance
//! (double precision here, so the tolerance is tight).

use pi3det_nn::sparse::{SparseConv3dConfig, SparseTensor};
use rand::{Rng, SeedableRng};
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

const SHAPE: [i64; 3] = [5, 7, 6];
const B: i64 = 2;
const C_IN: i64 = 3;
const C_OUT: i64 = 4;

fn random_input(seed: u64, density: f64) -> SparseTensor {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut coords = Vec::new();
    for b in 0..B as i32 {
        for z in 0..SHAPE[0] as i32 {
            for y in 0..SHAPE[1] as i32 {
                for x in 0..SHAPE[2] as i32 {
                    if rng.random_bool(density) {
                        coords.push([b, z, y, x]);
                    }
                }
            }
        }
    }
    tch::manual_seed(seed as i64);
    let f = Tensor::randn([coords.len() as i64, C_IN], (Kind::Double, Device::Cpu)).set_requires_grad(true);
    SparseTensor::new(f, coords, SHAPE, B).unwrap()
}

/// 1 on the tensor's active sites, `[B, 1, D, H, W]`.
fn mask(s: &SparseTensor) -> Tensor {
    s.with_features(Tensor::ones([s.len() as i64, 1], (Kind::Double, Device::Cpu))).dense()
}

/// Rows of a dense `[B, C, D, H, W]` tensor at the sparse tensor's sites, `[N, C]`.
fn at_sites(dense: &Tensor, s: &SparseTensor) -> Tensor {
    let rows: Vec<Tensor> = s
        .coords
        .iter()
        .map(|c| dense.get(c[0] as i64).select(1, c[1] as i64).select(1, c[2] as i64).select(1, c[3] as i64))
        .collect();
    Tensor::stack(&rows, 0)
}

fn max_diff(a: &Tensor, b: &Tensor) -> f64 {
    assert_eq!(a.size(), b.size());
    (a - b).abs().max().double_value(&[])
}

/// Sparse layer vs dense convolution with the same weights: forward on active output sites (and
/// zeros elsewhere for a regular convolution, whose dense output off them is exactly zero), and
/// the gradients of a random linear loss on the active outputs.
fn check_against_dense(cfg: SparseConv3dConfig, density: f64, seed: u64) {
    let x = random_input(seed, density);
    let vs = VarStore::new(Device::Cpu);
    let conv = cfg.init(vs.root(), C_IN, C_OUT);
    let mut vs = vs;
    vs.double();
    let y = conv.forward(&x).unwrap();
    assert_eq!(y.spatial_shape, cfg.output_shape(SHAPE));

    let x_dense = x.dense().detach().set_requires_grad(true);
    let w_dense = conv.weight.detach().copy().set_requires_grad(true);
    let y_dense = x_dense.conv3d(&w_dense, None::<Tensor>, cfg.stride, cfg.padding, [1, 1, 1], 1);
    let out_mask = mask(&y);
    let y_sparse_dense = y.dense();
    assert_eq!(y_sparse_dense.size(), y_dense.size());
    let d = max_diff(&y_sparse_dense, &(&y_dense * &out_mask));
    assert!(d < 1e-9, "{cfg:?}: forward differs by {d}");
    if cfg.kind == pi3det_nn::sparse::SparseConvKind::Regular {
        let off = (&y_dense * (out_mask.ones_like() - &out_mask)).abs().max().double_value(&[]);
        assert!(off < 1e-12, "a regular convolution's inactive sites must be zero in the dense one too: {off}");
    }

    let r = Tensor::randn(y_dense.size(), (Kind::Double, Device::Cpu));
    (&y_sparse_dense * &r).sum(Kind::Double).backward();
    (&y_dense * &out_mask * &r).sum(Kind::Double).backward();
    let gx = max_diff(&x.features.grad(), &at_sites(&x_dense.grad(), &x));
    let gw = max_diff(&conv.weight.grad(), &w_dense.grad());
    assert!(gx < 1e-9 && gw < 1e-9, "{cfg:?}: gradients differ by {gx} (input) / {gw} (weight)");
}

#[test]
fn submanifold_kernel_3_equals_dense() {
    check_against_dense(SparseConv3dConfig::submanifold(3), 0.25, 1);
    check_against_dense(SparseConv3dConfig::submanifold(3), 0.9, 2);
}

#[test]
fn regular_stride_1_and_2_equal_dense() {
    check_against_dense(SparseConv3dConfig::regular([3; 3], [1; 3], [1; 3]), 0.2, 3);
    check_against_dense(SparseConv3dConfig::regular([3; 3], [2; 3], [1; 3]), 0.2, 4);
    // VoxelBackBone8x's conv4 and conv_out paddings.
    check_against_dense(SparseConv3dConfig::regular([3; 3], [2; 3], [0, 1, 1]), 0.3, 5);
    check_against_dense(SparseConv3dConfig::regular([3, 1, 1], [2, 1, 1], [0; 3]), 0.3, 6);
}

/// The inverse convolution equals a transposed dense convolution restricted to the sites the
/// forward convolution read.
#[test]
fn inverse_equals_dense_transposed_convolution() {
    let x = random_input(7, 0.25);
    let vs = VarStore::new(Device::Cpu);
    let (k, s, p) = ([3i64; 3], [2i64; 3], [1i64; 3]);
    let down = SparseConv3dConfig::regular(k, s, p).with_key("down").init(vs.root() / "down", C_IN, C_OUT);
    let up = SparseConv3dConfig::inverse(k, "down").init(vs.root() / "up", C_OUT, C_IN);
    let mut vs = vs;
    vs.double();
    let mid = down.forward(&x).unwrap();
    let mid_in = mid.with_features(mid.features.detach().set_requires_grad(true));
    let y = up.forward(&mid_in).unwrap();
    assert_eq!(*y.coords, *x.coords);
    assert_eq!(y.spatial_shape, SHAPE);

    let m_dense = mid_in.dense().detach().set_requires_grad(true);
    let w = up.weight.detach().copy().set_requires_grad(true);
    let ms = mid.spatial_shape;
    let out_pad: Vec<i64> = (0..3).map(|a| SHAPE[a] - ((ms[a] - 1) * s[a] - 2 * p[a] + k[a])).collect();
    let y_dense = m_dense.conv_transpose3d(&w, None::<Tensor>, s, p, out_pad.as_slice(), 1, [1, 1, 1]);
    let in_mask = mask(&x);
    let d = max_diff(&y.dense(), &(&y_dense * &in_mask));
    assert!(d < 1e-9, "inverse forward differs by {d}");
    let r = Tensor::randn(y_dense.size(), (Kind::Double, Device::Cpu));
    (y.dense() * &r).sum(Kind::Double).backward();
    (&y_dense * &in_mask * &r).sum(Kind::Double).backward();
    let gx = max_diff(&mid_in.features.grad(), &at_sites(&m_dense.grad(), &mid));
    let gw = max_diff(&up.weight.grad(), &w.grad());
    assert!(gx < 1e-9 && gw < 1e-9, "inverse gradients differ by {gx} / {gw}");
    // Without the forward convolution there is nothing to invert.
    let fresh = random_input(8, 0.2);
    let up3 = SparseConv3dConfig::inverse(k, "down").init(VarStore::new(Device::Cpu).root(), C_IN, C_IN);
    assert!(up3.forward(&fresh).unwrap_err().to_string().contains("down"));
}

/// Two submanifold layers at one resolution build one rulebook; a stride-1 regular
/// convolution's output (more sites, same shape) gets its own.
#[test]
fn rulebooks_are_cached_per_site_list() {
    let x = random_input(9, 0.2);
    let vs = VarStore::new(Device::Cpu);
    let a = SparseConv3dConfig::submanifold(3).init(vs.root() / "a", C_IN, C_IN);
    let b = SparseConv3dConfig::submanifold(3).init(vs.root() / "b", C_IN, C_IN);
    let grow = SparseConv3dConfig::regular([3; 3], [1; 3], [1; 3]).init(vs.root() / "g", C_IN, C_IN);
    let mut vs = vs;
    vs.double();
    let y = b.forward(&a.forward(&x).unwrap()).unwrap();
    assert!(std::sync::Arc::ptr_eq(&y.coords, &x.coords));
    let g = grow.forward(&y).unwrap();
    assert!(g.len() > x.len());
    let z = a.forward(&g).unwrap();
    assert_eq!(z.len(), g.len(), "the grown site list has its own submanifold rulebook");
    assert_eq!(x.channels(), z.channels());
}
