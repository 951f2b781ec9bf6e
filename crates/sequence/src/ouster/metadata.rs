//! The sensor metadata JSON the Ouster SDK writes (`SensorInfo`), in both layouts it exists in:
//! the nested one of firmware ≥ 2.0 / SDK ≥ 0.10 (`beam_intrinsics`, `lidar_data_format`,
//! `config_params`, `lidar_intrinsics`, `calibration_status`) and the older flat one
//! (`beam_altitude_angles`, `data_format`, `lidar_mode`, ... at the top level).

use std::path::Path;

use serde_json::Value;

use crate::error::{Result, SequenceError};

/// The lidar packet layouts we decode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UdpProfile {
    /// Firmware < 2.2 default: column header, 12-byte pixels (20-bit range), column status.
    Legacy,
    /// Single return: packet header/footer, 12-byte pixels (19-bit range, 8-bit reflectivity).
    Rng19Rfl8Sig16Nir16,
}

impl UdpProfile {
    fn parse(s: &str) -> Option<Self> {
        match s {
            "LEGACY" => Some(Self::Legacy),
            "RNG19_RFL8_SIG16_NIR16" => Some(Self::Rng19Rfl8Sig16Nir16),
            _ => None,
        }
    }
}

/// What decoding needs from the metadata. Transforms are row-major 4×4 with translations in mm,
/// as the metadata stores them.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorMetadata {
    pub prod_line: Option<String>,
    pub profile: UdpProfile,
    pub columns_per_frame: usize,
    pub columns_per_packet: usize,
    pub pixels_per_column: usize,
    /// Destaggering: row `u` of the image is shifted right by this many columns.
    pub pixel_shift_by_row: Vec<i64>,
    pub beam_altitude_deg: Vec<f64>,
    pub beam_azimuth_deg: Vec<f64>,
    pub beam_to_lidar: [[f64; 4]; 4],
    pub lidar_to_sensor: [[f64; 4]; 4],
    pub fps: Option<u32>,
    /// `calibration_status.reflectivity.valid` when the metadata says.
    pub reflectivity_calibrated: Option<bool>,
}

/// Looks a key up in the nested section first, then at the top level (flat metadata).
fn find<'a>(root: &'a Value, sections: &[&str], key: &str) -> Option<&'a Value> {
    sections.iter().filter_map(|s| root.get(s)).find_map(|s| s.get(key)).or_else(|| root.get(key))
}

