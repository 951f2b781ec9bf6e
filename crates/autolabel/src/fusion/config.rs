//! Fusion parameters, a TOML file (`pi3det fuse --config`). The defaults are MS3D++'s published
//! settings (its `ps_config.yaml`, `ENSEMBLE_KBF` and `PS_SCORE_TH.NEG_TH`, and the bandwidths of
//! its `kbf`).

use serde::{Deserialize, Serialize};

use crate::AutolabelError;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FusionConfig {
    /// Detections with a score at or below this are dropped before anything else (MS3D++ 0.1).
    pub min_score: f64,
    pub bandwidth: Bandwidths,
    /// Grid of the 1-D size and score peaks: this many values from the members' min to max.
    pub grid_points: usize,
    /// Below this determinant of the centres' sample covariance the centre is found in x/y and
    /// z separately (a flat cluster makes the 3-D density singular).
    pub flat_cluster_det: f64,
    pub classes: Vec<ClassFusion>,
}

/// scipy `bw_method` factors (unitless multiples of the members' own spread).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Bandwidths {
    /// Weighted density of the centres; the densest member is the fused centre.
    pub centre: f64,
    /// Unweighted density of each of dx, dy, dz; its peak is the fused size.
    pub size: f64,
    /// Weighted density of sin(heading); the densest member's heading is kept.
    pub heading: f64,
    /// Weighted density of the scores; its peak is the fused score.
    pub score: f64,
}

/// One class: the names detectors may give it and how its boxes are clustered.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassFusion {
    /// The fused boxes' class name.
    pub name: String,
    /// Other detector class names mapped to this class (MS3D++'s super-categories).
    #[serde(default)]
    pub aliases: Vec<String>,
    /// Detections of this class with a score at or below this are dropped (MS3D++ `NEG_TH`).
    pub score_threshold: f64,
    /// Ball-query radius on 3-D centres, metres (`RADIUS`).
    pub radius_m: f64,
    /// A cluster needs this many members at as many distinct centres (`DISCARD`).
    pub min_members: usize,
    /// Rotated BEV NMS over the fused boxes: suppressed above this IoU (`NMS`).
    pub nms_iou: f64,
}

impl Default for Bandwidths {
    fn default() -> Self {
        Self { centre: 1.0, size: 2.0, heading: 0.1, score: 2.0 }
    }
}

impl Default for FusionConfig {
    fn default() -> Self {
        let class = |name: &str, aliases: &[&str], score_threshold, radius_m, nms_iou| ClassFusion {
            name: name.into(),
            aliases: aliases.iter().map(|s| s.to_string()).collect(),
            score_threshold,
            radius_m,
            min_members: 4,
            nms_iou,
        };
        Self {
            min_score: 0.1,
            bandwidth: Bandwidths::default(),
            grid_points: 100,
            flat_cluster_det: 1e-7,
            classes: vec![
                class("Car", &["Vehicle", "car", "vehicle", "truck", "bus", "Van", "Truck"], 0.2, 1.5, 0.1),
                class("Pedestrian", &["pedestrian", "Person_sitting"], 0.1, 0.3, 0.3),
                class("Cyclist", &["bicycle", "motorcycle", "cyclist"], 0.3, 0.2, 0.1),
            ],
        }
    }
}

impl FusionConfig {
    pub fn from_toml_str(text: &str) -> Result<Self, AutolabelError> {
        let cfg: Self = toml::from_str(text).map_err(|e| AutolabelError::Config(e.to_string()))?;
        cfg.validate()?;
        Ok(cfg)
    }

    pub fn from_file(path: &std::path::Path) -> Result<Self, AutolabelError> {
        let text = std::fs::read_to_string(path).map_err(|e| AutolabelError::io(path, e))?;
        Self::from_toml_str(&text).map_err(|e| AutolabelError::invalid(path, e.to_string()))
    }

    pub fn validate(&self) -> Result<(), AutolabelError> {
        let bad = |m: String| Err(AutolabelError::Config(m));
        let b = &self.bandwidth;
        if [b.centre, b.size, b.heading, b.score].iter().any(|v| !(v.is_finite() && *v > 0.0)) {
            return bad(format!("bandwidths must be positive: {b:?}"));
        }
        if !(2..=100_000).contains(&self.grid_points) {
            return bad(format!("grid_points must be in 2..=100000, not {}", self.grid_points));
        }
        let mut seen = std::collections::BTreeSet::new();
        for c in &self.classes {
            if !(c.radius_m.is_finite() && c.radius_m > 0.0) {
                return bad(format!("class {}: radius_m must be positive", c.name));
            }
            if c.min_members == 0 {
                return bad(format!("class {}: min_members must be at least 1", c.name));
            }
            for n in std::iter::once(&c.name).chain(&c.aliases) {
                if !seen.insert(n.as_str()) {
                    return bad(format!("class name {n:?} is given to two classes"));
                }
            }
        }
        Ok(())
    }

    /// The class a detector's class name belongs to.
    pub fn class_index(&self, name: &str) -> Option<usize> {
        self.classes.iter().position(|c| c.name == name || c.aliases.iter().any(|a| a == name))
    }

    /// Every name the classes accept, for error messages.
    pub fn known_names(&self) -> Vec<&str> {
        self.classes
            .iter()
            .flat_map(|c| std::iter::once(c.name.as_str()).chain(c.aliases.iter().map(String::as_str)))
            .collect()
    }
}
