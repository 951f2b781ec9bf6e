//! The spinning LiDAR: beam layout, range limits, noise, dropouts and intensity.

use serde::{Deserialize, Serialize};

use crate::rng::RayRng;
use crate::SimError;

/// A spinning multi-beam LiDAR. Every number has the Ouster OS1-64 default of Pi3DET's platforms.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorConfig {
    pub name: String,
    pub beams: u32,
    /// Without an `elevation_table_deg`, beams are spread evenly from the lowest to the highest
    /// elevation.
    pub elevation_min_deg: f64,
    pub elevation_max_deg: f64,
    /// The sensor's own beam elevations, one per beam in any order (Velodyne lists them in firing
    /// order): real sensors are not evenly spaced (the VLP-32C packs its beams around the horizon,
    /// the HDL-64E has two blocks of different pitch), and the point density on a car at range
    /// follows the spacing near the horizon, not the field of view.
    pub elevation_table_deg: Option<Vec<f64>>,
    /// Columns (azimuth steps) per revolution: 512, 1024 or 2048 on an OS1.
    pub columns: u32,
    pub rate_hz: f64,
    pub range_min_m: f64,
    pub range_max_m: f64,
    /// Gaussian range noise, one sigma.
    pub range_noise_std_m: f64,
    /// Returns whose incidence cosine falls below this are dropped with growing probability
    /// (grazing returns).
    pub grazing_cos: f64,
    /// Dark returns: the received signal `reflectivity · cos(incidence) · (ref / range)²` must
    /// exceed this (with a random ±50 % threshold so the cut-off is soft).
    pub min_signal: f64,
    pub signal_reference_range_m: f64,
    /// Returns lost for no geometric reason.
    pub random_dropout: f64,
    /// Exponent of the incidence falloff in the intensity (`reflectivity · cos^k`).
    pub intensity_cos_exponent: f64,
    pub intensity_noise_std: f64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self::os1_64()
    }
}

/// Named sensor presets: the beam layouts of the sensors the public datasets were recorded with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum SensorPreset {
    /// Ouster OS1-64 (Rev 6/7), as on every Pi3DET platform: 64 beams evenly in [−22.5°, +22.5°].
    #[cfg_attr(feature = "cli", value(name = "os1-64"))]
    Os1_64,
    /// Ouster OS1-128 (Rev 6/7): 128 beams evenly in [−22.5°, +22.5°].
    #[cfg_attr(feature = "cli", value(name = "os1-128"))]
    Os1_128,
    /// Velodyne HDL-32E, as on nuScenes' car: 32 beams from −30.67° to +10.67° in 4/3° steps, 20 Hz.
    #[cfg_attr(feature = "cli", value(name = "nuscenes-32", alias = "hdl-32"))]
    Nuscenes32,
    /// Velodyne HDL-64E (S2), as on KITTI's car: 32 beams from +2° to −8.33° in 1/3° steps above 32
    /// from −8.83° to −24.33° in 1/2° steps.
    #[cfg_attr(feature = "cli", value(name = "hdl-64"))]
    Hdl64,
    /// Velodyne VLP-32C (Ultra Puck), two of them on Argoverse 1's car: 32 beams in [−25°, +15°],
    /// dense around the horizon.
    #[cfg_attr(feature = "cli", value(name = "vlp-32c"))]
    Vlp32c,
    /// Velodyne VLP-16 (Puck): 16 beams from −15° to +15° in 2° steps.
    #[cfg_attr(feature = "cli", value(name = "vlp-16"))]
    Vlp16,
}

impl SensorPreset {
    pub const ALL: [SensorPreset; 6] = [
        SensorPreset::Os1_64,
        SensorPreset::Os1_128,
        SensorPreset::Nuscenes32,
        SensorPreset::Hdl64,
        SensorPreset::Vlp32c,
        SensorPreset::Vlp16,
    ];

    pub fn config(self) -> SensorConfig {
        match self {
            SensorPreset::Os1_64 => SensorConfig::os1_64(),
            SensorPreset::Os1_128 => SensorConfig::os1_128(),
            SensorPreset::Nuscenes32 => SensorConfig::nuscenes_32(),
            SensorPreset::Hdl64 => SensorConfig::hdl_64(),
            SensorPreset::Vlp32c => SensorConfig::vlp_32c(),
            SensorPreset::Vlp16 => SensorConfig::vlp_16(),
        }
    }

