//! Arguments shared by the detector commands: device and libtorch threads, a dataset and the part
//! of it to use.

use std::path::{Path, PathBuf};

use pi3det_data::Platform;

use pi3det_nn::data_loader::{open_split, Subset};
use pi3det_nn::device::{self, DeviceChoice};
use pi3det_nn::error::Result;
use pi3det_nn::precision::Precision;
use pi3det_nn::DetectorConfig;

/// Levelling frames to the detector's training height (`detect`, `run`, `autolabel`).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct LevelArgs {
    /// Level every frame through Virtual Platform Pose to a virtual sensor this many metres above
    /// the ground [default: the sensor height the checkpoint was trained at, when it records one];
    /// detections go back to the sensor frame.
    #[arg(long, value_name = "M", conflicts_with = "no_level")]
    pub vpp_height: Option<f64>,
    /// Do not level frames: only the config's z shift (frames already in the training frame).
    #[arg(long)]
    pub no_level: bool,
}

impl LevelArgs {
    pub fn level(&self) -> pi3det_nn::preprocess::Level {
        use pi3det_nn::preprocess::Level;
        match (self.vpp_height, self.no_level) {
            (Some(h), _) => Level::Height(h),
            (None, true) => Level::Off,
            (None, false) => Level::Trained,
        }
    }
}

/// Device and libtorch threads.
#[derive(clap::Args, Debug, Clone)]
pub struct DeviceArgs {
    /// cpu, cuda or auto (CUDA when libtorch finds a GPU).
    #[arg(long, default_value = "auto")]
    pub device: DeviceChoice,
    /// libtorch intra-op threads on the CPU [default: the config's `train.threads`, else
    /// $PI3DET_TORCH_THREADS, else every core; on a machine busy with other work 1 can be faster].
    #[arg(long, value_name = "N")]
    pub torch_threads: Option<usize>,
    /// Compute precision of the 2-D backbone and the neck, in training and at inference: f32,
    /// bf16, or auto (bf16 on CPUs with native bfloat16, e.g. AVX512-BF16; weights and heads stay
    /// f32) [default: the config's `train.precision` and `precision`].
    #[arg(long, value_name = "P")]
    pub precision: Option<Precision>,
}

impl DeviceArgs {
    /// Sets libtorch's threads (`configured`: the config's `train.threads`) and resolves the
    /// device.
    pub fn setup(&self, configured: usize) -> Result<tch::Device> {
        let n = self.threads(configured);
        device::set_threads(n);
        let d = device::resolve(self.device)?;
        tracing::info!("device {d:?}, {n} libtorch thread(s)");
        Ok(d)
    }

    /// Writes `--precision` into a config, for training and inference (the checkpoint then
    /// records what ran).
    pub fn apply_precision(&self, cfg: &mut DetectorConfig) {
        if let Some(p) = self.precision {
            cfg.precision = p;
            cfg.train.precision = p;
        }
    }

    /// The libtorch threads `setup` uses.
    pub fn threads(&self, configured: usize) -> usize {
        self.torch_threads.unwrap_or_else(|| device::default_threads(configured))
    }
}

/// A `--x` / `--no-x` pair: `Some(true)`, `Some(false)`, or `None` when neither was given (clap's
/// `overrides_with` keeps only the last of the two).
pub fn on_off(on: bool, off: bool) -> Option<bool> {
    match (on, off) {
        (true, _) => Some(true),
        (_, true) => Some(false),
        _ => None,
    }
}

/// Switches that earlier releases took as `--x true|false` (or `--x=BOOL`), now `--x` / `--no-x`.
pub const SWITCHES: &[&str] = &["per-class-nms", "ground-fit", "bev-fit", "upright-check", "tta", "vpp-diagnostics"];

