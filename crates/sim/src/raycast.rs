//! Ray casting: a uniform 2D grid over the ground plane (the terrain's own cells) holding, per
//! cell, the primitives whose footprint overlaps it and the highest z of anything in it. A ray
//! walks the cells it crosses (Amanatides–Woo), skips cells it passes above, and stops at the
//! first cell that ends beyond its nearest hit. No allocation per ray.

use crate::roads::RoadGrid;
use crate::shapes::{Hit, Primitive, Ray};
use crate::terrain::Terrain;

/// Everything a frame's rays can hit, ready for casting. Cheap to rebuild per frame (a few
/// hundred microseconds for a few thousand primitives).
pub struct World<'a> {
    terrain: &'a Terrain,
    paint: Option<&'a RoadGrid>,
    prims: Vec<Primitive>,
    cell_start: Vec<u32>,
    items: Vec<u32>,
    cell_z_max: Vec<f32>,
    cell_ground_max: Vec<f32>,
    z_max: f64,
    ground_reflectivity: f64,
}

impl<'a> World<'a> {
    /// `paint` gives the ground's reflectivity; without it the ground is `ground_reflectivity`.
    pub fn build(
        terrain: &'a Terrain,
        paint: Option<&'a RoadGrid>,
        prims: Vec<Primitive>,
        ground_reflectivity: f64,
    ) -> Self {
        let (nx, ny) = (terrain.nx, terrain.ny);
        let n_cells = nx * ny;
        let cell_ground_max: Vec<f32> = (0..n_cells).map(|c| terrain.cell_z_range(c % nx, c / nx)[1] as f32).collect();
        let mut cell_z_max = cell_ground_max.clone();
        let mut z_max = cell_z_max.iter().copied().fold(f32::NEG_INFINITY, f32::max) as f64;
        let ranges: Vec<Option<(usize, usize, usize, usize)>> =
            prims.iter().map(|p| cell_range(terrain, p.bev_bounds())).collect();
        let mut counts = vec![0u32; n_cells + 1];
        for (p, r) in prims.iter().zip(&ranges) {
            let Some((i0, j0, i1, j1)) = *r else { continue };
            let top = p.z_range()[1];
            z_max = z_max.max(top);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    let c = j * nx + i;
                    counts[c] += 1;
                    cell_z_max[c] = cell_z_max[c].max(top as f32);
                }
            }
        }
        // Exclusive prefix sum → CSR offsets.
        let mut cell_start = vec![0u32; n_cells + 1];
        for c in 0..n_cells {
            cell_start[c + 1] = cell_start[c] + counts[c];
        }
        let mut fill = cell_start.clone();
        let mut items = vec![0u32; cell_start[n_cells] as usize];
        for (k, r) in ranges.iter().enumerate() {
            let Some((i0, j0, i1, j1)) = *r else { continue };
            for j in j0..=j1 {
                for i in i0..=i1 {
                    let c = j * nx + i;
                    items[fill[c] as usize] = k as u32;
                    fill[c] += 1;
                }
            }
        }
        Self { terrain, paint, prims, cell_start, items, cell_z_max, cell_ground_max, z_max, ground_reflectivity }
    }

    pub fn primitives(&self) -> &[Primitive] {
        &self.prims
    }

    /// The nearest hit with range in `(0, t_max]`, or `None`. The ray origin must be inside the
    /// grid's footprint (rays from outside are clipped to it first).
    pub fn cast(&self, ray: &Ray, t_max: f64) -> Option<Hit> {
        let t = self.terrain;
        let cell = t.cell_m;
        let [bx0, by0, bx1, by1] = t.bounds();
        // Clip the ray to the grid footprint.
        let (mut t_in, mut t_out) = (0.0f64, t_max);
        for (o, d, lo, hi) in [(ray.origin[0], ray.dir[0], bx0, bx1), (ray.origin[1], ray.dir[1], by0, by1)] {
            if d.abs() < 1e-15 {
                if o < lo || o > hi {
                    return None;
                }
            } else {
                let (a, b) = ((lo - o) / d, (hi - o) / d);
                t_in = t_in.max(a.min(b));
                t_out = t_out.min(a.max(b));
            }
        }
        if t_in >= t_out {
            return None;
        }
        let start = ray.at(t_in + 1e-9);
        let (mut i, mut j) = t.cell_of([start[0], start[1]]);
        let step_i: i64 = if ray.dir[0] > 0.0 { 1 } else { -1 };
        let step_j: i64 = if ray.dir[1] > 0.0 { 1 } else { -1 };
        let next_boundary = |idx: usize, o: f64, d: f64, origin: f64| -> f64 {
            if d.abs() < 1e-15 {
                return f64::INFINITY;
            }
            let edge = origin + (idx as f64 + if d > 0.0 { 1.0 } else { 0.0 }) * cell;
            (edge - o) / d
        };
        let mut t_next_x = next_boundary(i, ray.origin[0], ray.dir[0], t.origin_xy[0]);
        let mut t_next_y = next_boundary(j, ray.origin[1], ray.dir[1], t.origin_xy[1]);
        let dt_x = if ray.dir[0].abs() < 1e-15 { f64::INFINITY } else { cell / ray.dir[0].abs() };
        let dt_y = if ray.dir[1].abs() < 1e-15 { f64::INFINITY } else { cell / ray.dir[1].abs() };
        let mut t_enter = t_in;
        let mut best: Option<(f64, [f64; 3], f32, f32)> = None;
        loop {
            let t_exit = t_next_x.min(t_next_y).min(t_out);
            let c = j * t.nx + i;
            let z_a = ray.origin[2] + t_enter * ray.dir[2];
            let z_b = ray.origin[2] + t_exit * ray.dir[2];
            let z_lo = z_a.min(z_b);
            if z_lo <= self.cell_z_max[c] as f64 + 1e-6 {
                let limit = best.map_or(t_out, |b| b.0);
                // The ground only where the ray comes down to it.
                let near_ground = z_lo <= self.cell_ground_max[c] as f64 + 1e-6;
                if let Some((th, n)) =
                    near_ground.then(|| t.intersect_cell(i, j, ray, t_enter, t_exit.min(limit))).flatten()
                {
                    if th <= limit {
                        let p = ray.at(th);
                        let r = self.paint.map_or(self.ground_reflectivity, |g| g.reflectivity_at([p[0], p[1]]));
                        best = Some((th, n, r as f32, 1.0));
                    }
                }
                let (s, e) = (self.cell_start[c] as usize, self.cell_start[c + 1] as usize);
                for &k in &self.items[s..e] {
                    let prim = &self.prims[k as usize];
                    let limit = best.map_or(t_out, |b| b.0);
                    if let Some((th, n)) = prim.intersect(ray, limit) {
                        best = Some((th, n, prim.reflectivity, prim.return_probability));
                    }
                }
            }
            if best.is_some_and(|b| b.0 <= t_exit) || t_exit >= t_out {
                break;
            }
            // Going up and already above everything: nothing more to hit.
            if ray.dir[2] > 0.0 && z_b > self.z_max {
                break;
            }
            if t_next_x < t_next_y {
                let ni = i as i64 + step_i;
                if ni < 0 || ni >= t.nx as i64 {
                    break;
                }
                i = ni as usize;
                t_next_x += dt_x;
            } else {
                let nj = j as i64 + step_j;
                if nj < 0 || nj >= t.ny as i64 {
                    break;
                }
                j = nj as usize;
                t_next_y += dt_y;
            }
            t_enter = t_exit;
        }
        best.map(|(t, normal, reflectivity, return_probability)| Hit { t, normal, reflectivity, return_probability })
    }
}

