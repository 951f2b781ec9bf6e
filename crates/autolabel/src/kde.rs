//! Weighted Gaussian kernel density estimation, as `scipy.stats.gaussian_kde` computes it: the
//! kernel covariance is the weighted sample covariance (numpy's `cov(aweights=w)`, unbiased)
//! times the square of a scalar bandwidth factor. The factor is unitless — a bandwidth of 2.0
//! widens the kernel to twice the data's own spread, it is not metres.
//!
//! MS3D++'s box fusion uses this everywhere and relies on scipy raising for a singular
//! covariance (members that agree exactly), falling back to an average; [`Kde::new`] returns
//! [`KdeError`] in the same cases.

use nalgebra::{DMatrix, DVector};

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum KdeError {
    #[error("a density needs more samples ({samples}) than dimensions ({dims})")]
    TooFewSamples { samples: usize, dims: usize },
    #[error("the weighted sample covariance is singular")]
    Singular,
    #[error("weights must be finite, non-negative and not all zero")]
    Weights,
}

/// A fitted density over `n` samples in `d` dimensions.
#[derive(Debug, Clone)]
pub struct Kde {
    dims: usize,
    /// `n × d`, row-major (flat: clusters are small and evaluated often, so no per-call allocation).
    samples: Vec<f64>,
    weights: Vec<f64>,
    /// Inverse of the kernel covariance, `d × d` row-major.
    precision: Vec<f64>,
    /// `1 / sqrt((2π)^d det K)`.
    norm: f64,
}

impl Kde {
    /// Fits samples (`n` rows of equal length `d`) with optional weights (uniform when `None`)
    /// and scipy's scalar `bw_method` factor.
    pub fn new(samples: &[Vec<f64>], weights: Option<&[f64]>, bandwidth: f64) -> Result<Self, KdeError> {
        let n = samples.len();
        let d = samples.first().map_or(0, Vec::len);
        // scipy refuses d > n; with d == n the covariance is singular anyway.
        if d == 0 || n <= d {
            return Err(KdeError::TooFewSamples { samples: n, dims: d });
        }
        let mut w: Vec<f64> = match weights {
            Some(w) => w.to_vec(),
            None => vec![1.0; n],
        };
        let total: f64 = w.iter().sum();
        if w.len() != n || w.iter().any(|x| !x.is_finite() || *x < 0.0) || total <= 0.0 {
            return Err(KdeError::Weights);
        }
        w.iter_mut().for_each(|x| *x /= total);
        let xs: Vec<DVector<f64>> = samples.iter().map(|s| DVector::from_column_slice(s)).collect();
        let mean = xs.iter().zip(&w).fold(DVector::zeros(d), |acc, (x, wi)| acc + x * *wi);
        let mut cov = DMatrix::zeros(d, d);
        for (x, wi) in xs.iter().zip(&w) {
            let c = x - &mean;
            cov += &c * c.transpose() * *wi;
        }
        // numpy's unbiased weighted covariance: divide by 1 − Σw² (weights summing to 1).
        let sum_sq: f64 = w.iter().map(|x| x * x).sum();
        let denom = 1.0 - sum_sq;
        if denom <= 0.0 {
            return Err(KdeError::Singular);
        }
        let kernel = cov / denom * (bandwidth * bandwidth);
        let chol = nalgebra::Cholesky::new(kernel).ok_or(KdeError::Singular)?;
        let det: f64 = chol.l_dirty().diagonal().iter().map(|v| v * v).product();
        if !(det.is_finite() && det > 0.0) {
            return Err(KdeError::Singular);
        }
        let inv = chol.inverse();
        let precision: Vec<f64> = (0..d * d).map(|k| inv[(k / d, k % d)]).collect();
        let norm = 1.0 / ((2.0 * std::f64::consts::PI).powi(d as i32) * det).sqrt();
        let samples = xs.iter().flat_map(|x| x.iter().copied()).collect();
        Ok(Self { dims: d, samples, weights: w, precision, norm })
    }

    /// Fits one-dimensional samples.
    pub fn new_1d(samples: &[f64], weights: Option<&[f64]>, bandwidth: f64) -> Result<Self, KdeError> {
        let rows: Vec<Vec<f64>> = samples.iter().map(|&s| vec![s]).collect();
        Self::new(&rows, weights, bandwidth)
    }

