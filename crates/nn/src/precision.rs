//! Mixed precision for the BEV network: the 2-D backbone and the neck may compute in bfloat16
//! while weights, batch-norm statistics, the optimiser and every head stay in f32 (the heads'
//! box residuals need f32's resolution at IoU 0.7). The layers here keep f32 weights and cast
//! them to their input's kind in `forward`, so one checkpoint serves both precisions and the
//! gradient reaches the f32 weights through the cast.
//!
//! `bf16` pays where the hardware has native bfloat16 dot products (x86 `avx512_bf16` / AMX,
//! through oneDNN); elsewhere oneDNN emulates it, slower than f32. `auto` picks bf16 on CPUs that
//! have it, f32 otherwise.
//!
//! Inference (`precision`) and training (`train.precision`) are set apart because they behave
//! differently: an f32-trained model scores the same when it infers in bf16, but training in bf16
//! cost the Pi3DET-Net preset AP. Measured: results/2026-12-06-mixed-precision.md.

use serde::{Deserialize, Serialize};
use tch::nn::{self, Module};
use tch::{Device, Kind, Tensor};

/// The BEV network's compute precision (`precision` at the top of a detector config).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum Precision {
    #[default]
    F32,
    Bf16,
    /// bf16 on CPUs with native bfloat16 dot products, else f32.
    Auto,
}

impl Precision {
    /// The kind the backbone and the neck compute in on `device`.
    pub fn compute_kind(self, device: Device) -> Kind {
        match self {
            Self::F32 => Kind::Float,
            Self::Bf16 => Kind::BFloat16,
            Self::Auto if device == Device::Cpu && cpu_has_bf16() => Kind::BFloat16,
            Self::Auto => Kind::Float,
        }
    }
}

/// Whether the CPU has native bfloat16 dot products.
pub fn cpu_has_bf16() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512bf16")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// A 2-D convolution (zero padding) computing in its input's kind.
#[derive(Debug)]
pub struct Conv2d {
    pub conv: nn::Conv2D,
    stride: i64,
    padding: i64,
    dilation: i64,
    groups: i64,
}

pub fn conv2d(vs: nn::Path, c_in: i64, c_out: i64, k: i64, cfg: nn::ConvConfig) -> Conv2d {
    let (stride, padding, dilation, groups) = (cfg.stride, cfg.padding, cfg.dilation, cfg.groups);
    Conv2d { conv: nn::conv2d(vs, c_in, c_out, k, cfg), stride, padding, dilation, groups }
}

impl Module for Conv2d {
    /// `[B, C_in, H, W]` → `[B, C_out, H', W']`, in `xs`'s kind.
    fn forward(&self, xs: &Tensor) -> Tensor {
        let k = xs.kind();
        xs.conv2d(
            &self.conv.ws.to_kind(k),
            self.conv.bs.as_ref().map(|b| b.to_kind(k)),
            [self.stride; 2],
            [self.padding; 2],
            [self.dilation; 2],
            self.groups,
        )
    }
}

/// A 2-D transposed convolution computing in its input's kind.
#[derive(Debug)]
pub struct ConvTranspose2d {
    pub conv: nn::ConvTranspose2D,
    stride: i64,
    padding: i64,
    output_padding: i64,
    dilation: i64,
    groups: i64,
}

pub fn conv_transpose2d(vs: nn::Path, c_in: i64, c_out: i64, k: i64, cfg: nn::ConvTransposeConfig) -> ConvTranspose2d {
    let (stride, padding, output_padding, dilation, groups) =
        (cfg.stride, cfg.padding, cfg.output_padding, cfg.dilation, cfg.groups);
    ConvTranspose2d {
        conv: nn::conv_transpose2d(vs, c_in, c_out, k, cfg),
        stride,
        padding,
        output_padding,
        dilation,
        groups,
    }
}

impl Module for ConvTranspose2d {
    /// `[B, C_in, H, W]` → `[B, C_out, H·s, W·s]`, in `xs`'s kind.
    fn forward(&self, xs: &Tensor) -> Tensor {
        let k = xs.kind();
        xs.conv_transpose2d(
            &self.conv.ws.to_kind(k),
            self.conv.bs.as_ref().map(|b| b.to_kind(k)),
            [self.stride; 2],
            [self.padding; 2],
            [self.output_padding; 2],
            self.groups,
            [self.dilation; 2],
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::nn::ModuleT;

    /// The layers give their f32 result in f32 and a close one in bf16, and the bf16 pass's
    /// gradient reaches the f32 weights (batch norm takes bf16 input with f32 statistics).
    #[test]
    fn bf16_forward_matches_f32_and_trains_f32_weights() {
        tch::manual_seed(0);
        let vs = nn::VarStore::new(Device::Cpu);
        let conv = conv2d(vs.root() / "c", 4, 8, 3, nn::ConvConfig { padding: 1, ..Default::default() });
        let up =
            conv_transpose2d(vs.root() / "u", 8, 4, 2, nn::ConvTransposeConfig { stride: 2, ..Default::default() });
        let bn = nn::batch_norm2d(vs.root() / "bn", 8, Default::default());
        let x = Tensor::randn([2, 4, 6, 6], (Kind::Float, Device::Cpu));
        let net = |x: &Tensor| up.forward(&bn.forward_t(&conv.forward(x), false).relu());
        let y32 = net(&x);
        let y16 = net(&x.to_kind(Kind::BFloat16));
        assert_eq!((y32.kind(), y16.kind()), (Kind::Float, Kind::BFloat16));
        assert_eq!(y16.size(), vec![2, 4, 12, 12]);
        let err = (y16.to_kind(Kind::Float) - &y32).abs().max().double_value(&[]);
        let scale = y32.abs().max().double_value(&[]);
        assert!(err < 0.05 * scale, "bf16 error {err} against max |y| {scale}");
        y16.to_kind(Kind::Float).sum(Kind::Float).backward();
        let g = conv.conv.ws.grad();
        assert_eq!(g.kind(), Kind::Float);
        assert!(g.abs().sum(Kind::Float).double_value(&[]) > 0.0);
        assert_eq!(Precision::F32.compute_kind(Device::Cpu), Kind::Float);
        assert_eq!(Precision::Bf16.compute_kind(Device::Cpu), Kind::BFloat16);
        let auto = Precision::Auto.compute_kind(Device::Cpu);
        assert_eq!(auto == Kind::BFloat16, cpu_has_bf16());
    }

    /// A config names its precision; anything else is an error naming the choices.
    #[test]
    fn precision_in_configs() {
        let cfg =
            crate::DetectorConfig::from_toml_str("precision = \"auto\"\n[train]\nprecision = \"bf16\"\n").unwrap();
        assert_eq!((cfg.precision, cfg.train.precision), (Precision::Auto, Precision::Bf16));
        let e = crate::DetectorConfig::from_toml_str("precision = \"fp16\"\n").unwrap_err().to_string();
        assert!(e.contains("fp16") && e.contains("bf16"), "{e}");
    }
}
