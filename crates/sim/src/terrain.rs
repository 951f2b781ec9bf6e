//! The ground: a height field on a regular grid of nodes, each cell split into two triangles, so
//! the surface the platforms stand on and the surface rays hit are exactly the same.

use rand::Rng;

use crate::shapes::Ray;

#[derive(Debug, Clone, PartialEq)]
pub struct Terrain {
    pub origin_xy: [f64; 2],
    pub cell_m: f64,
    /// Cells along x and y (nodes are one more).
    pub nx: usize,
    pub ny: usize,
    heights_m: Vec<f64>,
}

impl Terrain {
    /// Gentle rolling ground over `bounds` (`[xmin, ymin, xmax, ymax]`): a constant incline of up to
    /// `incline_deg` plus three long waves whose slopes add up to at most `max_slope_deg`, shifted
    /// so that the ground is at z = 0 under `anchor_xy` (the platform's start).
    pub fn rolling<R: Rng + ?Sized>(
        bounds: [f64; 4],
        cell_m: f64,
        max_slope_deg: f64,
        incline_deg: f64,
        anchor_xy: [f64; 2],
        rng: &mut R,
    ) -> Self {
        let nx = (((bounds[2] - bounds[0]) / cell_m).ceil() as usize).max(1);
        let ny = (((bounds[3] - bounds[1]) / cell_m).ceil() as usize).max(1);
        let incline_dir: f64 = rng.random_range(0.0..std::f64::consts::TAU);
        let incline = rng.random_range(0.0..=1.0) * incline_deg.to_radians().tan();
        let waves: Vec<(f64, f64, f64, f64)> = (0..3)
            .map(|_| {
                let wavelength_m: f64 = rng.random_range(60.0..220.0);
                let k = std::f64::consts::TAU / wavelength_m;
                let dir: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                let phase: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                let amp = max_slope_deg.to_radians().tan() / 3.0 / k;
                (k * dir.cos(), k * dir.sin(), phase, amp)
            })
            .collect();
        let f = |x: f64, y: f64| -> f64 {
            let mut h = incline * (incline_dir.cos() * x + incline_dir.sin() * y);
            for &(kx, ky, ph, a) in &waves {
                h += a * (kx * x + ky * y + ph).sin();
            }
            h
        };
        let h0 = f(anchor_xy[0], anchor_xy[1]);
        let mut heights_m = Vec::with_capacity((nx + 1) * (ny + 1));
        for j in 0..=ny {
            for i in 0..=nx {
                heights_m.push(f(bounds[0] + i as f64 * cell_m, bounds[1] + j as f64 * cell_m) - h0);
            }
        }
        Self { origin_xy: [bounds[0], bounds[1]], cell_m, nx, ny, heights_m }
    }

    /// Flat ground at z = 0 (tests, benchmarks).
    pub fn flat(bounds: [f64; 4], cell_m: f64) -> Self {
        let nx = (((bounds[2] - bounds[0]) / cell_m).ceil() as usize).max(1);
        let ny = (((bounds[3] - bounds[1]) / cell_m).ceil() as usize).max(1);
        Self { origin_xy: [bounds[0], bounds[1]], cell_m, nx, ny, heights_m: vec![0.0; (nx + 1) * (ny + 1)] }
    }

    pub fn bounds(&self) -> [f64; 4] {
        [
            self.origin_xy[0],
            self.origin_xy[1],
            self.origin_xy[0] + self.nx as f64 * self.cell_m,
            self.origin_xy[1] + self.ny as f64 * self.cell_m,
        ]
    }

    #[inline]
    fn node(&self, i: usize, j: usize) -> f64 {
        self.heights_m[j * (self.nx + 1) + i]
    }

    /// The four corner heights of a cell: `[h00, h10, h01, h11]`.
    #[inline]
    pub fn corners(&self, i: usize, j: usize) -> [f64; 4] {
        [self.node(i, j), self.node(i + 1, j), self.node(i, j + 1), self.node(i + 1, j + 1)]
    }

    /// Cell containing `xy`, clamped to the grid.
    #[inline]
    pub fn cell_of(&self, xy: [f64; 2]) -> (usize, usize) {
        let fx = ((xy[0] - self.origin_xy[0]) / self.cell_m).floor();
        let fy = ((xy[1] - self.origin_xy[1]) / self.cell_m).floor();
        (fx.clamp(0.0, (self.nx - 1) as f64) as usize, fy.clamp(0.0, (self.ny - 1) as f64) as usize)
    }

