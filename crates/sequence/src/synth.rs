//! Synthetic sequences written in pure Rust (hdf5-pure's writer, LZF, one sweep per chunk), for
//! the benchmark and the tests that need no Python. The packets follow the layouts of
//! [`crate::ouster::packet`]; `tests/fixtures/make_sequence.py` writes the h5py-made ones the
//! Ouster SDK peer check uses.

use std::path::{Path, PathBuf};

use pi3det_data::pickle::{self, NdArray, Value};
use serde_json::json;

use crate::error::{Result, SequenceError};
use crate::ouster::{UdpProfile, ROS_PACKET_PAD_BYTES};

#[derive(Debug, Clone)]
pub struct SynthSpec {
    pub name: String,
    pub beams: usize,
    pub columns: usize,
    pub frames: usize,
    pub profile: UdpProfile,
    pub seed: u64,
    /// Frames in the pose file (default: `frames`).
    pub pose_frames: Option<usize>,
    /// Metadata JSON to store instead of [`metadata_json`] (for bad-input tests).
    pub metadata: Option<String>,
    /// Bytes stored after each packet in `/ouster/data`: the release's layout by default
    /// ([`ROS_PACKET_PAD_BYTES`], as ouster-ros 0.x wrote it); 0 for exact-size rows.
    pub row_pad_bytes: usize,
}

impl SynthSpec {
    /// An OS1-64 in 1024x10, LEGACY packets.
    pub fn os1_64(name: &str, frames: usize) -> Self {
        Self {
            name: name.into(),
            beams: 64,
            columns: 1024,
            frames,
            profile: UdpProfile::Legacy,
            seed: 16,
            pose_frames: None,
            metadata: None,
            row_pad_bytes: ROS_PACKET_PAD_BYTES,
        }
    }
}

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        // xorshift64*: reproducible without a dependency.
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

