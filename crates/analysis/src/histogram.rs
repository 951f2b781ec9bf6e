//! Streaming, mergeable distributions with bounded memory: exact moments (Welford/Chan), fixed-bin
//! histograms (quantiles interpolated within a bin) and 2-D histograms with per-column moments.
//! Every accumulator can be filled on a worker thread and merged, so the whole analysis keeps
//! O(bins) memory per group whatever the dataset size.

use serde::Serialize;

use crate::error::AnalysisError;

/// Count, mean, variance, min and max of a stream of values, merged exactly (Chan et al.).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Moments {
    pub count: u64,
    pub mean: f64,
    /// Sum of squared deviations from the mean.
    m2: f64,
    pub min: f64,
    pub max: f64,
}

impl Default for Moments {
    fn default() -> Self {
        Self { count: 0, mean: 0.0, m2: 0.0, min: f64::INFINITY, max: f64::NEG_INFINITY }
    }
}

impl Moments {
    pub fn push(&mut self, v: f64) {
        self.count += 1;
        let delta = v - self.mean;
        self.mean += delta / self.count as f64;
        self.m2 += delta * (v - self.mean);
        self.min = self.min.min(v);
        self.max = self.max.max(v);
    }

    pub fn merge(&mut self, o: &Moments) {
        if o.count == 0 {
            return;
        }
        if self.count == 0 {
            *self = *o;
            return;
        }
        let n = (self.count + o.count) as f64;
        let delta = o.mean - self.mean;
        self.mean += delta * o.count as f64 / n;
        self.m2 += o.m2 + delta * delta * self.count as f64 * o.count as f64 / n;
        self.count += o.count;
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }

    /// Population variance (divides by n), as the paper's "variance" of a platform's data.
    pub fn variance(&self) -> f64 {
        if self.count == 0 {
            f64::NAN
        } else {
            self.m2 / self.count as f64
        }
    }

    pub fn std(&self) -> f64 {
        self.variance().sqrt()
    }

    pub fn mean_or_nan(&self) -> f64 {
        if self.count == 0 {
            f64::NAN
        } else {
            self.mean
        }
    }
}

/// How values map to bins. `Log10p1` bins `log10(1 + v)`: for heavy-tailed counts (points per box).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Scale {
    Linear,
    Log10p1,
}

impl Scale {
    fn forward(self, v: f64) -> f64 {
        match self {
            Scale::Linear => v,
            Scale::Log10p1 => (1.0 + v.max(0.0)).log10(),
        }
    }

    fn inverse(self, t: f64) -> f64 {
        match self {
            Scale::Linear => t,
            Scale::Log10p1 => 10f64.powf(t) - 1.0,
        }
    }
}

/// Fixed-bin histogram over `[lo, hi)` (in the scale's space) with under/overflow counts and exact
/// moments of the raw values; non-finite values are counted apart and ignored otherwise.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Histogram {
    pub lo: f64,
    pub hi: f64,
    pub scale: Scale,
    pub counts: Vec<u64>,
    pub underflow: u64,
    pub overflow: u64,
    pub non_finite: u64,
    pub moments: Moments,
}

/// The usual description of a distribution. Quantiles come from the histogram (accurate to a bin
/// width, exact at the extremes, which use the true min and max).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Summary {
    pub count: u64,
    pub mean: f64,
    pub std: f64,
    pub min: f64,
    pub p05: f64,
    pub p25: f64,
    pub p50: f64,
    pub p75: f64,
    pub p95: f64,
    pub max: f64,
}

impl Histogram {
    /// `bins` equal bins over `[lo, hi)` of the raw values.
    pub fn new(lo: f64, hi: f64, bins: usize) -> Self {
        Self::with_scale(lo, hi, bins, Scale::Linear)
    }

    /// Bins over `[lo, hi)` of `log10(1 + v)`; `lo`/`hi` are raw values.
    pub fn log10p1(lo: f64, hi: f64, bins: usize) -> Self {
        Self::with_scale(Scale::Log10p1.forward(lo), Scale::Log10p1.forward(hi), bins, Scale::Log10p1)
    }

