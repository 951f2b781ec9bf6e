//! Points → pillars (PointPillars, Lang et al. 2019): a BEV grid over the point-cloud range, at
//! most `max_points_per_pillar` points per occupied cell and at most `max_pillars` cells, each
//! point decorated with its offsets to the pillar's point mean and to the pillar's centre
//! (OpenPCDet `PillarVFE` features: x, y, z, intensity, x−x̄, y−ȳ, z−z̄, x−x_c, y−y_c, z−z_c).
//!
//! With `voxel_height` the grid is cut along z too and each cell is a voxel whose feature is the
//! mean of its points' (x, y, z, intensity) (OpenPCDet `MeanVFE`): the input of the voxel
//! detectors' sparse 3-D backbone ([`crate::sparse`]).
//!
//! Cells are taken in the order their first point arrives (OpenPCDet's voxel generator), so the
//! result is deterministic; the decoration runs in parallel over pillars (rayon).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{NnError, Result};

/// Number of decorated features per point.
pub const POINT_FEATURES: usize = 10;

/// Features of a voxel (mean x, y, z, intensity of its points).
pub const VOXEL_FEATURES: usize = 4;

/// The grid: range and pillar size.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PillarizeConfig {
    /// `[x_min, y_min, z_min, x_max, y_max, z_max]` in metres (after the config's z shift).
    pub point_cloud_range: [f64; 6],
    /// Pillar size `[x, y]` in metres; the pillar spans the whole z range.
    pub pillar_size: [f64; 2],
    pub max_points_per_pillar: usize,
    /// Pillars kept per frame when training / at inference (first come, first kept).
    pub max_pillars_train: usize,
    pub max_pillars_test: usize,
    /// Voxel detectors: the cells' height in metres (cells become voxels of `pillar_size` ×
    /// this; `max_points_per_pillar` and `max_pillars_*` then count points per voxel and voxels).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub voxel_height: Option<f64>,
}

impl Default for PillarizeConfig {
    fn default() -> Self {
        Self {
            point_cloud_range: [-40.0, -40.0, -2.0, 40.0, 40.0, 4.0],
            pillar_size: [0.4, 0.4],
            max_points_per_pillar: 20,
            max_pillars_train: 16000,
            max_pillars_test: 24000,
            voxel_height: None,
        }
    }
}

/// Grid dimensions derived from a [`PillarizeConfig`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    pub x_min: f64,
    pub y_min: f64,
    pub z_min: f64,
    pub x_max: f64,
    pub y_max: f64,
    pub z_max: f64,
    pub vx: f64,
    pub vy: f64,
    /// Cell height: the whole z range for pillars.
    pub vz: f64,
    /// Cells along x (columns of the BEV map), y (rows) and z (1 for pillars).
    pub nx: usize,
    pub ny: usize,
    pub nz: usize,
    /// Cells are voxels (`voxel_height` set): mean features, hashed, for a sparse backbone.
    pub voxels: bool,
}

impl Grid {
    pub fn new(cfg: &PillarizeConfig) -> Result<Self> {
        let r = cfg.point_cloud_range;
        let [vx, vy] = cfg.pillar_size;
        if r.iter().chain(&cfg.pillar_size).any(|v| !v.is_finite()) || vx <= 0.0 || vy <= 0.0 {
            return Err(NnError::config(
                "pillars",
                format!("pillar grid: bad range {r:?} or pillar size {:?}", cfg.pillar_size),
            ));
        }
        if r[3] <= r[0] || r[4] <= r[1] || r[5] <= r[2] {
            return Err(NnError::config(
                "pillars.point_cloud_range",
                format!("point_cloud_range {r:?}: each max must exceed its min"),
            ));
        }
        let nx = ((r[3] - r[0]) / vx).round() as usize;
        let ny = ((r[4] - r[1]) / vy).round() as usize;
        if nx == 0 || ny == 0 || nx * ny > 64 << 20 {
            return Err(NnError::config("pillars", format!("pillar grid {nx}×{ny} is empty or too large")));
        }
        let (vz, nz) = match cfg.voxel_height {
            None => (r[5] - r[2], 1),
            Some(h) if h.is_finite() && h > 0.0 => {
                let nz = ((r[5] - r[2]) / h).round() as usize;
                if nz == 0 || nz > 4096 {
                    return Err(NnError::config(
                        "pillars.voxel_height",
                        format!("voxel_height {h}: {nz} voxels along z (want 1..=4096)"),
                    ));
                }
                (h, nz)
            }
            Some(h) => {
                return Err(NnError::config("pillars.voxel_height", format!("voxel_height {h} must be positive")))
            }
        };
        if cfg.max_points_per_pillar == 0 || cfg.max_pillars_train == 0 || cfg.max_pillars_test == 0 {
            return Err(NnError::config("pillars", "max_points_per_pillar and max_pillars_* must be positive"));
        }
        Ok(Self {
            x_min: r[0],
            y_min: r[1],
            z_min: r[2],
            x_max: r[3],
            y_max: r[4],
            z_max: r[5],
            vx,
            vy,
            vz,
            nx,
            ny,
            nz,
            voxels: cfg.voxel_height.is_some(),
        })
    }