/// The metadata JSON of the spec (nested layout, firmware 2.x).
pub fn metadata_json(spec: &SynthSpec) -> String {
    let h = spec.beams;
    let alt: Vec<f64> = (0..h).map(|u| 21.5 - 43.9 * u as f64 / (h.max(2) - 1) as f64).collect();
    let az: Vec<f64> = (0..h).map(|u| [4.2, 1.4, -1.4, -4.2][u % 4]).collect();
    let step = if spec.columns >= 1024 { 12 } else { 6 };
    let shifts: Vec<i64> = (0..h).map(|u| (3 - (u % 4) as i64) * step).collect();
    let profile = match spec.profile {
        UdpProfile::Legacy => "LEGACY",
        UdpProfile::Rng19Rfl8Sig16Nir16 => "RNG19_RFL8_SIG16_NIR16",
    };
    json!({
        "sensor_info": {"prod_line": format!("OS-1-{h}"), "build_rev": "v2.5.2", "initialization_id": 0, "prod_sn": "0"},
        "beam_intrinsics": {
            "beam_altitude_angles": alt, "beam_azimuth_angles": az, "lidar_origin_to_beam_origin_mm": 15.806,
            "beam_to_lidar_transform": [1, 0, 0, 15.806, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
        },
        "calibration_status": {"reflectivity": {"valid": true}},
        "config_params": {"lidar_mode": format!("{}x10", spec.columns), "udp_profile_lidar": profile},
        "lidar_data_format": {
            "columns_per_frame": spec.columns, "columns_per_packet": 16, "pixels_per_column": h,
            "pixel_shift_by_row": shifts, "udp_profile_lidar": profile, "column_window": [0, spec.columns - 1]
        },
        "lidar_intrinsics": {"lidar_to_sensor_transform": [-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 36.18, 0, 0, 0, 1]}
    })
    .to_string()
}

/// One sweep's packets, concatenated: random returns (10 % empty, 0.3–80 m).
pub fn sweep_packets(spec: &SynthSpec, frame: usize, t0_ns: u64, rng: &mut impl FnMut() -> u64) -> Vec<u8> {
    sweep_packets_with(spec, frame, t0_ns, &mut |_, _| {
        let r = rng();
        let range = if r.is_multiple_of(10) { 0 } else { 300 + (r >> 8) % 80_000 } as u32;
        (range, ((r >> 40) % 256) as u16)
    })
}

/// One sweep's packets, concatenated, with `pixel(beam, measurement_id)` giving each pixel's
/// (range mm, reflectivity), in the spec's profile.
pub fn sweep_packets_with(
    spec: &SynthSpec,
    frame: usize,
    t0_ns: u64,
    pixel: &mut impl FnMut(usize, usize) -> (u32, u16),
) -> Vec<u8> {
    let (h, w) = (spec.beams, spec.columns);
    let mut out = Vec::new();
    for p in 0..w.div_ceil(16) {
        if spec.profile == UdpProfile::Rng19Rfl8Sig16Nir16 {
            out.extend_from_slice(&1u16.to_le_bytes());
            out.extend_from_slice(&(frame as u16).to_le_bytes());
            out.extend_from_slice(&[0; 28]);
        }
        for c in 0..16 {
            let m = (p * 16 + c) as u16;
            let ts = t0_ns + u64::from(m) * (100_000_000 / w as u64);
            out.extend_from_slice(&ts.to_le_bytes());
            out.extend_from_slice(&m.to_le_bytes());
            match spec.profile {
                UdpProfile::Legacy => {
                    out.extend_from_slice(&(frame as u16).to_le_bytes());
                    out.extend_from_slice(&(u32::from(m) * (90112 / w as u32)).to_le_bytes());
                }
                UdpProfile::Rng19Rfl8Sig16Nir16 => out.extend_from_slice(&1u16.to_le_bytes()),
            }
            for u in 0..h {
                let (range, refl) = pixel(u, usize::from(m));
                out.extend_from_slice(&range.to_le_bytes());
                match spec.profile {
                    UdpProfile::Legacy => out.extend_from_slice(&refl.to_le_bytes()),
                    UdpProfile::Rng19Rfl8Sig16Nir16 => out.extend_from_slice(&[refl.min(255) as u8, 0]),
                }
                out.extend_from_slice(&[0; 6]);
            }
            if spec.profile == UdpProfile::Legacy {
                out.extend_from_slice(&u32::MAX.to_le_bytes());
            }
        }
        if spec.profile == UdpProfile::Rng19Rfl8Sig16Nir16 {
            out.extend_from_slice(&[0; 32]);
        }
    }
    out
}

/// `Ln_T_L0` of frame k: a slow left turn while driving forward.
pub fn ln_t_l0(k: usize) -> [f64; 16] {
    let yaw = 0.05 * k as f64;
    let (s, c) = yaw.sin_cos();
    [c, -s, 0.0, 1.5 * k as f64, s, c, 0.0, 0.2 * k as f64, 0.0, 0.0, 1.0, 0.01 * k as f64, 0.0, 0.0, 0.0, 1.0]
}

/// Pseudo-labels of frame k: a vehicle, two pedestrians, one ignored vehicle.
pub fn label_rows(k: usize) -> Vec<[f32; 9]> {
    let k = k as f32;
    vec![
        [10.0 + k, 2.0, -0.8, 4.2, 1.9, 1.6, 0.1, 1.0, 0.93],
        [6.0, -3.0 - 0.1 * k, -0.9, 0.8, 0.6, 1.7, -1.2, 2.0, 0.71],
        [15.0, 8.0, -1.0, 0.7, 0.7, 1.8, 0.0, 3.0, 0.55],
        [30.0, -12.0, -0.7, 4.5, 2.0, 1.5, 2.0, -1.0, 0.35],
    ]
}

fn h5_err(path: &Path, e: impl std::fmt::Display) -> SequenceError {
    SequenceError::hdf5(path, "write", e)
}

/// Writes `<dir>/<name>/{<name>_data.h5, <name>_pose.h5, ps_labels/final_ps_dict.pkl}`; returns
/// the sequence folder.
pub fn write_sequence(dir: &Path, spec: &SynthSpec) -> Result<PathBuf> {
    let seq = dir.join(&spec.name);
    std::fs::create_dir_all(seq.join("ps_labels")).map_err(|e| SequenceError::invalid(&seq, e.to_string()))?;
    let mut state = Rng(spec.seed.max(1));
    let mut rng = move || state.below(u64::MAX);
    let t0_us = 1_650_000_000_000_000u64;
    let packets = spec.columns.div_ceil(16) as u64;
    let mut data = Vec::new();
    for k in 0..spec.frames {
        let sweep = sweep_packets(spec, k, (t0_us + k as u64 * 100_000) * 1000, &mut rng);
        for packet in sweep.chunks_exact(sweep.len() / packets as usize) {
            data.extend_from_slice(packet);
            data.extend(std::iter::repeat_n(0u8, spec.row_pad_bytes));
        }
    }
    let packet_bytes = (data.len() / spec.frames.max(1)) as u64 / packets;
    let data_path = seq.join(format!("{}_data.h5", spec.name));
    let mut b = hdf5_pure::FileBuilder::new();
    let mut g = b.create_group("ouster");
    g.create_dataset("data")
        .with_u8_data(&data)
        .with_shape(&[spec.frames as u64, packets, packet_bytes])
        .with_chunks(&[1, packets, packet_bytes])
        .with_lzf();
    let metadata = spec.metadata.clone().unwrap_or_else(|| metadata_json(spec));
    g.create_dataset("metadata").with_strings(&[&metadata]).map_err(|e| h5_err(&data_path, e))?;
    let starts: Vec<i64> = (0..spec.frames).map(|k| (t0_us + k as u64 * 100_000) as i64).collect();
    g.create_dataset("ts_start").with_i64_data(&starts);
    let ends: Vec<i64> = starts.iter().map(|s| s + 100_000).collect();
    g.create_dataset("ts_end").with_i64_data(&ends);
    b.add_group(g.finish());
    b.write(&data_path).map_err(|e| h5_err(&data_path, e))?;

    let pose_path = seq.join(format!("{}_pose.h5", spec.name));
    let n = spec.pose_frames.unwrap_or(spec.frames);
    let poses: Vec<f64> = (0..n).flat_map(ln_t_l0).collect();
    let mut b = hdf5_pure::FileBuilder::new();
    b.create_dataset("Ln_T_L0").with_f64_data(&poses).with_shape(&[n as u64, 4, 4]);
    b.write(&pose_path).map_err(|e| h5_err(&pose_path, e))?;

    let labels = Value::Dict(
        (0..spec.frames)
            .map(|k| {
                let rows = label_rows(k);
                let flat: Vec<f32> = rows.iter().flatten().copied().collect();
                let arr = NdArray::new(vec![rows.len(), 9], flat).expect("shape matches");
                (Value::Str(format!("{k:05}")), Value::dict([("gt_boxes", Value::Array(arr))]))
            })
            .collect(),
    );
    let labels_path = seq.join("ps_labels/final_ps_dict.pkl");
    pickle::to_path(&labels_path, &labels, true).map_err(|e| SequenceError::invalid(&labels_path, e.to_string()))?;
    Ok(seq)
}
