//! Fixed-size uniform samples of a stream (reservoir sampling, algorithm R) for scatter plots:
//! bounded memory, deterministic for a seed and an input order.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

#[derive(Debug, Clone, Serialize)]
pub struct Reservoir<T> {
    capacity: usize,
    seen: u64,
    pub items: Vec<T>,
    #[serde(skip)]
    rng: ChaCha8Rng,
}

impl<T> Reservoir<T> {
    pub fn new(capacity: usize, seed: u64) -> Self {
        Self { capacity, seen: 0, items: Vec::with_capacity(capacity.min(4096)), rng: ChaCha8Rng::seed_from_u64(seed) }
    }

    pub fn push(&mut self, item: T) {
        self.seen += 1;
        if self.items.len() < self.capacity {
            self.items.push(item);
        } else if self.capacity > 0 {
            let j = self.rng.random_range(0..self.seen);
            if (j as usize) < self.capacity {
                self.items[j as usize] = item;
            }
        }
    }

    pub fn seen(&self) -> u64 {
        self.seen
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_at_most_capacity_and_is_roughly_uniform() {
        let mut r = Reservoir::new(1000, 3);
        (0..100_000u32).for_each(|i| r.push(i));
        assert_eq!((r.items.len(), r.seen()), (1000, 100_000));
        let mean = r.items.iter().map(|&v| v as f64).sum::<f64>() / 1000.0;
        // Uniform on [0, 1e5): mean 5e4, standard error ≈ 2.9e4/√1000 ≈ 900.
        assert!((mean - 50_000.0).abs() < 4_000.0, "{mean}");
        let mut again = Reservoir::new(1000, 3);
        (0..100_000u32).for_each(|i| again.push(i));
        assert_eq!(r.items, again.items);
    }
}
