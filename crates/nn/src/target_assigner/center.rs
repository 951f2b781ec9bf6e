//! CenterPoint targets (Yin et al., CVPR 2021; OpenPCDet `CenterHead.assign_target_of_single_head`):
//! per class a BEV heatmap with a Gaussian at each box centre (radius from the box size, CornerNet
//! `gaussian_radius` with min overlap 0.1, at least `min_radius` cells), and per box the index of
//! its centre cell and its regression code `[Δx, Δy, z, log dx, log dy, log dz, cos θ, sin θ]`
//! (Δ: offset of the centre inside its cell, in cells). With `heading = "double_angle"` the last
//! two are `cos 2θ, sin 2θ`: the heading modulo π, for data whose objects look the same from
//! front and back, where an L1 fit of `cos θ, sin θ` to targets that flip by π averages to a
//! vector of no length and a random heading (BEV and 3D AP do not see the direction).

use pi3det_geometry::Box3d;
use serde::{Deserialize, Serialize};

/// Regression code size of the center head.
pub const CENTER_CODE_SIZE: usize = 8;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CenterTargetConfig {
    pub gaussian_overlap: f64,
    pub min_radius: usize,
    /// At most this many boxes per frame get regression targets.
    pub max_objects: usize,
    pub heading: HeadingCode,
}

/// How the heading is regressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum HeadingCode {
    /// `cos θ, sin θ` (OpenPCDet).
    #[default]
    Full,
    /// `cos 2θ, sin 2θ`: θ modulo π.
    DoubleAngle,
}

impl HeadingCode {
    pub fn factor(self) -> f64 {
        match self {
            Self::Full => 1.0,
            Self::DoubleAngle => 2.0,
        }
    }

    pub fn encode(self, heading: f64) -> [f32; 2] {
        let a = heading * self.factor();
        [a.cos() as f32, a.sin() as f32]
    }

    pub fn decode(self, cos: f64, sin: f64) -> f64 {
        sin.atan2(cos) / self.factor()
    }
}

impl Default for CenterTargetConfig {
    fn default() -> Self {
        Self { gaussian_overlap: 0.1, min_radius: 2, max_objects: 500, heading: HeadingCode::Full }
    }
}

/// The feature map the targets live on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CenterMap {
    pub h: usize,
    pub w: usize,
    /// Size of a feature cell in metres and the map's min corner.
    pub cell: [f64; 2],
    pub origin: [f64; 2],
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct CenterTargets {
    /// `[num_classes, h, w]`.
    pub heatmap: Vec<f32>,
    /// Per box on the map: flat centre cell `iy·w + ix`, class, and code (`CENTER_CODE_SIZE` each).
    pub index: Vec<i64>,
    pub class: Vec<i64>,
    pub codes: Vec<f32>,
    /// `[num_classes, h, w]` 1 where the heatmap loss counts, 0 on ignored boxes; empty when no
    /// cell is ignored (the common case costs no second map).
    pub mask: Vec<f32>,
}

/// CornerNet's radius for a box of `h × w` cells such that a corner displaced within it keeps IoU
/// ≥ `min_overlap` (the three cases of the reference, including its quirks).
pub fn gaussian_radius(h: f64, w: f64, min_overlap: f64) -> f64 {
    let a1 = 1.0;
    let b1 = h + w;
    let c1 = w * h * (1.0 - min_overlap) / (1.0 + min_overlap);
    let r1 = (b1 + (b1 * b1 - 4.0 * a1 * c1).max(0.0).sqrt()) / 2.0;
    let a2 = 4.0;
    let b2 = 2.0 * (h + w);
    let c2 = (1.0 - min_overlap) * w * h;
    let r2 = (b2 + (b2 * b2 - 4.0 * a2 * c2).max(0.0).sqrt()) / 2.0;
    let a3 = 4.0 * min_overlap;
    let b3 = -2.0 * min_overlap * (h + w);
    let c3 = (min_overlap - 1.0) * w * h;
    let r3 = (b3 + (b3 * b3 - 4.0 * a3 * c3).max(0.0).sqrt()) / 2.0;
    r1.min(r2).min(r3)
}

