//! RoI feature pooling from the BEV map: bilinear samples of the `[B, C, H, W]` map at points laid
//! out in each rotated RoI (zero outside the map), either a `G × G` lattice of cell centres of the
//! RoI (optionally enlarged by a margin in metres on every side) or the cheap 5-point layout of
//! the RoI centre and its four face centres.
//!
//! Map geometry ([`CenterMap`]): row = y, column = x; cell `(i, j)` covers
//! `x ∈ [origin_x + j·cell_x, origin_x + (j+1)·cell_x)` (likewise y), and its feature is the value
//! at the cell's centre: a point at `x` sits at pixel coordinate `(x − origin_x)/cell_x − ½`, and
//! one on a cell centre reads exactly that cell. These are the values of libtorch's
//! `grid_sampler_2d` with `align_corners = false` and zero padding, computed as gathers (see
//! [`bilinear`]).

use serde::{Deserialize, Serialize};
use tch::{Kind, Tensor};

use crate::error::{NnError, Result};
use crate::target_assigner::center::CenterMap;

/// Where the samples of a RoI lie.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PoolLayout {
    /// `grid_size × grid_size` lattice; sample `(i, j)` (point index `i·G + j`) at
    /// `u = ((j + ½)/G − ½)·(dx + 2m)` along the RoI's heading and `v = ((i + ½)/G − ½)·(dy + 2m)`
    /// across it (`m` the margin): rows along the RoI's y, columns along its x.
    #[default]
    Grid,
    /// 5 points: centre, front face (`+dx/2 + m`, 0), back face, left face (0, `+dy/2 + m`),
    /// right face, in this order.
    CenterFaces,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BevRoiPoolConfig {
    pub layout: PoolLayout,
    /// Lattice size `G` of [`PoolLayout::Grid`] (Voxel R-CNN: 6).
    pub grid_size: usize,
    /// Metres added to the RoI on every side before laying out the samples.
    pub margin: f64,
}

impl Default for BevRoiPoolConfig {
    fn default() -> Self {
        Self { layout: PoolLayout::Grid, grid_size: 6, margin: 0.0 }
    }
}

impl BevRoiPoolConfig {
    pub fn validate(&self) -> Result<()> {
        if self.layout == PoolLayout::Grid && !(1..=32).contains(&self.grid_size) {
            return Err(NnError::config(
                "roi_head.bev_pool",
                format!("roi pool: grid_size {} is not in 1..=32", self.grid_size),
            ));
        }
        if !(self.margin.is_finite() && self.margin >= 0.0) {
            return Err(NnError::config(
                "roi_head.bev_pool",
                format!("roi pool: margin {} must be finite and ≥ 0", self.margin),
            ));
        }
        Ok(())
    }

    /// Samples per RoI `P`: `G²` or 5.
    pub fn num_points(&self) -> i64 {
        match self.layout {
            PoolLayout::Grid => (self.grid_size * self.grid_size) as i64,
            PoolLayout::CenterFaces => 5,
        }
    }

    pub fn init(&self) -> Result<BevRoiPool> {
        self.validate()?;
        let offsets = self.unit_offsets();
        let offsets_t = Tensor::from_slice(offsets.as_flattened()).view([-1, 2]);
        Ok(BevRoiPool { cfg: self.clone(), offsets, offsets_t })
    }

    /// `[P, 2]` sample offsets in units of the (enlarged) RoI size, in `[−½, ½]`.
    fn unit_offsets(&self) -> Vec<[f32; 2]> {
        match self.layout {
            PoolLayout::Grid => {
                let g = self.grid_size;
                let at = |k: usize| ((k as f64 + 0.5) / g as f64 - 0.5) as f32;
                (0..g * g).map(|p| [at(p % g), at(p / g)]).collect()
            }
            PoolLayout::CenterFaces => vec![[0.0, 0.0], [0.5, 0.0], [-0.5, 0.0], [0.0, 0.5], [0.0, -0.5]],
        }
    }
}

