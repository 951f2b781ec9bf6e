//! The primitives scenes are built from, with analytic ray intersection: upright boxes (yaw only),
//! vertical cylinders and spheres. Rays are `o + t d` with `d` a unit vector, so `t` is the range.

/// A ray with unit direction.
#[derive(Debug, Clone, Copy)]
pub struct Ray {
    pub origin: [f64; 3],
    pub dir: [f64; 3],
}

impl Ray {
    #[inline]
    pub fn at(&self, t: f64) -> [f64; 3] {
        [self.origin[0] + t * self.dir[0], self.origin[1] + t * self.dir[1], self.origin[2] + t * self.dir[2]]
    }
}

/// The nearest surface along a ray: range, unit surface normal (world frame), reflectivity and
/// the probability that the surface returns the pulse at all (glass reflects it away).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub t: f64,
    pub normal: [f64; 3],
    pub reflectivity: f32,
    pub return_probability: f32,
}

/// Upright box: centre, half sizes along its own x (heading), y and z, and heading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UprightBox {
    pub center: [f64; 3],
    pub half: [f64; 3],
    pub cos_h: f64,
    pub sin_h: f64,
}

impl UprightBox {
    pub fn new(center: [f64; 3], size: [f64; 3], heading_rad: f64) -> Self {
        let (sin_h, cos_h) = heading_rad.sin_cos();
        Self { center, half: [0.5 * size[0], 0.5 * size[1], 0.5 * size[2]], cos_h, sin_h }
    }

    /// From a bottom height and a top height (what scenery is specified by).
    pub fn from_bottom_top(xy: [f64; 2], size_xy: [f64; 2], bottom_z: f64, top_z: f64, heading_rad: f64) -> Self {
        Self::new([xy[0], xy[1], 0.5 * (bottom_z + top_z)], [size_xy[0], size_xy[1], top_z - bottom_z], heading_rad)
    }

    pub fn heading_rad(&self) -> f64 {
        self.sin_h.atan2(self.cos_h)
    }

    pub fn top_z(&self) -> f64 {
        self.center[2] + self.half[2]
    }

    /// Whether the ground point `xy` lies in the footprint.
    pub fn footprint_contains(&self, xy: [f64; 2]) -> bool {
        let (dx, dy) = (xy[0] - self.center[0], xy[1] - self.center[1]);
        let u = self.cos_h * dx + self.sin_h * dy;
        let v = -self.sin_h * dx + self.cos_h * dy;
        u.abs() <= self.half[0] && v.abs() <= self.half[1]
    }

    /// Slab test in the box frame; returns the entry range and the world normal of the entry face.
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f64) -> Option<(f64, [f64; 3])> {
        let (ox, oy) = (ray.origin[0] - self.center[0], ray.origin[1] - self.center[1]);
        let o = [self.cos_h * ox + self.sin_h * oy, -self.sin_h * ox + self.cos_h * oy, ray.origin[2] - self.center[2]];
        let d = [
            self.cos_h * ray.dir[0] + self.sin_h * ray.dir[1],
            -self.sin_h * ray.dir[0] + self.cos_h * ray.dir[1],
            ray.dir[2],
        ];
        let mut t_near = f64::NEG_INFINITY;
        let mut t_far = t_max;
        let mut axis = 0usize;
        for k in 0..3 {
            if d[k].abs() < 1e-12 {
                if o[k].abs() > self.half[k] {
                    return None;
                }
                continue;
            }
            let inv = 1.0 / d[k];
            let mut t1 = (-self.half[k] - o[k]) * inv;
            let mut t2 = (self.half[k] - o[k]) * inv;
            if t1 > t2 {
                std::mem::swap(&mut t1, &mut t2);
            }
            if t1 > t_near {
                t_near = t1;
                axis = k;
            }
            t_far = t_far.min(t2);
            if t_near > t_far {
                return None;
            }
        }
        // Origin inside the box (t_near < 0): the sensor never sees the inside of a solid.
        if t_near <= 0.0 || t_near > t_far {
            return None;
        }
        let s = -d[axis].signum();
        let normal = match axis {
            0 => [s * self.cos_h, s * self.sin_h, 0.0],
            1 => [-s * self.sin_h, s * self.cos_h, 0.0],
            _ => [0.0, 0.0, s],
        };
        Some((t_near, normal))
    }

    /// Footprint bounds `[xmin, ymin, xmax, ymax]`.
    pub fn bev_bounds(&self) -> [f64; 4] {
        let ex = self.half[0] * self.cos_h.abs() + self.half[1] * self.sin_h.abs();
        let ey = self.half[0] * self.sin_h.abs() + self.half[1] * self.cos_h.abs();
        [self.center[0] - ex, self.center[1] - ey, self.center[0] + ex, self.center[1] + ey]
    }
}

