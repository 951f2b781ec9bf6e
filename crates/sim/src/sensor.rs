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
    /// Beams are spread evenly from the lowest to the highest elevation.
    pub elevation_min_deg: f64,
    pub elevation_max_deg: f64,
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

/// Named sensor presets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum SensorPreset {
    /// Ouster OS1-64, as on every Pi3DET platform: 64 beams in [−22.5°, +22.5°].
    #[cfg_attr(feature = "cli", value(name = "os1-64"))]
    Os1_64,
    /// nuScenes-like 32 beams in [−30°, +10°].
    #[cfg_attr(feature = "cli", value(name = "nuscenes-32"))]
    Nuscenes32,
    /// KITTI-like Velodyne HDL-64E: 64 beams in [−24.9°, +2°].
    #[cfg_attr(feature = "cli", value(name = "hdl-64"))]
    Hdl64,
}

impl SensorPreset {
    pub fn config(self) -> SensorConfig {
        match self {
            SensorPreset::Os1_64 => SensorConfig::os1_64(),
            SensorPreset::Nuscenes32 => SensorConfig::nuscenes_32(),
            SensorPreset::Hdl64 => SensorConfig::hdl_64(),
        }
    }

    pub fn parse(s: &str) -> Result<Self, SimError> {
        match s.to_ascii_lowercase().replace('_', "-").as_str() {
            "os1-64" | "os1" | "ouster" | "pi3det" => Ok(Self::Os1_64),
            "nuscenes-32" | "nuscenes" | "hdl-32" => Ok(Self::Nuscenes32),
            "hdl-64" | "kitti" => Ok(Self::Hdl64),
            other => Err(SimError::invalid(format!("unknown sensor preset {other:?} (os1-64, nuscenes-32, hdl-64)"))),
        }
    }
}

impl SensorConfig {
    pub fn os1_64() -> Self {
        Self {
            name: "os1-64".into(),
            beams: 64,
            elevation_min_deg: -22.5,
            elevation_max_deg: 22.5,
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

    pub fn nuscenes_32() -> Self {
        Self {
            name: "nuscenes-32".into(),
            beams: 32,
            elevation_min_deg: -30.0,
            elevation_max_deg: 10.0,
            columns: 1084,
            rate_hz: 20.0,
            range_max_m: 100.0,
            ..Self::os1_64()
        }
    }

    pub fn hdl_64() -> Self {
        Self {
            name: "hdl-64".into(),
            beams: 64,
            elevation_min_deg: -24.9,
            elevation_max_deg: 2.0,
            columns: 2048,
            range_max_m: 120.0,
            ..Self::os1_64()
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
        Ok(())
    }

    pub fn rays_per_scan(&self) -> usize {
        self.beams as usize * self.columns as usize
    }

    /// Elevation of beam `b` (beam 0 is the highest, as Ouster numbers them).
    pub fn beam_elevation_rad(&self, b: u32) -> f64 {
        let span = self.elevation_max_deg - self.elevation_min_deg;
        let frac = if self.beams > 1 { b as f64 / (self.beams - 1) as f64 } else { 0.5 };
        (self.elevation_max_deg - frac * span).to_radians()
    }

    /// Unit ray directions in the sensor frame, beam-major (`beam * columns + column`); column 0
    /// looks along +x and azimuth grows counter-clockwise.
    pub fn ray_directions(&self) -> Vec<[f64; 3]> {
        let mut dirs = Vec::with_capacity(self.rays_per_scan());
        for b in 0..self.beams {
            let el = self.beam_elevation_rad(b);
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
        assert!((SensorConfig::nuscenes_32().beam_elevation_rad(31).to_degrees() + 30.0).abs() < 1e-9);
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