impl SensorMetadata {
    /// Parses the metadata text; `path` is the file it came from, for errors.
    pub fn parse(path: &Path, text: &str) -> Result<Self> {
        let bad = |m: String| SequenceError::invalid(path, format!("/ouster/metadata: {m}"));
        let root: Value = serde_json::from_str(text).map_err(|e| bad(format!("not JSON: {e}")))?;
        if !root.is_object() {
            return Err(bad("not a JSON object".into()));
        }
        let fmt = ["lidar_data_format", "data_format"];
        let beams = ["beam_intrinsics"];
        let floats = |v: &Value, what: &str| -> Result<Vec<f64>> {
            v.as_array()
                .and_then(|a| a.iter().map(Value::as_f64).collect::<Option<Vec<_>>>())
                .ok_or_else(|| bad(format!("'{what}' should be a list of numbers")))
        };
        let altitude = find(&root, &beams, "beam_altitude_angles")
            .ok_or_else(|| bad("missing beam intrinsics ('beam_altitude_angles'): cannot compute XYZ".into()))?;
        let azimuth = find(&root, &beams, "beam_azimuth_angles")
            .ok_or_else(|| bad("missing beam intrinsics ('beam_azimuth_angles'): cannot compute XYZ".into()))?;
        let beam_altitude_deg = floats(altitude, "beam_altitude_angles")?;
        let beam_azimuth_deg = floats(azimuth, "beam_azimuth_angles")?;

        let mode = find(&root, &["config_params"], "lidar_mode").and_then(Value::as_str);
        let mode_cols = mode.and_then(|m| m.split_once('x')).and_then(|(c, _)| c.parse::<usize>().ok());
        let mode_fps = mode.and_then(|m| m.split_once('x')).and_then(|(_, f)| f.parse::<u32>().ok());
        let uint = |key: &str| -> Result<Option<usize>> {
            match find(&root, &fmt, key) {
                None => Ok(None),
                Some(v) => {
                    v.as_u64().map(|u| Some(u as usize)).ok_or_else(|| bad(format!("'{key}' should be an integer")))
                }
            }
        };
        let columns_per_frame = uint("columns_per_frame")?
            .or(mode_cols)
            .ok_or_else(|| bad("no 'columns_per_frame' and no 'lidar_mode' like 1024x10".into()))?;
        let columns_per_packet = uint("columns_per_packet")?.unwrap_or(16);
        let pixels_per_column = uint("pixels_per_column")?.unwrap_or(beam_altitude_deg.len());
        if !(1..=65536).contains(&columns_per_frame)
            || !(1..=1024).contains(&columns_per_packet)
            || !(1..=1024).contains(&pixels_per_column)
        {
            return Err(bad(format!(
                "implausible format: {columns_per_frame} columns per frame, {columns_per_packet} per packet, {pixels_per_column} pixels per column"
            )));
        }
        if beam_altitude_deg.len() != pixels_per_column || beam_azimuth_deg.len() != pixels_per_column {
            return Err(bad(format!(
                "{} altitude and {} azimuth angles for {pixels_per_column} pixels per column",
                beam_altitude_deg.len(),
                beam_azimuth_deg.len()
            )));
        }
        let pixel_shift_by_row = match find(&root, &fmt, "pixel_shift_by_row") {
            Some(v) => v
                .as_array()
                .and_then(|a| a.iter().map(Value::as_i64).collect::<Option<Vec<_>>>())
                .ok_or_else(|| bad("'pixel_shift_by_row' should be a list of integers".into()))?,
            // Pre-2.0 metadata without a data format: the SDK's default for OS-1 (gen 1).
            None => default_shifts(columns_per_frame, pixels_per_column),
        };
        if pixel_shift_by_row.len() != pixels_per_column {
            return Err(bad(format!(
                "{} pixel shifts for {pixels_per_column} pixels per column",
                pixel_shift_by_row.len()
            )));
        }
        let profile_name = find(&root, &fmt, "udp_profile_lidar")
            .or_else(|| find(&root, &["config_params"], "udp_profile_lidar"))
            .and_then(Value::as_str)
            .unwrap_or("LEGACY");
        let profile = UdpProfile::parse(profile_name).ok_or_else(|| {
            bad(format!("udp_profile_lidar {profile_name} is not supported (LEGACY, RNG19_RFL8_SIG16_NIR16)"))
        })?;

        let matrix = |v: &Value, what: &str| -> Result<[[f64; 4]; 4]> {
            let f = floats(v, what)?;
            if f.len() != 16 {
                return Err(bad(format!("'{what}' has {} values, expected 16", f.len())));
            }
            Ok(std::array::from_fn(|i| std::array::from_fn(|j| f[4 * i + j])))
        };
        // Newer metadata gives the beam origin as a transform; older only its distance along x,
        // which the SDK turns into the same transform.
        let beam_to_lidar = match find(&root, &beams, "beam_to_lidar_transform") {
            Some(v) => matrix(v, "beam_to_lidar_transform")?,
            None => {
                let d = find(&root, &beams, "lidar_origin_to_beam_origin_mm")
                    .map(|v| {
                        v.as_f64().ok_or_else(|| bad("'lidar_origin_to_beam_origin_mm' should be a number".into()))
                    })
                    .transpose()?
                    .unwrap_or(0.0);
                let mut m = identity();
                m[0][3] = d;
                m
            }
        };
        let lidar_to_sensor = match find(&root, &["lidar_intrinsics"], "lidar_to_sensor_transform") {
            Some(v) => matrix(v, "lidar_to_sensor_transform")?,
            None => identity(),
        };
        let fps = find(&root, &fmt, "fps").and_then(Value::as_u64).map(|f| f as u32).or(mode_fps);
        let reflectivity_calibrated = root
            .get("calibration_status")
            .and_then(|c| c.get("reflectivity"))
            .and_then(|r| r.get("valid"))
            .and_then(Value::as_bool);
        let prod_line = find(&root, &["sensor_info"], "prod_line").and_then(Value::as_str).map(str::to_string);
        Ok(Self {
            prod_line,
            profile,
            columns_per_frame,
            columns_per_packet,
            pixels_per_column,
            pixel_shift_by_row,
            beam_altitude_deg,
            beam_azimuth_deg,
            beam_to_lidar,
            lidar_to_sensor,
            fps,
            reflectivity_calibrated,
        })
    }

