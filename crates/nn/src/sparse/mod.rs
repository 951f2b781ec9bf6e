//! Sparse 3-D convolution on libtorch, without spconv: the rulebooks (which input site feeds
//! which output site through which kernel offset) are built in Rust from a hash of the active
//! coordinates ([`rulebook`]), the arithmetic is gather → GEMM per kernel offset → scatter-add in
//! tch ([`conv`]), so autograd gives the gradients and the same code runs on CPU and CUDA.
//!
//! A [`SparseTensor`] carries its active sites and a rulebook cache shared by every tensor derived
//! from it within one forward pass: submanifold layers at one resolution build their rulebook
//! once, and an inverse convolution finds the rulebook of the convolution it inverts by its
//! `indice_key` (spconv's naming).
//!
//! Bench: `pi3det bench sparse` (forward + backward of `VoxelBackBone8x` against dense `conv3d`).

pub mod conv;
pub mod rulebook;

use std::cell::RefCell;
use std::collections::HashMap;
use std::rc::Rc;
use std::sync::Arc;

use tch::{Device, Kind, Tensor};

pub use conv::{SparseConv3d, SparseConv3dConfig, SparseConvKind};
pub use rulebook::{Coord, Rulebook};

use crate::error::{NnError, Result};

/// A rulebook with its index tensors on the features' device.
pub struct DeviceRulebook {
    pub book: Rulebook,
    pub in_idx: Tensor,
    pub out_idx: Tensor,
}

/// One forward pass's rulebooks (a sparse tensor lives on one thread).
type Cache = Rc<RefCell<HashMap<String, Rc<DeviceRulebook>>>>;

/// Features on the active sites of a `[B, D, H, W]` grid.
pub struct SparseTensor {
    /// `[N, C]`, row `i` at `coords[i]`.
    pub features: Tensor,
    /// `(batch, z, y, x)` of each row.
    pub coords: Arc<Vec<Coord>>,
    /// `[D, H, W]`.
    pub spatial_shape: [i64; 3],
    pub batch_size: i64,
    cache: Cache,
}

impl std::fmt::Debug for SparseTensor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SparseTensor")
            .field("features", &self.features.size())
            .field("sites", &self.coords.len())
            .field("spatial_shape", &self.spatial_shape)
            .field("batch_size", &self.batch_size)
            .finish()
    }
}

impl SparseTensor {
    /// A sparse tensor with a fresh rulebook cache. Every coordinate must lie inside
    /// `spatial_shape` and `batch_size`, and `features` must have one row per coordinate.
    pub fn new(features: Tensor, coords: Vec<Coord>, spatial_shape: [i64; 3], batch_size: i64) -> Result<Self> {
        let n = features.size().first().copied().unwrap_or(-1);
        if features.dim() != 2 || n != coords.len() as i64 {
            return Err(NnError::Input(format!(
                "sparse tensor: features {:?} for {} coordinates (want [N, C])",
                features.size(),
                coords.len()
            )));
        }
        let bad = coords.iter().find(|c| {
            !(0..batch_size).contains(&(c[0] as i64))
                || (0..3).any(|a| !(0..spatial_shape[a]).contains(&(c[a + 1] as i64)))
        });
        if let Some(c) = bad {
            return Err(NnError::Input(format!(
                "sparse tensor: site {c:?} outside batch {batch_size} × shape {spatial_shape:?}"
            )));
        }
        Ok(Self { features, coords: Arc::new(coords), spatial_shape, batch_size, cache: Default::default() })
    }

    /// Decodes flat indices `b·D·H·W + z·H·W + y·W + x` (over a grid of `index_shape`) into a
    /// sparse tensor of shape `spatial_shape` (at least `index_shape` on each axis).
    pub fn from_flat_indices(
        features: Tensor,
        flat: &Tensor,
        index_shape: [i64; 3],
        spatial_shape: [i64; 3],
        batch_size: i64,
    ) -> Result<Self> {
        let flat: Vec<i64> = Vec::<i64>::try_from(flat.to_device(Device::Cpu).to_kind(Kind::Int64).flatten(0, -1))
            .map_err(|e| NnError::Input(format!("sparse tensor indices: {e}")))?;
        let [d, h, w] = index_shape;
        let coords = flat
            .iter()
            .map(|&f| [(f / (d * h * w)) as i32, (f / (h * w) % d) as i32, (f / w % h) as i32, (f % w) as i32])
            .collect();
        Self::new(features, coords, spatial_shape, batch_size)
    }