/// Vertical cylinder (poles, trunks, legs): axis at `xy`, from `z0` to `z1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cylinder {
    pub xy: [f64; 2],
    pub radius: f64,
    pub z0: f64,
    pub z1: f64,
}

impl Cylinder {
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f64) -> Option<(f64, [f64; 3])> {
        let (ox, oy) = (ray.origin[0] - self.xy[0], ray.origin[1] - self.xy[1]);
        let (dx, dy, dz) = (ray.dir[0], ray.dir[1], ray.dir[2]);
        let r2 = self.radius * self.radius;
        let mut best: Option<(f64, [f64; 3])> = None;
        let a = dx * dx + dy * dy;
        if a > 1e-14 {
            let b = ox * dx + oy * dy;
            let c = ox * ox + oy * oy - r2;
            let disc = b * b - a * c;
            if disc < 0.0 {
                return None; // misses the infinite cylinder, so the caps too
            }
            let t = (-b - disc.sqrt()) / a;
            if t > 0.0 && t < t_max {
                let z = ray.origin[2] + t * dz;
                if z >= self.z0 && z <= self.z1 {
                    let (nx, ny) = ((ox + t * dx) / self.radius, (oy + t * dy) / self.radius);
                    best = Some((t, [nx, ny, 0.0]));
                }
            }
        }
        if dz.abs() > 1e-12 {
            for (cap, nz) in [(self.z1, 1.0), (self.z0, -1.0)] {
                let t = (cap - ray.origin[2]) / dz;
                if t > 0.0 && t < best.map_or(t_max, |b| b.0) && -dz * nz > 0.0 {
                    let (px, py) = (ox + t * dx, oy + t * dy);
                    if px * px + py * py <= r2 {
                        best = Some((t, [0.0, 0.0, nz]));
                    }
                }
            }
        }
        best
    }

    pub fn bev_bounds(&self) -> [f64; 4] {
        [self.xy[0] - self.radius, self.xy[1] - self.radius, self.xy[0] + self.radius, self.xy[1] + self.radius]
    }
}

/// Sphere (tree crowns, heads).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    pub center: [f64; 3],
    pub radius: f64,
}

impl Sphere {
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f64) -> Option<(f64, [f64; 3])> {
        let o = [ray.origin[0] - self.center[0], ray.origin[1] - self.center[1], ray.origin[2] - self.center[2]];
        let b = o[0] * ray.dir[0] + o[1] * ray.dir[1] + o[2] * ray.dir[2];
        let c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - self.radius * self.radius;
        let disc = b * b - c;
        if disc < 0.0 || c < 0.0 {
            return None; // miss, or origin inside
        }
        let t = -b - disc.sqrt();
        if t <= 0.0 || t >= t_max {
            return None;
        }
        let inv = 1.0 / self.radius;
        Some((t, [(o[0] + t * ray.dir[0]) * inv, (o[1] + t * ray.dir[1]) * inv, (o[2] + t * ray.dir[2]) * inv]))
    }

    pub fn bev_bounds(&self) -> [f64; 4] {
        let r = self.radius;
        [self.center[0] - r, self.center[1] - r, self.center[0] + r, self.center[1] + r]
    }
}

/// One of the shapes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    Box(UprightBox),
    Cylinder(Cylinder),
    Sphere(Sphere),
}

