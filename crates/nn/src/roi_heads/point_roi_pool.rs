//! Raw-point features of a RoI, in the spirit of the canonical RoI points of PointRCNN / Part-A²:
//! the BEV map pooled by [`super::bev_roi_pool`] carries little evidence of where a box's top and
//! bottom are (the pillar VFE has already collapsed z), and 3D IoU at 0.7 is lost on z and height
//! (see `pi3det eval --breakdown`). This pool reads the points themselves.
//!
//! For each RoI, enlarged by `margin` on every side: an `L × L` lattice of BEV positions inside
//! the rotated box is looked up in the pillar grid (a cheap stand-in for a points-in-box query:
//! occupied cells only, each holding up to `max_points_per_pillar` points); the points inside the
//! enlarged box are expressed in the RoI's own frame (metres and in units of the enlarged size, plus
//! intensity), a small PointNet (`Linear → ReLU` per layer) runs on them and a max over the RoI's
//! points plus `ln(1 + n)/5` of its count of point lookups (a point whose cell two lattice
//! positions hit counts twice) give the RoI's vector `[B, N, C + 1]`, which the
//! RoI head concatenates to its BEV features. Differentiable in the PointNet's weights only (RoIs
//! and points are constants). Pillars only; a cell looked up twice contributes its points twice,
//! which a max does not mind.

use serde::{Deserialize, Serialize};
use tch::nn::{self, Module};
use tch::{Kind, Tensor};

use super::bev_roi_pool::{BevRoiPool, BevRoiPoolConfig, PoolLayout};
use crate::error::{NnError, Result};
use crate::pillarize::Grid;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PointRoiPoolConfig {
    /// Lattice size `L`: `L²` BEV cells looked up per RoI.
    pub lattice: usize,
    /// Metres added to the RoI on every side (x, y and z) before selecting points.
    pub margin: f64,
    /// PointNet widths.
    pub channels: Vec<i64>,
}

impl Default for PointRoiPoolConfig {
    fn default() -> Self {
        Self { lattice: 8, margin: 0.4, channels: vec![32, 64] }
    }
}

/// Per-point input features: local x, y, z (m), the same over the enlarged size, intensity.
const POINT_INPUTS: i64 = 7;

impl PointRoiPoolConfig {
    pub fn validate(&self) -> Result<()> {
        if !(1..=32).contains(&self.lattice) {
            return Err(NnError::config(
                "roi_head.point_pool",
                format!("roi point pool: lattice {} is not in 1..=32", self.lattice),
            ));
        }
        if !(self.margin.is_finite() && self.margin >= 0.0) {
            return Err(NnError::config(
                "roi_head.point_pool",
                format!("roi point pool: margin {} must be finite and ≥ 0", self.margin),
            ));
        }
        if self.channels.is_empty() || self.channels.iter().any(|&c| c < 1) {
            return Err(NnError::config(
                "roi_head.point_pool",
                "roi point pool: channels must be a non-empty list of positive widths",
            ));
        }
        Ok(())
    }

    /// Width of a RoI's vector: the last PointNet width plus the point count.
    pub fn out_channels(&self) -> i64 {
        self.channels.last().copied().unwrap_or(0) + 1
    }

    pub fn init(&self, vs: nn::Path) -> Result<PointRoiPool> {
        self.validate()?;
        let lattice =
            BevRoiPoolConfig { layout: PoolLayout::Grid, grid_size: self.lattice, margin: self.margin }.init()?;
        let mut dim = POINT_INPUTS;
        let layers = self
            .channels
            .iter()
            .enumerate()
            .map(|(k, &c)| {
                let l = nn::linear(&vs / format!("pointnet{k}"), dim, c, Default::default());
                dim = c;
                l
            })
            .collect();
        Ok(PointRoiPool { cfg: self.clone(), lattice, layers })
    }
}

