//! Kernel-density box fusion (KBF) of one cluster, as MS3D++'s `kbf` does it: the centre and the
//! heading are *selected* from a member (averaging centres or angles makes boxes no detector
//! proposed), the size and the score are the peaks of their densities.
//!
//! Deviations from the public code, each a bug there: its one- and two-member branches compare
//! `boxes.shape` (a tuple) with an integer and never run, so they are implemented as intended;
//! its heading fallback takes `argmin(angles − mean)` without the absolute value — here the
//! member nearest the circular mean.

use pi3det_geometry::boxes::wrap_angle;
use pi3det_geometry::Box3d;

use super::config::FusionConfig;
use crate::kde::{first_argmax, peak_1d, Kde};

/// A detection entering fusion.
#[derive(Debug, Clone, PartialEq)]
pub struct Member {
    pub box3d: Box3d,
    pub score: f64,
    /// Score × the detector's weight for the class; members with weight 0 are left out.
    pub weight: f64,
    /// Which input it came from.
    pub source: usize,
}

/// The fused box of a cluster.
#[derive(Debug, Clone, PartialEq)]
pub struct Fused {
    pub box3d: Box3d,
    pub score: f64,
    pub members: usize,
    /// Distinct inputs among the members.
    pub sources: usize,
}

/// Fuses the members of one cluster; `None` when every member has weight 0.
pub fn fuse_cluster(members: &[Member], cfg: &FusionConfig) -> Option<Fused> {
    let m: Vec<&Member> = members.iter().filter(|m| m.weight > 0.0).collect();
    let sources = m.iter().map(|m| m.source).collect::<std::collections::BTreeSet<_>>().len();
    let weights: Vec<f64> = m.iter().map(|m| m.weight).collect();
    let wavg = |v: &dyn Fn(&Member) -> f64| {
        m.iter().zip(&weights).map(|(m, w)| v(m) * w).sum::<f64>() / weights.iter().sum::<f64>()
    };
    let (box3d, score) = match m.len() {
        0 => return None,
        1 => (m[0].box3d, m[0].score),
        2 => {
            let best = first_argmax(&m.iter().map(|m| m.score * m.weight).collect::<Vec<_>>());
            let b = m[best].box3d;
            let fused = Box3d { dx: wavg(&|m| m.box3d.dx), dy: wavg(&|m| m.box3d.dy), dz: wavg(&|m| m.box3d.dz), ..b };
            (fused, wavg(&|m| m.score))
        }
        _ => {
            let [x, y, z] = centre(&m, &weights, cfg);
            let bw = &cfg.bandwidth;
            let size = |f: fn(&Box3d) -> f64| {
                let v: Vec<f64> = m.iter().map(|m| f(&m.box3d)).collect();
                peak_1d(&v, None, bw.size, cfg.grid_points).unwrap_or_else(|_| v.iter().sum::<f64>() / v.len() as f64)
            };
            let headings: Vec<f64> = m.iter().map(|m| m.box3d.heading).collect();
            let sin: Vec<f64> = headings.iter().map(|h| h.sin()).collect();
            let heading = match Kde::new_1d(&sin, Some(&weights), bw.heading) {
                Ok(kde) => headings[kde.densest_sample()],
                Err(_) => nearest_to_circular_mean(&headings),
            };
            let scores: Vec<f64> = m.iter().map(|m| m.score).collect();
            let score =
                peak_1d(&scores, Some(&weights), bw.score, cfg.grid_points).unwrap_or_else(|_| wavg(&|m| m.score));
            let b = Box3d { x, y, z, dx: size(|b| b.dx), dy: size(|b| b.dy), dz: size(|b| b.dz), heading };
            (b, score)
        }
    };
    Some(Fused { box3d, score, members: m.len(), sources })
}

/// The densest member's centre: in 3-D, or in x/y and z apart when the cluster is flat; the
/// weighted mean where a density cannot be fitted.
fn centre(m: &[&Member], weights: &[f64], cfg: &FusionConfig) -> [f64; 3] {
    let pts: Vec<[f64; 3]> = m.iter().map(|m| [m.box3d.x, m.box3d.y, m.box3d.z]).collect();
    let total: f64 = weights.iter().sum();
    let mean = |k: usize| pts.iter().zip(weights).map(|(p, w)| p[k] * w).sum::<f64>() / total;
    let bw = cfg.bandwidth.centre;
    if sample_cov_det(&pts) < cfg.flat_cluster_det {
        let xy: Vec<Vec<f64>> = pts.iter().map(|p| vec![p[0], p[1]]).collect();
        let [x, y] = match Kde::new(&xy, Some(weights), bw) {
            Ok(kde) => {
                let i = kde.densest_sample();
                [pts[i][0], pts[i][1]]
            }
            Err(_) => [mean(0), mean(1)],
        };
        let zs: Vec<f64> = pts.iter().map(|p| p[2]).collect();
        let z = Kde::new_1d(&zs, Some(weights), bw).map(|kde| zs[kde.densest_sample()]).unwrap_or_else(|_| mean(2));
        [x, y, z]
    } else {
        let rows: Vec<Vec<f64>> = pts.iter().map(|p| p.to_vec()).collect();
        match Kde::new(&rows, Some(weights), bw) {
            Ok(kde) => pts[kde.densest_sample()],
            Err(_) => [mean(0), mean(1), mean(2)],
        }
    }
}

