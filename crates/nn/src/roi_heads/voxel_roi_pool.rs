//! Voxel RoI pooling of Voxel R-CNN (Deng et al., AAAI 2021): a `G × G × G` grid of points in
//! each rotated RoI; for every grid point and every chosen stage of the sparse 3-D backbone, a
//! *voxel query* collects the active voxels around it (within `radius` voxels of that stage, the
//! nearest `max_neighbours` first), a shared `Linear → BN → ReLU` over [voxel feature, offset to
//! the grid point] and a max over the neighbours give the point's feature. The stages'
//! features are concatenated: `[B, N, ΣC, P]`, the layout of the BEV pool, so the RoI head's
//! point layer and MLPs take it unchanged.
//!
//! The query runs in Rust on a hash of each stage's active sites; the arithmetic (gather,
//! layer, masked max) in tch, differentiable in the voxel features.

use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};
use tch::nn::{self, Module, ModuleT};
use tch::{Kind, Tensor};

use crate::backbones_3d::Backbone3dConfig;
use crate::error::{NnError, Result};
use crate::pillarize::Grid;
use crate::sparse::SparseTensor;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VoxelPoolStage {
    /// Which stage of the 3-D backbone (1–4: strides 1, 2, 4, 8).
    pub stage: usize,
    /// Query cube half-width in this stage's voxels.
    pub radius: i32,
    pub max_neighbours: usize,
    /// Output channels of the stage's shared layer.
    pub channels: i64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VoxelRoiPoolConfig {
    /// Grid points per RoI side (Voxel R-CNN: 6).
    pub grid_size: usize,
    /// Voxel R-CNN pools from x_conv2, x_conv3 and x_conv4 with 16 neighbours; CPU: the last two.
    pub stages: Vec<VoxelPoolStage>,
}

impl Default for VoxelRoiPoolConfig {
    fn default() -> Self {
        Self {
            grid_size: 4,
            stages: vec![
                VoxelPoolStage { stage: 3, radius: 1, max_neighbours: 8, channels: 32 },
                VoxelPoolStage { stage: 4, radius: 1, max_neighbours: 8, channels: 32 },
            ],
        }
    }
}

impl VoxelRoiPoolConfig {
    pub fn validate(&self) -> Result<()> {
        if !(1..=12).contains(&self.grid_size) || self.stages.is_empty() {
            return Err(NnError::config(
                "roi_head.voxel_pool",
                "voxel roi pool: grid_size must be in 1..=12 and stages non-empty",
            ));
        }
        for s in &self.stages {
            if !(1..=4).contains(&s.stage) || !(0..=4).contains(&s.radius) || s.max_neighbours == 0 || s.channels < 1 {
                return Err(NnError::config(
                    "roi_head.voxel_pool",
                    format!(
                        "voxel roi pool: stage {} (1–4), radius {} (0–4), max_neighbours {} and channels {} (positive)",
                        s.stage, s.radius, s.max_neighbours, s.channels
                    ),
                ));
            }
        }
        Ok(())
    }

    pub fn num_points(&self) -> i64 {
        (self.grid_size * self.grid_size * self.grid_size) as i64
    }

    pub fn out_channels(&self) -> i64 {
        self.stages.iter().map(|s| s.channels).sum()
    }

    /// The pool over a backbone whose stage `s` has `stage_channels[s - 1]` channels.
    pub fn init(&self, vs: nn::Path, stage_channels: &[i64], bn: &crate::BatchNorm) -> Result<VoxelRoiPool> {
        self.validate()?;
        let layers = self
            .stages
            .iter()
            .enumerate()
            .map(|(k, s)| {
                let c_in = stage_channels.get(s.stage - 1).copied().ok_or_else(|| {
                    NnError::config(
                        "roi_head.voxel_pool",
                        format!("voxel roi pool: the 3-D backbone has no stage {}", s.stage),
                    )
                })?;
                let p = &vs / format!("stage{k}");
                let cfg = nn::LinearConfig { bias: false, ..Default::default() };
                Ok((
                    nn::linear(&p / "linear", c_in + 3, s.channels, cfg),
                    nn::batch_norm1d(&p / "bn", s.channels, bn.config()),
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(VoxelRoiPool { cfg: self.clone(), layers })
    }
}

/// Where a stage's voxel `q` lies, per axis `x, y, z`: centre `min + (a·q + b + ½)·v` in metres
/// (`a`, `b` in input voxels: strides and paddings compose).
#[derive(Debug, Clone, Copy)]
pub struct StageGeometry {
    pub min: [f64; 3],
    pub voxel: [f64; 3],
    pub a: [f64; 3],
    pub b: [f64; 3],
}

impl StageGeometry {
    /// Geometry of each of the backbone's four stages on `grid`.
    pub fn of(backbone: &Backbone3dConfig, grid: &Grid) -> Vec<Self> {
        let base = Self {
            min: [grid.x_min, grid.y_min, grid.z_min],
            voxel: [grid.vx, grid.vy, grid.vz],
            a: [1.0; 3],
            b: [0.0; 3],
        };
        let Backbone3dConfig::VoxelBackbone8x(c) = backbone;
        let (specs, ends) = c.stages();
        let mut out = Vec::new();
        let mut g = base;
        let mut start = 0;
        for end in ends {
            for (spec, _) in &specs[start..end] {
                if spec.kind == crate::sparse::SparseConvKind::Regular {
                    // Sparse order is (z, y, x); geometry is (x, y, z).
                    for (axis, dim) in [(0, 2), (1, 1), (2, 0)] {
                        let off = -(spec.padding[dim] as f64) + (spec.kernel[dim] - 1) as f64 / 2.0;
                        g.b[axis] += g.a[axis] * off;
                        g.a[axis] *= spec.stride[dim] as f64;
                    }
                }
            }
            start = end;
            out.push(g);
        }
        out
    }

    fn centre(&self, q: [i32; 3]) -> [f64; 3] {
        std::array::from_fn(|i| self.min[i] + (self.a[i] * q[i] as f64 + self.b[i] + 0.5) * self.voxel[i])
    }

    fn index(&self, p: [f64; 3]) -> [i32; 3] {
        std::array::from_fn(|i| (((p[i] - self.min[i]) / self.voxel[i] - 0.5 - self.b[i]) / self.a[i]).round() as i32)
    }
}

#[derive(Debug)]
pub struct VoxelRoiPool {
    pub cfg: VoxelRoiPoolConfig,
    layers: Vec<(nn::Linear, nn::BatchNorm)>,
}

/// `[x, y, z]` grid points `[B·N·P]` of `rois [B, N, 7]` (rows along x fastest, then y, z).
fn grid_points(rois: &[f32], g: usize) -> Vec<[f64; 3]> {
    let at = |k: usize| (k as f64 + 0.5) / g as f64 - 0.5;
    let mut pts = Vec::with_capacity(rois.len() / 7 * g * g * g);
    for r in rois.chunks_exact(7) {
        let r: [f64; 7] = std::array::from_fn(|i| r[i] as f64);
        let (s, c) = r[6].sin_cos();
        for iz in 0..g {
            for iy in 0..g {
                for ix in 0..g {
                    let (u, v, w) = (at(ix) * r[3], at(iy) * r[4], at(iz) * r[5]);
                    pts.push([r[0] + c * u - s * v, r[1] + s * u + c * v, r[2] + w]);
                }
            }
        }
    }
    pts
}

impl VoxelRoiPool {
    pub fn num_points(&self) -> i64 {
        self.cfg.num_points()
    }

    pub fn out_channels(&self) -> i64 {
        self.cfg.out_channels()
    }

    /// `stages[s - 1]`: the backbone's stage `s` and its geometry; `rois [B, N, 7]` (detector
    /// frame) → `[B, N, ΣC, P]`. Grid points without a voxel near them read zeros.
    pub fn forward_t(&self, stages: &[(SparseTensor, StageGeometry)], rois: &Tensor, train: bool) -> Result<Tensor> {
        let rs = rois.size();
        if rs.len() != 3 || rs[2] != 7 {
            return Err(NnError::Input(format!("voxel roi pool: rois {rs:?} is not [B, N, 7]")));
        }
        let (b, n) = (rs[0], rs[1]);
        let g = self.cfg.grid_size;
        let p = self.num_points();
        let flat: Vec<f32> =
            Vec::try_from(rois.detach().to_device(tch::Device::Cpu).to_kind(Kind::Float).flatten(0, -1))
                .map_err(|e| NnError::Input(format!("voxel roi pool: {e}")))?;
        let pts = grid_points(&flat, g);
        let per_roi = p as usize;
        let mut outs = Vec::with_capacity(self.layers.len());
        for (s, (linear, norm)) in self.cfg.stages.iter().zip(&self.layers) {
            let (x, geo) = stages.get(s.stage - 1).ok_or_else(|| {
                NnError::Input(format!("voxel roi pool: stage {} is not among the backbone's outputs", s.stage))
            })?;
            if x.batch_size != b {
                return Err(NnError::Input(format!(
                    "voxel roi pool: {} frames of voxels for {b} of RoIs",
                    x.batch_size
                )));
            }
            let index: FxHashMap<[i32; 4], i64> = x.coords.iter().enumerate().map(|(i, c)| (*c, i as i64)).collect();
            // The query cube's offsets, nearest first (stable: ties in raster order).
            let r = s.radius;
            let mut cube: Vec<[i32; 3]> = Vec::new();
            for dz in -r..=r {
                for dy in -r..=r {
                    for dx in -r..=r {
                        cube.push([dx, dy, dz]);
                    }
                }
            }
            cube.sort_by_key(|d| d[0].abs() + d[1].abs() + d[2].abs());
            let k = s.max_neighbours;
            let pad = x.len() as i64; // index of the zero row
            let mut nbr = vec![pad; pts.len() * k];
            let mut rel = vec![0f32; pts.len() * k * 3];
            for (m, pt) in pts.iter().enumerate() {
                let batch = (m / (per_roi * n as usize)) as i32;
                let q = geo.index(*pt);
                let mut found = 0;
                for d in &cube {
                    let v = [q[0] + d[0], q[1] + d[1], q[2] + d[2]];
                    if let Some(&i) = index.get(&[batch, v[2], v[1], v[0]]) {
                        let c = geo.centre(v);
                        nbr[m * k + found] = i;
                        for a in 0..3 {
                            rel[(m * k + found) * 3 + a] = (c[a] - pt[a]) as f32;
                        }
                        found += 1;
                        if found == k {
                            break;
                        }
                    }
                }
            }
            let dev = x.features.device();
            let c = x.channels();
            let feats = Tensor::cat(&[&x.features, &Tensor::zeros([1, c], (x.features.kind(), dev))], 0);
            let nbr_t = Tensor::from_slice(&nbr).to_device(dev);
            let valid = nbr_t.ne(pad).view([-1, k as i64, 1]);
            let rel_t = Tensor::from_slice(&rel).view([-1, 3]).to_device(dev).to_kind(x.features.kind());
            let h = Tensor::cat(&[feats.index_select(0, &nbr_t), rel_t], 1); // [M·K, C + 3]
            let h = norm.forward_t(&linear.forward(&h), train && h.size()[0] > 1).relu();
            let h = h.view([-1, k as i64, s.channels]);
            // ReLU outputs are ≥ 0, so zeroing the empty slots leaves the max of the real ones.
            let h = (h * valid.to_kind(x.features.kind())).amax([1].as_slice(), false); // [M, C']
            outs.push(h.view([b, n, p, s.channels]));
        }
        Ok(Tensor::cat(&outs, 3).permute([0, 1, 3, 2]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backbones_3d::VoxelBackbone8xConfig;
    use crate::pillarize::PillarizeConfig;
    use tch::Device;

    /// Stage geometry composes the strides and paddings: a stage-4 voxel centre is the centre of
    /// the input voxels it was computed from (OpenPCDet's conv4 pads z by 0, so z shifts by one).
    #[test]
    fn stage_centres_follow_the_convolutions() {
        let grid = Grid::new(&PillarizeConfig {
            point_cloud_range: [0.0, 0.0, -2.0, 12.8, 12.8, 4.0],
            pillar_size: [0.1, 0.1],
            voxel_height: Some(0.15),
            ..Default::default()
        })
        .unwrap();
        let bb = Backbone3dConfig::VoxelBackbone8x(VoxelBackbone8xConfig::default());
        let geo = StageGeometry::of(&bb, &grid);
        assert_eq!(geo.len(), 4);
        assert_eq!((geo[0].a, geo[0].b), ([1.0; 3], [0.0; 3]));
        assert_eq!(geo[1].a, [2.0; 3]);
        assert_eq!(geo[3].a, [8.0; 3]);
        // conv4: z padding 0 adds one input voxel (of stage 3, 4 base voxels) to z.
        assert_eq!(geo[3].b, [0.0, 0.0, 4.0]);
        let c = geo[2].centre([3, 5, 2]);
        assert!((c[0] - (0.0 + (4.0 * 3.0 + 0.5) * 0.1)).abs() < 1e-9);
        assert_eq!(geo[2].index(c), [3, 5, 2]);
    }

    /// A hand-built stage: the one grid point next to a voxel gets layer([f, offset]) (max over
    /// one neighbour), points far from every voxel read zeros, and gradients reach the features.
    #[test]
    fn pools_the_voxels_near_each_grid_point() {
        tch::manual_seed(0);
        let vs = nn::VarStore::new(Device::Cpu);
        let cfg = VoxelRoiPoolConfig {
            grid_size: 1,
            stages: vec![VoxelPoolStage { stage: 1, radius: 1, max_neighbours: 4, channels: 3 }],
        };
        let pool = cfg.init(vs.root(), &[2], &crate::BatchNorm::default()).unwrap();
        let geo = StageGeometry { min: [0.0; 3], voxel: [1.0; 3], a: [1.0; 3], b: [0.0; 3] };
        let f = Tensor::from_slice(&[1.0f32, 2.0, 3.0, 4.0]).view([2, 2]).set_requires_grad(true);
        // Voxels (x, y, z) = (2, 3, 1) and (9, 9, 9); coords are (b, z, y, x).
        let x = SparseTensor::new(f.shallow_clone(), vec![[0, 1, 3, 2], [0, 9, 9, 9]], [12, 12, 12], 1).unwrap();
        // RoI 0 centred at voxel (2, 3, 1)'s centre + 0.2 in x; RoI 1 far away.
        let rois = Tensor::from_slice(&[2.7f32, 3.5, 1.5, 1.0, 1.0, 1.0, 0.0, 6.0, 0.5, 5.5, 1.0, 1.0, 1.0, 0.0])
            .view([1, 2, 7]);
        let out = pool.forward_t(&[(x, geo)], &rois, false).unwrap();
        assert_eq!(out.size(), [1, 2, 3, 1]);
        let (linear, norm) = &pool.layers[0];
        let want = norm
            .forward_t(&linear.forward(&Tensor::from_slice(&[1.0f32, 2.0, -0.2, 0.0, 0.0]).view([1, 5])), false)
            .relu();
        let got = out.select(1, 0).view([1, 3]);
        assert!((got - want).abs().max().double_value(&[]) < 1e-6);
        assert_eq!(out.select(1, 1).abs().sum(Kind::Float).double_value(&[]), 0.0);
        out.sum(Kind::Float).backward();
        assert_eq!(f.grad().select(0, 1).abs().sum(Kind::Float).double_value(&[]), 0.0);
    }
}
