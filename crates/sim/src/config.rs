//! The whole simulator configuration, as TOML. Every number has a default; a TOML file only needs
//! the values it changes (it is merged over the defaults, platform presets included), and unknown
//! keys are errors so typos do not pass silently.

use std::path::Path;

use pi3det_data::Platform;
use serde::{Deserialize, Serialize};

use crate::actors::ActorConfig;
use crate::platform::PlatformConfig;
use crate::scene::SceneConfig;
use crate::sensor::SensorConfig;
use crate::SimError;

/// Which boxes become labels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LabelConfig {
    /// Keep a box only with at least this many points inside (counted with the stored box).
    pub min_points: u32,
    /// Keep a box only if its centre is within this BEV distance of the sensor; 0 means the
    /// sensor's maximum range.
    pub max_range_m: f64,
    /// An actor whose box (grown by this much) contains the sensor is left out of that frame, so no
    /// one walks or drives through the platform.
    pub hide_clearance_m: f64,
}

impl Default for LabelConfig {
    fn default() -> Self {
        Self { min_points: 5, max_range_m: 0.0, hide_clearance_m: 0.5 }
    }
}

/// Domain randomisation across sequences: what each sequence draws instead of the fixed setting.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RandomiseConfig {
    /// Sensor presets (`SensorPreset::parse` names: `os1-64`, `hdl-64`, `vlp-32c`, …); each
    /// sequence is recorded with one of them, drawn from the seed and its index. Empty: every
    /// sequence uses `sensor`.
    pub sensors: Vec<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    pub sensor: SensorConfig,
    pub randomise: RandomiseConfig,
    pub scene: SceneConfig,
    pub actors: ActorConfig,
    pub labels: LabelConfig,
    pub vehicle: PlatformConfig,
    pub drone: PlatformConfig,
    pub quadruped: PlatformConfig,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            sensor: SensorConfig::default(),
            randomise: RandomiseConfig::default(),
            scene: SceneConfig::default(),
            actors: ActorConfig::default(),
            labels: LabelConfig::default(),
            vehicle: PlatformConfig::vehicle(),
            drone: PlatformConfig::drone(),
            quadruped: PlatformConfig::quadruped(),
        }
    }
}

impl SimConfig {
    pub fn platform(&self, p: Platform) -> Result<&PlatformConfig, SimError> {
        match p {
            Platform::Vehicle => Ok(&self.vehicle),
            Platform::Drone => Ok(&self.drone),
            Platform::Quadruped => Ok(&self.quadruped),
            Platform::Unknown => Err(SimError::invalid("platform must be vehicle, drone or quadruped")),
        }
    }

    /// The label range in metres (the sensor range when `labels.max_range_m` is 0).
    pub fn label_range_m(&self) -> f64 {
        if self.labels.max_range_m > 0.0 {
            self.labels.max_range_m
        } else {
            self.sensor.range_max_m
        }
    }

    pub fn validate(&self) -> Result<(), SimError> {
        self.sensor.validate()?;
        for name in &self.randomise.sensors {
            crate::sensor::SensorPreset::parse(name)
                .map_err(|e| SimError::invalid(format!("randomise.sensors: {e}")))?;
        }
        self.scene.validate()?;
        self.actors.validate()?;
        self.vehicle.validate("vehicle")?;
        self.drone.validate("drone")?;
        self.quadruped.validate("quadruped")?;
        Ok(())
    }

    /// Parses TOML holding only the values to change.
    /// The configuration sequence `index` of a simulation seeded `seed` is rendered with: this one,
    /// with the sensor drawn from `randomise.sensors` when it lists any (the same seed and index
    /// always draw the same sensor, so splits stay reproducible).
    pub fn for_sequence(&self, seed: u64, index: u32) -> Result<SimConfig, SimError> {
        if self.randomise.sensors.is_empty() {
            return Ok(self.clone());
        }
        // SplitMix64 of (seed, index): independent of the sequence's own random stream.
        let mut z =
            seed.wrapping_add(0x9E37_79B9_7F4A_7C15).wrapping_add(u64::from(index).wrapping_mul(0xBF58_476D_1CE4_E5B9));
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        let name = &self.randomise.sensors[(z % self.randomise.sensors.len() as u64) as usize];
        let preset = crate::sensor::SensorPreset::parse(name)?;
        Ok(SimConfig { sensor: preset.config(), ..self.clone() })
    }

