//! Rulebooks of sparse 3-D convolution: for every kernel offset, the (input site, output site)
//! pairs it connects. Built in Rust from a hash of the active coordinates; the arithmetic on them
//! is in [`super::conv`].
//!
//! Conventions are spconv's (and a dense `conv3d`'s, which the tests compare against):
//! - **submanifold** (kernel odd): the output sites are the input sites;
//!   `out[p] += W_k · in[p + k − K/2]`.
//! - **regular** (strided): `out[q] += W_k · in[q·s − pad + k]`; a site is active when any input
//!   reaches it; output shape `(D + 2·pad − K) / s + 1` per axis.
//! - **inverse** of a regular convolution: the same pairs swapped, back onto its input sites.
//!
//! Kernel offsets are numbered row-major over `(kz, ky, kx)`, as a dense kernel's memory.

use std::sync::Arc;

use rayon::prelude::*;
use rustc_hash::FxHashMap;

use crate::error::{NnError, Result};

/// An active site: `(batch, z, y, x)`.
pub type Coord = [i32; 4];

/// The pairs of one sparse convolution, grouped by kernel offset.
#[derive(Debug, Clone, PartialEq)]
pub struct Rulebook {
    /// Pairs of kernel offset `k` are `in_idx[offsets[k]..offsets[k + 1]]` (same for `out_idx`).
    pub offsets: Vec<usize>,
    pub in_idx: Vec<i64>,
    pub out_idx: Vec<i64>,
    /// Sites the convolution reads and writes, and the output's spatial shape `[D, H, W]`.
    pub in_coords: Arc<Vec<Coord>>,
    pub out_coords: Arc<Vec<Coord>>,
    pub in_shape: [i64; 3],
    pub out_shape: [i64; 3],
}

/// Packs a site into one hash key (each coordinate in 16 bits: checked by [`check_shape`]).
#[inline]
fn key(c: &Coord) -> u64 {
    ((c[0] as u64) << 48) | ((c[1] as u64) << 32) | ((c[2] as u64) << 16) | c[3] as u64
}

fn index_of(coords: &[Coord]) -> FxHashMap<u64, u32> {
    let mut map = FxHashMap::with_capacity_and_hasher(coords.len(), Default::default());
    for (i, c) in coords.iter().enumerate() {
        map.insert(key(c), i as u32);
    }
    map
}

fn check_shape(shape: [i64; 3], kernel: [i64; 3]) -> Result<()> {
    if shape.iter().any(|&d| !(1..=u16::MAX as i64).contains(&d)) {
        return Err(NnError::config(
            "backbone_3d",
            format!("sparse tensor shape {shape:?}: each side must be in 1..=65535"),
        ));
    }
    if kernel.iter().any(|&k| k < 1) {
        return Err(NnError::config("backbone_3d", format!("sparse convolution kernel {kernel:?} must be positive")));
    }
    Ok(())
}

/// Offsets `(kz, ky, kx)` of a kernel, row-major.
fn kernel_offsets(kernel: [i64; 3]) -> Vec<[i64; 3]> {
    let mut v = Vec::with_capacity((kernel[0] * kernel[1] * kernel[2]) as usize);
    for kz in 0..kernel[0] {
        for ky in 0..kernel[1] {
            for kx in 0..kernel[2] {
                v.push([kz, ky, kx]);
            }
        }
    }
    v
}

/// Flattens per-offset pair lists into the rulebook's arrays.
fn flatten(per_k: Vec<Vec<(i64, i64)>>) -> (Vec<usize>, Vec<i64>, Vec<i64>) {
    let total: usize = per_k.iter().map(Vec::len).sum();
    let mut offsets = Vec::with_capacity(per_k.len() + 1);
    let (mut ins, mut outs) = (Vec::with_capacity(total), Vec::with_capacity(total));
    offsets.push(0);
    for pairs in per_k {
        for (i, o) in pairs {
            ins.push(i);
            outs.push(o);
        }
        offsets.push(ins.len());
    }
    (offsets, ins, outs)
}

impl Rulebook {
    /// Number of kernel offsets.
    pub fn kernel_volume(&self) -> usize {
        self.offsets.len() - 1
    }

    pub fn num_pairs(&self) -> usize {
        self.in_idx.len()
    }