/// Cells overlapped by a footprint, or `None` when it lies outside the grid.
fn cell_range(t: &Terrain, b: [f64; 4]) -> Option<(usize, usize, usize, usize)> {
    let [gx0, gy0, gx1, gy1] = t.bounds();
    if b[2] < gx0 || b[0] > gx1 || b[3] < gy0 || b[1] > gy1 {
        return None;
    }
    let (i0, j0) = t.cell_of([b[0], b[1]]);
    let (i1, j1) = t.cell_of([b[2], b[3]]);
    Some((i0, j0, i1, j1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::{Cylinder, Shape, UprightBox};

    /// Brute force: nearest of the ground and every primitive.
    fn brute(world: &World, terrain: &Terrain, ray: &Ray, t_max: f64) -> Option<f64> {
        let mut best = f64::INFINITY;
        for j in 0..terrain.ny {
            for i in 0..terrain.nx {
                if let Some((t, _)) = terrain.intersect_cell(i, j, ray, 0.0, t_max) {
                    best = best.min(t);
                }
            }
        }
        for p in world.primitives() {
            if let Some((t, _)) = p.intersect(ray, t_max) {
                best = best.min(t);
            }
        }
        best.is_finite().then_some(best)
    }

    #[test]
    fn grid_traversal_matches_brute_force() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let terrain = Terrain::rolling([-60.0, -60.0, 60.0, 60.0], 4.0, 5.0, 2.0, [0.0, 0.0], &mut rng);
        let mut prims = Vec::new();
        for _ in 0..60 {
            let xy = [rng.random_range(-55.0..55.0), rng.random_range(-55.0..55.0)];
            let h = terrain.height(xy);
            if rng.random_bool(0.5) {
                let b = UprightBox::from_bottom_top(
                    xy,
                    [rng.random_range(1.0..8.0), rng.random_range(1.0..5.0)],
                    h - 0.5,
                    h + rng.random_range(1.0..10.0),
                    rng.random_range(0.0..3.0),
                );
                prims.push(Primitive::new(Shape::Box(b), 0.5));
            } else {
                prims
                    .push(Primitive::new(Shape::Cylinder(Cylinder { xy, radius: 0.3, z0: h - 0.2, z1: h + 6.0 }), 0.5));
            }
        }
        let world = World::build(&terrain, None, prims, 0.2);
        let mut checked = 0;
        for k in 0..3000 {
            let az = k as f64 * 0.0137;
            let el = (-0.6f64).max(-0.7 + 0.9 * ((k * 7919) % 1000) as f64 / 1000.0);
            let origin =
                [(k % 13) as f64 - 6.0, (k % 7) as f64 - 3.0, terrain.height([0.0, 0.0]) + 1.0 + (k % 5) as f64 * 3.0];
            let ray = Ray { origin, dir: [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()] };
            let fast = world.cast(&ray, 120.0).map(|h| h.t);
            let slow = brute(&world, &terrain, &ray, 120.0);
            match (fast, slow) {
                (Some(a), Some(b)) => assert!((a - b).abs() < 1e-6, "ray {k}: {a} vs {b}"),
                (None, None) => {}
                other => panic!("ray {k}: {other:?}"),
            }
            checked += fast.is_some() as usize;
        }
        assert!(checked > 1000);
    }
}