    /// Whether cells are voxels (`voxel_height` set).
    pub fn is_voxel(&self) -> bool {
        self.voxels
    }

    /// Cell of a point, `iz·ny·nx + iy·nx + ix`; `None` outside the range (max bounds exclusive).
    #[inline]
    pub fn cell(&self, x: f32, y: f32, z: f32) -> Option<usize> {
        let (x, y, z) = (x as f64, y as f64, z as f64);
        if !(x >= self.x_min
            && x < self.x_max
            && y >= self.y_min
            && y < self.y_max
            && z >= self.z_min
            && z < self.z_max)
        {
            return None;
        }
        let ix = (((x - self.x_min) / self.vx) as usize).min(self.nx - 1);
        let iy = (((y - self.y_min) / self.vy) as usize).min(self.ny - 1);
        let iz = (((z - self.z_min) / self.vz) as usize).min(self.nz - 1);
        Some((iz * self.ny + iy) * self.nx + ix)
    }

    pub fn contains_xy(&self, x: f64, y: f64) -> bool {
        x >= self.x_min && x < self.x_max && y >= self.y_min && y < self.y_max
    }
}

/// Pillars of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Pillars {
    /// `[num_pillars, max_points, point_features]`, zero-padded (voxels: `[V, 1, 4]` means).
    pub features: Vec<f32>,
    /// Flat cell of each pillar, `iy * nx + ix` (voxels: `(iz * ny + iy) * nx + ix`).
    pub cells: Vec<i64>,
    pub max_points: usize,
    /// Features per point slot: [`POINT_FEATURES`] or [`VOXEL_FEATURES`].
    pub point_features: usize,
    /// Points that fell in a full pillar or beyond `max_pillars` and were dropped.
    pub dropped_points: usize,
}

impl Pillars {
    pub fn len(&self) -> usize {
        self.cells.len()
    }
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }
}

/// Reusable pillarizer (keeps its cell lookup table between frames).
pub struct Pillarizer {
    pub grid: Grid,
    max_points: usize,
    /// Cell → pillar index + 1 (0: empty); reset after each frame through `touched`. Empty for
    /// voxel grids (a table of nx·ny·nz cells would be hundreds of MB; they use a hash).
    lookup: Vec<u32>,
}

impl Pillarizer {
    pub fn new(cfg: &PillarizeConfig) -> Result<Self> {
        let grid = Grid::new(cfg)?;
        let lookup = if grid.is_voxel() { Vec::new() } else { vec![0; grid.nx * grid.ny] };
        Ok(Self { grid, max_points: cfg.max_points_per_pillar, lookup })
    }

    /// Whether this pillarizer is the one `cfg` makes (same grid and pillar size).
    pub fn fits(&self, cfg: &PillarizeConfig) -> bool {
        Grid::new(cfg).is_ok_and(|g| g == self.grid) && cfg.max_points_per_pillar == self.max_points
    }