/// A shape with its surface reflectivity in `[0, 1]` and the probability that a pulse hitting it
/// comes back (below 1 for glazed facades).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Primitive {
    pub shape: Shape,
    pub reflectivity: f32,
    pub return_probability: f32,
}

impl Primitive {
    pub fn new(shape: Shape, reflectivity: f64) -> Self {
        Self { shape, reflectivity: reflectivity.clamp(0.0, 1.0) as f32, return_probability: 1.0 }
    }

    pub fn with_return_probability(mut self, p: f64) -> Self {
        self.return_probability = p.clamp(0.0, 1.0) as f32;
        self
    }

    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f64) -> Option<(f64, [f64; 3])> {
        match &self.shape {
            Shape::Box(b) => b.intersect(ray, t_max),
            Shape::Cylinder(c) => c.intersect(ray, t_max),
            Shape::Sphere(s) => s.intersect(ray, t_max),
        }
    }

    pub fn bev_bounds(&self) -> [f64; 4] {
        match &self.shape {
            Shape::Box(b) => b.bev_bounds(),
            Shape::Cylinder(c) => c.bev_bounds(),
            Shape::Sphere(s) => s.bev_bounds(),
        }
    }

    /// Lowest and highest z of the shape.
    pub fn z_range(&self) -> [f64; 2] {
        match &self.shape {
            Shape::Box(b) => [b.center[2] - b.half[2], b.center[2] + b.half[2]],
            Shape::Cylinder(c) => [c.z0, c.z1],
            Shape::Sphere(s) => [s.center[2] - s.radius, s.center[2] + s.radius],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(o: [f64; 3], d: [f64; 3]) -> Ray {
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        Ray { origin: o, dir: [d[0] / n, d[1] / n, d[2] / n] }
    }

    #[test]
    fn box_hit_range_and_normal() {
        let b = UprightBox::new([10.0, 0.0, 1.0], [2.0, 2.0, 2.0], 0.0);
        let (t, n) = b.intersect(&ray([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]), 100.0).unwrap();
        assert!((t - 9.0).abs() < 1e-12);
        assert_eq!(n, [-1.0, 0.0, 0.0]);
        assert!(b.intersect(&ray([0.0, 0.0, 3.0], [1.0, 0.0, 0.0]), 100.0).is_none());
        assert!(b.intersect(&ray([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]), 5.0).is_none());
        // Rotated 45°: the corner points at the sensor.
        let r = UprightBox::new([10.0, 0.0, 1.0], [2.0, 2.0, 2.0], std::f64::consts::FRAC_PI_4);
        let (t, _) = r.intersect(&ray([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]), 100.0).unwrap();
        assert!((t - (10.0 - 2f64.sqrt())).abs() < 1e-9);
        // From above: top face.
        let (t, n) = b.intersect(&ray([10.0, 0.0, 10.0], [0.0, 0.0, -1.0]), 100.0).unwrap();
        assert!((t - 8.0).abs() < 1e-12 && n == [0.0, 0.0, 1.0]);
    }

    #[test]
    fn cylinder_side_and_cap() {
        let c = Cylinder { xy: [5.0, 0.0], radius: 0.5, z0: 0.0, z1: 4.0 };
        let (t, n) = c.intersect(&ray([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]), 100.0).unwrap();
        assert!((t - 4.5).abs() < 1e-12 && (n[0] + 1.0).abs() < 1e-12);
        let (t, n) = c.intersect(&ray([5.0, 0.0, 10.0], [0.0, 0.0, -1.0]), 100.0).unwrap();
        assert!((t - 6.0).abs() < 1e-12 && n == [0.0, 0.0, 1.0]);
        assert!(c.intersect(&ray([0.0, 0.0, 5.0], [1.0, 0.0, 0.0]), 100.0).is_none());
    }

    #[test]
    fn sphere_hit() {
        let s = Sphere { center: [0.0, 10.0, 0.0], radius: 2.0 };
        let (t, n) = s.intersect(&ray([0.0, 0.0, 0.0], [0.0, 1.0, 0.0]), 100.0).unwrap();
        assert!((t - 8.0).abs() < 1e-12 && (n[1] + 1.0).abs() < 1e-12);
    }
}