    /// The density at `point` (length `d`).
    pub fn density(&self, point: &[f64]) -> f64 {
        let d = self.dims;
        let mut sum = 0.0;
        for (x, w) in self.samples.chunks_exact(d).zip(&self.weights) {
            // (p − x)ᵀ P (p − x), the differences recomputed: d is 1 to 3 here.
            let mut q = 0.0;
            for (i, row) in self.precision.chunks_exact(d).enumerate() {
                let inner: f64 = row.iter().enumerate().map(|(j, pij)| pij * (point[j] - x[j])).sum();
                q += (point[i] - x[i]) * inner;
            }
            sum += w * (-0.5 * q).exp();
        }
        sum * self.norm
    }

    /// Index of the sample of highest density (the first one on ties, like `np.where(..)[0][0]`).
    pub fn densest_sample(&self) -> usize {
        let densities: Vec<f64> = self.samples.chunks_exact(self.dims).map(|x| self.density(x)).collect();
        first_argmax(&densities)
    }
}

/// Index of the first maximum.
pub fn first_argmax(values: &[f64]) -> usize {
    let mut best = 0;
    for (i, v) in values.iter().enumerate() {
        if *v > values[best] {
            best = i;
        }
    }
    best
}

/// `np.linspace(lo, hi, n)`.
pub fn linspace(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    match n {
        0 => Vec::new(),
        1 => vec![lo],
        _ => {
            let step = (hi - lo) / (n - 1) as f64;
            (0..n).map(|i| if i == n - 1 { hi } else { lo + step * i as f64 }).collect()
        }
    }
}

/// The peak of a 1-D density over `grid_points` evenly spaced values from the samples' minimum
/// to their maximum (MS3D++'s `return_max`): the grid value, not a sample.
pub fn peak_1d(samples: &[f64], weights: Option<&[f64]>, bandwidth: f64, grid_points: usize) -> Result<f64, KdeError> {
    let kde = Kde::new_1d(samples, weights, bandwidth)?;
    let lo = samples.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = samples.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let grid = linspace(lo, hi, grid_points);
    let densities: Vec<f64> = grid.iter().map(|&x| kde.density(&[x])).collect();
    Ok(grid[first_argmax(&densities)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_dimensional_density_by_hand() {
        // Samples 0, 1, 3 uniform: mean 4/3, unbiased variance ((16+1+25)/9)/2 = 7/3.
        let kde = Kde::new_1d(&[0.0, 1.0, 3.0], None, 0.5).unwrap();
        let var = 7.0 / 3.0 * 0.25;
        let at = |x: f64| {
            [0.0, 1.0, 3.0_f64].iter().map(|s| (-(x - s).powi(2) / (2.0 * var)).exp()).sum::<f64>()
                / 3.0
                / (2.0 * std::f64::consts::PI * var).sqrt()
        };
        for x in [-1.0, 0.0, 0.7, 2.0, 5.0] {
            assert!((kde.density(&[x]) - at(x)).abs() < 1e-12, "x = {x}");
        }
    }

    #[test]
    fn weighted_covariance_is_numpys_unbiased_aweights() {
        // w = (0.25, 0.375, 0.375); mean 0.75; Σw(x-m)² = 0.1875; Σw² = 0.34375.
        let kde = Kde::new_1d(&[0.0, 1.0, 1.0], Some(&[1.0, 1.5, 1.5]), 1.0).unwrap();
        let var = 0.1875 / (1.0 - 0.34375);
        let expect = (0.25 * (-(0.0f64).powi(2) / (2.0 * var)).exp() + 0.75 * (-(1.0f64).powi(2) / (2.0 * var)).exp())
            / (2.0 * std::f64::consts::PI * var).sqrt();
        assert!((kde.density(&[0.0]) - expect).abs() < 1e-12);
    }

    #[test]
    fn identical_samples_are_singular_like_scipy() {
        assert_eq!(Kde::new_1d(&[2.0, 2.0, 2.0], None, 1.0).unwrap_err(), KdeError::Singular);
        let collinear = vec![vec![0.0, 0.0], vec![1.0, 1.0], vec![2.0, 2.0], vec![3.0, 3.0]];
        assert_eq!(Kde::new(&collinear, None, 1.0).unwrap_err(), KdeError::Singular);
        assert!(matches!(Kde::new_1d(&[1.0], None, 1.0), Err(KdeError::TooFewSamples { .. })));
    }

    #[test]
    fn peak_of_a_bimodal_sample_is_on_the_heavier_mode() {
        let s = [1.0, 1.1, 0.9, 1.0, 5.0, 5.1];
        let peak = peak_1d(&s, None, 0.2, 100).unwrap();
        assert!((peak - 1.0).abs() < 0.1, "{peak}");
        let g = linspace(0.0, 1.0, 5);
        assert_eq!(g, vec![0.0, 0.25, 0.5, 0.75, 1.0]);
    }
}
