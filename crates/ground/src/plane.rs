//! Robust plane fitting: RANSAC on three-point hypotheses that pass the attitude prior, then total
//! least squares (PCA) on the inliers, re-selecting inliers a few times.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// The plane `{p : normal · p + offset_m = 0}` with a unit normal pointing up (towards the side
/// the sensor is on). `offset_m` is then the sensor's height above the plane: the signed distance
/// of the LiDAR origin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    pub normal: Vector3<f64>,
    pub offset_m: f64,
}

impl Plane {
    #[inline]
    pub fn signed_distance_m(&self, p: &[f64; 3]) -> f64 {
        self.normal.x * p[0] + self.normal.y * p[1] + self.normal.z * p[2] + self.offset_m
    }

    /// Through three points, normal oriented towards `up`; `None` when (nearly) collinear.
    pub fn through(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], up: &Vector3<f64>) -> Option<Self> {
        let (a, b, c) = (Vector3::from(*a), Vector3::from(*b), Vector3::from(*c));
        let n = (b - a).cross(&(c - a));
        let norm = n.norm();
        // Collinear or coincident samples give no plane (relative test: edges of ~metres).
        if norm < 1e-6 * (b - a).norm().max(1e-9) * (c - a).norm().max(1e-9) {
            return None;
        }
        let mut n = n / norm;
        if n.dot(up) < 0.0 {
            n = -n;
        }
        Some(Self { normal: n, offset_m: -n.dot(&a) })
    }
}

/// What the prior allows: normal within `max_tilt_rad` of `up`, sensor between `min_height_m` and
/// `max_height_m` above the plane (ground is below the sensor).
#[derive(Debug, Clone, Copy)]
pub struct PlanePrior {
    pub up: Vector3<f64>,
    pub cos_max_tilt: f64,
    pub min_height_m: f64,
    pub max_height_m: f64,
}

impl PlanePrior {
    pub fn accepts(&self, plane: &Plane) -> bool {
        plane.normal.dot(&self.up) >= self.cos_max_tilt
            && plane.offset_m >= self.min_height_m
            && plane.offset_m <= self.max_height_m
    }
}

/// A least-squares plane and the spread of its points.
#[derive(Debug, Clone, Copy)]
pub struct PlaneFit {
    pub plane: Plane,
    /// Root mean square of the point-to-plane distances.
    pub rms_m: f64,
    /// Standard deviation of the points along the plane's weaker in-plane axis: a plane seen only
    /// along a thin strip has a poorly defined tilt.
    pub spread_m: f64,
}

/// Total least squares through `points[i]` for `i` in `indices`, normal oriented towards `up`.
pub fn fit_least_squares(points: &[[f64; 3]], indices: &[usize], up: &Vector3<f64>) -> Option<PlaneFit> {
    if indices.len() < 3 {
        return None;
    }
    let n = indices.len() as f64;
    let centroid = indices.iter().fold(Vector3::zeros(), |s, &i| s + Vector3::from(points[i])) / n;
    let mut cov = Matrix3::zeros();
    for &i in indices {
        let d = Vector3::from(points[i]) - centroid;
        cov += d * d.transpose();
    }
    cov /= n;
    let eig = SymmetricEigen::new(cov);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let mut normal: Vector3<f64> = eig.eigenvectors.column(order[0]).into_owned();
    if !normal.iter().all(|v| v.is_finite()) || normal.norm() < 0.5 {
        return None;
    }
    normal.normalize_mut();
    if normal.dot(up) < 0.0 {
        normal = -normal;
    }
    let plane = Plane { normal, offset_m: -normal.dot(&centroid) };
    Some(PlaneFit {
        plane,
        rms_m: eig.eigenvalues[order[0]].max(0.0).sqrt(),
        spread_m: eig.eigenvalues[order[1]].max(0.0).sqrt(),
    })
}

/// Indices of the points within `threshold_m` of the plane.
pub fn inliers(points: &[[f64; 3]], plane: &Plane, threshold_m: f64) -> Vec<usize> {
    points.iter().enumerate().filter(|(_, p)| plane.signed_distance_m(p).abs() <= threshold_m).map(|(i, _)| i).collect()
}

fn count_inliers(points: &[[f64; 3]], plane: &Plane, threshold_m: f64) -> usize {
    points.iter().filter(|p| plane.signed_distance_m(p).abs() <= threshold_m).count()
}

/// RANSAC settings.
#[derive(Debug, Clone, Copy)]
pub struct RansacParams {
    pub threshold_m: f64,
    pub min_iterations: usize,
    pub max_iterations: usize,
    /// Stop once a hypothesis made only of inliers has been drawn with this probability.
    pub success_probability: f64,
}