    pub fn parse(s: &str) -> Result<Self, SimError> {
        match s.to_ascii_lowercase().replace('_', "-").as_str() {
            "os1-64" | "os1" | "ouster" | "pi3det" => Ok(Self::Os1_64),
            "os1-128" => Ok(Self::Os1_128),
            "nuscenes-32" | "nuscenes" | "hdl-32" | "hdl-32e" => Ok(Self::Nuscenes32),
            "hdl-64" | "hdl-64e" | "kitti" => Ok(Self::Hdl64),
            "vlp-32c" | "vlp-32" | "argoverse" => Ok(Self::Vlp32c),
            "vlp-16" => Ok(Self::Vlp16),
            other => Err(SimError::invalid(format!(
                "unknown sensor preset {other:?} (os1-64, os1-128, nuscenes-32, hdl-64, vlp-32c, vlp-16)"
            ))),
        }
    }
}

/// Velodyne VLP-32C elevations in firing order (laser ID 0–31), from its user manual's table.
const VLP_32C_ELEVATIONS_DEG: [f64; 32] = [
    -25.0, -1.0, -1.667, -15.639, -11.31, 0.0, -0.667, -8.843, -7.254, 0.333, -0.333, -6.148, -5.333, 1.333, 0.667,
    -4.0, -4.667, 1.667, 1.0, -3.667, -3.333, 3.333, 2.333, -2.667, -3.0, 7.0, 4.667, -2.333, -2.0, 15.0, 10.333,
    -1.333,
];

/// The HDL-64E S2's nominal elevations: an upper block of 32 lasers from +2° down in 1/3° steps
/// and a lower block of 32 from −8.83° down in 1/2° steps (each unit's calibration file shifts
/// them by fractions of a degree).
fn hdl_64e_elevations_deg() -> Vec<f64> {
    let upper = (0..32).map(|i| 2.0 - i as f64 / 3.0);
    let lower = (0..32).map(|i| -8.83 - 0.5 * i as f64);
    upper.chain(lower).collect()
}

impl SensorConfig {
    pub fn os1_64() -> Self {
        Self {
            name: "os1-64".into(),
            beams: 64,
            elevation_min_deg: -22.5,
            elevation_max_deg: 22.5,
            elevation_table_deg: None,
            columns: 1024,
            rate_hz: 10.0,
            range_min_m: 0.5,
            range_max_m: 120.0,
            range_noise_std_m: 0.02,
            grazing_cos: 0.06,
            min_signal: 0.003,
            signal_reference_range_m: 30.0,
            random_dropout: 0.005,
            intensity_cos_exponent: 1.0,
            intensity_noise_std: 0.02,
        }
    }

    pub fn os1_128() -> Self {
        Self { name: "os1-128".into(), beams: 128, ..Self::os1_64() }
    }

    /// The HDL-32E: evenly spaced, so no table is needed.
    pub fn nuscenes_32() -> Self {
        Self {
            name: "nuscenes-32".into(),
            beams: 32,
            elevation_min_deg: -30.67,
            elevation_max_deg: 10.67,
            columns: 1084,
            rate_hz: 20.0,
            range_max_m: 100.0,
            ..Self::os1_64()
        }
    }

    pub fn hdl_64() -> Self {
        Self::from_table(
            "hdl-64",
            hdl_64e_elevations_deg(),
            Self { columns: 2048, range_max_m: 120.0, ..Self::os1_64() },
        )
    }

    pub fn vlp_32c() -> Self {
        Self::from_table(
            "vlp-32c",
            VLP_32C_ELEVATIONS_DEG.to_vec(),
            Self { columns: 1800, range_max_m: 200.0, ..Self::os1_64() },
        )
    }

    pub fn vlp_16() -> Self {
        Self::from_table(
            "vlp-16",
            (0..16).map(|i| -15.0 + 2.0 * i as f64).collect(),
            Self { columns: 1800, range_max_m: 100.0, ..Self::os1_64() },
        )
    }

    /// `base` with its beams from `table`; the field of view is the table's span.
    fn from_table(name: &str, table: Vec<f64>, base: Self) -> Self {
        let lo = table.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = table.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Self {
            name: name.into(),
            beams: table.len() as u32,
            elevation_min_deg: lo,
            elevation_max_deg: hi,
            elevation_table_deg: Some(table),
            ..base
        }
    }