    /// Pillarizes `points` (x, y, z, intensity); non-finite points and points outside the range
    /// are skipped.
    pub fn run(&mut self, points: &[[f32; 4]], max_pillars: usize) -> Pillars {
        if self.grid.is_voxel() {
            return self.voxelize(points, max_pillars);
        }
        let g = self.grid;
        let m = self.max_points;
        // Pass 1 (sequential, cheap): assign points to pillars in arrival order.
        let mut cells: Vec<i64> = Vec::new();
        let mut members: Vec<u32> = Vec::new(); // pillar-major, m slots per pillar
        let mut counts: Vec<u32> = Vec::new();
        let mut dropped = 0usize;
        for (i, p) in points.iter().enumerate() {
            let Some(c) = g.cell(p[0], p[1], p[2]) else { continue };
            let slot = self.lookup[c];
            let pillar = if slot == 0 {
                if cells.len() >= max_pillars {
                    dropped += 1;
                    continue;
                }
                cells.push(c as i64);
                counts.push(0);
                members.resize(members.len() + m, 0);
                self.lookup[c] = cells.len() as u32;
                cells.len() - 1
            } else {
                slot as usize - 1
            };
            let n = counts[pillar] as usize;
            if n >= m {
                dropped += 1;
                continue;
            }
            members[pillar * m + n] = i as u32;
            counts[pillar] += 1;
        }
        for &c in &cells {
            self.lookup[c as usize] = 0;
        }
        // Pass 2 (parallel): decorate.
        let mut features = vec![0f32; cells.len() * m * POINT_FEATURES];
        features.par_chunks_mut(m * POINT_FEATURES).enumerate().for_each(|(k, out)| {
            let n = counts[k] as usize;
            let idx = &members[k * m..k * m + n];
            let (mut sx, mut sy, mut sz) = (0f32, 0f32, 0f32);
            for &i in idx {
                let p = points[i as usize];
                sx += p[0];
                sy += p[1];
                sz += p[2];
            }
            let inv = 1.0 / n.max(1) as f32;
            let (mx, my, mz) = (sx * inv, sy * inv, sz * inv);
            let c = cells[k] as usize;
            let cx = (g.x_min + ((c % g.nx) as f64 + 0.5) * g.vx) as f32;
            let cy = (g.y_min + ((c / g.nx) as f64 + 0.5) * g.vy) as f32;
            let cz = ((g.z_min + g.z_max) * 0.5) as f32;
            for (j, &i) in idx.iter().enumerate() {
                let p = points[i as usize];
                let f = &mut out[j * POINT_FEATURES..(j + 1) * POINT_FEATURES];
                f.copy_from_slice(&[
                    p[0],
                    p[1],
                    p[2],
                    p[3],
                    p[0] - mx,
                    p[1] - my,
                    p[2] - mz,
                    p[0] - cx,
                    p[1] - cy,
                    p[2] - cz,
                ]);
            }
        });
        Pillars { features, cells, max_points: m, point_features: POINT_FEATURES, dropped_points: dropped }
    }