/// Determinant of the unweighted sample covariance (`np.cov`, ddof 1) of 3-D points.
fn sample_cov_det(pts: &[[f64; 3]]) -> f64 {
    let n = pts.len() as f64;
    let mean = [0, 1, 2].map(|k| pts.iter().map(|p| p[k]).sum::<f64>() / n);
    let mut c = nalgebra::Matrix3::<f64>::zeros();
    for p in pts {
        let d = nalgebra::Vector3::new(p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]);
        c += d * d.transpose();
    }
    (c / (n - 1.0)).determinant()
}

/// The heading nearest (on the circle) to the mean direction of all headings.
fn nearest_to_circular_mean(headings: &[f64]) -> f64 {
    let (s, c) = headings.iter().fold((0.0, 0.0), |(s, c), h| (s + h.sin(), c + h.cos()));
    let mean = s.atan2(c);
    let dist: Vec<f64> = headings.iter().map(|h| -wrap_angle(h - mean).abs()).collect();
    headings[first_argmax(&dist)]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn member(x: f64, y: f64, z: f64, dx: f64, heading: f64, score: f64, source: usize) -> Member {
        Member { box3d: Box3d { x, y, z, dx, dy: 1.8, dz: 1.6, heading }, score, weight: score, source }
    }

    #[test]
    fn the_centre_is_the_densest_member_and_the_size_a_peak() {
        let cfg = FusionConfig::default();
        // Three members agree near (10, 5, -1); one is off by 0.6 m.
        let m = vec![
            member(10.0, 5.0, -1.0, 4.0, 0.10, 0.9, 0),
            member(10.1, 5.05, -0.95, 4.2, 0.12, 0.8, 1),
            member(9.95, 4.9, -1.05, 4.1, 0.08, 0.7, 2),
            member(10.6, 5.5, -0.7, 4.8, 0.50, 0.3, 3),
        ];
        let f = fuse_cluster(&m, &cfg).unwrap();
        // A near-collinear cluster: x/y from the densest member in the plane, z from the densest in z.
        assert!(sample_cov_det(&m.iter().map(|m| [m.box3d.x, m.box3d.y, m.box3d.z]).collect::<Vec<_>>()) < 1e-7);
        assert!(m.iter().any(|m| m.box3d.x == f.box3d.x && m.box3d.y == f.box3d.y));
        assert!(m.iter().any(|m| m.box3d.z == f.box3d.z));
        assert_ne!(f.box3d.x, 10.6);
        assert!(f.box3d.dx > 4.0 && f.box3d.dx < 4.8);
        assert!([0.10, 0.12, 0.08].contains(&f.box3d.heading));
        assert_eq!((f.members, f.sources), (4, 4));
        assert!(f.score > 0.3 && f.score < 0.9);
        // Identical sizes make the size density singular: the mean is kept.
        assert_eq!(f.box3d.dy, 1.8);
    }

    #[test]
    fn small_clusters_and_zero_weights() {
        let cfg = FusionConfig::default();
        let mut m = vec![member(0.0, 0.0, 0.0, 4.0, 0.0, 0.9, 0), member(1.0, 0.0, 0.0, 5.0, 1.0, 0.3, 1)];
        let f = fuse_cluster(&m, &cfg).unwrap();
        // Two members: the better one's centre and heading, weighted-mean size and score.
        assert_eq!((f.box3d.x, f.box3d.heading), (0.0, 0.0));
        assert!((f.box3d.dx - (4.0 * 0.9 + 5.0 * 0.3) / 1.2).abs() < 1e-12);
        assert!((f.score - (0.9 * 0.9 + 0.3 * 0.3) / 1.2).abs() < 1e-12);
        m[0].weight = 0.0;
        assert_eq!(fuse_cluster(&m, &cfg).unwrap().box3d, m[1].box3d);
        m[1].weight = 0.0;
        assert!(fuse_cluster(&m, &cfg).is_none());
    }

    #[test]
    fn circular_mean_fallback_handles_the_wrap() {
        let h = [3.1, -3.1, 3.12];
        assert_eq!(nearest_to_circular_mean(&h), 3.12);
    }
}
