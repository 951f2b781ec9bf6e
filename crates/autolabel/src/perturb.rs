//! Simulated detectors for testing an annotation pipeline without trained models: ground truth
//! with seeded misses (more of them far away and on sparse boxes), localisation noise, the
//! occasional badly displaced box and false positives — each detector its own seed and error
//! profile, so fusion and tracking have something real to repair.

use pi3det_data::{FrameInfo, Object};
use pi3det_geometry::Box3d;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use crate::labels::LabelSet;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectorNoise {
    /// Probability of missing a box at 0 m, rising linearly to `miss_far` at `far_m`.
    pub miss_near: f64,
    pub miss_far: f64,
    pub far_m: f64,
    /// Extra miss probability for boxes with fewer than 20 points (when the data counts them).
    pub miss_sparse: f64,
    /// Standard deviations of the centre (m per axis for a car; smaller boxes in proportion,
    /// down to 0.3×), relative size and heading (rad).
    pub centre_sigma_m: f64,
    pub size_sigma: f64,
    pub heading_sigma_rad: f64,
    /// Probability that a found box is displaced by `displaced_m` in a random direction.
    pub displaced: f64,
    pub displaced_m: f64,
    /// Probability that a found box faces the other way (heading + π).
    pub flipped: f64,
    /// Mean false positives per frame (Poisson), within `far_m` of the sensor.
    pub false_positives: f64,
}

impl Default for DetectorNoise {
    fn default() -> Self {
        Self {
            miss_near: 0.1,
            miss_far: 0.5,
            far_m: 60.0,
            miss_sparse: 0.2,
            centre_sigma_m: 0.15,
            size_sigma: 0.05,
            heading_sigma_rad: 0.05,
            displaced: 0.1,
            displaced_m: 1.0,
            flipped: 0.05,
            false_positives: 1.0,
        }
    }
}

/// Detections of one simulated detector over `gt`'s frames.
pub fn simulate_detector(gt: &[FrameInfo], noise: &DetectorNoise, seed: u64) -> LabelSet {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut out = LabelSet::default();
    for info in gt {
        let mut dets = Vec::new();
        for o in &info.objects {
            let b = o.box3d;
            let range = b.x.hypot(b.y);
            let mut miss = noise.miss_near + (noise.miss_far - noise.miss_near) * (range / noise.far_m).min(1.0);
            if o.num_points.is_some_and(|n| n < 20) {
                miss += noise.miss_sparse;
            }
            if rng.random::<f64>() < miss {
                continue;
            }
            let mut n = || normal(&mut rng);
            // Small objects are placed as well relative to their size, not in metres.
            let sigma = noise.centre_sigma_m * (b.dx.hypot(b.dy) / 4.6).clamp(0.3, 1.0);
            let (ex, ey, ez) = (n() * sigma, n() * sigma, n() * sigma * 0.5);
            let (sx, sy, sz, sh) = (n() * noise.size_sigma, n() * noise.size_sigma, n() * noise.size_sigma, n());
            let mut d = Box3d {
                x: b.x + ex,
                y: b.y + ey,
                z: b.z + ez,
                dx: b.dx * (1.0 + sx),
                dy: b.dy * (1.0 + sy),
                dz: b.dz * (1.0 + sz),
                heading: b.heading + sh * noise.heading_sigma_rad,
            };
            let mut score = 0.95 - 0.4 * (range / noise.far_m).min(1.0) + 0.08 * n();
            if rng.random::<f64>() < noise.displaced {
                let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                let r = noise.displaced_m * (b.dx.hypot(b.dy) / 4.6).clamp(0.3, 1.0);
                d.x += r * a.cos();
                d.y += r * a.sin();
                score -= 0.2;
            }
            if rng.random::<f64>() < noise.flipped {
                d.heading += std::f64::consts::PI;
            }
            let mut det = Object::new(o.name.clone(), d.with_wrapped_heading());
            det.score = Some(score.clamp(0.05, 1.0));
            dets.push(det);
        }
        let n_fp = poisson(&mut rng, noise.false_positives);
        for _ in 0..n_fp {
            let template = info.objects.get(rng.random_range(0..info.objects.len().max(1)));
            let Some(t) = template else { break };
            let r: f64 = rng.random_range(5.0..noise.far_m);
            let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let b = Box3d { x: r * a.cos(), y: r * a.sin(), heading: rng.random_range(-3.1..3.1), ..t.box3d };
            let mut det = Object::new(t.name.clone(), b);
            det.score = Some(rng.random_range(0.1..0.6));
            dets.push(det);
        }
        out.frames.insert(info.id.clone(), dets);
    }
    out
}

/// A standard normal draw (Box–Muller).
fn normal(rng: &mut impl Rng) -> f64 {
    let u: f64 = 1.0 - rng.random::<f64>();
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

/// Detector error profiles: each noisier in a different way.
pub fn noise_profiles(n: usize) -> Vec<DetectorNoise> {
    (0..n)
        .map(|k| {
            let d = DetectorNoise::default();
            match k % 3 {
                0 => d,
                1 => DetectorNoise { miss_near: 0.15, centre_sigma_m: 0.2, displaced: 0.15, ..d },
                _ => DetectorNoise {
                    miss_far: 0.6,
                    size_sigma: 0.08,
                    heading_sigma_rad: 0.08,
                    false_positives: 2.0,
                    ..d
                },
            }
        })
        .collect()
}

fn poisson(rng: &mut impl Rng, mean: f64) -> usize {
    // Knuth's method; means here are a few per frame.
    let l = (-mean).exp();
    let (mut k, mut p) = (0, 1.0);
    loop {
        p *= rng.random::<f64>();
        if p <= l {
            return k;
        }
        k += 1;
    }
}