/// Draws a Gaussian of the given radius at `(cx, cy)` into `map` (`h × w`) by elementwise max.
pub fn draw_gaussian(map: &mut [f32], h: usize, w: usize, cx: usize, cy: usize, radius: usize) {
    let sigma = (2 * radius + 1) as f64 / 6.0;
    let r = radius as i64;
    let (cx, cy) = (cx as i64, cy as i64);
    for dy in -r..=r {
        let y = cy + dy;
        if y < 0 || y >= h as i64 {
            continue;
        }
        for dx in -r..=r {
            let x = cx + dx;
            if x < 0 || x >= w as i64 {
                continue;
            }
            let g = (-((dx * dx + dy * dy) as f64) / (2.0 * sigma * sigma)).exp();
            // The reference zeroes values below machine epsilon times the peak.
            let g = if g < f64::EPSILON { 0.0 } else { g } as f32;
            let cell = &mut map[y as usize * w + x as usize];
            if g > *cell {
                *cell = g;
            }
        }
    }
}

/// Where a box lands on the map: its centre cell `(ix, iy)`, the centre in cells `(fx, fy)` and
/// its Gaussian radius in cells; `None` off the map or for a box of no area.
fn footprint(cfg: &CenterTargetConfig, map: &CenterMap, b: &Box3d) -> Option<(usize, usize, f64, f64, usize)> {
    let fx = (b.x - map.origin[0]) / map.cell[0];
    let fy = (b.y - map.origin[1]) / map.cell[1];
    let on_map = fx >= 0.0 && fy >= 0.0 && fx < map.w as f64 && fy < map.h as f64;
    if !(on_map && b.dx > 0.0 && b.dy > 0.0) {
        return None;
    }
    let radius = gaussian_radius(b.dx / map.cell[0], b.dy / map.cell[1], cfg.gaussian_overlap);
    let radius = (radius.max(0.0) as usize).max(cfg.min_radius);
    Some((fx.floor() as usize, fy.floor() as usize, fx, fy, radius))
}

/// Targets of one frame: `gt` boxes with class indices `gt_class` (`< num_classes`). The cells of
/// class `k` an `ignored` box of class `k` (`ignored_class`) would draw its Gaussian on (same
/// radius rule) get mask 0, except the peaks of `gt` boxes: the focal loss neither pushes them
/// up nor down. Ignored boxes make no peak and no regression target.
pub fn assign(
    cfg: &CenterTargetConfig,
    map: &CenterMap,
    num_classes: usize,
    gt: &[Box3d],
    gt_class: &[usize],
    ignored: &[Box3d],
    ignored_class: &[usize],
) -> CenterTargets {
    let (h, w) = (map.h, map.w);
    let mut t = CenterTargets { heatmap: vec![0.0; num_classes * h * w], ..Default::default() };
    for (b, &c) in gt.iter().zip(gt_class) {
        if t.index.len() >= cfg.max_objects || c >= num_classes {
            continue;
        }
        let Some((ix, iy, fx, fy, radius)) = footprint(cfg, map, b) else { continue };
        draw_gaussian(&mut t.heatmap[c * h * w..(c + 1) * h * w], h, w, ix, iy, radius);
        t.index.push((iy * w + ix) as i64);
        t.class.push(c as i64);
        t.codes.extend_from_slice(&[
            (fx - ix as f64) as f32,
            (fy - iy as f64) as f32,
            b.z as f32,
            b.dx.max(1e-3).ln() as f32,
            b.dy.max(1e-3).ln() as f32,
            b.dz.max(1e-3).ln() as f32,
            cfg.heading.encode(b.heading)[0],
            cfg.heading.encode(b.heading)[1],
        ]);
    }
    for (b, &c) in ignored.iter().zip(ignored_class) {
        if c >= num_classes {
            continue;
        }
        let Some((ix, iy, _, _, radius)) = footprint(cfg, map, b) else { continue };
        if t.mask.is_empty() {
            t.mask = vec![1.0; num_classes * h * w];
        }
        let plane = c * h * w;
        // The cells draw_gaussian would touch (the corners' values are far above its ε cut).
        for y in iy.saturating_sub(radius)..=(iy + radius).min(h - 1) {
            for x in ix.saturating_sub(radius)..=(ix + radius).min(w - 1) {
                let cell = plane + y * w + x;
                if t.heatmap[cell] < 1.0 {
                    t.mask[cell] = 0.0;
                }
            }
        }
    }
    t
}