    fn with_scale(lo: f64, hi: f64, bins: usize, scale: Scale) -> Self {
        assert!(hi > lo && bins > 0, "histogram needs hi > lo and at least one bin");
        Self {
            lo,
            hi,
            scale,
            counts: vec![0; bins],
            underflow: 0,
            overflow: 0,
            non_finite: 0,
            moments: Moments::default(),
        }
    }

    pub fn bins(&self) -> usize {
        self.counts.len()
    }

    /// Bin width in the scale's space.
    pub fn bin_width(&self) -> f64 {
        (self.hi - self.lo) / self.bins() as f64
    }

    pub fn count(&self) -> u64 {
        self.moments.count
    }

    pub fn add(&mut self, v: f64) {
        if !v.is_finite() {
            self.non_finite += 1;
            return;
        }
        self.moments.push(v);
        let t = self.scale.forward(v);
        if t < self.lo {
            self.underflow += 1;
        } else if t >= self.hi {
            self.overflow += 1;
        } else {
            let last = self.bins() - 1;
            let i = ((t - self.lo) / self.bin_width()) as usize;
            self.counts[i.min(last)] += 1;
        }
    }

    pub fn merge(&mut self, o: &Histogram) -> Result<(), AnalysisError> {
        if self.lo != o.lo || self.hi != o.hi || self.bins() != o.bins() || self.scale != o.scale {
            return Err(AnalysisError::Invalid("merging histograms with different bins".into()));
        }
        for (a, b) in self.counts.iter_mut().zip(&o.counts) {
            *a += b;
        }
        self.underflow += o.underflow;
        self.overflow += o.overflow;
        self.non_finite += o.non_finite;
        self.moments.merge(&o.moments);
        Ok(())
    }

    /// Edges of bin `i` as raw values.
    pub fn bin_edges(&self, i: usize) -> (f64, f64) {
        let w = self.bin_width();
        (self.scale.inverse(self.lo + i as f64 * w), self.scale.inverse(self.lo + (i + 1) as f64 * w))
    }

    /// The `q`-quantile (0..=1), interpolated linearly inside the bin; values outside the range
    /// resolve to the exact min / max. `None` when empty.
    pub fn quantile(&self, q: f64) -> Option<f64> {
        let n = self.count();
        if n == 0 {
            return None;
        }
        let target = q.clamp(0.0, 1.0) * n as f64;
        let (min, max) = (self.moments.min, self.moments.max);
        if target <= self.underflow as f64 {
            return Some(min);
        }
        let mut below = self.underflow as f64;
        let w = self.bin_width();
        for (i, &c) in self.counts.iter().enumerate() {
            let c = c as f64;
            if c > 0.0 && below + c >= target {
                let t = self.lo + (i as f64 + (target - below) / c) * w;
                return Some(self.scale.inverse(t).clamp(min, max));
            }
            below += c;
        }
        Some(max)
    }

    pub fn summary(&self) -> Summary {
        let q = |p| self.quantile(p).unwrap_or(f64::NAN);
        let m = &self.moments;
        let empty = m.count == 0;
        Summary {
            count: m.count,
            mean: m.mean_or_nan(),
            std: m.std(),
            min: if empty { f64::NAN } else { m.min },
            p05: q(0.05),
            p25: q(0.25),
            p50: q(0.5),
            p75: q(0.75),
            p95: q(0.95),
            max: if empty { f64::NAN } else { m.max },
        }
    }

    /// Share of values above `v` (raw value), interpolated inside the bin containing `v` (exact
    /// when `v` is a bin edge; underflow counts as below).
    pub fn share_above(&self, v: f64) -> f64 {
        let n = self.count();
        if n == 0 {
            return f64::NAN;
        }
        let t = self.scale.forward(v);
        let w = self.bin_width();
        let mut above = self.overflow as f64;
        for (i, &c) in self.counts.iter().enumerate() {
            let (a, b) = (self.lo + i as f64 * w, self.lo + (i + 1) as f64 * w);
            if a >= t {
                above += c as f64;
            } else if b > t {
                above += c as f64 * (b - t) / w;
            }
        }
        above / n as f64
    }