    pub fn len(&self) -> usize {
        self.coords.len()
    }

    pub fn is_empty(&self) -> bool {
        self.coords.is_empty()
    }

    pub fn channels(&self) -> i64 {
        self.features.size()[1]
    }

    /// The same sites with other features (the cache is shared).
    pub fn with_features(&self, features: Tensor) -> Self {
        Self {
            features,
            coords: self.coords.clone(),
            spatial_shape: self.spatial_shape,
            batch_size: self.batch_size,
            cache: self.cache.clone(),
        }
    }

    /// The rulebook cached under `key`, built by `build` the first time.
    pub fn rulebook(&self, key: &str, build: impl FnOnce() -> Result<Rulebook>) -> Result<Rc<DeviceRulebook>> {
        if let Some(rb) = self.cached(key) {
            return Ok(rb);
        }
        let book = build()?;
        let device = self.features.device();
        let in_idx = Tensor::from_slice(&book.in_idx).to_device(device);
        let out_idx = Tensor::from_slice(&book.out_idx).to_device(device);
        let rb = Rc::new(DeviceRulebook { book, in_idx, out_idx });
        self.cache.borrow_mut().insert(key.to_string(), rb.clone());
        Ok(rb)
    }

    /// A cached rulebook, if one was built under `key`.
    pub fn cached(&self, key: &str) -> Option<Rc<DeviceRulebook>> {
        self.cache.borrow().get(key).cloned()
    }

    /// A tensor on a rulebook's output sites (sharing this tensor's cache).
    pub fn derived(&self, features: Tensor, rb: &Rulebook) -> Self {
        Self {
            features,
            coords: rb.out_coords.clone(),
            spatial_shape: rb.out_shape,
            batch_size: self.batch_size,
            cache: self.cache.clone(),
        }
    }

    /// The dense `[B, C, D, H, W]` tensor (zeros off the active sites).
    pub fn dense(&self) -> Tensor {
        let [d, h, w] = self.spatial_shape;
        let c = self.channels();
        let flat: Vec<i64> =
            self.coords.iter().map(|q| ((q[0] as i64 * d + q[1] as i64) * h + q[2] as i64) * w + q[3] as i64).collect();
        let idx = Tensor::from_slice(&flat).to_device(self.features.device());
        let rows = Tensor::zeros([self.batch_size * d * h * w, c], (self.features.kind(), self.features.device()));
        rows.index_copy(0, &idx, &self.features).view([self.batch_size, d, h, w, c]).permute([0, 4, 1, 2, 3])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_indices_decode_and_dense_places_rows() {
        let f = Tensor::from_slice(&[1f32, 2., 3., 4.]).view([2, 2]);
        // Batch 1, z 2, y 0, x 1 over an index grid [3, 2, 4]; batch 0, z 0, y 1, x 3.
        let flat = Tensor::from_slice(&[3i64 * 2 * 4 + 2 * 8 + 1, 7]);
        let s = SparseTensor::from_flat_indices(f, &flat, [3, 2, 4], [4, 2, 4], 2).unwrap();
        assert_eq!(*s.coords, vec![[1, 2, 0, 1], [0, 0, 1, 3]]);
        let d = s.dense();
        assert_eq!(d.size(), [2, 2, 4, 2, 4]);
        assert_eq!(d.double_value(&[1, 0, 2, 0, 1]), 1.0);
        assert_eq!(d.double_value(&[1, 1, 2, 0, 1]), 2.0);
        assert_eq!(d.double_value(&[0, 1, 0, 1, 3]), 4.0);
        assert_eq!(d.sum(Kind::Float).double_value(&[]), 10.0);
    }

    #[test]
    fn sites_outside_the_grid_are_refused() {
        let f = Tensor::zeros([1, 2], (Kind::Float, Device::Cpu));
        assert!(SparseTensor::new(f.shallow_clone(), vec![[0, 0, 0, 5]], [2, 2, 5], 1).is_err());
        assert!(SparseTensor::new(f.shallow_clone(), vec![[1, 0, 0, 0]], [2, 2, 5], 1).is_err());
        assert!(SparseTensor::new(f, vec![[0, 0, 0, 0], [0, 0, 0, 1]], [2, 2, 5], 1).is_err());
    }
}
