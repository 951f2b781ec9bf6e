//! The road network of a layout: a regular grid of streets with sidewalks. It decides what the
//! ground is made of (asphalt, lane markings, sidewalk, lawn) and where lanes, parking strips and
//! sidewalks run.

/// What the ground is at a point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    Road,
    Marking,
    Sidewalk,
    Lawn,
}

/// Streets along x at `y = offset[1] + j·block_m` and along y at `x = offset[0] + i·block_m`.
#[derive(Debug, Clone, PartialEq)]
pub struct RoadGrid {
    pub block_m: f64,
    pub offset: [f64; 2],
    pub road_half_width_m: f64,
    pub sidewalk_width_m: f64,
    /// Reflectivity of asphalt, markings, sidewalk, lawn.
    pub reflectivity: [f64; 4],
}

impl RoadGrid {
    /// Signed distance of `v` to the nearest street centre line of period `block_m` through `offset`.
    #[inline]
    fn to_nearest_line(&self, v: f64, offset: f64) -> f64 {
        let k = ((v - offset) / self.block_m).round();
        v - (offset + k * self.block_m)
    }

    /// Distance from `x` to the nearest street running along y (a vertical line `x = const`).
    pub fn distance_to_street_along_y(&self, x: f64) -> f64 {
        self.to_nearest_line(x, self.offset[0]).abs()
    }

    /// Distance from `y` to the nearest street running along x.
    pub fn distance_to_street_along_x(&self, y: f64) -> f64 {
        self.to_nearest_line(y, self.offset[1]).abs()
    }

    /// Distance to the nearest street centre line (either direction).
    pub fn distance_to_street(&self, xy: [f64; 2]) -> f64 {
        self.to_nearest_line(xy[0], self.offset[0]).abs().min(self.to_nearest_line(xy[1], self.offset[1]).abs())
    }

    #[inline]
    pub fn surface_at(&self, xy: [f64; 2]) -> Surface {
        let ax = self.to_nearest_line(xy[0], self.offset[0]).abs();
        let ay = self.to_nearest_line(xy[1], self.offset[1]).abs();
        let d = ax.min(ay);
        if d <= self.road_half_width_m {
            // Centre marking, interrupted inside intersections.
            let in_junction = ax.max(ay) <= self.road_half_width_m;
            if d < 0.08 && !in_junction {
                Surface::Marking
            } else {
                Surface::Road
            }
        } else if d <= self.road_half_width_m + self.sidewalk_width_m {
            Surface::Sidewalk
        } else {
            Surface::Lawn
        }
    }

    #[inline]
    pub fn reflectivity_at(&self, xy: [f64; 2]) -> f64 {
        match self.surface_at(xy) {
            Surface::Road => self.reflectivity[0],
            Surface::Marking => self.reflectivity[1],
            Surface::Sidewalk => self.reflectivity[2],
            Surface::Lawn => self.reflectivity[3],
        }
    }

    /// The intersection with grid indices `(i, j)`.
    pub fn intersection(&self, ij: (i64, i64)) -> [f64; 2] {
        [self.offset[0] + ij.0 as f64 * self.block_m, self.offset[1] + ij.1 as f64 * self.block_m]
    }

    /// Grid indices of the intersection nearest to `xy`.
    pub fn nearest_intersection(&self, xy: [f64; 2]) -> (i64, i64) {
        (
            ((xy[0] - self.offset[0]) / self.block_m).round() as i64,
            ((xy[1] - self.offset[1]) / self.block_m).round() as i64,
        )
    }

    /// Street centre lines crossing `bounds` (`[xmin, ymin, xmax, ymax]`): x positions of the
    /// streets running along y, and y positions of the streets running along x.
    pub fn streets_in(&self, bounds: [f64; 4]) -> (Vec<f64>, Vec<f64>) {
        let lines = |lo: f64, hi: f64, off: f64| -> Vec<f64> {
            let k0 = ((lo - off) / self.block_m).floor() as i64;
            let k1 = ((hi - off) / self.block_m).ceil() as i64;
            (k0..=k1).map(|k| off + k as f64 * self.block_m).filter(|v| *v >= lo && *v <= hi).collect()
        };
        (lines(bounds[0], bounds[2], self.offset[0]), lines(bounds[1], bounds[3], self.offset[1]))
    }

    /// Interior blocks (between streets) overlapping `bounds`, as `[xmin, ymin, xmax, ymax]` of the
    /// buildable land (inside the sidewalks).
    pub fn blocks_in(&self, bounds: [f64; 4]) -> Vec<[f64; 4]> {
        let edge = self.road_half_width_m + self.sidewalk_width_m;
        let k = |v: f64, off: f64| ((v - off) / self.block_m).floor() as i64;
        let mut out = Vec::new();
        for j in k(bounds[1], self.offset[1])..=k(bounds[3], self.offset[1]) {
            for i in k(bounds[0], self.offset[0])..=k(bounds[2], self.offset[0]) {
                let x0 = self.offset[0] + i as f64 * self.block_m;
                let y0 = self.offset[1] + j as f64 * self.block_m;
                let b = [x0 + edge, y0 + edge, x0 + self.block_m - edge, y0 + self.block_m - edge];
                if b[2] > b[0]
                    && b[3] > b[1]
                    && b[2] > bounds[0]
                    && b[0] < bounds[2]
                    && b[3] > bounds[1]
                    && b[1] < bounds[3]
                {
                    out.push(b);
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn surfaces_by_distance_to_street() {
        let g = RoadGrid {
            block_m: 100.0,
            offset: [0.0, 0.0],
            road_half_width_m: 6.0,
            sidewalk_width_m: 4.0,
            reflectivity: [0.1, 0.6, 0.3, 0.4],
        };
        assert_eq!(g.surface_at([50.0, 3.0]), Surface::Road);
        assert_eq!(g.surface_at([50.0, 0.0]), Surface::Marking);
        assert_eq!(g.surface_at([0.0, 0.0]), Surface::Road);
        assert_eq!(g.surface_at([50.0, 8.0]), Surface::Sidewalk);
        assert_eq!(g.surface_at([50.0, 50.0]), Surface::Lawn);
        assert_eq!(g.nearest_intersection([160.0, -40.0]), (2, 0));
        assert_eq!(g.blocks_in([1.0, 1.0, 99.0, 99.0]), vec![[10.0, 10.0, 90.0, 90.0]]);
    }
}