/// The pooling layer (no parameters).
#[derive(Debug)]
pub struct BevRoiPool {
    pub cfg: BevRoiPoolConfig,
    offsets: Vec<[f32; 2]>,
    /// `offsets` as a `[P, 2]` tensor made once. Made from Rust data inside a TorchScript trace
    /// on every call, the traced module got other values for it (wrong sample points, found by
    /// crates/nn/tests/export.rs); a tensor living outside the trace is captured as a constant,
    /// like the weights.
    offsets_t: Tensor,
}

impl Clone for BevRoiPool {
    fn clone(&self) -> Self {
        Self { cfg: self.cfg.clone(), offsets: self.offsets.clone(), offsets_t: self.offsets_t.shallow_clone() }
    }
}

impl BevRoiPool {
    pub fn num_points(&self) -> i64 {
        self.offsets.len() as i64
    }

    /// Sample points `[..., P, 2]` (x, y in the detector's frame, metres) of `rois [..., 7]`.
    pub fn sample_points(&self, rois: &Tensor) -> Tensor {
        let rois = rois.detach();
        let off = self.offsets_t.to_device(rois.device()).to_kind(rois.kind());
        let m = 2.0 * self.cfg.margin;
        let r = rois.unbind(-1);
        let u = off.select(1, 0) * (&r[3] + m).unsqueeze(-1); // [..., P]
        let v = off.select(1, 1) * (&r[4] + m).unsqueeze(-1);
        let (s, c) = (r[6].sin().unsqueeze(-1), r[6].cos().unsqueeze(-1));
        let x = r[0].unsqueeze(-1) + &c * &u - &s * &v;
        let y = r[1].unsqueeze(-1) + &s * &u + &c * &v;
        Tensor::stack(&[x, y], -1)
    }

    /// Pools `bev [B, C, H, W]` (laid out as `map`) at the samples of `rois [B, N, 7]`:
    /// `[B, N, C, P]` (for the grid layout, `.view([B, N, C, G, G])` gives rows along the RoI's y).
    /// Differentiable in `bev`; RoIs are constants. Samples off the map read zeros.
    pub fn forward(&self, bev: &Tensor, rois: &Tensor, map: &CenterMap) -> Result<Tensor> {
        let (b, _c, h, w) =
            bev.size4().map_err(|_| NnError::Input(format!("roi pool: bev {:?} is not [B, C, H, W]", bev.size())))?;
        let rs = rois.size();
        if rs.len() != 3 || rs[0] != b || rs[2] != 7 {
            return Err(NnError::Input(format!("roi pool: rois {rs:?} is not [{b}, N, 7]")));
        }
        if h != map.h as i64 || w != map.w as i64 {
            return Err(NnError::Input(format!("roi pool: bev is {h}×{w}, the map geometry {}×{}", map.h, map.w)));
        }
        // [B, N, P, 2], f64 for the metres.
        let pts = self.sample_points(&rois.to_kind(Kind::Double));
        // Pixel coordinates with cell centres on integers (the sampler's align_corners = false).
        let px = (pts.select(-1, 0) - map.origin[0]) / map.cell[0] - 0.5;
        let py = (pts.select(-1, 1) - map.origin[1]) / map.cell[1] - 0.5;
        Ok(bilinear(bev, &px, &py))
    }
}