    /// A submanifold convolution's pairs: output sites = input sites.
    pub fn submanifold(coords: Arc<Vec<Coord>>, shape: [i64; 3], kernel: [i64; 3]) -> Result<Self> {
        check_shape(shape, kernel)?;
        if kernel.iter().any(|k| k % 2 == 0) {
            return Err(NnError::config(
                "backbone_3d",
                format!("submanifold convolution needs an odd kernel, got {kernel:?}"),
            ));
        }
        let map = index_of(&coords);
        let per_k: Vec<Vec<(i64, i64)>> = kernel_offsets(kernel)
            .into_par_iter()
            .map(|k| {
                let d = [k[0] - kernel[0] / 2, k[1] - kernel[1] / 2, k[2] - kernel[2] / 2];
                let mut pairs = Vec::new();
                for (o, c) in coords.iter().enumerate() {
                    let n = [c[1] as i64 + d[0], c[2] as i64 + d[1], c[3] as i64 + d[2]];
                    if (0..3).any(|a| n[a] < 0 || n[a] >= shape[a]) {
                        continue;
                    }
                    if let Some(&i) = map.get(&key(&[c[0], n[0] as i32, n[1] as i32, n[2] as i32])) {
                        pairs.push((i as i64, o as i64));
                    }
                }
                pairs
            })
            .collect();
        let (offsets, in_idx, out_idx) = flatten(per_k);
        Ok(Self {
            offsets,
            in_idx,
            out_idx,
            out_coords: coords.clone(),
            in_coords: coords,
            in_shape: shape,
            out_shape: shape,
        })
    }

    /// A regular (strided) convolution's pairs and output sites (in the order inputs first reach
    /// them, so the result is deterministic).
    pub fn regular(
        coords: Arc<Vec<Coord>>,
        shape: [i64; 3],
        kernel: [i64; 3],
        stride: [i64; 3],
        padding: [i64; 3],
    ) -> Result<Self> {
        check_shape(shape, kernel)?;
        if stride.iter().any(|&s| s < 1) || padding.iter().any(|&p| p < 0) {
            return Err(NnError::config(
                "backbone_3d",
                format!("sparse convolution stride {stride:?} / padding {padding:?}"),
            ));
        }
        let out_shape: [i64; 3] = std::array::from_fn(|a| {
            let span = shape[a] + 2 * padding[a] - kernel[a];
            if span < 0 {
                0
            } else {
                span / stride[a] + 1
            }
        });
        if out_shape.iter().any(|&d| d < 1) {
            return Err(NnError::config("backbone_3d", format!(
                "sparse convolution of kernel {kernel:?}, stride {stride:?}, padding {padding:?} on shape {shape:?} has an empty output"
            )));
        }
        let offsets_k = kernel_offsets(kernel);
        // The output site an input reaches through offset k: q = (i + pad − k) / s when exact.
        let target = |c: &Coord, k: &[i64; 3]| -> Option<Coord> {
            let mut q = [c[0], 0, 0, 0];
            for a in 0..3 {
                let v = c[a + 1] as i64 + padding[a] - k[a];
                if v < 0 || v % stride[a] != 0 || v / stride[a] >= out_shape[a] {
                    return None;
                }
                q[a + 1] = (v / stride[a]) as i32;
            }
            Some(q)
        };
        let mut out_map: FxHashMap<u64, u32> = FxHashMap::default();
        let mut out_coords = Vec::new();
        for c in coords.iter() {
            for k in &offsets_k {
                if let Some(q) = target(c, k) {
                    out_map.entry(key(&q)).or_insert_with(|| {
                        out_coords.push(q);
                        (out_coords.len() - 1) as u32
                    });
                }
            }
        }
        let per_k: Vec<Vec<(i64, i64)>> = offsets_k
            .par_iter()
            .map(|k| {
                coords
                    .iter()
                    .enumerate()
                    .filter_map(|(i, c)| target(c, k).map(|q| (i as i64, out_map[&key(&q)] as i64)))
                    .collect()
            })
            .collect();
        let (offsets, in_idx, out_idx) = flatten(per_k);
        Ok(Self {
            offsets,
            in_idx,
            out_idx,
            in_coords: coords,
            out_coords: Arc::new(out_coords),
            in_shape: shape,
            out_shape,
        })
    }