    /// `(bin centre as a raw value, share of all values in that bin)`: comparable across groups
    /// with the same bins whatever their sizes.
    pub fn shares(&self) -> Vec<(f64, f64)> {
        let n = self.count().max(1) as f64;
        (0..self.bins())
            .map(|i| {
                let w = self.bin_width();
                (self.scale.inverse(self.lo + (i as f64 + 0.5) * w), self.counts[i] as f64 / n)
            })
            .collect()
    }
}

/// 2-D histogram over `[x_lo, x_hi) × [y_lo, y_hi)` with exact moments of `y` per `x` column (the
/// per-distance mean and variance of the relative pitch).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Histogram2d {
    pub x_lo: f64,
    pub x_hi: f64,
    pub nx: usize,
    pub y_lo: f64,
    pub y_hi: f64,
    pub ny: usize,
    /// Row-major by x: `counts[ix * ny + iy]`.
    pub counts: Vec<u64>,
    /// Values outside the x range (any y) or outside the y range.
    pub outside: u64,
    /// Moments of y for each x column (values with y outside the y range included).
    pub columns: Vec<Moments>,
    pub x: Moments,
    pub y: Moments,
}

impl Histogram2d {
    pub fn new(x: (f64, f64), nx: usize, y: (f64, f64), ny: usize) -> Self {
        assert!(x.1 > x.0 && y.1 > y.0 && nx > 0 && ny > 0, "2-D histogram needs positive ranges and bins");
        Self {
            x_lo: x.0,
            x_hi: x.1,
            nx,
            y_lo: y.0,
            y_hi: y.1,
            ny,
            counts: vec![0; nx * ny],
            outside: 0,
            columns: vec![Moments::default(); nx],
            x: Moments::default(),
            y: Moments::default(),
        }
    }

    fn x_index(&self, x: f64) -> Option<usize> {
        (x >= self.x_lo && x < self.x_hi)
            .then(|| (((x - self.x_lo) / (self.x_hi - self.x_lo) * self.nx as f64) as usize).min(self.nx - 1))
    }

    fn y_index(&self, y: f64) -> Option<usize> {
        (y >= self.y_lo && y < self.y_hi)
            .then(|| (((y - self.y_lo) / (self.y_hi - self.y_lo) * self.ny as f64) as usize).min(self.ny - 1))
    }

    pub fn add(&mut self, x: f64, y: f64) {
        if !(x.is_finite() && y.is_finite()) {
            self.outside += 1;
            return;
        }
        self.x.push(x);
        self.y.push(y);
        let ix = self.x_index(x);
        if let Some(ix) = ix {
            self.columns[ix].push(y);
        }
        match (ix, self.y_index(y)) {
            (Some(ix), Some(iy)) => self.counts[ix * self.ny + iy] += 1,
            _ => self.outside += 1,
        }
    }

    pub fn merge(&mut self, o: &Histogram2d) -> Result<(), AnalysisError> {
        let same = (self.x_lo, self.x_hi, self.nx, self.y_lo, self.y_hi, self.ny)
            == (o.x_lo, o.x_hi, o.nx, o.y_lo, o.y_hi, o.ny);
        if !same {
            return Err(AnalysisError::Invalid("merging 2-D histograms with different bins".into()));
        }
        for (a, b) in self.counts.iter_mut().zip(&o.counts) {
            *a += b;
        }
        for (a, b) in self.columns.iter_mut().zip(&o.columns) {
            a.merge(b);
        }
        self.outside += o.outside;
        self.x.merge(&o.x);
        self.y.merge(&o.y);
        Ok(())
    }

    pub fn count(&self, ix: usize, iy: usize) -> u64 {
        self.counts[ix * self.ny + iy]
    }