/// Decodes a code at cell `(ix, iy)` (Rust side; the head decodes on tensors).
pub fn decode(code: &[f32; CENTER_CODE_SIZE], ix: usize, iy: usize, map: &CenterMap, heading: HeadingCode) -> Box3d {
    let c = code.map(f64::from);
    Box3d {
        x: (ix as f64 + c[0]) * map.cell[0] + map.origin[0],
        y: (iy as f64 + c[1]) * map.cell[1] + map.origin[1],
        z: c[2],
        dx: c[3].exp(),
        dy: c[4].exp(),
        dz: c[5].exp(),
        heading: heading.decode(c[6], c[7]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radius_matches_reference_values() {
        // Values from OpenPCDet's gaussian_radius (numpy) for these inputs.
        assert!((gaussian_radius(10.0, 5.0, 0.1) - 3.0).abs() < 1e-9);
        assert!((gaussian_radius(2.0, 2.0, 0.1) - 0.8649110640673517).abs() < 1e-9);
    }

    #[test]
    fn heatmap_peaks_at_centres_and_codes_round_trip() {
        let map = CenterMap { h: 20, w: 30, cell: [0.5, 0.5], origin: [-5.0, -5.0] };
        let cfg = CenterTargetConfig::default();
        let gt = vec![
            Box3d::new(1.3, 0.2, -1.0, 4.2, 1.9, 1.6, 2.5),
            Box3d::new(1.9, 0.4, -1.0, 0.7, 0.6, 1.8, -0.4),
            Box3d::new(-4.9, -4.9, -1.0, 0.7, 0.6, 1.8, 0.0), // corner: Gaussian clipped
            Box3d::new(50.0, 0.0, -1.0, 4.0, 2.0, 1.5, 0.0),  // off the map
        ];
        let t = assign(&cfg, &map, 2, &gt, &[0, 1, 1, 0], &[], &[]);
        assert_eq!(t.index.len(), 3);
        for (j, (&idx, &c)) in t.index.iter().zip(&t.class).enumerate() {
            let (iy, ix) = (idx as usize / map.w, idx as usize % map.w);
            let hm = &t.heatmap[c as usize * map.h * map.w..(c as usize + 1) * map.h * map.w];
            assert_eq!(hm[idx as usize], 1.0, "peak at the centre cell");
            // Symmetric neighbours, decreasing away from the centre, at least min_radius wide.
            if ix >= 2 && ix + 2 < map.w {
                assert_eq!(hm[idx as usize - 1], hm[idx as usize + 1]);
                assert!(hm[idx as usize - 1] < 1.0 && hm[idx as usize - 2] < hm[idx as usize - 1]);
                assert!(hm[idx as usize - 2] > 0.0);
            }
            let code: [f32; 8] = t.codes[j * 8..j * 8 + 8].try_into().unwrap();
            let b = decode(&code, ix, iy, &map, cfg.heading);
            let g = &gt[j];
            for (a, e) in b.to_array().iter().zip(g.to_array()) {
                assert!((a - e).abs() < 1e-5, "{b:?} vs {g:?}");
            }
        }
        // Classes do not leak into each other's heatmap.
        let car = &t.heatmap[..map.h * map.w];
        assert_eq!(car.iter().filter(|&&v| v == 1.0).count(), 1);
        assert!(t.heatmap.iter().all(|v| (0.0..=1.0).contains(v)));
    }

    #[test]
    fn double_angle_heading_is_the_heading_modulo_pi() {
        let map = CenterMap { h: 20, w: 30, cell: [0.5, 0.5], origin: [-5.0, -5.0] };
        let cfg = CenterTargetConfig { heading: HeadingCode::DoubleAngle, ..Default::default() };
        let front = Box3d::new(1.3, 0.2, -1.0, 4.2, 1.9, 1.6, 0.4);
        let back = Box3d { heading: 0.4 - std::f64::consts::PI, ..front };
        let a = assign(&cfg, &map, 1, &[front], &[0], &[], &[]);
        let b = assign(&cfg, &map, 1, &[back], &[0], &[], &[]);
        for (x, y) in a.codes.iter().zip(&b.codes) {
            assert!((x - y).abs() < 1e-6, "a car and the same car turned by π get one target");
        }
        let code: [f32; 8] = a.codes[..8].try_into().unwrap();
        let idx = a.index[0] as usize;
        let d = decode(&code, idx % map.w, idx / map.w, &map, cfg.heading);
        assert!((d.heading - 0.4).abs() < 1e-6);
    }
}
