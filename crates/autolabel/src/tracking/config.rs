//! Tracking parameters, a TOML file (`pi3det track --config`). Association, birth and death
//! defaults are MS3D++'s published SimpleTrack settings (`TRACKING.VEH_ALL` / `PEDESTRIAN`),
//! the refinement ones its `TEMPORAL_REFINEMENT`, except the car score gates (see below).

use serde::{Deserialize, Serialize};

use crate::AutolabelError;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackingConfig {
    pub classes: Vec<TrackClass>,
    /// Fill frames a confirmed track missed (between two observations) by interpolation, for
    /// gaps of at most this many frames; 0 turns it off.
    pub max_interpolated_gap: usize,
    pub static_objects: StaticRefinement,
    /// Every box of a track gets `(1 − w)·own + w·track mean` as score (0 keeps own scores).
    pub score_smoothing: f64,
}

/// Per class: which detections track, how tracks associate, are born and die.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackClass {
    /// Class name of the detections (exact) and the tracks.
    pub name: String,
    /// Detections below this score do not take part (`RUNNING.SCORE_TH`).
    pub min_score: f64,
    /// A detection and a predicted track associate when their BEV GIoU exceeds this
    /// (SimpleTrack's distance `1 − GIoU < ASSO_TH`: 1.3 → −0.3).
    pub min_giou: f64,
    /// A track is output once it has been observed this many times (`MIN_HITS_TO_BIRTH`).
    pub min_hits: usize,
    /// A track ends after this many frames without an observation (`MAX_AGE_SINCE_UPDATE`).
    pub max_misses: usize,
    /// A track is kept only with at least this many observations scoring `confident_score` or
    /// more (`MIN_DETS_ABOVE_POS_TH_FOR_TRACKS_*`; 0 keeps all).
    pub min_confident_hits: usize,
    pub confident_score: f64,
}

/// Tracks that do not move are one object seen many times: their boxes are fused over a
/// window (MS3D++'s rolling KBF), which steadies size and position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StaticRefinement {
    pub enabled: bool,
    /// Static when the first and last centre are closer than this (m)…
    pub max_travel_m: f64,
    /// …and the mean variance of the x and y centres is below this (m²).
    pub max_centre_variance_m2: f64,
    /// Observations on each side of a frame fused into its box.
    pub half_window: usize,
    /// Static tracks need at least this many observations (`MIN_NUM_STATIC_VEH_TRACKS`).
    pub min_observations: usize,
}

impl Default for StaticRefinement {
    fn default() -> Self {
        Self { enabled: true, max_travel_m: 1.0, max_centre_variance_m2: 0.1, half_window: 5, min_observations: 7 }
    }
}

impl Default for TrackingConfig {
    fn default() -> Self {
        let class = |name: &str, min_score, min_giou, min_confident_hits, confident_score| TrackClass {
            name: name.into(),
            min_score,
            min_giou,
            min_hits: 2,
            max_misses: 2,
            min_confident_hits,
            confident_score,
        };
        Self {
            // Car: MS3D++ starts tracks at score 0.5 and keeps those with 3 boxes ≥ 0.7; on
            // `pi3det bench autolabel` that dropped every far car (results/2026-12-01-autolabel.md).
            classes: vec![
                class("Car", 0.3, -0.3, 1, 0.5),
                class("Pedestrian", 0.2, -0.5, 1, 0.6),
                class("Cyclist", 0.2, -0.5, 1, 0.5),
            ],
            max_interpolated_gap: 5,
            static_objects: StaticRefinement::default(),
            score_smoothing: 0.5,
        }
    }
}

impl TrackingConfig {
    pub fn from_file(path: &std::path::Path) -> Result<Self, AutolabelError> {
        let text = std::fs::read_to_string(path).map_err(|e| AutolabelError::io(path, e))?;
        let cfg: Self = toml::from_str(&text).map_err(|e| AutolabelError::invalid(path, e.to_string()))?;
        cfg.validate().map_err(|e| AutolabelError::invalid(path, e.to_string()))?;
        Ok(cfg)
    }

    pub fn validate(&self) -> Result<(), AutolabelError> {
        let bad = |m: String| Err(AutolabelError::Config(m));
        for c in &self.classes {
            if c.min_hits == 0 {
                return bad(format!("class {}: min_hits must be at least 1", c.name));
            }
            if !(-1.0..=1.0).contains(&c.min_giou) {
                return bad(format!("class {}: min_giou must be in [-1, 1]", c.name));
            }
        }
        if !(0.0..=1.0).contains(&self.score_smoothing) {
            return bad("score_smoothing must be in [0, 1]".into());
        }
        Ok(())
    }
}