    pub fn x_edges(&self, ix: usize) -> (f64, f64) {
        let w = (self.x_hi - self.x_lo) / self.nx as f64;
        (self.x_lo + ix as f64 * w, self.x_lo + (ix + 1) as f64 * w)
    }

    pub fn y_edges(&self, iy: usize) -> (f64, f64) {
        let w = (self.y_hi - self.y_lo) / self.ny as f64;
        (self.y_lo + iy as f64 * w, self.y_lo + (iy + 1) as f64 * w)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moments_merge_equals_single_pass() {
        let v: Vec<f64> = (0..101).map(|i| (i as f64 * 0.37).sin() * 3.0 + i as f64 * 0.01).collect();
        let mut all = Moments::default();
        v.iter().for_each(|&x| all.push(x));
        let (mut a, mut b) = (Moments::default(), Moments::default());
        v[..40].iter().for_each(|&x| a.push(x));
        v[40..].iter().for_each(|&x| b.push(x));
        a.merge(&b);
        assert_eq!(a.count, 101);
        assert!((a.mean - all.mean).abs() < 1e-12 && (a.variance() - all.variance()).abs() < 1e-10);
        assert_eq!((a.min, a.max), (all.min, all.max));
        // Known answer: 1..=4 has mean 2.5 and population variance 1.25.
        let mut m = Moments::default();
        [1.0, 2.0, 3.0, 4.0].iter().for_each(|&x| m.push(x));
        assert_eq!((m.mean, m.variance()), (2.5, 1.25));
    }

    #[test]
    fn quantiles_within_a_bin_and_exact_extremes() {
        let mut h = Histogram::new(0.0, 100.0, 100);
        (0..1000).for_each(|i| h.add(i as f64 * 0.1)); // uniform on [0, 100)
        let s = h.summary();
        assert!((s.p50 - 50.0).abs() <= 1.0, "{s:?}");
        assert!((s.p95 - 95.0).abs() <= 1.0, "{s:?}");
        assert_eq!((s.min, s.max), (0.0, 99.9));
        h.add(-5.0);
        h.add(500.0);
        h.add(f64::NAN);
        assert_eq!((h.underflow, h.overflow, h.non_finite), (1, 1, 1));
        assert_eq!(h.quantile(0.0), Some(-5.0));
        assert_eq!(h.quantile(1.0), Some(500.0));
        assert!(Histogram::new(0.0, 1.0, 4).quantile(0.5).is_none());
    }

    #[test]
    fn log_scale_and_share_above() {
        let mut h = Histogram::log10p1(0.0, 1e4, 40);
        for n in [0.0, 9.0, 99.0, 999.0] {
            h.add(n);
        }
        assert!((h.quantile(0.5).unwrap() - 9.0).abs() < 1.0, "{:?}", h.quantile(0.5));
        assert_eq!(h.moments.max, 999.0);
        let mut z = Histogram::new(-2.0, 2.0, 4);
        for v in [-1.5, -0.5, 0.5, 1.5] {
            z.add(v);
        }
        assert_eq!(z.share_above(0.0), 0.5);
        assert!(z.merge(&Histogram::new(-2.0, 2.0, 5)).is_err());
    }

    #[test]
    fn histogram_2d_columns() {
        let mut h = Histogram2d::new((0.0, 10.0), 2, (-10.0, 10.0), 4);
        h.add(1.0, -1.0);
        h.add(2.0, 3.0);
        h.add(7.0, 20.0); // y outside: column moments still see it
        h.add(11.0, 0.0);
        assert_eq!(h.count(0, 1), 1);
        assert_eq!(h.count(0, 2), 1);
        assert_eq!(h.outside, 2);
        assert_eq!(h.columns[0].mean, 1.0);
        assert_eq!(h.columns[1].mean, 20.0);
        let mut m = h.clone();
        m.merge(&h).unwrap();
        assert_eq!(m.count(0, 1), 2);
        assert_eq!(m.columns[0].count, 4);
    }
}