    /// Lidar packets per sweep.
    pub fn packets_per_frame(&self) -> usize {
        self.columns_per_frame.div_ceil(self.columns_per_packet)
    }
}

fn identity() -> [[f64; 4]; 4] {
    std::array::from_fn(|i| std::array::from_fn(|j| if i == j { 1.0 } else { 0.0 }))
}

/// The SDK's `default_data_format` shifts for gen-1 OS-1 sensors: 4 staggered columns.
fn default_shifts(columns: usize, pixels: usize) -> Vec<i64> {
    let step = match columns {
        512 => 3,
        2048 => 12,
        4096 => 24,
        _ => 6,
    };
    (0..pixels).map(|u| (3 - (u % 4) as i64) * step).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_and_nested_layouts() {
        let p = Path::new("x.h5");
        let flat = r#"{"lidar_mode": "512x20", "beam_altitude_angles": [1, -1], "beam_azimuth_angles": [0.5, -0.5],
            "lidar_origin_to_beam_origin_mm": 12.0, "data_format": {"pixels_per_column": 2, "pixel_shift_by_row": [3, 0]}}"#;
        let m = SensorMetadata::parse(p, flat).unwrap();
        assert_eq!((m.columns_per_frame, m.columns_per_packet, m.pixels_per_column, m.fps), (512, 16, 2, Some(20)));
        assert_eq!(m.beam_to_lidar[0][3], 12.0);
        assert_eq!(m.profile, UdpProfile::Legacy);
        let nested = r#"{"beam_intrinsics": {"beam_altitude_angles": [1], "beam_azimuth_angles": [0],
            "beam_to_lidar_transform": [1,0,0,15.8,0,1,0,0,0,0,1,2,0,0,0,1]},
            "config_params": {"lidar_mode": "1024x10"},
            "lidar_data_format": {"columns_per_frame": 1024, "columns_per_packet": 16, "pixels_per_column": 1,
              "pixel_shift_by_row": [0], "udp_profile_lidar": "RNG19_RFL8_SIG16_NIR16"}}"#;
        let m = SensorMetadata::parse(p, nested).unwrap();
        assert_eq!(m.profile, UdpProfile::Rng19Rfl8Sig16Nir16);
        assert_eq!(m.beam_to_lidar[2][3], 2.0);
        assert_eq!(m.packets_per_frame(), 64);
    }

    #[test]
    fn errors_name_the_file_and_the_problem() {
        let p = Path::new("seq_data.h5");
        let e = SensorMetadata::parse(p, r#"{"lidar_mode": "1024x10"}"#).unwrap_err().to_string();
        assert!(e.contains("seq_data.h5") && e.contains("beam intrinsics"), "{e}");
        let e = SensorMetadata::parse(p, "{not json").unwrap_err().to_string();
        assert!(e.contains("not JSON"), "{e}");
        let e = SensorMetadata::parse(
            p,
            r#"{"lidar_mode": "1024x10", "beam_altitude_angles": [1], "beam_azimuth_angles": [0],
                "data_format": {"udp_profile_lidar": "FIVE_WORD_PIXEL"}}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("FIVE_WORD_PIXEL"), "{e}");
    }
}
