//! What a user can choose about an evaluation (serde, so configs and `--json` can carry it).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::classes::{default_name_map, default_overlaps, Overlaps, DEFAULT_CLASSES};
use crate::error::EvalError;
use crate::protocol::ClassSpec;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvalOptions {
    /// KITTI class names to evaluate (after `name_map`). Empty: those of Car, Pedestrian and
    /// Cyclist that occur in the ground truth (Car when none does).
    pub classes: Vec<String>,
    /// Drop detections scoring below this before evaluating (the paper reports with 0.2; the
    /// reference itself has no threshold).
    pub score_threshold: Option<f64>,
    /// Keep only ground truths and detections whose BEV centre (LiDAR frame) lies inside
    /// `[x_min, y_min, x_max, y_max]`, bounds included. DontCare regions are kept.
    pub bev_range: Option<[f64; 4]>,
    /// Dataset name → KITTI name, keys compared case-insensitively, applied to ground truth and
    /// detections alike. Default: Vehicle → Car.
    pub name_map: BTreeMap<String, String>,
    /// Minimum overlaps per class, overriding or extending the reference's table (Car, Van,
    /// Truck, Pedestrian, Person_sitting, Cyclist).
    pub overlaps: BTreeMap<String, Overlaps>,
    /// Also evaluate each platform on its own when the frames come from several.
    pub per_platform: bool,
    /// Also evaluate each sequence on its own when the frames come from several.
    pub per_sequence: bool,
    /// Image size `[width, height]` used to clip the projected 2D box of a LiDAR detection on a
    /// KITTI frame when the detection file carries no `bbox` (OpenPCDet clips to each frame's
    /// image; KITTI images are 1224–1242 × 370–376 px).
    pub image_size: [f64; 2],
    /// Detection frames whose id is not in the ground truth are an error unless this is set
    /// (then they are skipped).
    pub allow_unknown_frames: bool,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            classes: Vec::new(),
            score_threshold: None,
            bev_range: None,
            name_map: default_name_map(),
            overlaps: BTreeMap::new(),
            per_platform: true,
            per_sequence: true,
            image_size: [1242.0, 375.0],
            allow_unknown_frames: false,
        }
    }
}

impl EvalOptions {
    /// The paper's setting: score threshold 0.2, everything else as the reference.
    pub fn paper() -> Self {
        Self { score_threshold: Some(0.2), ..Self::default() }
    }

    pub fn validate(&self) -> Result<(), EvalError> {
        if let Some(t) = self.score_threshold {
            if !t.is_finite() {
                return Err(EvalError::Option(format!("score threshold {t} is not finite")));
            }
        }
        if let Some(r) = self.bev_range {
            if r.iter().any(|v| v.is_nan()) || r[0] > r[2] || r[1] > r[3] {
                return Err(EvalError::Option(format!(
                    "BEV range {r:?} must be [x_min, y_min, x_max, y_max] with min ≤ max"
                )));
            }
        }
        if !(self.image_size.iter().all(|v| v.is_finite() && *v >= 1.0)) {
            return Err(EvalError::Option(format!("image size {:?} must be two sizes ≥ 1 px", self.image_size)));
        }
        Ok(())
    }

    /// The classes to evaluate with their overlaps; `present` are the (mapped) ground-truth
    /// names, used when no classes were asked for.
    pub fn class_specs<'a>(&self, present: impl IntoIterator<Item = &'a str>) -> Result<Vec<ClassSpec>, EvalError> {
        let names: Vec<String> = if self.classes.is_empty() {
            let present: Vec<String> = present.into_iter().map(str::to_lowercase).collect();
            let found: Vec<String> = DEFAULT_CLASSES
                .iter()
                .filter(|c| present.iter().any(|p| *p == c.to_lowercase()))
                .map(|c| c.to_string())
                .collect();
            if found.is_empty() {
                vec![DEFAULT_CLASSES[0].to_string()]
            } else {
                found
            }
        } else {
            self.classes.clone()
        };
        let mut specs: Vec<ClassSpec> = Vec::new();
        for name in names {
            if specs.iter().any(|s| s.name.eq_ignore_ascii_case(&name)) {
                continue;
            }
            let custom = self.overlaps.iter().find(|(k, _)| k.eq_ignore_ascii_case(&name)).map(|(_, v)| *v);
            let overlaps = custom.or_else(|| default_overlaps(&name)).ok_or_else(|| {
                EvalError::Option(format!(
                    "class {name:?} has no IoU thresholds in the KITTI table; give them (overlaps.{name} = {{ strict = [bbox, bev, 3d], loose = [...] }})"
                ))
            })?;
            for v in overlaps.strict.iter().chain(&overlaps.loose) {
                if !(0.0..=1.0).contains(v) {
                    return Err(EvalError::Option(format!("class {name}: min overlap {v} is not in [0, 1]")));
                }
            }
            specs.push(ClassSpec { name, overlaps });
        }
        Ok(specs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_classes_follow_the_ground_truth() {
        let o = EvalOptions::default();
        let s = o.class_specs(["car", "Pedestrian", "Van"]).unwrap();
        assert_eq!(s.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["Car", "Pedestrian"]);
        assert_eq!(o.class_specs([]).unwrap()[0].name, "Car");
        let o = EvalOptions { classes: vec!["Sign".into()], ..EvalOptions::default() };
        assert!(o.class_specs([]).unwrap_err().to_string().contains("Sign"));
    }

    #[test]
    fn options_round_trip_and_validate() {
        let o = EvalOptions::paper();
        let j = serde_json::to_string(&o).unwrap();
        assert_eq!(serde_json::from_str::<EvalOptions>(&j).unwrap(), o);
        let partial: EvalOptions = serde_json::from_str(r#"{"classes": ["Car"]}"#).unwrap();
        assert_eq!(partial.name_map.get("Vehicle").map(String::as_str), Some("Car"));
        assert!(EvalOptions { bev_range: Some([1.0, 0.0, 0.0, 1.0]), ..o.clone() }.validate().is_err());
        assert!(o.validate().is_ok());
    }
}
