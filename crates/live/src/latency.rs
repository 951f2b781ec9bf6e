//! Latency percentiles in fixed memory: a histogram of 0.1 ms bins up to 10 s (larger values
//! land in the last bin), so a soak of hours keeps the same footprint.

const BIN_MS: f64 = 0.1;
const BINS: usize = 100_000;

#[derive(Clone)]
pub struct LatencyHistogram {
    bins: Vec<u32>,
    count: u64,
    sum_ms: f64,
    max_ms: f64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self { bins: vec![0; BINS], count: 0, sum_ms: 0.0, max_ms: 0.0 }
    }
}

impl std::fmt::Debug for LatencyHistogram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LatencyHistogram({})", self.summary())
    }
}

impl LatencyHistogram {
    pub fn record(&mut self, ms: f64) {
        if !ms.is_finite() {
            return;
        }
        let ms = ms.max(0.0);
        let bin = ((ms / BIN_MS) as usize).min(BINS - 1);
        self.bins[bin] = self.bins[bin].saturating_add(1);
        self.count += 1;
        self.sum_ms += ms;
        self.max_ms = self.max_ms.max(ms);
    }

    pub fn count(&self) -> u64 {
        self.count
    }

    pub fn mean_ms(&self) -> f64 {
        if self.count == 0 {
            f64::NAN
        } else {
            self.sum_ms / self.count as f64
        }
    }

    pub fn max_ms(&self) -> f64 {
        self.max_ms
    }

    /// The `q`-quantile (0–1), to the bin's upper edge (0.1 ms); NaN when empty.
    pub fn quantile_ms(&self, q: f64) -> f64 {
        if self.count == 0 {
            return f64::NAN;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0u64;
        for (i, &n) in self.bins.iter().enumerate() {
            seen += u64::from(n);
            if seen >= rank {
                return ((i + 1) as f64 * BIN_MS).min(self.max_ms.max(BIN_MS));
            }
        }
        self.max_ms
    }

    /// `p50 / p95 / p99 / max` in ms.
    pub fn summary(&self) -> String {
        format!(
            "p50 {:.1} / p95 {:.1} / p99 {:.1} / max {:.1} ms",
            self.quantile_ms(0.5),
            self.quantile_ms(0.95),
            self.quantile_ms(0.99),
            self.max_ms
        )
    }

    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "count": self.count, "mean_ms": self.mean_ms(), "p50_ms": self.quantile_ms(0.5),
            "p95_ms": self.quantile_ms(0.95), "p99_ms": self.quantile_ms(0.99), "max_ms": self.max_ms,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_of_a_uniform_ramp() {
        let mut h = LatencyHistogram::default();
        for i in 1..=1000 {
            h.record(i as f64 * 0.1);
        }
        assert!((h.quantile_ms(0.5) - 50.0).abs() <= 0.11, "{}", h.quantile_ms(0.5));
        assert!((h.quantile_ms(0.99) - 99.0).abs() <= 0.11);
        assert!((h.max_ms() - 100.0).abs() < 1e-9);
        assert!((h.mean_ms() - 50.05).abs() < 1e-6);
    }

    #[test]
    fn empty_and_non_finite() {
        let mut h = LatencyHistogram::default();
        assert!(h.quantile_ms(0.5).is_nan());
        h.record(f64::NAN);
        assert_eq!(h.count(), 0);
        h.record(1e9);
        // Beyond the last bin: reported at the histogram's 10 s edge, the maximum kept exactly.
        assert_eq!(h.quantile_ms(1.0), 10_000.0);
        assert_eq!(h.max_ms(), 1e9);
    }
}