    pub fn from_toml_str(text: &str) -> Result<Self, String> {
        let user: toml::Table = toml::from_str(text).map_err(|e| e.to_string())?;
        let mut merged = toml::Table::try_from(Self::default()).map_err(|e| e.to_string())?;
        merge(&mut merged, user);
        let cfg: Self = merged.try_into().map_err(|e: toml::de::Error| e.to_string())?;
        Ok(cfg)
    }

    pub fn load(path: &Path) -> Result<Self, SimError> {
        let text = std::fs::read_to_string(path).map_err(|source| SimError::Io { path: path.to_path_buf(), source })?;
        let cfg =
            Self::from_toml_str(&text).map_err(|message| SimError::Config { path: path.to_path_buf(), message })?;
        cfg.validate().map_err(|e| SimError::Config { path: path.to_path_buf(), message: e.to_string() })?;
        Ok(cfg)
    }

    /// The full configuration as TOML (a starting point for a config file).
    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# cannot serialise configuration: {e}\n"))
    }
}

/// Overlays `user` on `base`, table by table.
fn merge(base: &mut toml::Table, user: toml::Table) {
    for (k, v) in user {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(u)) => merge(b, u),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pedestrian_groups_out_of_range_are_refused() {
        for bad in [
            "pedestrian_group_share = 1.5",
            "pedestrian_group_size = [3, 1]",
            "pedestrian_group_spacing_m = [0.2, 0.4]",
        ] {
            let cfg = SimConfig::from_toml_str(&format!("[actors]\n{bad}\n")).unwrap();
            let e = cfg.validate().unwrap_err().to_string();
            assert!(e.contains("actors.pedestrian_group"), "{bad}: {e}");
        }
        let ok = SimConfig::from_toml_str("[actors]\npedestrian_group_share = 0.3\n").unwrap();
        assert!(ok.validate().is_ok());
    }

    #[test]
    fn partial_toml_keeps_platform_presets() {
        let cfg =
            SimConfig::from_toml_str("[drone]\nsensor_height_m = [10.0, 12.0]\n[sensor]\ncolumns = 512\n").unwrap();
        assert_eq!(cfg.drone.sensor_height_m, [10.0, 12.0]);
        assert_eq!(cfg.drone.jitter_std_deg, PlatformConfig::drone().jitter_std_deg);
        assert_eq!(cfg.quadruped, PlatformConfig::quadruped());
        assert_eq!(cfg.sensor.columns, 512);
        assert_eq!(cfg.sensor.beams, 64);
    }

    #[test]
    fn unknown_keys_are_rejected_and_defaults_round_trip() {
        assert!(SimConfig::from_toml_str("[sensor]\ncolumnz = 512\n").is_err());
        let text = SimConfig::default().to_toml_string();
        assert_eq!(SimConfig::from_toml_str(&text).unwrap(), SimConfig::default());
        SimConfig::default().validate().unwrap();
    }

    #[test]
    fn randomised_sensors_are_drawn_per_sequence_and_reproducibly() {
        let cfg = SimConfig {
            randomise: RandomiseConfig { sensors: vec!["os1-64".into(), "hdl-64".into(), "vlp-32c".into()] },
            ..SimConfig::default()
        };
        cfg.validate().unwrap();
        let names: Vec<String> = (0..30).map(|i| cfg.for_sequence(7, i).unwrap().sensor.name).collect();
        for n in ["os1-64", "hdl-64", "vlp-32c"] {
            assert!(names.iter().filter(|m| *m == n).count() >= 4, "{n}: {names:?}");
        }
        let again: Vec<String> = (0..30).map(|i| cfg.for_sequence(7, i).unwrap().sensor.name).collect();
        assert_eq!(names, again);
        assert_eq!(SimConfig::default().for_sequence(7, 3).unwrap(), SimConfig::default());
        let bad =
            SimConfig { randomise: RandomiseConfig { sensors: vec!["lidar-9000".into()] }, ..SimConfig::default() };
        assert!(bad.validate().unwrap_err().to_string().contains("randomise.sensors"));
    }
}
