//! Per-class anchors on the head's feature map (SECOND / PointPillars; OpenPCDet
//! `AnchorGenerator`, with anchors at cell centres). Order: row (y), column (x), class, rotation —
//! the order in which the anchor head's 1×1 convolution outputs are flattened.

use pi3det_geometry::Box3d;
use serde::{Deserialize, Serialize};
use tch::Tensor;

use crate::error::{NnError, Result};

/// Anchors and matching thresholds of one class.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnchorClassConfig {
    pub class: String,
    /// `[dx, dy, dz]` in metres, or a list of them (a Car class that also holds vans and buses
    /// needs more than one: a 12 m bus overlaps a 4.8 m anchor by IoU 0.35, below any matching
    /// threshold).
    pub size: AnchorSizes,
    /// z of the anchor's bottom face (after the config's z shift).
    pub bottom_z: f64,
    #[serde(default = "default_rotations")]
    pub rotations: Vec<f64>,
    /// Anchors with (nearest-BEV) IoU ≥ this are positives…
    pub matched_threshold: f64,
    /// …and below this negatives; in between they are ignored.
    pub unmatched_threshold: f64,
}

/// One anchor size or several.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum AnchorSizes {
    One([f64; 3]),
    Many(Vec<[f64; 3]>),
}

impl AnchorSizes {
    pub fn as_slice(&self) -> &[[f64; 3]] {
        match self {
            Self::One(s) => std::slice::from_ref(s),
            Self::Many(v) => v,
        }
    }
}

impl From<[f64; 3]> for AnchorSizes {
    fn from(s: [f64; 3]) -> Self {
        Self::One(s)
    }
}

fn default_rotations() -> Vec<f64> {
    vec![0.0, std::f64::consts::FRAC_PI_2]
}

impl AnchorClassConfig {
    pub fn validate(&self) -> Result<()> {
        let sizes = self.size.as_slice();
        let bad = sizes.is_empty()
            || sizes.iter().flatten().any(|v| !v.is_finite() || *v <= 0.0)
            || self.rotations.is_empty()
            || self.rotations.iter().any(|r| !r.is_finite())
            || !self.bottom_z.is_finite()
            || !(0.0..=1.0).contains(&self.matched_threshold)
            || !(0.0..=1.0).contains(&self.unmatched_threshold)
            || self.unmatched_threshold > self.matched_threshold;
        if bad {
            return Err(NnError::config(
                "head.anchors",
                format!(
                    "anchors of {}: need positive sizes, finite bottom_z and rotations, 0 ≤ unmatched ≤ matched ≤ 1",
                    self.class
                ),
            ));
        }
        Ok(())
    }
}

/// The anchors of a feature map.
#[derive(Debug, Clone)]
pub struct Anchors {
    /// `[H·W·A]` boxes in the order described in the module docs.
    pub boxes: Vec<Box3d>,
    /// Class index (into the config's class list) of each anchor slot `0..A`.
    pub slot_class: Vec<usize>,
    /// Anchors per location.
    pub per_location: usize,
    pub h: usize,
    pub w: usize,
    /// Feature cell size and the map's origin (the grid's min corner).
    pub cell: [f64; 2],
    pub origin: [f64; 2],
}

impl Anchors {
    /// `classes`: the anchor configs, already mapped to class indices.
    pub fn generate(
        per_class: &[(usize, AnchorClassConfig)],
        h: usize,
        w: usize,
        cell: [f64; 2],
        origin: [f64; 2],
    ) -> Self {
        let mut slots: Vec<(usize, Box3d)> = Vec::new();
        for (class, c) in per_class {
            for size in c.size.as_slice() {
                for &r in &c.rotations {
                    let b = Box3d::new(0.0, 0.0, c.bottom_z + 0.5 * size[2], size[0], size[1], size[2], r);
                    slots.push((*class, b));
                }
            }
        }
        let a = slots.len();
        let mut boxes = Vec::with_capacity(h * w * a);
        for iy in 0..h {
            let y = origin[1] + (iy as f64 + 0.5) * cell[1];
            for ix in 0..w {
                let x = origin[0] + (ix as f64 + 0.5) * cell[0];
                for (_, s) in &slots {
                    boxes.push(Box3d { x, y, ..*s });
                }
            }
        }
        Self { boxes, slot_class: slots.iter().map(|s| s.0).collect(), per_location: a, h, w, cell, origin }
    }

    pub fn len(&self) -> usize {
        self.boxes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.boxes.is_empty()
    }

    /// `[N, 7]` float tensor.
    pub fn to_tensor(&self) -> Tensor {
        let flat: Vec<f32> = self.boxes.iter().flat_map(|b| b.to_array().map(|v| v as f32)).collect();
        Tensor::from_slice(&flat).view([self.boxes.len() as i64, 7])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_order() {
        let car = AnchorClassConfig {
            class: "Car".into(),
            size: [4.0, 2.0, 1.5].into(),
            bottom_z: -1.0,
            rotations: default_rotations(),
            matched_threshold: 0.6,
            unmatched_threshold: 0.45,
        };
        let ped = AnchorClassConfig {
            class: "Pedestrian".into(),
            size: [0.8, 0.6, 1.7].into(),
            rotations: vec![0.0],
            ..car.clone()
        };
        let a = Anchors::generate(&[(0, car), (1, ped)], 2, 3, [1.0, 2.0], [-1.0, 0.0]);
        assert_eq!(a.len(), 2 * 3 * 3);
        assert_eq!(a.slot_class, vec![0, 0, 1]);
        // Row 1, column 2, slot 1 (car at 90°).
        let b = a.boxes[(3 + 2) * 3 + 1];
        assert_eq!((b.x, b.y, b.z, b.heading), (1.5, 3.0, -0.25, std::f64::consts::FRAC_PI_2));
        assert_eq!(a.to_tensor().size(), vec![18, 7]);
    }

    #[test]
    fn several_sizes_per_class_each_get_every_rotation() {
        let car = AnchorClassConfig {
            class: "Car".into(),
            size: AnchorSizes::Many(vec![[4.8, 2.1, 1.7], [11.0, 2.6, 3.2]]),
            bottom_z: 0.0,
            rotations: default_rotations(),
            matched_threshold: 0.6,
            unmatched_threshold: 0.45,
        };
        car.validate().unwrap();
        let a = Anchors::generate(&[(0, car.clone())], 1, 1, [1.0, 1.0], [0.0, 0.0]);
        assert_eq!(a.per_location, 4);
        assert_eq!(a.boxes.iter().map(|b| (b.dx, b.heading)).collect::<Vec<_>>()[2], (11.0, 0.0));
        assert_eq!(a.boxes[3].z, 1.6, "bottom on bottom_z");
        // A TOML list of sizes and a single size both parse.
        let one: AnchorClassConfig = toml::from_str(
            "class = \"Car\"\nsize = [4.2, 2.0, 1.6]\nbottom_z = 0.0\nmatched_threshold = 0.6\nunmatched_threshold = 0.45",
        )
        .unwrap();
        assert_eq!(one.size.as_slice().len(), 1);
        let bad = AnchorClassConfig { size: AnchorSizes::Many(vec![]), ..car };
        assert!(bad.validate().is_err());
    }
}