    /// The inverse convolution's pairs: this rulebook's, swapped, back onto its input sites.
    pub fn inverse(&self) -> Self {
        Self {
            offsets: self.offsets.clone(),
            in_idx: self.out_idx.clone(),
            out_idx: self.in_idx.clone(),
            in_coords: self.out_coords.clone(),
            out_coords: self.in_coords.clone(),
            in_shape: self.out_shape,
            out_shape: self.in_shape,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_sites(rng: &mut rand_chacha::ChaCha8Rng, shape: [i64; 3], batch: i32, density: f64) -> Vec<Coord> {
        let mut v = Vec::new();
        for b in 0..batch {
            for z in 0..shape[0] as i32 {
                for y in 0..shape[1] as i32 {
                    for x in 0..shape[2] as i32 {
                        if rng.random_bool(density) {
                            v.push([b, z, y, x]);
                        }
                    }
                }
            }
        }
        v
    }

    /// Every (in, out, k) triple of a brute-force scan over all site pairs, sorted.
    fn brute(
        ins: &[Coord],
        outs: &[Coord],
        kernel: [i64; 3],
        rel: impl Fn(&Coord, &Coord, [i64; 3]) -> bool,
    ) -> Vec<(usize, i64, i64)> {
        let mut v = Vec::new();
        for (k, off) in kernel_offsets(kernel).into_iter().enumerate() {
            for (i, a) in ins.iter().enumerate() {
                for (o, b) in outs.iter().enumerate() {
                    if a[0] == b[0] && rel(a, b, off) {
                        v.push((k, i as i64, o as i64));
                    }
                }
            }
        }
        v.sort();
        v
    }

    fn triples(rb: &Rulebook) -> Vec<(usize, i64, i64)> {
        let mut v = Vec::new();
        for k in 0..rb.kernel_volume() {
            for p in rb.offsets[k]..rb.offsets[k + 1] {
                v.push((k, rb.in_idx[p], rb.out_idx[p]));
            }
        }
        v.sort();
        v
    }

    #[test]
    fn submanifold_pairs_equal_brute_force() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let shape = [4, 5, 6];
        let sites = Arc::new(random_sites(&mut rng, shape, 2, 0.3));
        for kernel in [[3, 3, 3], [1, 3, 3], [3, 1, 1]] {
            let rb = Rulebook::submanifold(sites.clone(), shape, kernel).unwrap();
            let want = brute(&sites, &sites, kernel, |a, b, k| {
                (0..3).all(|d| a[d + 1] as i64 == b[d + 1] as i64 + k[d] - kernel[d] / 2)
            });
            assert_eq!(triples(&rb), want, "kernel {kernel:?}");
            assert_eq!(rb.out_coords, sites);
        }
        assert!(Rulebook::submanifold(sites, shape, [2, 3, 3]).is_err());
    }

    #[test]
    fn regular_pairs_and_sites_equal_brute_force() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let shape = [5, 7, 6];
        let sites = Arc::new(random_sites(&mut rng, shape, 2, 0.2));
        for (kernel, stride, padding) in [
            ([3, 3, 3], [2, 2, 2], [1, 1, 1]),
            ([3, 3, 3], [1, 1, 1], [1, 1, 1]),
            ([3, 1, 1], [2, 1, 1], [0, 0, 0]),
            ([3, 3, 3], [2, 2, 2], [0, 1, 1]),
        ] {
            let rb = Rulebook::regular(sites.clone(), shape, kernel, stride, padding).unwrap();
            let os: [i64; 3] = std::array::from_fn(|a| (shape[a] + 2 * padding[a] - kernel[a]) / stride[a] + 1);
            assert_eq!(rb.out_shape, os);
            let rel = |a: &Coord, b: &Coord, k: [i64; 3]| {
                (0..3).all(|d| a[d + 1] as i64 == b[d + 1] as i64 * stride[d] - padding[d] + k[d])
            };
            // Active output sites: exactly those some input reaches.
            let mut all_out = Vec::new();
            for b in 0..2 {
                for z in 0..os[0] as i32 {
                    for y in 0..os[1] as i32 {
                        for x in 0..os[2] as i32 {
                            all_out.push([b, z, y, x]);
                        }
                    }
                }
            }
            let mut reached: Vec<Coord> = all_out
                .iter()
                .filter(|q| {
                    sites.iter().any(|s| s[0] == q[0] && kernel_offsets(kernel).into_iter().any(|k| rel(s, q, k)))
                })
                .copied()
                .collect();
            let mut got = (*rb.out_coords).clone();
            got.sort();
            reached.sort();
            assert_eq!(got, reached, "{kernel:?} {stride:?} {padding:?}");
            assert_eq!(triples(&rb), brute(&sites, &rb.out_coords, kernel, rel));
            // The inverse swaps every pair.
            let inv = rb.inverse();
            let mut swapped: Vec<_> = triples(&rb).into_iter().map(|(k, i, o)| (k, o, i)).collect();
            swapped.sort();
            assert_eq!(triples(&inv), swapped);
            assert_eq!(inv.out_coords, sites);
        }
    }

    #[test]
    fn empty_inputs_and_bad_shapes() {
        let rb = Rulebook::regular(Arc::new(vec![]), [3, 3, 3], [3, 3, 3], [2, 2, 2], [1, 1, 1]).unwrap();
        assert_eq!((rb.num_pairs(), rb.out_coords.len(), rb.kernel_volume()), (0, 0, 27));
        assert!(Rulebook::regular(Arc::new(vec![]), [2, 3, 3], [3, 3, 3], [1, 1, 1], [0, 0, 0]).is_err());
        // A span of −1 is empty (not −1 / 2 + 1 = 1).
        assert!(Rulebook::regular(Arc::new(vec![]), [2, 3, 3], [3, 3, 3], [2, 2, 2], [0, 1, 1]).is_err());
        assert!(Rulebook::submanifold(Arc::new(vec![]), [0, 3, 3], [3, 3, 3]).is_err());
        assert!(Rulebook::submanifold(Arc::new(vec![]), [70000, 3, 3], [3, 3, 3]).is_err());
    }
}
