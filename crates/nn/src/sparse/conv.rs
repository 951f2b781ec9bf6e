//! Sparse 3-D convolution layers (spconv's `SubMConv3d`, `SparseConv3d`, `SparseInverseConv3d`):
//! gather the input rows of every pair, one GEMM per kernel offset, scatter-add onto the output
//! rows. Weights are stored as a dense convolution's (`[C_out, C_in, kz, ky, kx]`; the inverse as
//! a transposed convolution's `[C_in, C_out, kz, ky, kx]`), so a checkpoint's tensors drop into
//! `conv3d` / `conv_transpose3d` unchanged — which is how the tests check the arithmetic.

use serde::{Deserialize, Serialize};
use tch::nn;
use tch::Tensor;

use super::{Rulebook, SparseTensor};
use crate::error::{NnError, Result};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SparseConvKind {
    /// Output sites = input sites (`SubMConv3d`).
    Submanifold,
    /// Strided; output sites = every site an input reaches (`SparseConv3d`).
    Regular,
    /// Back onto the input sites of the regular convolution with the same `indice_key`
    /// (`SparseInverseConv3d`).
    Inverse,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SparseConv3dConfig {
    pub kind: SparseConvKind,
    /// `[kz, ky, kx]`.
    pub kernel: [i64; 3],
    pub stride: [i64; 3],
    pub padding: [i64; 3],
    pub bias: bool,
    /// Rulebook cache key: layers with one key share a rulebook (spconv's `indice_key`). Without
    /// one, submanifold layers share theirs per kernel and resolution. An inverse convolution
    /// names the regular convolution it inverts.
    pub indice_key: Option<String>,
}

impl Default for SparseConv3dConfig {
    fn default() -> Self {
        Self::submanifold(3)
    }
}

impl SparseConv3dConfig {
    pub fn submanifold(k: i64) -> Self {
        Self {
            kind: SparseConvKind::Submanifold,
            kernel: [k; 3],
            stride: [1; 3],
            padding: [k / 2; 3],
            bias: false,
            indice_key: None,
        }
    }

    pub fn regular(kernel: [i64; 3], stride: [i64; 3], padding: [i64; 3]) -> Self {
        Self { kind: SparseConvKind::Regular, kernel, stride, padding, bias: false, indice_key: None }
    }

    /// The inverse of the regular convolution cached under `key`, with its kernel.
    pub fn inverse(kernel: [i64; 3], key: &str) -> Self {
        Self { kind: SparseConvKind::Inverse, indice_key: Some(key.into()), ..Self::regular(kernel, [1; 3], [0; 3]) }
    }

    pub fn with_key(mut self, key: &str) -> Self {
        self.indice_key = Some(key.into());
        self
    }

    pub fn with_bias(mut self, bias: bool) -> Self {
        self.bias = bias;
        self
    }

    /// Output spatial shape on an input of `shape` (inverse: decided by the rulebook it inverts).
    pub fn output_shape(&self, shape: [i64; 3]) -> [i64; 3] {
        match self.kind {
            SparseConvKind::Submanifold | SparseConvKind::Inverse => shape,
            SparseConvKind::Regular => std::array::from_fn(|a| {
                let span = shape[a] + 2 * self.padding[a] - self.kernel[a];
                if span < 0 {
                    0
                } else {
                    span / self.stride[a] + 1
                }
            }),
        }
    }

    pub fn init(&self, vs: nn::Path, c_in: i64, c_out: i64) -> SparseConv3d {
        let [kz, ky, kx] = self.kernel;
        let shape = match self.kind {
            SparseConvKind::Inverse => [c_in, c_out, kz, ky, kx],
            _ => [c_out, c_in, kz, ky, kx],
        };
        let weight = vs.var("weight", &shape, nn::init::DEFAULT_KAIMING_UNIFORM);
        let bias = self.bias.then(|| vs.var("bias", &[c_out], nn::Init::Const(0.0)));
        SparseConv3d { cfg: self.clone(), weight, bias, c_in, c_out }
    }
}

#[derive(Debug)]
pub struct SparseConv3d {
    cfg: SparseConv3dConfig,
    pub weight: Tensor,
    pub bias: Option<Tensor>,
    c_in: i64,
    c_out: i64,
}

impl SparseConv3d {
    pub fn config(&self) -> &SparseConv3dConfig {
        &self.cfg
    }

    /// The cache key of this layer's rulebook on `x`: its `indice_key`, else the layer's geometry
    /// and `x`'s site list (the cache keeps that list alive, so its address is not reused).
    fn key(&self, x: &SparseTensor) -> String {
        if let Some(k) = &self.cfg.indice_key {
            return k.clone();
        }
        let c = &self.cfg;
        let sites = std::sync::Arc::as_ptr(&x.coords) as usize;
        match c.kind {
            SparseConvKind::Submanifold => format!("subm k{:?} @ {:?} #{sites:x}", c.kernel, x.spatial_shape),
            _ => format!("{:?} k{:?} s{:?} p{:?} #{sites:x}", c.kind, c.kernel, c.stride, c.padding),
        }
    }

    /// `x`: `[N, C_in]` on its sites → `[N', C_out]` on the output sites.
    pub fn forward(&self, x: &SparseTensor) -> Result<SparseTensor> {
        if x.channels() != self.c_in {
            return Err(NnError::Input(format!(
                "sparse convolution expects {} channels, got {}",
                self.c_in,
                x.channels()
            )));
        }
        let c = &self.cfg;
        let key = self.key(x);
        let rb = match c.kind {
            SparseConvKind::Submanifold => {
                x.rulebook(&key, || Rulebook::submanifold(x.coords.clone(), x.spatial_shape, c.kernel))?
            }
            SparseConvKind::Regular => x.rulebook(&key, || {
                Rulebook::regular(x.coords.clone(), x.spatial_shape, c.kernel, c.stride, c.padding)
            })?,
            SparseConvKind::Inverse => {
                let fwd = x.cached(&key).ok_or_else(|| {
                    NnError::Input(format!(
                        "inverse sparse convolution: no convolution with indice_key {key:?} ran before"
                    ))
                })?;
                if !std::sync::Arc::ptr_eq(&fwd.book.out_coords, &x.coords)
                    || fwd.book.kernel_volume() as i64 != c.kernel.iter().product::<i64>()
                {
                    return Err(NnError::Input(format!(
                        "inverse sparse convolution {key:?}: its input is not the output of that convolution"
                    )));
                }
                x.rulebook(&format!("{key} (inverse)"), || Ok(fwd.book.inverse()))?
            }
        };
        let k3 = rb.book.kernel_volume() as i64;
        tracing::trace!(
            key,
            sites_in = x.len(),
            sites_out = rb.book.out_coords.len(),
            pairs = rb.book.num_pairs(),
            "sparse conv"
        );
        // [K³, C_in, C_out] matrices from the dense layout.
        let w = match c.kind {
            SparseConvKind::Inverse => self.weight.view([self.c_in, self.c_out, k3]).permute([2, 0, 1]),
            _ => self.weight.view([self.c_out, self.c_in, k3]).permute([2, 1, 0]),
        }
        .contiguous();
        let n_out = rb.book.out_coords.len() as i64;
        let mut out = Tensor::zeros([n_out, self.c_out], (x.features.kind(), x.features.device()));
        if rb.book.num_pairs() > 0 {
            // One split and one unbind (not a narrow / select per offset): their backward is one
            // cat / stack, where 27 narrows would each zero-fill a gradient of all the pairs.
            let sizes: Vec<i64> = rb.book.offsets.windows(2).map(|o| (o[1] - o[0]) as i64).collect();
            let gathered = x.features.index_select(0, &rb.in_idx).split_with_sizes(&sizes, 0);
            let parts: Vec<Tensor> = gathered
                .iter()
                .zip(w.unbind(0))
                .zip(&sizes)
                .filter(|(_, &n)| n > 0)
                .map(|((g, wk), _)| g.mm(&wk))
                .collect();
            out = out.index_add(0, &rb.out_idx, &Tensor::cat(&parts, 0));
        }
        if let Some(b) = &self.bias {
            out += b;
        }
        Ok(x.derived(out, &rb.book))
    }
}