/// The pillars of a batch, as the VFE got them.
pub struct PillarPoints<'a> {
    /// `[ΣP, M, F]` decorated points, x, y, z, intensity first (detector frame); padding slots are
    /// all zero.
    pub features: &'a Tensor,
    /// `[ΣP]` flat cell `b·ny·nx + iy·nx + ix`.
    pub cells: &'a Tensor,
    pub batch_size: i64,
    pub grid: Grid,
}

#[derive(Debug)]
pub struct PointRoiPool {
    pub cfg: PointRoiPoolConfig,
    lattice: BevRoiPool,
    layers: Vec<nn::Linear>,
}

impl PointRoiPool {
    pub fn out_channels(&self) -> i64 {
        self.cfg.out_channels()
    }

    /// `rois [B, N, 7]` (detector frame) → `[B, N, C + 1]` point features.
    pub fn forward(&self, pts: &PillarPoints, rois: &Tensor) -> Result<Tensor> {
        let g = &pts.grid;
        if g.voxels {
            return Err(NnError::config("roi_head.point_pool", "roi point pool: needs a pillar grid, not voxels"));
        }
        let (b, n, seven) = rois
            .size3()
            .map_err(|_| NnError::Input(format!("roi point pool: rois {:?} is not [B, N, 7]", rois.size())))?;
        let (p, m, f) = pts.features.size3().map_err(|_| {
            NnError::Input(format!("roi point pool: pillars {:?} are not [P, M, F]", pts.features.size()))
        })?;
        if seven != 7 || b != pts.batch_size || f < 4 || pts.cells.size() != [p] {
            return Err(NnError::Input(format!(
                "roi point pool: rois {:?}, pillars {:?}, cells {:?} for a batch of {}",
                rois.size(),
                pts.features.size(),
                pts.cells.size(),
                pts.batch_size
            )));
        }
        let dev = rois.device();
        let r = b * n;
        let rois = rois.detach().to_kind(Kind::Float).view([r, 7]);
        let (nx, ny) = (g.nx as i64, g.ny as i64);
        // Lattice positions → pillar rows (row `p` is an all-zero pillar for empty cells).
        let xy = self.lattice.sample_points(&rois.to_kind(Kind::Double)); // [R, L², 2]
        let ix = ((xy.select(-1, 0) - g.x_min) / g.vx).floor().to_kind(Kind::Int64);
        let iy = ((xy.select(-1, 1) - g.y_min) / g.vy).floor().to_kind(Kind::Int64);
        let inside = ix.ge(0).logical_and(&ix.lt(nx)).logical_and(&iy.ge(0)).logical_and(&iy.lt(ny));
        let frame = Tensor::arange(b, (Kind::Int64, dev)).repeat_interleave_self_int(n, 0, None).unsqueeze(1);
        let empty = Tensor::from(b * ny * nx).to_device(dev);
        let flat = (frame * (ny * nx) + iy.clamp(0, ny - 1) * nx + ix.clamp(0, nx - 1)).where_self(&inside, &empty);
        let table = Tensor::full([b * ny * nx + 1], p, (Kind::Int64, dev)).index_put(
            &[Some(pts.cells.to_device(dev).to_kind(Kind::Int64))],
            &Tensor::arange(p, (Kind::Int64, dev)),
            false,
        );
        let rows = table.index_select(0, &flat.view([-1]));
        let raw = pts.features.narrow(2, 0, 4).to_device(dev).to_kind(Kind::Float);
        let raw = Tensor::cat(&[raw, Tensor::zeros([1, m, 4], (Kind::Float, dev))], 0);
        let raw = raw.index_select(0, &rows).view([r, -1, 4]); // [R, S, 4]
                                                               // The RoI's frame.
        let c = rois.unbind(1);
        let (cos, sin) = (c[6].cos().view([r, 1]), c[6].sin().view([r, 1]));
        let dx = raw.select(2, 0) - c[0].view([r, 1]);
        let dy = raw.select(2, 1) - c[1].view([r, 1]);
        let dz = raw.select(2, 2) - c[2].view([r, 1]);
        let local = Tensor::stack(&[&dx * &cos + &dy * &sin, &dy * &cos - &dx * &sin, dz], 2); // [R, S, 3]
        let size = (rois.narrow(1, 3, 3) + 2.0 * self.cfg.margin).clamp_min(1e-3).unsqueeze(1); // [R, 1, 3]
        let unit = &local / &size;
        let valid = raw
            .abs()
            .sum_dim_intlist([2].as_slice(), false, Kind::Float)
            .gt(0.0)
            .logical_and(&unit.abs().le(0.5).all_dims(&[2i64][..], false)); // [R, S]
                                                                            // PointNet on the valid points only, max per RoI.
        let idx = valid.view([-1]).nonzero().squeeze_dim(1);
        let x = Tensor::cat(&[local, unit, raw.narrow(2, 3, 1)], 2).view([-1, POINT_INPUTS]).index_select(0, &idx);
        let h = self.layers.iter().fold(x, |h, l| l.forward(&h).relu());
        let s = raw.size()[1];
        let owner = idx.divide_scalar_mode(s, "floor");
        let c_out = self.cfg.channels.last().copied().unwrap_or(0);
        let pooled = Tensor::zeros([r, c_out], (Kind::Float, dev)).index_reduce(0, &owner, &h, "amax", true);
        let count = valid.to_kind(Kind::Float).sum_dim_intlist([1].as_slice(), true, Kind::Float);
        let count = (count + 1.0).log() / 5.0;
        Ok(Tensor::cat(&[pooled, count], 1).view([b, n, -1]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pillarize::PillarizeConfig;

    fn grid() -> Grid {
        Grid::new(&PillarizeConfig {
            point_cloud_range: [-8.0, -8.0, -2.0, 8.0, 8.0, 4.0],
            pillar_size: [0.5, 0.5],
            ..Default::default()
        })
        .unwrap()
    }

    /// Pillars `[P, 2, 10]` of the given points (one per pillar, second slot padding) and cells.
    fn pillars(g: &Grid, frames: &[Vec<[f32; 4]>]) -> (Tensor, Tensor) {
        let (mut feats, mut cells) = (vec![], vec![]);
        for (b, pts) in frames.iter().enumerate() {
            for p in pts {
                let c = g.cell(p[0], p[1], p[2]).unwrap();
                cells.push((b * g.ny * g.nx + c) as i64);
                let mut row = [0f32; 20];
                row[..4].copy_from_slice(p);
                feats.extend_from_slice(&row);
            }
        }
        (Tensor::from_slice(&feats).view([-1, 2, 10]), Tensor::from_slice(&cells))
    }

    #[test]
    fn counts_only_the_points_inside_each_rotated_roi_and_frame() {
        tch::manual_seed(0);
        let g = grid();
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let cfg = PointRoiPoolConfig { lattice: 16, margin: 0.0, channels: vec![4] };
        let pool = cfg.init(vs.root()).unwrap();
        // Frame 0: two points in the rotated RoI (one of them high up, outside its z range), one
        // beside it; frame 1: a point where frame 0's RoI is, and one in its own RoI.
        let f0 = vec![[1.2, 1.2, 0.5, 0.3], [2.8, 2.8, 0.2, 0.9], [2.0, 2.0, 3.0, 0.5], [5.2, 0.0, 0.0, 0.1]];
        let f1 = vec![[2.0, 2.0, 0.0, 0.2], [-4.0, -4.0, 0.0, 0.7]];
        let (features, cells) = pillars(&g, &[f0, f1]);
        let pts = PillarPoints { features: &features, cells: &cells, batch_size: 2, grid: g };
        let h = std::f32::consts::FRAC_PI_4;
        let rois = Tensor::from_slice(&[
            2.0f32, 2.0, 0.5, 3.0, 1.0, 2.0, h, // frame 0: diagonal 3 m box over (1.2,1.2)…(2.8,2.8)
            -4.0, -4.0, 0.0, 1.0, 1.0, 1.0, 0.0, // frame 0: empty
            -4.0, -4.0, 0.0, 1.0, 1.0, 1.0, 0.0, // frame 1: one point
            0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, // frame 1: empty
        ])
        .view([2, 2, 7]);
        let out = pool.forward(&pts, &rois).unwrap();
        assert_eq!(out.size(), [2, 2, 5]);
        let count = |b: i64, k: i64| (out.double_value(&[b, k, 4]) * 5.0).exp() - 1.0;
        // Each point is seen once per lattice cell that falls in its pillar: count distinct via > 0.
        assert!(count(0, 0) >= 2.0, "{}", count(0, 0));
        assert_eq!(count(0, 1), 0.0);
        assert!(count(1, 0) >= 1.0);
        assert_eq!(count(1, 1), 0.0);
        // Empty RoIs pool zeros; features are finite and get gradients.
        assert_eq!(out.get(0).get(1).abs().sum(Kind::Float).double_value(&[]), 0.0);
        let loss = out.sum(Kind::Float);
        loss.backward();
        assert!(vs.trainable_variables().iter().any(|v| v.grad().abs().sum(Kind::Float).double_value(&[]) > 0.0));
    }

    #[test]
    fn features_are_the_points_in_the_rois_frame() {
        // One linear layer with identity weights on (local x, y, z): the max over the RoI's points
        // of relu(local) is a hand computation.
        let g = grid();
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let cfg = PointRoiPoolConfig { lattice: 8, margin: 0.5, channels: vec![3] };
        let pool = cfg.init(vs.root()).unwrap();
        tch::no_grad(|| {
            for (name, mut v) in vs.variables() {
                if name.ends_with("weight") {
                    let mut w = vec![0f32; 21];
                    for i in 0..3 {
                        w[i * 7 + i] = 1.0;
                    }
                    v.copy_(&Tensor::from_slice(&w).view([3, 7]));
                } else {
                    let _ = v.zero_();
                }
            }
        });
        // RoI at (1, −2, 0.5) heading π/2: its local x is the world y.
        let f0 = vec![[1.3, -1.2, 0.9, 0.5], [0.8, -2.6, 0.1, 0.5]];
        let (features, cells) = pillars(&g, &[f0]);
        let pts = PillarPoints { features: &features, cells: &cells, batch_size: 1, grid: g };
        let h = std::f32::consts::FRAC_PI_2;
        let rois = Tensor::from_slice(&[1.0f32, -2.0, 0.5, 2.0, 1.0, 1.0, h]).view([1, 1, 7]);
        let out = pool.forward(&pts, &rois).unwrap();
        // Local (x, y, z): point 1 → (0.8, −0.3, 0.4), point 2 → (−0.6, 0.2, −0.4).
        let want = [0.8, 0.2, 0.4];
        for (k, w) in want.iter().enumerate() {
            assert!((out.double_value(&[0, 0, k as i64]) - w).abs() < 1e-5, "{k}: {out}");
        }
    }

    #[test]
    fn bad_configs_and_inputs_are_errors() {
        assert!(PointRoiPoolConfig { lattice: 0, ..Default::default() }.validate().is_err());
        assert!(PointRoiPoolConfig { margin: -1.0, ..Default::default() }.validate().is_err());
        assert!(PointRoiPoolConfig { channels: vec![], ..Default::default() }.validate().is_err());
        let g = grid();
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let pool = PointRoiPoolConfig::default().init(vs.root()).unwrap();
        let (features, cells) = pillars(&g, &[vec![[0.0, 1.0, 0.0, 0.0]]]);
        let pts = PillarPoints { features: &features, cells: &cells, batch_size: 2, grid: g };
        assert!(pool.forward(&pts, &Tensor::zeros([1, 1, 7], (Kind::Float, tch::Device::Cpu))).is_err());
    }
}