    /// Voxels with the mean of their first `max_points` points (arrival order), at most
    /// `max_voxels`; the rest is counted in `dropped_points`.
    fn voxelize(&self, points: &[[f32; 4]], max_voxels: usize) -> Pillars {
        let g = self.grid;
        let mut index: rustc_hash::FxHashMap<usize, u32> = Default::default();
        let mut cells: Vec<i64> = Vec::new();
        let mut sums: Vec<[f32; 4]> = Vec::new();
        let mut counts: Vec<u32> = Vec::new();
        let mut dropped = 0usize;
        for p in points {
            let Some(c) = g.cell(p[0], p[1], p[2]) else { continue };
            let v = match index.get(&c) {
                Some(&v) => v as usize,
                None => {
                    if cells.len() >= max_voxels {
                        dropped += 1;
                        continue;
                    }
                    index.insert(c, cells.len() as u32);
                    cells.push(c as i64);
                    sums.push([0.0; 4]);
                    counts.push(0);
                    cells.len() - 1
                }
            };
            if counts[v] as usize >= self.max_points {
                dropped += 1;
                continue;
            }
            for (s, x) in sums[v].iter_mut().zip(p) {
                *s += x;
            }
            counts[v] += 1;
        }
        let features = sums.iter().zip(&counts).flat_map(|(s, &n)| s.map(|v| v / n as f32)).collect();
        Pillars { features, cells, max_points: 1, point_features: VOXEL_FEATURES, dropped_points: dropped }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> PillarizeConfig {
        PillarizeConfig {
            point_cloud_range: [0.0, -2.0, -1.0, 4.0, 2.0, 1.0],
            pillar_size: [1.0, 1.0],
            max_points_per_pillar: 2,
            max_pillars_train: 3,
            max_pillars_test: 3,
            voxel_height: None,
        }
    }

    /// Voxels: cells along z too, each the mean of its first points; full voxels and voxels
    /// beyond the limit drop points (counted).
    #[test]
    fn voxels_average_their_points() {
        let c = PillarizeConfig { voxel_height: Some(0.5), ..cfg() };
        let mut p = Pillarizer::new(&c).unwrap();
        assert_eq!((p.grid.nx, p.grid.ny, p.grid.nz), (4, 4, 4));
        let pts = [
            [0.5, -1.5, -0.9, 0.2], // voxel (0, 0, 0)
            [0.5, -1.5, 0.1, 0.5],  // (0, 0, 2): cell 2·16
            [0.7, -1.3, -0.7, 0.4], // (0, 0, 0) again
            [0.6, -1.4, -0.8, 0.0], // third point in a full voxel: dropped
            [3.5, 1.5, 0.9, 1.0],   // (3, 3, 3): the third voxel
            [2.5, 1.5, 0.9, 1.0],   // fourth voxel: dropped
            [f32::NAN, 0.0, 0.0, 0.0],
        ];
        let r = p.run(&pts, 3);
        assert_eq!(r.cells, vec![0, 32, 3 * 16 + 3 * 4 + 3]);
        assert_eq!((r.max_points, r.point_features, r.dropped_points), (1, VOXEL_FEATURES, 2));
        let want = [0.6, -1.4, -0.8, 0.3];
        for (a, b) in r.features[..4].iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{:?}", &r.features[..4]);
        }
        assert_eq!(&r.features[4..8], &[0.5, -1.5, 0.1, 0.5]);
        assert!(Grid::new(&PillarizeConfig { voxel_height: Some(-1.0), ..cfg() }).is_err());
    }

    #[test]
    fn assigns_in_arrival_order_and_decorates() {
        let mut p = Pillarizer::new(&cfg()).unwrap();
        assert_eq!((p.grid.nx, p.grid.ny), (4, 4));
        let pts = [
            [0.5, -1.5, 0.0, 0.1], // cell (0, 0)
            [3.5, 1.5, 0.5, 0.2],  // cell (3, 3)
            [0.25, -1.75, 0.5, 0.3],
            [0.75, -1.25, 0.0, 0.4], // third point in a full pillar: dropped
            [9.0, 0.0, 0.0, 0.0],    // outside
            [f32::NAN, 0.0, 0.0, 0.0],
            [1.5, 0.5, -0.5, 0.5], // cell (1, 2)
            [2.5, 0.5, -0.5, 0.5], // fourth pillar: dropped
            [3.5, 1.5, 1.0, 0.5],  // z max is exclusive: outside
        ];
        let r = p.run(&pts, 3);
        assert_eq!(r.cells, vec![0, 15, 9]);
        assert_eq!(r.dropped_points, 2);
        let f = &r.features;
        let pf = POINT_FEATURES;
        // Pillar 0, point 0: mean of its two points is (0.375, -1.625, 0.25); centre (0.5, -1.5, 0).
        let p0 = &f[0..pf];
        let want = [0.5, -1.5, 0.0, 0.1, 0.125, 0.125, -0.25, 0.0, 0.0, 0.0];
        for (a, b) in p0.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{p0:?}");
        }
        // Pillar 1 has one point: its second slot is zero padding.
        assert!(f[(2 + 1) * pf..(2 + 2) * pf].iter().all(|&v| v == 0.0));
        // The lookup table is clean for the next frame.
        let r2 = p.run(&pts[6..7], 3);
        assert_eq!(r2.cells, vec![9]);
    }

    #[test]
    fn rejects_bad_grids() {
        let mut c = cfg();
        c.pillar_size = [0.0, 1.0];
        assert!(Grid::new(&c).is_err());
        let mut c = cfg();
        c.point_cloud_range[3] = -1.0;
        assert!(Grid::new(&c).is_err());
    }
}