/// Rewrites the old spellings of [`SWITCHES`] (`--tta false`, `--tta=true`) into the new ones
/// (`--no-tta`, `--tta`), so command lines written for earlier releases keep working; everything
/// else is left as it is.
pub fn rewrite_old_switches(args: Vec<std::ffi::OsString>) -> Vec<std::ffi::OsString> {
    let mut out = Vec::with_capacity(args.len());
    let mut it = args.into_iter().peekable();
    while let Some(a) = it.next() {
        let text = a.to_str().unwrap_or("");
        if text == "--" {
            out.push(a);
            out.extend(it);
            break;
        }
        let (name, inline) = match text.strip_prefix("--").map(|t| t.split_once('=')) {
            Some(Some((n, v))) => (n, Some(v.to_string())),
            Some(None) => (&text[2..], None),
            None => ("", None),
        };
        if SWITCHES.contains(&name) {
            let value = match inline {
                Some(v) => Some(v),
                None => it
                    .peek()
                    .and_then(|v| v.to_str())
                    .filter(|v| matches!(*v, "true" | "false"))
                    .map(String::from)
                    .inspect(|_| {
                        it.next();
                    }),
            };
            match value.as_deref() {
                Some("false") => out.push(format!("--no-{name}").into()),
                Some("true") | None => out.push(format!("--{name}").into()),
                // Anything else is passed on for clap to refuse.
                Some(v) => out.push(format!("--{name}={v}").into()),
            }
            continue;
        }
        out.push(a);
    }
    out
}

pub fn parse_platform(s: &str) -> std::result::Result<Platform, String> {
    match Platform::parse(s) {
        Platform::Unknown => Err(format!("unknown platform {s:?} (vehicle, drone, quadruped)")),
        p => Ok(p),
    }
}

/// A dataset and the part of it to use.
#[derive(clap::Args, Debug, Clone)]
pub struct DataArgs {
    /// A Pi3DET folder (or info .pkl), a KITTI folder or an mmdet3d info .pkl.
    #[arg(long, value_name = "PATH")]
    pub data: PathBuf,
    /// When DATA is a Pi3DET folder with several info files, use pi3det_infos_<SPLIT>.pkl.
    #[arg(long)]
    pub split: Option<String>,
    /// Only frames of this platform.
    #[arg(long, value_parser = parse_platform)]
    pub platform: Option<Platform>,
    /// At most this many frames, spread evenly (0: all) [train: default the config's
    /// `train.max_train_frames`; detect: all].
    #[arg(long, value_name = "N")]
    pub max_frames: Option<usize>,
}

impl DataArgs {
    /// The frames to use: `--split` (else `default_split`), `--platform`, then at most
    /// `--max-frames` (else `default_max`; 0: all) spread evenly.
    pub fn subset(&self, default_split: &str, default_max: usize) -> Result<Subset> {
        open_subset(
            &self.data,
            Some(self.split.as_deref().unwrap_or(default_split)),
            self.platform,
            self.max_frames.unwrap_or(default_max),
        )
    }
}

/// A split of a dataset, optionally one platform's frames, at most `max` of them spread evenly
/// (0: all).
pub fn open_subset(path: &Path, split: Option<&str>, platform: Option<Platform>, max: usize) -> Result<Subset> {
    let mut s = Subset::all(open_split(path, split)?);
    if let Some(p) = platform {
        s = s.platform(p)?;
    }
    Ok(s.take_spread(max))
}

#[cfg(test)]
mod switch_tests {
    use super::*;

    fn v(a: &[&str]) -> Vec<std::ffi::OsString> {
        a.iter().map(Into::into).collect()
    }

    #[test]
    fn old_switch_spellings_are_rewritten() {
        assert_eq!(
            rewrite_old_switches(v(&["detect", "--tta", "false", "--bev-fit=true", "--upright-check", "--out", "o"])),
            v(&["detect", "--no-tta", "--bev-fit", "--upright-check", "--out", "o"])
        );
        assert_eq!(
            rewrite_old_switches(v(&["adapt", "--vpp-diagnostics", "false"])),
            v(&["adapt", "--no-vpp-diagnostics"])
        );
        // Lists (autolabel's views) and words after `--` stay as they are.
        assert_eq!(
            rewrite_old_switches(v(&["autolabel", "--tta", "flip,rot"])),
            v(&["autolabel", "--tta", "flip,rot"])
        );
        assert_eq!(rewrite_old_switches(v(&["x", "--", "--tta", "false"])), v(&["x", "--", "--tta", "false"]));
        assert_eq!(on_off(false, false), None);
        assert_eq!(on_off(false, true), Some(false));
    }
}
