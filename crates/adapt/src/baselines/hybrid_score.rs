//! ST3D++'s hybrid quality-aware criterion (Yang et al. 2022, §3.2.1): a pseudo-label's quality
//! is `w_iou·σ(iou_logit) + w_cls·σ(cls_logit)`, the IoU branch weighted more for classes whose
//! boxes are the hard part (car 0.8 / 0.2) and evenly for pedestrians (0.5 / 0.5). Our two-stage
//! detectors expose both parts as probabilities (`post.score_fusion = "hybrid"`).

use serde::{Deserialize, Serialize};

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// Weights of the two criteria for one class.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HybridWeights {
    pub w_iou: f64,
    pub w_cls: f64,
}

impl HybridWeights {
    /// ST3D++'s weights for a class name (car-like 0.8/0.2, others 0.5/0.5).
    pub fn for_class(name: &str) -> Self {
        match name.to_ascii_lowercase().as_str() {
            "car" | "vehicle" | "truck" | "bus" => Self { w_iou: 0.8, w_cls: 0.2 },
            _ => Self { w_iou: 0.5, w_cls: 0.5 },
        }
    }

    /// The hybrid score of raw logits.
    pub fn of_logits(&self, iou_logit: f64, cls_logit: f64) -> f64 {
        self.of_probabilities(sigmoid(iou_logit), sigmoid(cls_logit))
    }

    /// The hybrid score of probabilities already through the sigmoid.
    pub fn of_probabilities(&self, iou: f64, cls: f64) -> f64 {
        self.w_iou * iou + self.w_cls * cls
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hybrid_of_logits_and_probabilities() {
        let car = HybridWeights::for_class("Car");
        assert_eq!((car.w_iou, car.w_cls), (0.8, 0.2));
        // σ(0) = 0.5, σ(ln 3) = 0.75.
        assert!((car.of_logits(0.0, 3f64.ln()) - (0.8 * 0.5 + 0.2 * 0.75)).abs() < 1e-12);
        let ped = HybridWeights::for_class("Pedestrian");
        assert!((ped.of_probabilities(0.2, 0.6) - 0.4).abs() < 1e-12);
    }
}
