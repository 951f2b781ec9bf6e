//! Evaluation classes: the reference's IoU threshold table, its neighbour-class rule and the
//! mapping from dataset names to KITTI names.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Minimum overlaps of one class for the metrics `[bbox, bev, 3d]`, in the reference's two sets.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Overlaps {
    pub strict: [f64; 3],
    pub loose: [f64; 3],
}

impl Overlaps {
    pub fn sets(&self) -> [[f64; 3]; 2] {
        [self.strict, self.loose]
    }
}

const CAR: Overlaps = Overlaps { strict: [0.7, 0.7, 0.7], loose: [0.7, 0.5, 0.5] };
const PED: Overlaps = Overlaps { strict: [0.5, 0.5, 0.5], loose: [0.5, 0.25, 0.25] };
const TRUCK: Overlaps = Overlaps { strict: [0.7, 0.7, 0.7], loose: [0.5, 0.5, 0.5] };

/// OpenPCDet's `get_official_eval_result` table (mmdet3d has the first five columns).
pub fn default_overlaps(class: &str) -> Option<Overlaps> {
    match class.to_ascii_lowercase().as_str() {
        "car" | "van" => Some(CAR),
        "pedestrian" | "cyclist" | "person_sitting" => Some(PED),
        "truck" => Some(TRUCK),
        _ => None,
    }
}

/// Classes whose ground truths are ignored (neither TP nor FN, but they consume detections) when
/// evaluating another class: `(evaluated, neighbour)`, lower case, as `clean_data` hard-codes them.
pub const NEIGHBOURS: [(&str, &str); 2] = [("car", "van"), ("pedestrian", "person_sitting")];

pub fn is_neighbour(class_lc: &str, gt_name_lc: &str) -> bool {
    NEIGHBOURS.iter().any(|&(c, n)| c == class_lc && n == gt_name_lc)
}

/// Classes evaluated when none are asked for: those of these that occur in the ground truth.
pub const DEFAULT_CLASSES: [&str; 3] = ["Car", "Pedestrian", "Cyclist"];

/// The default dataset → KITTI name mapping (Pi3DET and Waymo say Vehicle).
pub fn default_name_map() -> BTreeMap<String, String> {
    BTreeMap::from([("Vehicle".to_string(), "Car".to_string())])
}

/// Maps names with keys compared case-insensitively; unmapped names pass through unchanged.
#[derive(Debug, Clone, Default)]
pub struct NameMap {
    lower: BTreeMap<String, String>,
}

impl NameMap {
    pub fn new(map: &BTreeMap<String, String>) -> Self {
        Self { lower: map.iter().map(|(k, v)| (k.to_ascii_lowercase(), v.clone())).collect() }
    }

    pub fn map(&self, name: &str) -> String {
        self.lower.get(&name.to_ascii_lowercase()).cloned().unwrap_or_else(|| name.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_and_neighbours() {
        assert_eq!(default_overlaps("CAR").unwrap().loose, [0.7, 0.5, 0.5]);
        assert_eq!(default_overlaps("Pedestrian").unwrap().loose, [0.5, 0.25, 0.25]);
        assert!(default_overlaps("Sign").is_none());
        assert!(is_neighbour("car", "van") && !is_neighbour("van", "car"));
        let m = NameMap::new(&default_name_map());
        assert_eq!(m.map("vehicle"), "Car");
        assert_eq!(m.map("Cyclist"), "Cyclist");
    }
}