/// Result of the hypothesis search.
#[derive(Debug, Clone, Copy)]
pub struct RansacResult {
    pub plane: Plane,
    pub inliers: usize,
    pub iterations: usize,
}

/// The hypothesis with the most inliers among those the prior accepts. Iterations adapt to the
/// best inlier ratio so far (standard `log(1-p) / log(1-w³)` bound), within the given limits.
pub fn ransac(
    points: &[[f64; 3]],
    prior: &PlanePrior,
    params: &RansacParams,
    rng: &mut ChaCha8Rng,
) -> Option<RansacResult> {
    let n = points.len();
    if n < 3 {
        return None;
    }
    let mut best: Option<RansacResult> = None;
    let mut needed = params.max_iterations;
    let mut it = 0;
    while it < needed.max(params.min_iterations).min(params.max_iterations) {
        it += 1;
        let (a, b, c) = (rng.random_range(0..n), rng.random_range(0..n), rng.random_range(0..n));
        if a == b || b == c || a == c {
            continue;
        }
        let Some(plane) = Plane::through(&points[a], &points[b], &points[c], &prior.up) else { continue };
        if !prior.accepts(&plane) {
            continue;
        }
        let count = count_inliers(points, &plane, params.threshold_m);
        if best.is_none_or(|b| count > b.inliers) {
            best = Some(RansacResult { plane, inliers: count, iterations: it });
            let w = count as f64 / n as f64;
            let miss = 1.0 - w * w * w;
            needed = if miss <= 0.0 {
                params.min_iterations
            } else {
                ((1.0 - params.success_probability).ln() / miss.ln()).ceil().min(params.max_iterations as f64) as usize
            };
        }
    }
    best.map(|b| RansacResult { iterations: it, ..b })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn plane_through_three_points_points_up() {
        let up = Vector3::z();
        let p = Plane::through(&[0.0, 0.0, -2.0], &[1.0, 0.0, -2.0], &[0.0, 1.0, -2.0], &up).unwrap();
        assert!((p.normal - Vector3::z()).norm() < 1e-12);
        assert!((p.offset_m - 2.0).abs() < 1e-12, "sensor 2 m above");
        // Reversed winding still points up.
        let q = Plane::through(&[0.0, 1.0, -2.0], &[1.0, 0.0, -2.0], &[0.0, 0.0, -2.0], &up).unwrap();
        assert!((q.normal - Vector3::z()).norm() < 1e-12);
        assert!(Plane::through(&[0.0; 3], &[1.0, 0.0, 0.0], &[2.0, 0.0, 0.0], &up).is_none());
    }

    #[test]
    fn ransac_finds_the_dominant_plane_and_least_squares_refines_it() {
        let mut pts = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (i as f64 * 0.5 - 10.0, j as f64 * 0.5 - 10.0);
                let noise = (((i * 7 + j * 13) % 11) as f64 - 5.0) * 0.004;
                pts.push([x, y, -1.5 + 0.05 * x + noise]);
            }
        }
        // A wall (vertical, rejected by the prior) and an overhead plane (sensor below it).
        for i in 0..600 {
            pts.push([5.0, (i % 30) as f64 * 0.3 - 4.0, (i / 30) as f64 * 0.2 - 1.0]);
            pts.push([(i % 30) as f64 * 0.3, (i / 30) as f64 * 0.3, 2.5]);
        }
        let prior = PlanePrior {
            up: Vector3::z(),
            cos_max_tilt: 30f64.to_radians().cos(),
            min_height_m: 0.1,
            max_height_m: 100.0,
        };
        let params =
            RansacParams { threshold_m: 0.1, min_iterations: 20, max_iterations: 500, success_probability: 0.999 };
        let r = ransac(&pts, &prior, &params, &mut ChaCha8Rng::seed_from_u64(1)).unwrap();
        assert_eq!(r.inliers, 1600);
        let fit = fit_least_squares(&pts, &inliers(&pts, &r.plane, 0.1), &Vector3::z()).unwrap();
        let expected = Vector3::new(-0.05, 0.0, 1.0).normalize();
        assert!((fit.plane.normal - expected).norm() < 1e-3, "{:?}", fit.plane.normal);
        assert!((fit.plane.offset_m - 1.5 * expected.z).abs() < 5e-3);
        assert!(fit.rms_m < 0.02 && fit.spread_m > 5.0, "{fit:?}");
    }
}