    /// Every beam's elevation in degrees, highest first (the order of `beam_elevation_rad`).
    pub fn elevations_deg(&self) -> Vec<f64> {
        match &self.elevation_table_deg {
            Some(t) => {
                let mut sorted = t.clone();
                sorted.sort_by(|a, b| b.total_cmp(a));
                sorted
            }
            None => (0..self.beams).map(|b| self.beam_elevation_rad(b).to_degrees()).collect(),
        }
    }

    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |m: &str| Err(SimError::invalid(format!("sensor: {m}")));
        if self.beams == 0 || self.columns == 0 {
            return bad("beams and columns must be positive");
        }
        if !(self.elevation_min_deg <= self.elevation_max_deg
            && self.elevation_max_deg < 90.0
            && self.elevation_min_deg > -90.0)
        {
            return bad("need −90° < elevation_min_deg ≤ elevation_max_deg < 90°");
        }
        if !(self.range_min_m >= 0.0 && self.range_max_m > self.range_min_m) {
            return bad("need 0 ≤ range_min_m < range_max_m");
        }
        if self.rate_hz.is_nan() || self.rate_hz <= 0.0 {
            return bad("rate_hz must be positive");
        }
        if let Some(t) = &self.elevation_table_deg {
            if t.len() != self.beams as usize {
                return Err(SimError::invalid(format!(
                    "sensor: elevation_table_deg has {} entries for {} beams",
                    t.len(),
                    self.beams
                )));
            }
            if !t.iter().all(|e| e.is_finite() && e.abs() < 90.0) {
                return bad("elevation_table_deg: every elevation must be finite and within (−90°, 90°)");
            }
        }
        Ok(())
    }

    pub fn rays_per_scan(&self) -> usize {
        self.beams as usize * self.columns as usize
    }

    /// Elevation of beam `b` (beam 0 is the highest, as Ouster numbers them; a table is sorted so).
    pub fn beam_elevation_rad(&self, b: u32) -> f64 {
        if self.elevation_table_deg.is_some() {
            return self.elevations_deg()[b as usize].to_radians();
        }
        let span = self.elevation_max_deg - self.elevation_min_deg;
        let frac = if self.beams > 1 { b as f64 / (self.beams - 1) as f64 } else { 0.5 };
        (self.elevation_max_deg - frac * span).to_radians()
    }

    /// Unit ray directions in the sensor frame, beam-major (`beam * columns + column`); column 0
    /// looks along +x and azimuth grows counter-clockwise.
    pub fn ray_directions(&self) -> Vec<[f64; 3]> {
        let mut dirs = Vec::with_capacity(self.rays_per_scan());
        // A table is sorted once, not per beam.
        let elevations_rad: Vec<f64> = match &self.elevation_table_deg {
            Some(_) => self.elevations_deg().into_iter().map(f64::to_radians).collect(),
            None => (0..self.beams).map(|b| self.beam_elevation_rad(b)).collect(),
        };
        for el in elevations_rad {
            let (se, ce) = el.sin_cos();
            for c in 0..self.columns {
                let az = std::f64::consts::TAU * c as f64 / self.columns as f64;
                let (sa, ca) = az.sin_cos();
                dirs.push([ce * ca, ce * sa, se]);
            }
        }
        dirs
    }

    /// What the sensor reports for a surface at `range_m` with `reflectivity` seen at incidence
    /// cosine `cos_incidence`: `Some((measured range, intensity))`, or `None` for a dropout.
    #[inline]
    pub fn measure(&self, range_m: f64, cos_incidence: f64, reflectivity: f64, rng: &mut RayRng) -> Option<(f64, f32)> {
        let cos_i = cos_incidence.abs().min(1.0);
        // Grazing: keep with probability rising linearly to 1 at `grazing_cos`.
        if cos_i < self.grazing_cos && rng.uniform() * self.grazing_cos > cos_i {
            return None;
        }
        let rr = self.signal_reference_range_m / range_m.max(1e-3);
        let signal = reflectivity * cos_i * rr * rr;
        if signal < self.min_signal * (0.5 + rng.uniform()) {
            return None;
        }
        if rng.uniform() < self.random_dropout {
            return None;
        }
        let r = range_m + self.range_noise_std_m * rng.normal();
        if r < self.range_min_m || r > self.range_max_m {
            return None;
        }
        let i = reflectivity * cos_i.powf(self.intensity_cos_exponent) + self.intensity_noise_std * rng.normal();
        Some((r, i.clamp(0.0, 1.0) as f32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn os1_beams_span_the_field_of_view() {
        let s = SensorConfig::os1_64();
        assert!((s.beam_elevation_rad(0).to_degrees() - 22.5).abs() < 1e-9);
        assert!((s.beam_elevation_rad(63).to_degrees() + 22.5).abs() < 1e-9);
        let d = s.ray_directions();
        assert_eq!(d.len(), 64 * 1024);
        for v in d.iter().step_by(977) {
            assert!(((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) - 1.0).abs() < 1e-12);
        }
        assert!((SensorConfig::hdl_64().beam_elevation_rad(0).to_degrees() - 2.0).abs() < 1e-9);
        assert!((SensorConfig::nuscenes_32().beam_elevation_rad(31).to_degrees() + 30.67).abs() < 1e-9);
    }

    /// Each preset's beams against the elevations its maker publishes (sorted, highest first).
    #[test]
    fn beam_tables_are_the_published_elevations() {
        let close = |got: Vec<f64>, want: Vec<f64>, name: &str| {
            assert_eq!(got.len(), want.len(), "{name}");
            for (g, w) in got.iter().zip(&want) {
                assert!((g - w).abs() < 2e-3, "{name}: {got:?} vs {want:?}");
            }
        };
        let mut vlp32 = vec![
            -25.0, -15.639, -11.31, -8.843, -7.254, -6.148, -5.333, -4.667, -4.0, -3.667, -3.333, -3.0, -2.667, -2.333,
            -2.0, -1.667, -1.333, -1.0, -0.667, -0.333, 0.0, 0.333, 0.667, 1.0, 1.333, 1.667, 2.333, 3.333, 4.667, 7.0,
            10.333, 15.0,
        ];
        vlp32.reverse();
        close(SensorPreset::Vlp32c.config().elevations_deg(), vlp32, "vlp-32c");
        let vlp16: Vec<f64> = (0..16).map(|i| 15.0 - 2.0 * i as f64).collect();
        close(SensorPreset::Vlp16.config().elevations_deg(), vlp16, "vlp-16");
        let hdl32: Vec<f64> = (0..32).map(|i| 10.67 - i as f64 * (41.34 / 31.0)).collect();
        close(SensorPreset::Nuscenes32.config().elevations_deg(), hdl32, "hdl-32e");
        let hdl64 = SensorPreset::Hdl64.config().elevations_deg();
        assert_eq!(hdl64.len(), 64);
        assert!((hdl64[0] - 2.0).abs() < 1e-9 && (hdl64[31] + 8.333).abs() < 1e-3);
        assert!((hdl64[32] + 8.83).abs() < 1e-9 && (hdl64[63] + 24.33).abs() < 1e-9);
        // Two pitches: 1/3° in the upper block, 1/2° in the lower.
        assert!((hdl64[0] - hdl64[1] - 1.0 / 3.0).abs() < 1e-9 && (hdl64[40] - hdl64[41] - 0.5).abs() < 1e-9);
        for (preset, beams) in [(SensorPreset::Os1_64, 64), (SensorPreset::Os1_128, 128)] {
            let e = preset.config().elevations_deg();
            assert_eq!(e.len(), beams);
            assert!((e[0] - 22.5).abs() < 1e-9 && (e[beams - 1] + 22.5).abs() < 1e-9);
        }
        for p in SensorPreset::ALL {
            p.config().validate().unwrap();
            let name = p.config().name;
            assert_eq!(SensorPreset::parse(&name).unwrap(), p, "{name}");
        }
    }

    #[test]
    fn a_table_of_the_wrong_length_is_refused() {
        let mut s = SensorConfig::vlp_16();
        s.beams = 17;
        assert!(s.validate().unwrap_err().to_string().contains("16 entries for 17 beams"));
    }

    #[test]
    fn measurement_noise_and_dropouts() {
        let s = SensorConfig::os1_64();
        let mut rng = RayRng::new(1, 1);
        let ranges: Vec<f64> = (0..5000).filter_map(|_| s.measure(10.0, 1.0, 0.5, &mut rng)).map(|m| m.0).collect();
        assert!(ranges.len() > 4900);
        let mean = ranges.iter().sum::<f64>() / ranges.len() as f64;
        let sd = (ranges.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / ranges.len() as f64).sqrt();
        assert!((mean - 10.0).abs() < 0.002 && (sd - 0.02).abs() < 0.003, "{mean} {sd}");
        // Dark asphalt far away at grazing incidence mostly vanishes; a bright wall does not.
        let dark = (0..1000).filter(|_| s.measure(80.0, 0.05, 0.08, &mut rng).is_some()).count();
        let bright = (0..1000).filter(|_| s.measure(80.0, 0.9, 0.6, &mut rng).is_some()).count();
        assert!(dark < 50 && bright > 950, "{dark} {bright}");
        let (_, i) = s.measure(10.0, 1.0, 0.7, &mut rng).unwrap();
        assert!((0.0..=1.0).contains(&i));
    }
}