    /// Ground height at `xy` on the triangulated surface (clamped to the grid's edge outside).
    pub fn height(&self, xy: [f64; 2]) -> f64 {
        let (i, j) = self.cell_of(xy);
        let u = ((xy[0] - self.origin_xy[0]) / self.cell_m - i as f64).clamp(0.0, 1.0);
        let v = ((xy[1] - self.origin_xy[1]) / self.cell_m - j as f64).clamp(0.0, 1.0);
        let [h00, h10, h01, h11] = self.corners(i, j);
        if u >= v {
            h00 + (h10 - h00) * u + (h11 - h10) * v
        } else {
            h00 + (h11 - h01) * u + (h01 - h00) * v
        }
    }

    /// Lowest ground height over a rectangle (for sinking building foundations).
    pub fn min_height_over(&self, bounds: [f64; 4]) -> f64 {
        let (i0, j0) = self.cell_of([bounds[0], bounds[1]]);
        let (i1, j1) = self.cell_of([bounds[2], bounds[3]]);
        let mut m = f64::INFINITY;
        for j in j0..=j1 + 1 {
            for i in i0..=i1 + 1 {
                m = m.min(self.node(i.min(self.nx), j.min(self.ny)));
            }
        }
        m
    }

    /// Ray against the two triangles of cell `(i, j)`, accepting hits with range in `[t0, t1]`.
    #[inline]
    pub fn intersect_cell(&self, i: usize, j: usize, ray: &Ray, t0: f64, t1: f64) -> Option<(f64, [f64; 3])> {
        let [h00, h10, h01, h11] = self.corners(i, j);
        let inv = 1.0 / self.cell_m;
        let u0 = (ray.origin[0] - (self.origin_xy[0] + i as f64 * self.cell_m)) * inv;
        let v0 = (ray.origin[1] - (self.origin_xy[1] + j as f64 * self.cell_m)) * inv;
        let (du, dv) = (ray.dir[0] * inv, ray.dir[1] * inv);
        let mut best: Option<(f64, [f64; 3])> = None;
        // Triangle A (u >= v) and B (v >= u): z = h00 + a·u + b·v.
        for (a, b, upper) in [(h10 - h00, h11 - h10, false), (h11 - h01, h01 - h00, true)] {
            let den = ray.dir[2] - a * du - b * dv;
            if den.abs() < 1e-12 {
                continue;
            }
            let t = (h00 + a * u0 + b * v0 - ray.origin[2]) / den;
            if t <= 0.0 || t < t0 - 1e-9 || t > t1 + 1e-9 || best.is_some_and(|h| h.0 <= t) {
                continue;
            }
            let (u, v) = (u0 + t * du, v0 + t * dv);
            let inside = if upper { v >= u } else { u >= v };
            if inside && (-1e-9..=1.0 + 1e-9).contains(&u) && (-1e-9..=1.0 + 1e-9).contains(&v) {
                let n = [-a * inv, -b * inv, 1.0];
                let l = (n[0] * n[0] + n[1] * n[1] + 1.0).sqrt();
                best = Some((t, [n[0] / l, n[1] / l, 1.0 / l]));
            }
        }
        best
    }

    /// `[min, max]` height of a cell's corners.
    #[inline]
    pub fn cell_z_range(&self, i: usize, j: usize) -> [f64; 2] {
        let c = self.corners(i, j);
        [c[0].min(c[1]).min(c[2]).min(c[3]), c[0].max(c[1]).max(c[2]).max(c[3])]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn rays_hit_the_surface_the_height_function_describes() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let t = Terrain::rolling([-50.0, -50.0, 50.0, 50.0], 4.0, 4.0, 2.0, [0.0, 0.0], &mut rng);
        assert!(t.height([0.0, 0.0]).abs() < 0.05);
        for k in 0..50 {
            let xy = [-40.0 + 1.7 * k as f64, 30.0 - 1.1 * k as f64];
            let ray = Ray { origin: [xy[0], xy[1], 20.0], dir: [0.0, 0.0, -1.0] };
            let (i, j) = t.cell_of(xy);
            let (hit, n) = t.intersect_cell(i, j, &ray, 0.0, 100.0).unwrap();
            assert!((20.0 - hit - t.height(xy)).abs() < 1e-9);
            assert!(n[2] > 0.99);
        }
    }
}