/// Bilinear samples of `bev [B, C, H, W]` at pixel coordinates `px, py [B, N, P]` (f64), zero
/// outside the map: `[B, N, C, P]`, the values of `grid_sampler_2d` (zero padding,
/// align_corners = false). Written as gathers of the map's `[B·H·W, C]` rows (a view of a
/// channels-last map) so that the gradient is one `index_add` into a map-sized buffer: libtorch's
/// CPU grid-sampler backward on the preset's 192 × 128 × 128 map was a sizeable share of a
/// training step. Measured: results/2026-12-06-training-step.md.
fn bilinear(bev: &Tensor, px: &Tensor, py: &Tensor) -> Tensor {
    let (b, c, h, w) = bev.size4().expect("bev is [B, C, H, W]");
    let (n, p) = (px.size()[1], px.size()[2]);
    let dev = bev.device();
    let (x0, y0) = (px.floor(), py.floor());
    let (fx, fy) = (px - &x0, py - &y0);
    let frame = Tensor::arange(b, (Kind::Int64, dev)).view([b, 1, 1]) * (h * w);
    let x0 = x0.to_device(dev).to_kind(Kind::Int64);
    let y0 = y0.to_device(dev).to_kind(Kind::Int64);
    let mut index = Vec::with_capacity(4);
    let mut weight = Vec::with_capacity(4);
    for (dy, wy) in [(0, 1.0 - &fy), (1, fy.shallow_clone())] {
        for (dx, wx) in [(0, 1.0 - &fx), (1, fx.shallow_clone())] {
            let (xi, yi) = (&x0 + dx, &y0 + dy);
            let inside = xi.ge(0).logical_and(&xi.lt(w)).logical_and(&yi.ge(0)).logical_and(&yi.lt(h));
            index.push(&frame + yi.clamp(0, h - 1) * w + xi.clamp(0, w - 1));
            weight.push((wy.shallow_clone() * wx).to_device(dev) * inside.to_kind(Kind::Double));
        }
    }
    let index = Tensor::stack(&index, 0).view([-1]);
    let weight = Tensor::stack(&weight, 0).to_kind(bev.kind()).view([4, b * n * p, 1]);
    let rows = bev.permute([0, 2, 3, 1]).reshape([b * h * w, c]);
    let corners = rows.index_select(0, &index).view([4, b * n * p, c]);
    (corners * weight).sum_dim_intlist(&[0i64][..], false, bev.kind()).view([b, n, p, c]).permute([0, 1, 3, 2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use pi3det_geometry::Box3d;
    use tch::Device;

    const H: usize = 4;
    const W: usize = 5;

    fn map() -> CenterMap {
        CenterMap { h: H, w: W, cell: [0.5, 1.0], origin: [-1.0, 2.0] }
    }

    /// Channel `c`, row `i`, column `j`.
    fn value(c: usize, i: usize, j: usize) -> f64 {
        100.0 * c as f64 + 10.0 * i as f64 + j as f64 + 0.25 * (i * j) as f64
    }

    fn bev() -> Tensor {
        let v: Vec<f32> =
            (0..2).flat_map(|c| (0..H).flat_map(move |i| (0..W).map(move |j| value(c, i, j) as f32))).collect();
        Tensor::from_slice(&v).view([1, 2, H as i64, W as i64])
    }

    /// Bilinear interpolation with zero padding, cell centres at integer pixel coordinates.
    fn manual(c: usize, x: f64, y: f64) -> f64 {
        let m = map();
        let px = (x - m.origin[0]) / m.cell[0] - 0.5;
        let py = (y - m.origin[1]) / m.cell[1] - 0.5;
        let (j0, i0) = (px.floor(), py.floor());
        let (fx, fy) = (px - j0, py - i0);
        let at = |i: f64, j: f64| {
            if i < 0.0 || j < 0.0 || i >= H as f64 || j >= W as f64 {
                0.0
            } else {
                value(c, i as usize, j as usize)
            }
        };
        at(i0, j0) * (1.0 - fx) * (1.0 - fy)
            + at(i0, j0 + 1.0) * fx * (1.0 - fy)
            + at(i0 + 1.0, j0) * (1.0 - fx) * fy
            + at(i0 + 1.0, j0 + 1.0) * fx * fy
    }

    fn rois(b: &[Box3d]) -> Tensor {
        let v: Vec<f32> = b.iter().flat_map(|b| b.to_array().map(|v| v as f32)).collect();
        Tensor::from_slice(&v).view([1, b.len() as i64, 7])
    }

    #[test]
    fn grid_samples_match_manual_bilinear() {
        let m = map();
        let pool = BevRoiPoolConfig { grid_size: 2, ..Default::default() }.init().unwrap();
        // Cell (i, j) centre: x = −1 + 0.5(j + ½), y = 2 + (i + ½).
        // RoI 1: axis-aligned, 1 m × 2 m centred on the corner between cells (1..2, 1..2): its
        // 2×2 samples fall exactly on the centres of cells (1,1) (1,2) (2,1) (2,2).
        let on_centres = Box3d::new(-1.0 + 0.5 * 2.0, 2.0 + 2.0, 0.0, 1.0, 2.0, 1.0, 0.0);
        // RoI 2: the same shifted by a fraction of a cell, turned by 90°: samples between cells.
        let between = Box3d::new(-0.15, 4.3, 0.0, 1.6, 0.8, 1.0, std::f64::consts::FRAC_PI_2);
        // RoI 3: partly off the map (zero padding).
        let off_map = Box3d::new(-1.1, 2.2, 0.0, 1.0, 1.0, 1.0, 0.3);
        let boxes = [on_centres, between, off_map];
        let out = pool.forward(&bev(), &rois(&boxes), &m).unwrap();
        assert_eq!(out.size(), [1, 3, 2, 4]);
        let pts: Vec<f64> =
            Vec::try_from(pool.sample_points(&rois(&boxes).to_kind(Kind::Double)).reshape([-1])).unwrap();
        let got: Vec<f64> = Vec::try_from(out.to_kind(Kind::Double).reshape([-1])).unwrap();
        for n in 0..3 {
            for c in 0..2 {
                for p in 0..4 {
                    let (x, y) = (pts[(n * 4 + p) * 2], pts[(n * 4 + p) * 2 + 1]);
                    let want = manual(c, x, y);
                    let g = got[(n * 2 + c) * 4 + p];
                    assert!((g - want).abs() < 1e-4, "roi {n} channel {c} point {p} at ({x}, {y}): {g} vs {want}");
                }
            }
        }
        // On centres: exactly the cell values, rows along the RoI's y, columns along its x.
        let first: Vec<f64> = (0..4).map(|p| got[p]).collect();
        assert_eq!(first, vec![value(0, 1, 1), value(0, 1, 2), value(0, 2, 1), value(0, 2, 2)]);
        // The 90° RoI: its first sample (u, v) = (−0.4, −0.2) lies at (x + 0.2, y − 0.4).
        assert!((pts[8] - 0.05).abs() < 1e-6 && (pts[9] - 3.9).abs() < 1e-6);
        // Off the map: a sample entirely outside reads zero, one half outside a partial value.
        assert_eq!(got[2 * 8], 0.0);
        assert!(got[2 * 8 + 3] > 0.0 && got[2 * 8 + 3] < value(0, 0, 1));
    }

    #[test]
    fn center_faces_layout_and_margin() {
        let m = map();
        let pool =
            BevRoiPoolConfig { layout: PoolLayout::CenterFaces, margin: 0.25, ..Default::default() }.init().unwrap();
        assert_eq!(pool.num_points(), 5);
        let b = Box3d::new(0.25, 4.0, 0.0, 1.0, 1.0, 1.0, 0.0);
        let pts: Vec<f64> = Vec::try_from(pool.sample_points(&rois(&[b]).to_kind(Kind::Double)).reshape([-1])).unwrap();
        let want = [[0.25, 4.0], [1.0, 4.0], [-0.5, 4.0], [0.25, 4.75], [0.25, 3.25]];
        for (p, w) in want.iter().enumerate() {
            assert!((pts[2 * p] - w[0]).abs() < 1e-9 && (pts[2 * p + 1] - w[1]).abs() < 1e-9, "{pts:?}");
        }
        let out = pool.forward(&bev(), &rois(&[b]), &m).unwrap();
        assert_eq!(out.size(), [1, 1, 2, 5]);
        let got: Vec<f64> = Vec::try_from(out.to_kind(Kind::Double).reshape([-1])).unwrap();
        for c in 0..2 {
            for (p, w) in want.iter().enumerate() {
                assert!((got[c * 5 + p] - manual(c, w[0], w[1])).abs() < 1e-4);
            }
        }
    }

    /// The gathers give `grid_sampler_2d`'s values and map gradients, on a channels-last map
    /// and with samples off the map and on its edges.
    #[test]
    fn gathers_equal_the_grid_sampler() {
        tch::manual_seed(5);
        let (b, c, h, w) = (2, 3, 6, 7);
        let map = Tensor::randn([b, h, w, c], (Kind::Float, Device::Cpu)).permute([0, 3, 1, 2]);
        let px = Tensor::rand([b, 4, 5], (Kind::Double, Device::Cpu)) * (w as f64 + 2.0) - 1.5;
        let py = Tensor::rand([b, 4, 5], (Kind::Double, Device::Cpu)) * (h as f64 + 2.0) - 1.5;
        let _ = px.get(0).get(0).get(0).fill_(-0.5);
        let _ = py.get(0).get(0).get(0).fill_(h as f64 - 0.5);
        let grid = Tensor::stack(&[(&px + 0.5) * (2.0 / w as f64) - 1.0, (&py + 0.5) * (2.0 / h as f64) - 1.0], -1)
            .to_kind(Kind::Float);
        let x = map.set_requires_grad(true);
        let want = x.grid_sampler_2d(&grid, 0, 0, false).permute([0, 2, 1, 3]);
        let weights = Tensor::randn(want.size(), (Kind::Float, Device::Cpu));
        let g_want = Tensor::run_backward(&[(&want * &weights).sum(Kind::Float)], &[&x], false, false);
        let got = bilinear(&x, &px, &py);
        let g_got = Tensor::run_backward(&[(&got * &weights).sum(Kind::Float)], &[&x], false, false);
        assert!(got.allclose(&want, 1e-5, 1e-6, false), "{got} vs {want}");
        assert!(g_got[0].allclose(&g_want[0], 1e-5, 1e-6, false));
    }

    #[test]
    fn gradients_flow_to_the_map() {
        let m = map();
        let pool = BevRoiPoolConfig { grid_size: 3, ..Default::default() }.init().unwrap();
        let x = bev().set_requires_grad(true);
        let b = Box3d::new(0.2, 4.1, 0.0, 1.2, 1.4, 1.0, 0.4);
        let out = pool.forward(&x, &rois(&[b]), &m).unwrap();
        out.sum(Kind::Float).backward();
        let g = x.grad();
        // Every sample is inside the map: its four bilinear weights sum to 1 per channel.
        let total = f64::try_from(g.sum(Kind::Double)).unwrap();
        assert!((total - 2.0 * 9.0).abs() < 1e-4, "{total}");
        assert!(f64::try_from(g.min()).unwrap() >= 0.0);
        // Cells far from the RoI get nothing.
        assert_eq!(f64::try_from(g.get(0).get(0).get(3).get(4)).unwrap(), 0.0);
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        assert!(BevRoiPoolConfig { grid_size: 0, ..Default::default() }.init().is_err());
        assert!(BevRoiPoolConfig { margin: -1.0, ..Default::default() }.validate().is_err());
        let pool = BevRoiPoolConfig::default().init().unwrap();
        let r = Tensor::zeros([1, 3, 7], (Kind::Float, Device::Cpu));
        assert!(pool.forward(&bev(), &r, &CenterMap { h: 5, ..map() }).is_err());
        assert!(pool.forward(&bev(), &Tensor::zeros([2, 3, 7], (Kind::Float, Device::Cpu)), &map()).is_err());
        assert!(pool.forward(&bev().view([2, 4, 5]), &r, &map()).is_err());
    }
}
