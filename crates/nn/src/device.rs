//! Device choice: CPU, CUDA, or CUDA when available.
//!
//! libtorch's CUDA code lives in `libtorch_cuda.so`, which the linker drops from our binaries
//! (nothing references it directly), so we load it by hand before asking libtorch about CUDA. On
//! machines without a GPU or without the CUDA libraries this fails quietly and `auto` picks the CPU.

use std::str::FromStr;

use serde::{Deserialize, Serialize};
use tch::Device;

use crate::error::{NnError, Result};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum DeviceChoice {
    Cpu,
    Cuda,
    #[default]
    Auto,
}

impl FromStr for DeviceChoice {
    type Err = NnError;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "cpu" => Ok(Self::Cpu),
            "cuda" | "gpu" => Ok(Self::Cuda),
            "auto" => Ok(Self::Auto),
            _ => Err(NnError::Device(format!("unknown device {s:?} (cpu, cuda or auto)"))),
        }
    }
}

impl std::fmt::Display for DeviceChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Cpu => "cpu",
            Self::Cuda => "cuda",
            Self::Auto => "auto",
        })
    }
}

/// Loads libtorch's CUDA library (once) and reports whether CUDA is usable.
pub fn cuda_available() -> bool {
    static LOADED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *LOADED.get_or_init(|| {
        load_torch_cuda();
        tch::Cuda::is_available()
    })
}

fn load_torch_cuda() {
    // Look beside the libtorch_cpu.so this process loaded, then let the loader search.
    let mut candidates: Vec<std::ffi::CString> = Vec::new();
    if let Ok(maps) = std::fs::read_to_string("/proc/self/maps") {
        if let Some(line) = maps.lines().find(|l| l.ends_with("/libtorch_cpu.so")) {
            if let Some(path) = line.split_whitespace().last() {
                let dir = std::path::Path::new(path).parent().map(|p| p.join("libtorch_cuda.so"));
                if let Some(Ok(c)) = dir.map(|d| std::ffi::CString::new(d.to_string_lossy().as_bytes())) {
                    candidates.push(c);
                }
            }
        }
    }
    if let Ok(c) = std::ffi::CString::new("libtorch_cuda.so") {
        candidates.push(c);
    }
    for c in candidates {
        // SAFETY: dlopen with a valid NUL-terminated path; the handle is deliberately leaked so
        // the library stays loaded for the life of the process.
        let handle = unsafe { libc::dlopen(c.as_ptr(), libc::RTLD_NOW | libc::RTLD_GLOBAL) };
        if !handle.is_null() {
            return;
        }
    }
}

/// Resolves a choice to a libtorch device.
pub fn resolve(choice: DeviceChoice) -> Result<Device> {
    match choice {
        DeviceChoice::Cpu => Ok(Device::Cpu),
        DeviceChoice::Cuda => {
            if cuda_available() {
                Ok(Device::Cuda(0))
            } else {
                Err(NnError::Device(
                    "CUDA requested but not available (no GPU, or libtorch's CUDA libraries failed to load)".into(),
                ))
            }
        }
        DeviceChoice::Auto => Ok(if cuda_available() { Device::Cuda(0) } else { Device::Cpu }),
    }
}

/// Intra-op threads for libtorch on the CPU: the config's value, else the `PI3DET_TORCH_THREADS`
/// environment variable, else every core. On an idle machine the loader thread keeps up with
/// every core training; on a machine busy with other work one thread can be faster, which the
/// variable or `--torch-threads 1` selects. Measured:
/// results/2026-12-01-two-stage-preset-seeds.md.
pub fn default_threads(configured: usize) -> usize {
    if configured > 0 {
        return configured;
    }
    env_threads().unwrap_or_else(cores)
}

/// `$PI3DET_TORCH_THREADS`, when it holds a positive number.
pub fn env_threads() -> Option<usize> {
    std::env::var("PI3DET_TORCH_THREADS").ok().and_then(|v| v.parse::<usize>().ok()).filter(|&n| n > 0)
}

/// The cores this process may use.
pub fn cores() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

/// Sets libtorch's intra-op thread count.
pub fn set_threads(n: usize) {
    tch::set_num_threads(n.max(1) as i32);
}

/// Makes glibc keep freed memory for reuse instead of handing each large block back to the
/// kernel. libtorch on the CPU allocates and frees tens of MB per layer and step; with glibc's
/// defaults every such block comes back as fresh pages the kernel must fault in and zero
/// (`perf`: `clear_page_erms` and page faults among the top entries); keeping them makes both
/// `pi3det bench sparse` and `bench nn`'s two-stage PointPillars step faster. Measured:
/// results/2026-12-02-voxel-detectors.md. Call once, at the start of a process that runs
/// networks; a no-op off glibc.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator thresholds; it is called before other threads start.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_resolves() {
        assert_eq!("CPU".parse::<DeviceChoice>().unwrap(), DeviceChoice::Cpu);
        assert!("tpu".parse::<DeviceChoice>().is_err());
        assert_eq!(resolve(DeviceChoice::Cpu).unwrap(), Device::Cpu);
        // auto never fails.
        resolve(DeviceChoice::Auto).unwrap();
    }
}
